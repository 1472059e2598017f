"""Object proposals from grasps (IJRR paper, combined grasp and object detection): project the point
between the fingers into the RGB image and cut a fixed-size window around it.  Pure numpy geometry."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from graspd.core.types import F64


def finger_centres(positions: F64, approach: F64, hand_depth: float) -> F64:
    """The point between the fingers (M,3): hand-base centre plus half the finger length along approach."""
    return np.asarray(positions, np.float64) + 0.5 * hand_depth * np.asarray(approach, np.float64)


def inside_image(pixels: F64, height: int, width: int) -> NDArray[np.bool_]:
    """Pixels that fall on the image (pixel centres at integer coordinates, NaN is outside)."""
    u, v = pixels[:, 0], pixels[:, 1]
    with np.errstate(invalid="ignore"):
        return np.isfinite(u) & np.isfinite(v) & (u >= -0.5) & (u < width - 0.5) & (v >= -0.5) & (v < height - 0.5)


def crop_windows(image: NDArray[np.uint8], pixels: F64, size: int) -> NDArray[np.uint8]:
    """size x size windows (M,size,size,C) centred on each pixel; parts beyond the border are black.

    Rows of non-finite pixels are all black.  Vectorised gather with clipped indices and a mask.
    """
    h, w = image.shape[:2]
    m = len(pixels)
    centres = np.where(np.isfinite(pixels), np.round(np.nan_to_num(pixels)), -10 * (h + w + size))
    offsets = np.arange(size) - size // 2
    cols = centres[:, 0:1].astype(np.int64) + offsets  # (M, size)
    rows = centres[:, 1:2].astype(np.int64) + offsets
    valid = (rows[:, :, None] >= 0) & (rows[:, :, None] < h) & (cols[:, None, :] >= 0) & (cols[:, None, :] < w)
    out = image[np.clip(rows, 0, h - 1)[:, :, None], np.clip(cols, 0, w - 1)[:, None, :]]
    out[~valid] = 0
    return out.reshape(m, size, size, *image.shape[2:])
