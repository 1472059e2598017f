"""The viewpoint cloud: points seen by one or more cameras, in the caller's frame (metres)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from graspd.core.errors import FieldError

FloatArray = NDArray[np.float32]
IntArray = NDArray[np.int32]


class CloudError(FieldError):
    """The cloud is malformed; `field` names the offending one (e.g. "cloud.points")."""


@dataclass(frozen=True, eq=False)
class CloudGrid:
    """Where an organised cloud's points lie on its camera's image: height x width pixels, and each kept point's
    row-major pixel index (N,) int64 (rows with no depth were dropped, so the index is not the row number).  Lets
    image-neighbour filters and normals work on the grid instead of searching 3-D neighbours."""

    height: int
    width: int
    pixel: NDArray[np.int64]

    def __post_init__(self) -> None:
        h, w = int(self.height), int(self.width)
        if h < 1 or w < 1:
            raise CloudError("cloud.shape", f"height and width must be positive, got {h}x{w}")
        pix = np.ascontiguousarray(np.asarray(self.pixel).astype(np.int64, copy=False)).reshape(-1)
        if pix.size and (int(pix.min()) < 0 or int(pix.max()) >= h * w):
            raise CloudError("cloud.shape", f"pixel indices must lie in [0, {h * w - 1}] ({h}x{w} image)")
        object.__setattr__(self, "height", h)
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "pixel", pix)

    @classmethod
    def of_rows(cls, height: int, width: int, kept: NDArray[np.bool_] | None = None) -> CloudGrid:
        """The grid of height*width rows as received (row-major), of which the rows `kept` remain (None: all)."""
        pixel = np.arange(int(height) * int(width), dtype=np.int64) if kept is None else np.flatnonzero(kept)
        return cls(height, width, pixel)


@dataclass(frozen=True)
class ViewpointCloud:
    """Points (N,3) float32, optional unit normals (N,3) pointing toward the observing camera,
    per-point camera index camera_source (N,) int32 into viewpoints (K,3) float32 camera positions, and for an
    organised cloud (one camera's image) the grid its points lie on (None: unorganised)."""

    points: FloatArray
    viewpoints: FloatArray
    camera_source: IntArray = field(default_factory=lambda: np.zeros(0, np.int32))
    normals: FloatArray | None = None
    grid: CloudGrid | None = None

    def __post_init__(self) -> None:
        pts = np.ascontiguousarray(np.asarray(self.points, dtype=np.float32))
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise CloudError("cloud.points", f"must have shape (N, 3), got {pts.shape}")
        vps = np.ascontiguousarray(np.asarray(self.viewpoints, dtype=np.float32).reshape(-1, 3))
        if vps.shape[0] < 1:
            raise CloudError("cloud.viewpoints", "needs at least one camera position")
        if not np.isfinite(vps).all():
            raise CloudError("cloud.viewpoints", "must be finite")
        src = np.asarray(self.camera_source)
        if src.size == 0:
            src = np.zeros(pts.shape[0], np.int32)
        src = np.ascontiguousarray(src.astype(np.int32, copy=False)).reshape(-1)
        if src.shape[0] != pts.shape[0]:
            raise CloudError("cloud.camera_source",
                             f"must have one entry per point ({pts.shape[0]}), got {src.shape[0]}")
        if src.size and (src.min() < 0 or src.max() >= vps.shape[0]):
            raise CloudError("cloud.camera_source",
                             f"indices must lie in [0, {vps.shape[0] - 1}] (one per viewpoint)")
        nrm = self.normals
        if nrm is not None:
            nrm = np.ascontiguousarray(np.asarray(nrm, dtype=np.float32))
            if nrm.shape != pts.shape:
                raise CloudError("cloud.normals", f"must have shape {pts.shape}, got {nrm.shape}")
        if self.grid is not None and len(self.grid.pixel) != pts.shape[0]:
            raise CloudError("cloud.shape", f"the grid must hold one pixel index per point ({pts.shape[0]}), "
                             f"got {len(self.grid.pixel)}")
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "viewpoints", vps)
        object.__setattr__(self, "camera_source", src)
        object.__setattr__(self, "normals", nrm)

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def num_cameras(self) -> int:
        return int(self.viewpoints.shape[0])

    def select(self, mask_or_index: NDArray[np.bool_] | NDArray[np.intp]) -> ViewpointCloud:
        """The sub-cloud at a boolean mask or index array (viewpoints kept)."""
        return replace(
            self,
            points=self.points[mask_or_index],
            camera_source=self.camera_source[mask_or_index],
            normals=None if self.normals is None else self.normals[mask_or_index],
            grid=None if self.grid is None else replace(self.grid, pixel=self.grid.pixel[mask_or_index]),
        )

    def transformed(self, rotation: NDArray[np.floating], translation: NDArray[np.floating]) -> ViewpointCloud:
        """The cloud moved rigidly: p -> R p + t (viewpoints and normals too; the grid indexes rows, so it stays)."""
        r = np.asarray(rotation, np.float64)
        t = np.asarray(translation, np.float64)
        return ViewpointCloud(
            points=(self.points @ r.T + t).astype(np.float32),
            viewpoints=(self.viewpoints @ r.T + t).astype(np.float32),
            camera_source=self.camera_source,
            normals=None if self.normals is None else (self.normals @ r.T).astype(np.float32),
            grid=self.grid,
        )
