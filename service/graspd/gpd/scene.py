"""A preprocessed cloud made ready for hand search and image encoding: a kd-tree and the unobserved volume.

The unobserved volume follows the IJRR paper: space occluded from view by every camera.  As GPD does,
we march "shadow" samples from each surface point away from each camera for `shadow_length` metres;
a voxel shadowed from every camera and holding no point is unobserved.  The volume is a dense boolean
voxel grid over the shadows' bounding box, built on first use (only the 15-channel and Herzog images
need it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.core.hand import HandGeometry

MAX_GRID_CELLS = 48_000_000
#: Shadow samples (surface points x steps) placed together when marking the unobserved volume.
SHADOW_BLOCK = 1 << 19


@dataclass(frozen=True)
class VoxelGrid:
    """Boolean voxels of edge `voxel` (m); cell (i, j, k) spans origin + [i, i+1) * voxel along each axis.
    Border cells are False (lookups outside the grid clip onto them)."""

    origin: NDArray[np.float64]
    voxel: float
    cells: NDArray[np.bool_]

    def contains(self, xyz: NDArray[np.floating]) -> NDArray[np.bool_]:
        """Whether each position (...,3) lies in a true cell.  Positions outside the grid are clipped to
        its border, whose cells are always False (see unobserved_grid), so they read False."""
        shape = self.cells.shape
        g = (xyz.reshape(-1, 3) - self.origin.astype(xyz.dtype)) * xyz.dtype.type(1.0 / self.voxel)
        np.floor(g, out=g)
        np.clip(g, 0, np.array(shape) - 1, out=g)
        gi = g.astype(np.int32)  # at most MAX_GRID_CELLS cells: flat ids fit in int32
        flat = (gi[:, 0] * shape[1] + gi[:, 1]) * shape[2] + gi[:, 2]
        return self.cells.reshape(-1)[flat].reshape(xyz.shape[:-1])

    def centres(self) -> NDArray[np.float32]:
        """Centres (U,3) of the true cells (m)."""
        return (self.origin + (np.argwhere(self.cells) + 0.5) * self.voxel).astype(np.float32)


@dataclass(frozen=True)
class Scene:
    """Oriented cloud (points, normals, per-point camera) + kd-tree; the unobserved volume on demand."""

    cloud: ViewpointCloud
    tree: cKDTree
    shadow_voxel: float = 0.004
    shadow_length: float = 0.10
    _cache: dict[str, VoxelGrid] = field(default_factory=dict, repr=False, compare=False)

    @property
    def points(self) -> NDArray[np.float32]:
        return self.cloud.points

    @property
    def normals(self) -> NDArray[np.float32]:
        assert self.cloud.normals is not None
        return self.cloud.normals

    @property
    def unobserved(self) -> VoxelGrid:
        """Space within shadow_length behind the surface from every camera (computed once): the images' volume."""
        return self.unobserved_within(self.shadow_length)

    def unobserved_within(self, length: float) -> VoxelGrid:
        """Space within length (m) behind the surface from every camera (computed once per length): the hand
        checks look deeper than the images (graspd.gpd.occlusion.hand_shadow_length)."""
        key = "unobserved" if length == self.shadow_length else f"unobserved@{length:.6f}"
        if key not in self._cache:
            self._cache[key] = unobserved_grid(self.cloud.points, self.cloud.viewpoints, self.shadow_voxel, length)
        return self._cache[key]

    @staticmethod
    def build(cloud: ViewpointCloud, hand: HandGeometry | None = None, shadow_voxel: float = 0.004,
              shadow_length: float | None = None) -> Scene:
        """Index a cloud that has normals (see graspd.gpd.preprocess); shadow_length defaults to the
        hand's closing width, the deepest an object between the fingers can reach behind its surface."""
        if cloud.normals is None:
            raise CloudError("cloud.normals", "are required: run graspd.gpd.preprocess.preprocess first")
        h = hand or HandGeometry()
        return Scene(
            cloud=cloud,
            tree=cKDTree(cloud.points) if len(cloud) else cKDTree(np.zeros((0, 3))),
            shadow_voxel=shadow_voxel,
            shadow_length=h.max_aperture if shadow_length is None else shadow_length,
        )


def unobserved_grid(points: NDArray[np.float32], viewpoints: NDArray[np.float32], voxel: float,
                    length: float) -> VoxelGrid:
    """Voxels within `length` behind the surface as seen from every camera, and holding no point.

    The grid's voxel grows past `voxel` only if the shadows' bounding box would exceed MAX_GRID_CELLS."""
    if len(points) == 0 or length <= 0.0:
        return VoxelGrid(np.zeros(3), voxel, np.zeros((1, 1, 1), bool))
    pts = points.astype(np.float64)
    lo = pts.min(axis=0) - length
    hi = pts.max(axis=0) + length
    v = max(voxel, float(np.cbrt(np.prod(hi - lo) / MAX_GRID_CELLS)))
    shape = tuple(int(s) for s in np.ceil((hi - lo) / v).astype(np.int64) + 1)
    # Surface points thinned to one per voxel: shadows are resolved at the voxel size anyway.
    occ_idx = np.floor((pts - lo) / v).astype(np.int64)
    flat = (occ_idx[:, 0] * shape[1] + occ_idx[:, 1]) * shape[2] + occ_idx[:, 2]
    uniq, first = np.unique(flat, return_index=True)
    occupied = np.zeros(int(np.prod(shape)), bool)
    occupied[uniq] = True
    surface = pts[first]
    steps = np.arange(1, int(np.ceil(length / v)) + 1) * v
    shadowed = np.ones(int(np.prod(shape)), bool)
    top = np.array(shape) - 1
    per = max(1, SHADOW_BLOCK // max(1, len(surface)))  # steps marked together (bounded temporaries)
    for cam in viewpoints.astype(np.float64):
        ray = surface - cam
        ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-9)
        mine = np.zeros(int(np.prod(shape)), bool)
        for a in range(0, len(steps), per):
            # the same positions as one step at a time: surface + ray * step, each step in turn
            g = np.floor((surface[None] + ray[None] * steps[a : a + per, None, None] - lo) / v).astype(np.int64)
            np.clip(g, 0, top, out=g)
            mine[((g[..., 0] * shape[1] + g[..., 1]) * shape[2] + g[..., 2]).reshape(-1)] = True
        shadowed &= mine
    cells = (shadowed & ~occupied).reshape(shape)
    # The box reaches `length` past every point, so border cells are (at most) the shadows' rounding
    # spill: clear them, which lets lookups clip out-of-grid positions onto the border.
    cells[[0, -1], :, :] = False
    cells[:, [0, -1], :] = False
    cells[:, :, [0, -1]] = False
    return VoxelGrid(lo, v, cells)


def ball_pairs(tree: cKDTree, centres: NDArray[np.floating], radius: float
               ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """All (centre index, point index) pairs closer than radius, as two int64 arrays (unordered)."""
    if len(centres) == 0 or tree.n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    pairs = cKDTree(centres).sparse_distance_matrix(tree, radius, output_type="ndarray")
    return np.ascontiguousarray(pairs["i"], np.int64), np.ascontiguousarray(pairs["j"], np.int64)


@dataclass(frozen=True)
class ClosingRegionPoints:
    """Points inside each grasp's closing region, flattened: grasp index, hand-frame coordinates (m),
    and for cloud points their index (to look up normals); hand frame x = approach from the base."""

    grasp: NDArray[np.int64]
    local: NDArray[np.float32]
    index: NDArray[np.int64]

    def subset(self, keep: NDArray[np.bool_]) -> ClosingRegionPoints:
        """The points of the grasps where keep is True, grasp indices renumbered to match grasps[keep]."""
        if bool(keep.all()):
            return self
        new_id = np.cumsum(keep) - 1
        rows = keep[self.grasp]
        return ClosingRegionPoints(new_id[self.grasp[rows]], self.local[rows], self.index[rows])


def closing_region_points(tree: cKDTree, points: NDArray[np.float32], positions: NDArray[np.float64],
                          rotations: NDArray[np.float64], hand: HandGeometry) -> ClosingRegionPoints:
    """The points of `points` (indexed by `tree`) that lie between the open fingers of each hand."""
    half_w = hand.closing_half_width
    centres = positions + rotations[:, :, 0] * (hand.hand_depth / 2.0)
    radius = float(np.sqrt((hand.hand_depth / 2) ** 2 + half_w**2 + (hand.hand_height / 2) ** 2))
    if len(positions) == 0 or tree.n == 0:
        return ClosingRegionPoints(np.zeros(0, np.int64), np.zeros((0, 3), np.float32), np.zeros(0, np.int64))
    gid, idx = ball_pairs(tree, centres, radius)
    d = points[idx] - positions[gid].astype(np.float32)
    rot = rotations.astype(np.float32)
    z = np.einsum("tj,tj->t", d, rot[gid, :, 2])
    keep = np.abs(z) <= hand.hand_height / 2.0
    gid, idx, d, z = gid[keep], idx[keep], d[keep], z[keep]
    x = np.einsum("tj,tj->t", d, rot[gid, :, 0])
    y = np.einsum("tj,tj->t", d, rot[gid, :, 1])
    inside = (x >= 0.0) & (x <= hand.hand_depth) & (np.abs(y) <= half_w)
    local = np.stack([x[inside], y[inside], z[inside]], axis=1)
    return ClosingRegionPoints(gid[inside], local, idx[inside])
