"""Grasp detectors behind one small interface, as the benchmark sees them.

- TopDownBaseline: no learning; vertical grasps at the highest points, closing across the narrow side.
- InProcessGPD: graspd.gpd.detector.GraspDetector in this process (optionally with a classifier).
- ServiceGPD: the graspd service over HTTP through graspd_client.GraspClient.
All take a world-frame ViewpointCloud and return world-frame grasps, best first.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy.spatial import cKDTree

from graspd.core.cloud import ViewpointCloud
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.points import voxel_downsample
from graspd.core.types import F64
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd_client import GraspClient, Grasps

Workspace = tuple[float, float, float, float, float, float]


class SimDetector(Protocol):
    """What the benchmark needs from a detector."""

    name: str

    def detect(self, cloud: ViewpointCloud, workspace: Workspace, hand: HandGeometry, seed: int) -> GraspSet:
        """Grasps in the cloud's frame, best first (scores NaN when unscored).  workspace [xmin, xmax, ymin,
        ymax, zmin, zmax] is the box around the scene the robot looks at, table and tray walls included (what
        a user sends as the request's workspace)."""
        ...


def hand_frame_points(points: F64, position: F64, rotation: F64) -> F64:
    """Points (N,3) expressed in the hand frame (x approach, y binormal, z axis) of one grasp."""
    return (points - position) @ rotation


def hand_collides(local: F64, hand: HandGeometry, opening: float) -> bool:
    """True if any hand-frame point lies inside the palm (hand.palm_depth deep) or the two fingers opened to
    `opening` (m)."""
    return bool(hand.body_contains(local, opening).any())


@dataclass
class TopDownBaseline:
    """Vertical grasps at local height maxima, closing across the narrowest horizontal direction there.

    The fingertips go bite (m) below the local top; the hand is centred on the points between the
    fingers and rejected if a cloud point lies inside a finger or the palm.  Ranked by height.
    """

    name: str = "baseline"
    bite: float = 0.025
    cell: float = 0.01
    seed_spacing: float = 0.03
    max_seeds: int = 40
    num_yaws: int = 8
    max_grasps: int = 10
    inset: float = 0.025

    def detect(self, cloud: ViewpointCloud, workspace: Workspace, hand: HandGeometry, seed: int) -> GraspSet:
        pts = voxel_downsample(cloud.points.astype(np.float64), 0.004)
        floor = max(workspace[4], 0.0)
        pts = pts[pts[:, 2] > floor + 0.005]
        if len(pts) == 0:
            return GraspSet()
        # seeds: the highest point of each seed_spacing cell of the xy grid, highest first
        cells = np.floor(pts[:, :2] / self.seed_spacing).astype(np.int64)
        order = np.lexsort((-pts[:, 2], cells[:, 1], cells[:, 0]))
        first = np.ones(len(order), bool)
        first[1:] = np.any(np.diff(cells[order], axis=0) != 0, axis=1)
        tops = pts[order[first]]
        # seeds well inside the box (a workspace drawn around a tray holds its walls)
        inset = self.inset
        inside = ((tops[:, 0] > workspace[0] + inset) & (tops[:, 0] < workspace[1] - inset)
                  & (tops[:, 1] > workspace[2] + inset) & (tops[:, 1] < workspace[3] - inset))
        tops = tops[inside]
        seeds = tops[np.argsort(-tops[:, 2])][: self.max_seeds]
        tree = cKDTree(pts[:, :2])
        out: list[tuple[F64, F64, float, float]] = []
        approach = np.array([0.0, 0.0, -1.0])
        usable = hand.max_aperture - 0.01
        for top, idx in zip(seeds, tree.query_ball_point(seeds[:, :2], 0.08), strict=True):
            near = pts[idx]
            slab = near[near[:, 2] > top[2] - self.bite]
            xy = slab[:, :2] - slab[:, :2].mean(axis=0)
            cov = xy.T @ xy / max(len(xy), 1)
            _, vecs = np.linalg.eigh(cov)
            base = np.arctan2(vecs[1, 0], vecs[0, 0])  # narrowest direction first
            best = None
            for yaw in base + np.linspace(0, np.pi, self.num_yaws, endpoint=False):
                b = np.array([np.cos(yaw), np.sin(yaw), 0.0])
                rot = np.column_stack([approach, b, np.cross(approach, b)])
                tip = top[2] - self.bite
                if tip < floor + 0.003:
                    tip = floor + 0.003
                pos = np.array([top[0], top[1], tip + hand.hand_depth])
                local = hand_frame_points(near, pos, rot)
                between = local[(np.abs(local[:, 2]) < hand.hand_height / 2) & (local[:, 0] >= 0)
                                & (local[:, 0] < hand.hand_depth) & (np.abs(local[:, 1]) < 0.08)]
                # grow the closing region from the seed until a gap of 1 cm separates the object
                ys = np.sort(between[:, 1])
                if len(ys) == 0:
                    continue
                gaps = np.flatnonzero(np.diff(ys) > 0.01)
                centre_idx = int(np.searchsorted(ys, 0.0))
                lo_cut = gaps[gaps < centre_idx]
                hi_cut = gaps[gaps >= centre_idx]
                y_lo = ys[lo_cut[-1] + 1] if len(lo_cut) else ys[0]
                y_hi = ys[hi_cut[0]] if len(hi_cut) else ys[-1]
                width = float(y_hi - y_lo)
                if width > usable:
                    continue
                pos = pos + b * (y_lo + y_hi) / 2
                local = hand_frame_points(near, pos, rot)
                if hand_collides(local, hand, hand.max_aperture):
                    continue
                if best is None or width < best[2]:
                    best = (pos, rot, width, float(top[2]))
            if best is not None:
                out.append(best)
                if len(out) >= self.max_grasps:
                    break
        if not out:
            return GraspSet()
        return GraspSet(
            positions=np.array([o[0] for o in out]),
            rotations=np.array([o[1] for o in out]),
            widths=np.array([o[2] for o in out]),
            scores=np.array([o[3] for o in out]),
            samples=np.array([o[0] + hand.hand_depth * approach for o in out]),
        )


@dataclass
class InProcessGPD:
    """graspd's GraspDetector in this process; classifier None is the paper's "no classification"."""

    name: str = "gpd"
    classifier: Any = None
    options: dict[str, Any] = field(default_factory=dict)
    #: The warning codes of the last detection (what a robot acting on the answer reads: Setting.relook, flat_retry).
    warned: frozenset[str] = field(default=frozenset(), init=False, repr=False)

    def detect(self, cloud: ViewpointCloud, workspace: Workspace, hand: HandGeometry, seed: int) -> GraspSet:
        params = DetectionParams(seed=seed, workspace=workspace,
                                 use_classifier=self.classifier is not None, **self.options)
        found = GraspDetector(classifier=self.classifier, hand=hand).detect(cloud, params, hand=hand)
        self.warned = frozenset(w.code for w in found.warnings)
        return found.grasps


@dataclass
class ServiceGPD:
    """The graspd service over HTTP, through the robot-side client library (graspd_client.GraspClient), called
    as a user calls it: the cloud, its cameras, the hand, a workspace box around the scene and the service's
    defaults for everything else (options only for named ablations); model None is the server's default."""

    url: str
    name: str = "gpd-service"
    model: str | None = None
    options: dict[str, Any] = field(default_factory=dict)
    #: The last answer as the client parsed it (its scene_objects and each grasp's ranking: bench/oracle.py's records).
    last: Grasps | None = field(default=None, init=False, repr=False)

    def detect(self, cloud: ViewpointCloud, workspace: Workspace, hand: HandGeometry, seed: int) -> GraspSet:
        with GraspClient(self.url, timeout=120.0) as client:
            g = self.last = client.detect(cloud.points, cloud.viewpoints, cloud.camera_source, workspace=workspace,
                              hand=hand.to_dict(), model=self.model, seed=seed % (2**32), **self.options)
        return GraspSet(positions=g.positions, rotations=g.rotations, widths=g.widths, scores=g.scores,
                        samples=g.samples)

    @property
    def warned(self) -> frozenset[str]:
        """The warning codes of the last answer (what a robot acting on the answer reads: Setting.relook,
        flat_retry)."""
        return frozenset() if self.last is None else frozenset(w["code"] for w in self.last.warnings)
