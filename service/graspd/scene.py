"""A preprocessed cloud made ready for hand search and image encoding: kd-trees and the unobserved volume.

The unobserved volume follows the IJRR paper: space occluded from view by every camera.  We
approximate it as GPD does, with "shadow" samples: from each surface point we march away from
each camera for `shadow_length` metres; a voxel occluded from all cameras and not occupied is
unobserved, and is represented by its centre.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from .cloud import CloudError, ViewpointCloud
from .hand import HandGeometry


@dataclass(frozen=True)
class Scene:
    """Oriented cloud (points, normals, per-point camera) + kd-tree; unobserved voxel centres + kd-tree."""

    cloud: ViewpointCloud
    tree: cKDTree
    unobserved_keys: NDArray[np.int64]
    shadow_voxel: float
    dense_origin: NDArray[np.int64] = field(default_factory=lambda: np.zeros(3, np.int64))
    dense: NDArray[np.bool_] | None = None

    @property
    def points(self) -> NDArray[np.float32]:
        return self.cloud.points

    @property
    def unobserved(self) -> NDArray[np.float32]:
        """Centres (U,3) of the unobserved voxels (m)."""
        return voxel_centres(self.unobserved_keys, self.shadow_voxel)

    def is_unobserved(self, xyz: NDArray[np.float32]) -> NDArray[np.bool_]:
        """Whether each position (...,3) lies in an unobserved voxel."""
        grid = np.floor(xyz.reshape(-1, 3) / self.shadow_voxel).astype(np.int64)
        if self.dense is not None:
            g = grid - self.dense_origin
            shape = np.array(self.dense.shape)
            ok = np.all((g >= 0) & (g < shape), axis=1)
            flat = np.where(ok, (g[:, 0] * shape[1] + g[:, 1]) * shape[2] + g[:, 2], 0)
            return (self.dense.reshape(-1)[flat] & ok).reshape(xyz.shape[:-1])
        keys = _voxel_keys(grid)
        if len(self.unobserved_keys) == 0:
            return np.zeros(xyz.shape[:-1], bool)
        pos = np.minimum(np.searchsorted(self.unobserved_keys, keys), len(self.unobserved_keys) - 1)
        return (self.unobserved_keys[pos] == keys).reshape(xyz.shape[:-1])

    @property
    def normals(self) -> NDArray[np.float32]:
        assert self.cloud.normals is not None
        return self.cloud.normals

    @staticmethod
    def build(cloud: ViewpointCloud, hand: HandGeometry | None = None, shadow_voxel: float = 0.004,
              shadow_length: float | None = None) -> Scene:
        """Index a cloud that has normals (see graspd.preprocess); shadow_length defaults to the
        hand's closing width, the deepest an object between the fingers can reach behind its surface."""
        if cloud.normals is None:
            raise CloudError("cloud.normals are required: run graspd.preprocess.preprocess first")
        h = hand or HandGeometry()
        length = h.max_aperture if shadow_length is None else shadow_length
        keys = unobserved_voxels(cloud.points, cloud.viewpoints, shadow_voxel, length)
        origin, dense = dense_grid(keys)
        return Scene(
            cloud=cloud,
            tree=cKDTree(cloud.points) if len(cloud) else cKDTree(np.zeros((0, 3))),
            unobserved_keys=keys,
            shadow_voxel=shadow_voxel,
            dense_origin=origin,
            dense=dense,
        )


def _voxel_keys(grid: NDArray[np.int64]) -> NDArray[np.int64]:
    """One int64 per voxel index triple (each coordinate offset into 21 bits)."""
    g = grid + (1 << 20)
    return (g[:, 0] << 42) | (g[:, 1] << 21) | g[:, 2]


def voxel_centres(keys: NDArray[np.int64], voxel: float) -> NDArray[np.float32]:
    """Voxel centres (U,3) of packed voxel keys."""
    return (voxel_indices(keys).astype(np.float32) + 0.5) * np.float32(voxel)


def voxel_indices(keys: NDArray[np.int64]) -> NDArray[np.int64]:
    """Integer voxel index triples (U,3) of packed voxel keys."""
    mask = (1 << 21) - 1
    return np.stack([(keys >> 42) & mask, (keys >> 21) & mask, keys & mask], 1) - (1 << 20)


def dense_grid(keys: NDArray[np.int64], max_cells: int = 32_000_000
               ) -> tuple[NDArray[np.int64], NDArray[np.bool_] | None]:
    """A boolean voxel array over the keys' bounding box (origin index, array) for O(1) lookups;
    None when it would exceed max_cells (lookups then use the sorted keys)."""
    if len(keys) == 0:
        return np.zeros(3, np.int64), None
    idx = voxel_indices(keys)
    lo = idx.min(axis=0)
    shape = idx.max(axis=0) - lo + 1
    if int(np.prod(shape)) > max_cells:
        return lo, None
    dense = np.zeros(tuple(int(v) for v in shape), bool)
    g = idx - lo
    dense[g[:, 0], g[:, 1], g[:, 2]] = True
    return lo, dense


def unobserved_voxels(points: NDArray[np.float32], viewpoints: NDArray[np.float32], voxel: float,
                      length: float) -> NDArray[np.int64]:
    """Sorted keys of voxels within `length` behind the surface from every camera, and not occupied."""
    if len(points) == 0 or length <= 0.0:
        return np.zeros(0, np.int64)
    steps = np.arange(1, int(np.ceil(length / voxel)) + 1, dtype=np.float32) * voxel
    occupied = np.unique(_voxel_keys(np.floor(points / voxel).astype(np.int64)))
    shadowed: NDArray[np.int64] | None = None
    for cam in viewpoints:
        ray = points - cam
        ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-9)
        samples = points[:, None, :] + ray[:, None, :] * steps[None, :, None]
        keys = np.unique(_voxel_keys(np.floor(samples.reshape(-1, 3) / voxel).astype(np.int64)))
        shadowed = keys if shadowed is None else np.intersect1d(shadowed, keys, assume_unique=True)
    assert shadowed is not None
    return np.setdiff1d(shadowed, occupied, assume_unique=True)


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
        new_id = np.cumsum(keep) - 1
        rows = keep[self.grasp]
        return ClosingRegionPoints(new_id[self.grasp[rows]], self.local[rows], self.index[rows])


def closing_region_points(tree: cKDTree, points: NDArray[np.float32], positions: NDArray[np.float64],
                          rotations: NDArray[np.float64], hand: HandGeometry) -> ClosingRegionPoints:
    """The points of `points` (indexed by `tree`) that lie between the open fingers of each hand."""
    half_w = hand.hand_outer_diameter / 2.0 - hand.finger_width
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
