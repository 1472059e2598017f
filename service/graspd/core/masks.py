"""Binary image masks run-length encoded as COCO writes them (pycocotools): the image read column by column
(column-major), counts alternating between runs of 0 and runs of 1, starting with 0; either a list of counts or
pycocotools' compressed string (6-bit characters from '0', deltas between runs two apart).  Decoded into one flag
per pixel in row-major order, the order of an organised cloud's rows."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from graspd.core.errors import FieldError


def rle_string_counts(text: str, field: str = "counts") -> NDArray[np.int64]:
    """The run lengths of pycocotools' compressed counts string (vectorised: no Python loop per character).
    FieldError naming field when a character is out of range or a value is cut off."""
    raw = np.frombuffer(text.encode("ascii", errors="replace"), np.uint8).astype(np.int64) - 48
    if len(raw) == 0:
        return np.zeros(0, np.int64)
    if raw.min() < 0 or raw.max() > 63:
        raise FieldError(field, "not a COCO RLE string (characters '0' to 'o' expected)")
    more = (raw & 0x20) != 0
    if more[-1]:
        raise FieldError(field, "not a COCO RLE string (the last value is cut off)")
    ends = np.flatnonzero(~more)
    starts = np.concatenate([[0], ends[:-1] + 1])
    value_of = np.repeat(np.arange(len(ends)), ends - starts + 1)
    shift = 5 * (np.arange(len(raw)) - starts[value_of])
    if shift.max() > 55:
        raise FieldError(field, "not a COCO RLE string (a value of more than 12 characters)")
    values = np.bincount(value_of, (raw & 0x1F) << shift, len(ends)).astype(np.int64)
    negative = (raw[ends] & 0x10) != 0  # sign bit of the last character: extend it
    values[negative] -= np.left_shift(np.int64(1), 5 * (ends - starts + 1)[negative])
    counts = values.copy()  # from the fourth run on, each is a delta to the run two before
    if len(counts) > 3:
        counts[3::2] = np.cumsum(values[1::2])[1:]
        counts[4::2] = values[2] + np.cumsum(values[4::2])
    return counts


def rle_decode(counts: NDArray[np.integer], height: int, width: int, field: str = "counts") -> NDArray[np.bool_]:
    """One flag per pixel (height * width,), row-major, from column-major COCO run lengths; FieldError naming field
    when a run is negative or the runs do not add up to the image."""
    c = np.asarray(counts, np.int64).reshape(-1)
    if len(c) and c.min() < 0:
        raise FieldError(field, "run lengths must be >= 0")
    total = int(c.sum())
    if total != height * width:
        raise FieldError(field, f"the runs cover {total} pixels, the {height}x{width} image has {height * width}")
    column_major = np.repeat((np.arange(len(c)) % 2).astype(bool), c)
    out: NDArray[np.bool_] = np.ascontiguousarray(column_major.reshape(width, height).T).reshape(-1)
    return out
