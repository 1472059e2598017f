"""Label-preserving augmentation of grasp images: mirror images across the hand's y and z planes."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from graspd.gpd.images import channel_layout

_AXES = {"x": 0, "y": 1, "z": 2}
_IMAGE_AXES = {0: (1, 2), 1: (0, 2), 2: (0, 1)}  # projection along hand axis p -> hand axes of (rows, cols)


def mirror_images(images: NDArray[np.uint8], representation: str, axis: int) -> NDArray[np.uint8]:
    """Grasp images (B,C,S,S) of the same grasps reflected through the hand plane normal to hand axis 1 (y, the
    closing direction) or 2 (z, the hand axis).  The hand is symmetric under both reflections and antipodal
    grasps stay antipodal, so the label is unchanged: a free, exact augmentation."""
    if axis not in (1, 2):
        raise ValueError(f"axis must be 1 (hand y) or 2 (hand z), got {axis}")
    layout = channel_layout(representation)
    out = images.copy()
    occupied: dict[str, NDArray[np.bool_]] = {}
    for proj in "xyz":
        normals = [layout.index(f"{proj}:{c}") for c in ("nx", "ny", "nz") if f"{proj}:{c}" in layout]
        if normals:
            occupied[proj] = np.any(images[:, normals] > 0, axis=1)
    for c, name in enumerate(layout):
        proj, kind = name.split(":")
        p = _AXES[proj]
        rows, cols = _IMAGE_AXES[p]
        value = images[:, c]
        if kind in ("nx", "ny", "nz") and _AXES[kind[1]] == axis:
            value = np.where(occupied[proj], 255 - value, 0).astype(np.uint8)
        elif kind in ("occ", "unobs") and p == axis:
            hit = occupied[proj] if kind == "occ" and proj in occupied else value > 0
            value = np.where(hit, 255 - value, 0).astype(np.uint8)
        if rows == axis:
            value = value[:, ::-1, :]
        elif cols == axis:
            value = value[:, :, ::-1]
        out[:, c] = value
    return out


def augment(images: NDArray[np.uint8], representation: str, rng: np.random.Generator) -> NDArray[np.uint8]:
    """Each image mirrored across hand y and/or hand z with probability 1/2 each (see mirror_images)."""
    out = images.copy()
    for axis in (1, 2):
        sel = rng.random(len(out)) < 0.5
        if sel.any():
            out[sel] = mirror_images(out[sel], representation, axis)
    return out
