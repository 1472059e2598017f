"""What a point cloud file (PCD, PLY) holds besides x, y, z: normals, colours, per-point scalars, the camera
position and an organised cloud's image shape, row for row as the file stores them (an organised cloud's NaN
pixels kept, in pixel order: graspd.io.inputs drops and counts them)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

#: Per-point scalar fields a file may carry that are kept (others are skipped): PCL's and CloudCompare's names.
KEPT_SCALARS = ("intensity", "label", "curvature")
#: CloudCompare writes its scalar fields as `scalar_NAME`; at most this many scalar fields are kept.
SCALAR_PREFIX = "scalar_"
MAX_SCALARS = 8


def kept_scalar(name: str) -> bool:
    """Whether a per-point field of this name is kept among FileCloud.scalars."""
    return name in KEPT_SCALARS or name.startswith(SCALAR_PREFIX)


@dataclass(frozen=True)
class FileCloud:
    """A cloud file's contents: points (N,3) float32 (m, in the file's frame); normals (N,3) float32 when the
    file has all three normal fields; colors (N,3) uint8 RGB when it has rgb/rgba or red/green/blue; scalars
    (intensity, label, curvature, CloudCompare's scalar_*) by name, (N,) each; viewpoint (3,) float32, the camera
    position the header declares (PCD VIEWPOINT); shape (height, width) of an organised cloud (rows in pixel
    order, row-major), None when unorganised."""

    points: NDArray[np.float32]
    normals: NDArray[np.float32] | None = None
    colors: NDArray[np.uint8] | None = None
    scalars: dict[str, NDArray[np.generic]] = field(default_factory=dict)
    viewpoint: NDArray[np.float32] | None = None
    shape: tuple[int, int] | None = None

    def usable_normals(self) -> NDArray[np.float32] | None:
        """The file's normals for detection: when every row with a finite point has a finite, non-zero normal
        (PCL leaves NaN normals where a point had too few neighbours; using them would drop those points), else
        None and the detector estimates its own.  Rows whose point is not finite are dropped anyway."""
        if self.normals is None:
            return None
        finite = np.isfinite(self.points).all(axis=1)
        nrm = self.normals[finite]
        if not np.isfinite(nrm).all() or (np.abs(nrm).sum(axis=1) == 0).any():
            return None
        return self.normals


def colours_from_packed(packed: NDArray[np.uint32]) -> NDArray[np.uint8]:
    """(N,3) uint8 RGB of PCL's packed rgb/rgba words (0xAARRGGBB, read as little-endian uint32)."""
    out = np.empty((len(packed), 3), np.uint8)
    for k, shift in enumerate((16, 8, 0)):
        out[:, k] = (packed >> shift) & 0xFF
    return out


def colours_from_channels(channels: list[NDArray[np.generic]]) -> NDArray[np.uint8]:
    """(N,3) uint8 RGB of three colour columns: integers as they are (0-255), floats as fractions 0-1 (Open3D
    and some PLY writers store colours so)."""
    out = np.empty((len(channels[0]), 3), np.uint8)
    for k, column in enumerate(channels):
        values = np.asarray(column)
        if values.dtype.kind == "f":
            with np.errstate(invalid="ignore"):
                values = np.rint(np.nan_to_num(values, nan=0.0) * 255.0)
        out[:, k] = np.clip(values, 0, 255)
    return out
