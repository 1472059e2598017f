"""What a request asks to grasp: rows of its cloud (indices or a mask), an oriented box, sample points or a scene
object's id; resolved to the preprocessed points it covers.

Candidates are sampled on the target only and a hand's closing region may hold no object point outside it;
collisions, the environment and unseen space are still checked against the whole cloud (graspd.gpd.detector).
Rows map to preprocessed points through the one voxel grid (graspd.core.points.voxel_groups): a voxel belongs to
the target when at least half of its rows do.  Frames: the box and the points are in the frame detection runs in
(the request's: the robot frame with camera poses), metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from graspd.core.cloud import ViewpointCloud
from graspd.core.errors import FieldError
from graspd.core.points import voxel_groups
from graspd.gpd.objects import MIN_OBJECT_EXTENT, Segmentation
from graspd.gpd.preprocess import Workspace, crop_mask

TargetKind = Literal["indices", "mask", "box", "points", "object"]
TARGET_KINDS: tuple[TargetKind, ...] = ("indices", "mask", "box", "points", "object")
#: A target with fewer object points than this is too small to grasp (a 3 mm voxel each: about 1 cm^2 seen).
MIN_TARGET_POINTS = 10


class TargetError(FieldError):
    """The target selects nothing or points outside the cloud; field names it (target.indices, ...): a 422."""


@dataclass(frozen=True)
class OrientedBox:
    """A box: centre (3,), rotation (3,3; columns are the box axes) and half extents (3,) along them (m)."""

    centre: NDArray[np.float64]
    rotation: NDArray[np.float64]
    half_extents: NDArray[np.float64]

    def contains(self, points: NDArray[np.floating]) -> NDArray[np.bool_]:
        """Which points (N,3) lie inside (boundary included)."""
        local = (np.asarray(points, np.float64) - self.centre) @ self.rotation
        inside: NDArray[np.bool_] = np.all(np.abs(local) <= self.half_extents, axis=1)
        return inside


@dataclass(frozen=True)
class Target:
    """One target: kind says which of rows (N,) over the detector's cloud rows (indices, mask), box, points (K,3)
    or object_id is set."""

    kind: TargetKind
    rows: NDArray[np.bool_] | None = field(default=None, compare=False, repr=False)
    box: OrientedBox | None = field(default=None, compare=False)
    points: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)
    object_id: int | None = None

    def __post_init__(self) -> None:
        given = {"indices": self.rows, "mask": self.rows, "box": self.box, "points": self.points,
                 "object": self.object_id}
        if self.kind not in given or given[self.kind] is None:
            raise ValueError(f"a {self.kind!r} target needs its value")

    @property
    def field(self) -> str:
        """The request field the target came from (what a 422 names)."""
        return f"target.{self.kind}"

    def check_rows(self, num_rows: int) -> None:
        """TargetError unless rows has one flag per cloud row and selects at least one."""
        if self.rows is None:
            return
        if len(self.rows) != num_rows:
            raise TargetError(self.field, f"one flag per cloud row ({num_rows}) expected, got {len(self.rows)}")
        if not self.rows.any():
            raise TargetError(self.field, "selects no point with finite coordinates")


def rows_on_prepared(rows: NDArray[np.bool_], cloud: ViewpointCloud, prepared: ViewpointCloud, voxel_size: float,
                     workspace: Workspace | None) -> NDArray[np.bool_]:
    """The preprocessed points (graspd.gpd.preprocess.preprocess of cloud) that the cloud rows flagged in rows
    (N,) make up: the points in voxels of voxel_size (m; the grid of graspd.core.points.voxel_groups) at least half
    of whose rows (inside the workspace) are flagged; without voxels, the points at a flagged row.  Only the rows
    and points within a voxel of the flagged rows' bounds are looked at: a few ms however large the cloud."""
    out = np.zeros(len(prepared), bool)
    flagged = cloud.points[rows]
    flagged = flagged[np.isfinite(flagged).all(axis=1)]
    if len(flagged) == 0 or len(prepared) == 0:
        return out
    margin = max(voxel_size, 1e-6)
    lo, hi = flagged.min(axis=0) - margin, flagged.max(axis=0) + margin
    near = np.flatnonzero(np.all((cloud.points >= lo) & (cloud.points <= hi), axis=1))
    if workspace is not None:
        near = near[crop_mask(cloud.points[near], workspace)]
    if cloud.normals is not None:
        near = near[np.isfinite(cloud.normals[near]).all(axis=1)]
    pts, flags = cloud.points[near], rows[near]
    candidates = np.flatnonzero(np.all((prepared.points >= lo) & (prepared.points <= hi), axis=1))
    if len(pts) == 0 or len(candidates) == 0:
        return out
    if voxel_size <= 0.0:  # preprocessed points are rows of the cloud: match them by position
        dist, nearest = cKDTree(np.asarray(pts, np.float64)).query(np.asarray(prepared.points[candidates], np.float64))
        out[candidates] = flags[nearest] & (dist <= 1e-6)
        return out
    cells = np.floor(pts / voxel_size).astype(np.int64)  # the grid and arithmetic of voxel_groups
    base = cells.min(axis=0)
    dims = cells.max(axis=0) - base + 1
    key = ((cells[:, 0] - base[0]) * dims[1] + cells[:, 1] - base[1]) * dims[2] + cells[:, 2] - base[2]
    voxels, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    votes = np.bincount(inverse.reshape(-1), flags.astype(np.float64), len(voxels))
    chosen = voxels[2.0 * votes >= counts]
    at = np.floor(prepared.points[candidates] / voxel_size).astype(np.int64) - base
    inside = np.all((at >= 0) & (at < dims), axis=1)
    pkey = (at[:, 0] * dims[1] + at[:, 1]) * dims[2] + at[:, 2]
    out[candidates] = inside & np.isin(pkey, chosen)
    return out


#: A row list flagging fewer than this share of the rows in the cells it touches, and spanning more than
#: MIN_OBJECT_EXTENT, is sparse (every 10th row of an object, as gpd_ros CloudIndexed users often send; a mask flags
#: nearly all): it names the objects its rows lie on.  A handful of neighbouring rows is a small patch instead.
SPARSE_ROWS = 0.5
#: Edge (m) of the cells sparse_rows counts rows in.
SHARE_CELL = 0.01


def sparse_rows(rows: NDArray[np.bool_], cloud: ViewpointCloud, cell: float = SHARE_CELL) -> bool:
    """Whether flagged rows (N,) are a sparse list over an object: they span more than MIN_OBJECT_EXTENT (m) and
    are under SPARSE_ROWS of all the rows in the cells of edge `cell` (m, graspd.core.points.voxel_groups) that
    hold one (about 1 for a mask, less at its rim; about a tenth for every 10th row)."""
    flagged = cloud.points[rows]
    flagged = flagged[np.isfinite(flagged).all(axis=1)]
    if len(flagged) == 0:
        return False
    lo, hi = flagged.min(axis=0), flagged.max(axis=0)
    if float(np.max(hi - lo)) <= MIN_OBJECT_EXTENT:
        return False
    near = np.flatnonzero(np.all((cloud.points >= lo) & (cloud.points <= hi), axis=1))
    inverse, counts = voxel_groups(cloud.points[near], cell)
    votes = np.bincount(inverse, rows[near].astype(np.float64), len(counts))
    return float(votes.sum() / counts[votes > 0].sum()) < SPARSE_ROWS


def sparse_rows_objects(rows: NDArray[np.bool_], cloud: ViewpointCloud, prepared: ViewpointCloud,
                        segmentation: Segmentation) -> NDArray[np.bool_]:
    """The preprocessed points of the scene objects (segmentation) that hold most of the flagged rows' nearest
    preprocessed points: what a sparse row list points at."""
    out = np.zeros(len(prepared), bool)
    flagged = cloud.points[rows]
    flagged = flagged[np.isfinite(flagged).all(axis=1)]
    if len(flagged) == 0 or len(prepared) == 0 or not segmentation.objects:
        return out
    _, nearest = cKDTree(np.asarray(prepared.points, np.float64)).query(np.asarray(flagged, np.float64))
    labels = segmentation.labels[nearest]
    labels = labels[labels >= 0]
    if len(labels) == 0:
        return out
    votes = np.bincount(labels, minlength=len(segmentation.objects))
    chosen = np.flatnonzero(2 * votes >= votes.max())  # the objects holding at least half as many as the most
    return np.asarray(np.isin(segmentation.labels, chosen))


def target_mask(target: Target, cloud: ViewpointCloud, prepared: ViewpointCloud, voxel_size: float,
                workspace: Workspace | None, segmentation: Segmentation) -> NDArray[np.bool_] | None:
    """The preprocessed points the target covers (None for sample points, which say where to sample instead).
    TargetError naming the field when it covers none of them, or names an object the scene does not have."""
    if target.kind == "points":
        return None
    if target.object_id is not None:
        n = len(segmentation.objects)
        if not 0 <= target.object_id < n:
            have = f"ids 0 to {n - 1}" if n else "no object"
            raise TargetError(target.field, f"no object {target.object_id} in this cloud (it has {have}; the "
                              "answer's objects list them)")
        return np.asarray(segmentation.labels == target.object_id)
    if target.box is not None:
        mask = target.box.contains(prepared.points)
        if not mask.any():
            raise TargetError(target.field, "holds no point of the cloud (after the workspace crop); the box is in "
                              "the request's frame (m): check its centre and half_extents")
        return mask
    assert target.rows is not None
    target.check_rows(len(cloud))
    if sparse_rows(target.rows, cloud):
        mask = sparse_rows_objects(target.rows, cloud, prepared, segmentation)
    else:
        mask = rows_on_prepared(target.rows, cloud, prepared, voxel_size, workspace)
    if not mask.any():
        raise TargetError(target.field, f"its {int(target.rows.sum())} points lie outside the workspace or make "
                          "up no voxel of the cloud")
    return mask
