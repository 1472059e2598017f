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
from graspd.core.jit import kernel

MAX_GRID_CELLS = 48_000_000


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
    focus: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None  # (lo, hi) m: where hands can reach
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
        """Space within length (m) behind the surface from every camera (computed once per length; exact inside
        the focus box, where hands reach, when there is one): the hand checks look deeper than the images
        (graspd.gpd.occlusion.hand_shadow_length)."""
        key = "unobserved" if length == self.shadow_length else f"unobserved@{length:.6f}"
        if key not in self._cache:
            self._cache[key] = unobserved_grid(self.cloud.points, self.cloud.viewpoints, self.shadow_voxel, length,
                                               self.focus)
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
                    length: float, focus: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
                    ) -> VoxelGrid:
    """Voxels within `length` behind the surface as seen from every camera, and holding no point.  With a focus
    box (lo, hi; m) only the cells inside it are exact (those outside may read False): the shadows that cannot
    reach it are not marched, which spares most of a large scene when hands can reach only part of it.

    The grid's voxel grows past `voxel` only if the shadows' bounding box would exceed MAX_GRID_CELLS."""
    if len(points) == 0 or length <= 0.0:
        return VoxelGrid(np.zeros(3), voxel, np.zeros((1, 1, 1), bool))
    pts = points.astype(np.float64)
    lo = pts.min(axis=0) - length
    hi = pts.max(axis=0) + length
    v = max(voxel, float(np.cbrt(np.prod(hi - lo) / MAX_GRID_CELLS)))
    whole = np.ceil((hi - lo) / v).astype(np.int64) + 1
    first, shape = np.zeros(3, np.int64), whole
    if focus is not None:
        # Only the focus box is exact, so only the cells from two before it to two past it are kept: the same
        # cells of the same lattice as the whole box's, which a deep shadow would otherwise allocate in vain.
        # Points off them still cast shadows into them: they are thinned to one a cell of the whole lattice
        # (the first, as the kernel thins the others), so the marked cells are exactly the whole grid's.
        first = np.clip(np.floor((np.asarray(focus[0], np.float64) - lo) / v).astype(np.int64) - 2, 0, whole - 1)
        last = np.clip(np.floor((np.asarray(focus[1], np.float64) - lo) / v).astype(np.int64) + 3, first + 1, whole)
        shape = last - first
        cell = np.floor((pts - lo) / v).astype(np.int64)
        off = np.any((cell < first) | (cell >= last), axis=1)
        if off.any():
            keys = np.ravel_multi_index(tuple(cell[off].T), tuple(whole))  # cells of the whole box
            _, once = np.unique(keys, return_index=True)
            pts = np.concatenate([pts[~off], pts[np.flatnonzero(off)[np.sort(once)]]])
    cells = np.empty(tuple(int(s) for s in shape), bool)
    steps = np.arange(1, int(np.ceil(length / v)) + 1, dtype=np.float64) * v
    # a cell of margin round the focus: a shadow passing just outside it still marks the cells it rounds into
    near_lo = lo if focus is None else np.asarray(focus[0], np.float64) - v
    near_hi = hi if focus is None else np.asarray(focus[1], np.float64) + v
    _unobserved(pts, viewpoints.astype(np.float64), lo, first, v, steps, near_lo, near_hi, cells)
    # The box reaches `length` past every point, so the whole grid's border cells are (at most) the shadows'
    # rounding spill, and a focused grid's lie outside the focus: clear them, which lets lookups clip
    # out-of-grid positions onto the border.
    cells[[0, -1], :, :] = False
    cells[:, [0, -1], :] = False
    cells[:, :, [0, -1]] = False
    return VoxelGrid(lo + first * v, v, cells)


@kernel
def _unobserved(pts: NDArray[np.float64], cams: NDArray[np.float64], lo: NDArray[np.float64],
                first: NDArray[np.int64], v: float, steps: NDArray[np.float64], near_lo: NDArray[np.float64],
                near_hi: NDArray[np.float64], cells: NDArray[np.bool_]) -> None:
    """cells (the cells from index first on of a lattice of voxel v from lo): True where every camera's shadow
    (each surface voxel's first point marched away from the camera by steps, m) reaches and no point lies;
    shadows whose bounds miss the box [near_lo, near_hi] are not marched.  Points off cells are taken as given
    (already one a voxel)."""
    s0, s1, s2 = cells.shape
    f0, f1, f2 = first[0], first[1], first[2]
    occupied = np.zeros((s0, s1, s2), np.bool_)
    surface = np.empty(len(pts), np.int64)  # surface points thinned to one per voxel (the first): shadows are
    n = 0  # resolved at the voxel size anyway
    for i in range(len(pts)):
        a = int(np.floor((pts[i, 0] - lo[0]) / v)) - f0
        b = int(np.floor((pts[i, 1] - lo[1]) / v)) - f1
        c = int(np.floor((pts[i, 2] - lo[2]) / v)) - f2
        if not (0 <= a < s0 and 0 <= b < s1 and 0 <= c < s2):  # off the cells: its shadow may still cross them
            surface[n] = i
            n += 1
        elif not occupied[a, b, c]:
            occupied[a, b, c] = True
            surface[n] = i
            n += 1
    reach = steps[-1] if len(steps) else 0.0
    cells[:] = True
    mine = np.empty((s0, s1, s2), np.bool_)
    for cam in range(len(cams)):
        mine[:] = False
        for q in range(n):
            p = surface[q]
            r0, r1, r2 = pts[p, 0] - cams[cam, 0], pts[p, 1] - cams[cam, 1], pts[p, 2] - cams[cam, 2]
            norm = max(np.sqrt(r0 * r0 + r1 * r1 + r2 * r2), 1e-9)
            r0, r1, r2 = r0 / norm, r1 / norm, r2 / norm
            e0, e1, e2 = pts[p, 0] + r0 * reach, pts[p, 1] + r1 * reach, pts[p, 2] + r2 * reach
            if (max(pts[p, 0], e0) < near_lo[0] or min(pts[p, 0], e0) > near_hi[0]
                    or max(pts[p, 1], e1) < near_lo[1] or min(pts[p, 1], e1) > near_hi[1]
                    or max(pts[p, 2], e2) < near_lo[2] or min(pts[p, 2], e2) > near_hi[2]):
                continue  # the shadow's bounds miss the box
            for step in steps:
                m0 = min(max(int(np.floor((pts[p, 0] + r0 * step - lo[0]) / v)) - f0, 0), s0 - 1)
                m1 = min(max(int(np.floor((pts[p, 1] + r1 * step - lo[1]) / v)) - f1, 0), s1 - 1)
                m2 = min(max(int(np.floor((pts[p, 2] + r2 * step - lo[2]) / v)) - f2, 0), s2 - 1)
                mine[m0, m1, m2] = True
        cells &= mine
    cells &= ~occupied


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
