"""Training rows: the images, labels and categories of a dataset's split part (read chunk by chunk, cached
across the models of a plan) and the robot's executed grasps from a feedback store."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, SQLAlchemyError

from graspd.gpd.images import REPRESENTATIONS
from graspd.store.database import StoreError
from graspd.store.outcomes import OutcomeStore
from graspd_lab.training.dataset import CATEGORIES, derive_images, read_manifest, read_split, split_mask


def load_rows(directory: str | Path, kind: str, part: str, representation: str,
              categories: list[str] | None = None, limit: int | None = None,
              seed: int = 0) -> tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.uint8]]:
    """(images (M,C,S,S) uint8 of a representation, labels (M,), categories (M,)) of one split part.

    Reads the small per-row arrays first, then the images chunk by chunk into one preallocated
    array, so the peak memory is the result plus one chunk; limit keeps a seeded random subset.
    """
    directory = Path(directory)
    manifest = read_manifest(directory)
    split = read_split(directory, kind)
    codes = None if categories is None else np.array([CATEGORIES[c] for c in categories], np.uint8)
    masks: list[NDArray[np.bool_]] = []
    for entry in manifest["chunks"]:
        with np.load(directory / entry["file"]) as z:
            mask = split_mask(z["object_ids"], z["view_ids"], split, part)
            if codes is not None:
                mask &= np.isin(z["categories"], codes)
            masks.append(mask)
    total = int(sum(m.sum() for m in masks))
    if total == 0:
        raise ValueError(f"split {kind!r} part {part!r} (categories {categories}) has no rows in {directory}")
    if limit is not None and limit < total:
        keep = np.zeros(total, bool)
        keep[np.random.default_rng(seed).choice(total, limit, replace=False)] = True
        start = 0
        for i, m in enumerate(masks):
            idx = np.flatnonzero(m)
            m = np.zeros_like(m)
            m[idx[keep[start : start + len(idx)]]] = True
            start += len(idx)
            masks[i] = m
        total = limit
    channels = REPRESENTATIONS[representation]
    size = int(manifest["image_size"])
    images = np.empty((total, channels, size, size), np.uint8)
    labels = np.empty(total, np.uint8)
    cats = np.empty(total, np.uint8)
    row = 0
    for entry, mask in zip(manifest["chunks"], masks, strict=True):
        n = int(mask.sum())
        if n == 0:
            continue
        with np.load(directory / entry["file"]) as z:
            images[row : row + n] = derive_images(z["images"][mask], representation)
            labels[row : row + n] = z["labels"][mask]
            cats[row : row + n] = z["categories"][mask]
        row += n
    return images, labels, cats


_RowKey = tuple[str, str, str, tuple[str, ...] | None, int | None, int]
_Rows = tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.uint8]]
_ROW_CACHE: dict[_RowKey, _Rows] | None = None


@contextmanager
def row_cache() -> Iterator[None]:
    """Within this block, training keeps the train and val rows it loaded last (15 channels) in memory, so
    consecutive models of a plan that differ only in representation or network read the dataset once."""
    global _ROW_CACHE
    _ROW_CACHE = {}
    try:
        yield
    finally:
        _ROW_CACHE = None


def training_rows(dataset: str, kind: str, part: str, categories: list[str] | None, limit: int | None,
                  seed: int) -> _Rows:
    """(15-channel images, labels, categories) of a split part, restricted to categories and to a seeded
    random subset of at most limit rows; served from the row cache when one is active (one entry per part)."""
    key: _RowKey = (str(Path(dataset).resolve()), kind, part, None if categories is None else tuple(categories),
                    limit, seed)
    if _ROW_CACHE is not None and key in _ROW_CACHE:
        return _ROW_CACHE[key]
    if _ROW_CACHE is not None:  # free the previous rows of this part before loading new ones
        for old in [k for k in _ROW_CACHE if k[2] == part]:
            del _ROW_CACHE[old]
    rows = load_rows(dataset, kind, part, "15", categories, limit, seed)
    if _ROW_CACHE is not None:
        _ROW_CACHE[key] = rows
    return rows


def feedback_rows(url: str, representation: str, image_size: int
                  ) -> tuple[NDArray[np.uint8], NDArray[np.uint8], dict[str, Any]]:
    """(images (M,C,S,S) uint8 of a representation, labels (M,): 1 = the grasp held, summary) of the executed
    grasps stored with their grasp image in a feedback store (graspd.store.outcomes, any SQLAlchemy URL).

    These are the robot's own outcomes (POST /feedback): real labels from the real sensor, added to the
    training rows.  15-channel images are derived to any representation; an image stored in another
    representation must match the one trained, and one of another size is skipped (counted in summary).
    """
    try:
        shown = make_url(url).render_as_string(hide_password=True)
    except ArgumentError as exc:
        raise ValueError(f"feedback: not a SQLAlchemy URL: {url!r} ({exc})") from exc
    channels = REPRESENTATIONS[representation]
    images: list[NDArray[np.uint8]] = []
    labels: list[int] = []
    skipped = 0
    try:
        rows = list(_stored_outcomes(url))
    except (SQLAlchemyError, StoreError) as exc:
        raise ValueError(f"feedback: cannot read the store {shown}: {exc}") from exc
    for row in rows:
        img, rep = row["image"], row["representation"]
        if img.ndim != 3 or img.shape[1:] != (image_size, image_size):
            skipped += 1
        elif rep == representation and img.shape[0] == channels:
            images.append(img)
            labels.append(int(row["success"]))
        elif rep == "15" and img.shape[0] == 15:
            images.append(derive_images(img[None], representation)[0])
            labels.append(int(row["success"]))
        else:
            skipped += 1
    x = np.stack(images) if images else np.zeros((0, channels, image_size, image_size), np.uint8)
    y = np.asarray(labels, np.uint8)
    summary = {"store": shown, "outcomes": int(len(y)),
               "successes": int(y.sum()), "skipped": skipped}
    return x, y, summary


def _stored_outcomes(url: str) -> Iterator[dict[str, Any]]:
    """The outcomes with images of a feedback store (oldest first); the store must exist (no new file)."""
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite" and parsed.database not in (None, "", ":memory:") \
            and not Path(parsed.database).exists():
        raise ValueError(f"feedback: no such store {parsed.database}")
    with OutcomeStore(url) as store:
        yield from store.iter_outcomes(with_images_only=True)
