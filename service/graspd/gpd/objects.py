"""Scene objects: the object points the environment stage kept (not support, walls or declared boxes), split into
groups no farther than OBJECT_GAP apart.  Ids count the groups from 0 in order of position (x, then y, then z of
their centres, cloud frame), so the same cloud gets the same ids whatever the request samples, targets or seeds.
Touching objects are one group; a target (graspd.gpd.target) tells them apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from graspd.core.points import eps_clusters
from graspd.core.types import F64, I64
from graspd.gpd.scene import ClosingRegionPoints

#: Object points at most this far apart (m) belong to one object: two voxels of the default 3 mm grid, less than
#: the 1 cm a finger needs to pass between two objects.
OBJECT_GAP = 0.006
#: Fewer points than this are a speck (noise, a sliver seen at a grazing angle), not an object.
MIN_OBJECT_POINTS = 20
#: A group no longer than this (m) in every direction is a blob of sensor artefacts (stereo speckle, mixed pixels
#: at a silhouette), not an object: it joins no object and no hand is sampled on it.  Smaller than anything a
#: two-finger hand is asked to pick (the household set's smallest largest extent is 4 cm).
MIN_OBJECT_EXTENT = 0.02
#: Centres are compared to this resolution (m) when ids are ordered, so that float noise cannot swap two ids.
ORDER_RESOLUTION = 1e-3


@dataclass(frozen=True)
class SceneObject:
    """One object of the scene: its id, the centre and extent of its points' axis-aligned bounds (m, the frame
    of the cloud detection ran in) and how many (preprocessed) points it has."""

    id: int
    centre: F64
    extent: F64
    num_points: int

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "centre": self.centre.tolist(), "extent": self.extent.tolist(),
                "num_points": self.num_points}


@dataclass(frozen=True)
class Segmentation:
    """The object id of every preprocessed point (N,) (-1: environment, an artefact, or no object in the scene),
    the objects by id, and which points are sensor artefacts (N,) (blobs: no hand is sampled on them)."""

    labels: I64
    objects: tuple[SceneObject, ...] = ()
    artefacts: NDArray[np.bool_] | None = None

    @staticmethod
    def empty(n: int, artefacts: NDArray[np.bool_] | None = None) -> Segmentation:
        return Segmentation(np.full(n, -1, np.int64), artefacts=artefacts)

    def sampleable(self, object_mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """The object points hands may be sampled on: all but the artefacts."""
        return object_mask if self.artefacts is None else object_mask & ~self.artefacts

    def grasp_objects(self, region: ClosingRegionPoints, num_grasps: int) -> I64:
        """The object each of num_grasps hands closes on: the one with most points in its closing region (ties:
        the lower id); -1 when the region holds no object point."""
        out = np.full(num_grasps, -1, np.int64)
        k = len(self.objects)
        if k == 0 or num_grasps == 0 or len(region.grasp) == 0:
            return out
        lab = self.labels[region.index]
        on = lab >= 0
        votes = np.bincount(region.grasp[on] * k + lab[on], minlength=num_grasps * k).reshape(num_grasps, k)
        best = np.argmax(votes, axis=1)
        has = votes[np.arange(num_grasps), best] > 0
        out[has] = best[has]
        return out


def segment_objects(points: NDArray[np.floating], object_mask: NDArray[np.bool_], gap: float = OBJECT_GAP,
                    min_points: int = MIN_OBJECT_POINTS, min_extent: float = MIN_OBJECT_EXTENT) -> Segmentation:
    """The objects among points (N,3, m) where object_mask holds: groups of points linked by steps of at most gap
    (m), at least min_points each and longer than min_extent (m) in some direction.  Smaller groups (specks: strips
    of a side seen at a grazing angle, noise) join the nearest object; blobs (enough points, but shorter than
    min_extent every way: sensor artefacts) belong to none (label -1).  An object's centre and extent are those of
    its own group.  Ids are ordered by the position of the objects' centres (x, then y, then z)."""
    n = len(points)
    idx = np.flatnonzero(object_mask)
    if len(idx) < min_points:
        return Segmentation.empty(n)
    pts = np.asarray(points, np.float64)[idx]
    group = eps_clusters(pts, gap)
    sizes = np.bincount(group)
    by_group = np.argsort(group, kind="stable")
    first = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    group_lo = np.minimum.reduceat(pts[by_group], first, axis=0)  # each group's bounds: blobs are told by them,
    group_hi = np.maximum.reduceat(pts[by_group], first, axis=0)  # an object's centre and extent are its group's
    blob = (sizes >= min_points) & ((group_hi - group_lo).max(axis=1) < min_extent)
    artefacts = np.zeros(n, bool)
    artefacts[idx[blob[group]]] = True
    keep = np.flatnonzero((sizes >= min_points) & ~blob)
    if len(keep) == 0:
        return Segmentation.empty(n, artefacts)
    kept = np.full(len(sizes), -1, np.int64)
    kept[keep] = np.arange(len(keep))
    label = kept[group]
    solid = np.flatnonzero(label >= 0)
    lo, hi = group_lo[keep], group_hi[keep]
    centres = (lo + hi) / 2.0
    key = np.round(centres / ORDER_RESOLUTION).astype(np.int64)
    order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
    new_id = np.empty(len(keep), np.int64)
    new_id[order] = np.arange(len(keep))
    specks = np.flatnonzero((label < 0) & ~blob[group])
    if len(specks):
        label[specks] = label[solid[cKDTree(pts[solid]).query(pts[specks])[1]]]
    on = label >= 0
    counts = np.bincount(label[on], minlength=len(keep))
    labels = np.full(n, -1, np.int64)
    labels[idx[on]] = new_id[label[on]]
    objects = tuple(SceneObject(id=i, centre=centres[j], extent=hi[j] - lo[j], num_points=int(counts[j]))
                    for i, j in enumerate(order))
    return Segmentation(labels, objects, artefacts)
