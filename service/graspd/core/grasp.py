"""GraspSet: a batch of 6-DOF grasps as numpy arrays, in the project's grasp convention.

Rotation columns are [approach, binormal, axis] (hand x, y, z); position is the centre of the
hand base; fingertips are at position + hand_depth * approach.  Everything is in the frame of
the cloud the caller sent, in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from graspd.core.types import F64


def _empty(*shape: int) -> F64:
    return np.zeros((0, *shape), np.float64)


def rotation_to_quat_xyzw(rotations: F64) -> F64:
    """Unit quaternions (M,4) in x, y, z, w order for rotation matrices (M,3,3)."""

    if len(rotations) == 0:
        return _empty(4)
    return np.asarray(Rotation.from_matrix(rotations).as_quat(), np.float64)


#: How selection combines the ranking terms (the response's ranking_rule says the same to a person).
RANKING_RULE = ("key = classifier x utility x width x unknown: classifier is the model's probability (1 when "
                "unscored; with robust_copies, for the first grasps by key, averaged over that many copies moved "
                "2 mm and turned 3 degrees, and those grasps sorted among themselves ahead of the rest), utility "
                "J(h) of the IJRR paper (top approaches and high grasps first, from the support up), width in "
                "[0.2, 1] (a grasp whose object fills the opening ranks lower), unknown = 1 - the share of the hand "
                "in space no camera saw; grasps are sorted by key, best first")


@dataclass(frozen=True)
class Ranking:
    """The terms that ranked M grasps (each (M,), dimensionless): see RANKING_RULE."""

    classifier: F64
    utility: F64
    width: F64
    unknown: F64
    key: F64

    def __getitem__(self, index: Any) -> Ranking:
        return Ranking(*(getattr(self, f)[index] for f in ("classifier", "utility", "width", "unknown", "key")))

    def to_dicts(self) -> list[dict[str, float]]:
        cols = (self.classifier, self.utility, self.width, self.unknown, self.key)
        return [{"classifier": float(c), "utility": float(u), "width": float(w), "unknown": float(k),
                 "key": float(y)} for c, u, w, k, y in zip(*cols, strict=True)]


@dataclass(frozen=True)
class GraspSet:
    """M grasps: positions (M,3), rotations (M,3,3), widths (M,), scores (M,), samples (M,3), and unknown (M,):
    the share of each open hand and its approach path that lies in space no camera saw (NaN: not checked);
    objects (M,): the id of the scene object each closes on (graspd.gpd.objects; -1: none or not known).

    scores are NaN until a classifier has scored the set; widths are the object extent between
    the fingers along the binormal (m).  ranking: the terms selection ranked them by (None before selection).
    """

    positions: F64 = field(default_factory=lambda: _empty(3))
    rotations: F64 = field(default_factory=lambda: _empty(3, 3))
    widths: F64 = field(default_factory=lambda: _empty())
    scores: F64 = field(default_factory=lambda: _empty())
    samples: F64 = field(default_factory=lambda: _empty(3))
    unknown: F64 | None = None
    ranking: Ranking | None = None
    objects: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        m = len(self.positions)
        if self.unknown is None:
            object.__setattr__(self, "unknown", np.full(m, np.nan))
        if self.objects is None:
            object.__setattr__(self, "objects", np.full(m, -1, np.int64))
        for name in ("rotations", "widths", "scores", "samples", "unknown", "objects"):
            if len(getattr(self, name)) != m:
                raise ValueError(f"GraspSet.{name} has {len(getattr(self, name))} rows, expected {m}")
        if self.ranking is not None and len(self.ranking.key) != m:
            raise ValueError(f"GraspSet.ranking has {len(self.ranking.key)} rows, expected {m}")

    @property
    def unknown_share(self) -> F64:
        """unknown as an array (M,) (the field is never None after construction)."""
        assert self.unknown is not None
        return self.unknown

    @property
    def object_ids(self) -> NDArray[np.int64]:
        """objects as an array (M,) (the field is never None after construction)."""
        assert self.objects is not None
        return self.objects

    def __len__(self) -> int:
        return int(self.positions.shape[0])

    def __getitem__(self, index: Any) -> GraspSet:
        """Rows at an index, slice, boolean mask or index array (always a GraspSet)."""
        if isinstance(index, (int, np.integer)):
            index = np.array([index])
        return GraspSet(
            positions=self.positions[index],
            rotations=self.rotations[index],
            widths=self.widths[index],
            scores=self.scores[index],
            samples=self.samples[index],
            unknown=self.unknown_share[index],
            ranking=None if self.ranking is None else self.ranking[index],
            objects=self.object_ids[index],
        )

    @property
    def approach(self) -> F64:
        return self.rotations[:, :, 0]

    @property
    def binormal(self) -> F64:
        return self.rotations[:, :, 1]

    @property
    def axis(self) -> F64:
        return self.rotations[:, :, 2]

    @property
    def poses(self) -> F64:
        """Homogeneous hand poses (M,4,4): rotation [approach, binormal, axis], translation position."""
        out = np.zeros((len(self), 4, 4))
        out[:, :3, :3] = self.rotations
        out[:, :3, 3] = self.positions
        out[:, 3, 3] = 1.0
        return out

    @property
    def quat_xyzw(self) -> F64:
        return rotation_to_quat_xyzw(self.rotations)

    def with_scores(self, scores: NDArray[np.floating]) -> GraspSet:
        return replace(self, scores=np.asarray(scores, np.float64).reshape(-1))

    def with_unknown(self, unknown: NDArray[np.floating]) -> GraspSet:
        """The set with each hand's share in unseen space (M,) recorded."""
        return replace(self, unknown=np.asarray(unknown, np.float64).reshape(-1))

    def with_objects(self, objects: NDArray[np.integer]) -> GraspSet:
        """The set with the scene object each grasp closes on (M,) recorded (-1: none)."""
        return replace(self, objects=np.asarray(objects, np.int64).reshape(-1))

    def transformed(self, rotation: NDArray[np.floating], translation: NDArray[np.floating]) -> GraspSet:
        """The grasps moved rigidly by p -> R p + t."""
        r = np.asarray(rotation, np.float64)
        t = np.asarray(translation, np.float64)
        return replace(
            self,
            positions=self.positions @ r.T + t,
            rotations=np.einsum("ij,mjk->mik", r, self.rotations),
            samples=self.samples @ r.T + t,
        )

    @staticmethod
    def concatenate(sets: list[GraspSet]) -> GraspSet:
        if not sets:
            return GraspSet()
        return GraspSet(
            positions=np.concatenate([s.positions for s in sets]),
            rotations=np.concatenate([s.rotations for s in sets]),
            widths=np.concatenate([s.widths for s in sets]),
            scores=np.concatenate([s.scores for s in sets]),
            samples=np.concatenate([s.samples for s in sets]),
            unknown=np.concatenate([s.unknown_share for s in sets]),
            objects=np.concatenate([s.object_ids for s in sets]),
        )

    def to_dicts(self) -> list[dict[str, Any]]:
        """One JSON-ready dict per grasp, with the wire contract's field names (gpd_ros GraspConfig)."""
        quats = self.quat_xyzw
        poses = self.poses
        out = []
        for i in range(len(self)):
            score = float(self.scores[i])
            out.append(
                {
                    "position": self.positions[i].tolist(),
                    "approach": self.approach[i].tolist(),
                    "binormal": self.binormal[i].tolist(),
                    "axis": self.axis[i].tolist(),
                    "width": float(self.widths[i]),
                    "score": None if np.isnan(score) else score,
                    "sample": self.samples[i].tolist(),
                    "pose": poses[i].tolist(),
                    "quat_xyzw": quats[i].tolist(),
                }
            )
        return out
