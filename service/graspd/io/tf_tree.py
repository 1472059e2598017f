"""A tree of transforms (a bag's /tf_static and /tf), composed along the whole chain: the pose of any frame in its
tree's root, or in any other frame of the same tree (through their common root), not one parent-child step.

Static edges (/tf_static) hold at every time.  Dynamic edges (/tf) are looked up at a stamp as tf2 does: the
two transforms of the edge that bracket the stamp are interpolated (translation linearly, rotation by slerp);
a stamp at or outside the ends of the edge's record takes the nearest transform when it lies within
TF_TOLERANCE_NS of the stamp, and is a CloudError otherwise (tf2's extrapolation error): a camera pose from
a stale transform would put the cloud where the camera no longer is."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from graspd.core.cloud import CloudError

#: Most frames a tree may hold (robots have tens to a few hundred).
MAX_FRAMES = 10_000
#: Most dynamic transforms a tree may hold, over all its edges (a 100 Hz tree of 20 frames for 4 minutes).
MAX_SAMPLES = 500_000
#: How far (ns) from a stamp the nearest transform of a dynamic edge may be when the stamp is not between two of
#: them: 0.1 s, a 10 Hz broadcaster's period (an arm moving at 0.5 m/s moves 5 cm in it).
TF_TOLERANCE_NS = 100_000_000


def _seconds(ns: int) -> str:
    """ns as seconds with 3 decimals, for messages."""
    return f"{ns / 1e9:.3f} s"


@dataclass
class _Edge:
    """A dynamic edge's record: stamps (ns), parent names and poses (4,4) of the child in the parent, in the
    order added until sorted (by stamp, stable) for lookups."""

    stamps: list[int]
    parents: list[str]
    poses: list[NDArray[np.float64]]
    ordered: bool = True

    def sort(self) -> None:
        if not self.ordered:
            order = sorted(range(len(self.stamps)), key=self.stamps.__getitem__)
            self.stamps = [self.stamps[k] for k in order]
            self.parents = [self.parents[k] for k in order]
            self.poses = [self.poses[k] for k in order]
            self.ordered = True


def interpolate(a: NDArray[np.float64], b: NDArray[np.float64], fraction: float) -> NDArray[np.float64]:
    """The pose (4,4) a fraction (0..1) of the way from a to b: translation linearly, rotation by slerp."""
    qa, qb = Rotation.from_matrix(a[:3, :3]).as_quat(), Rotation.from_matrix(b[:3, :3]).as_quat()
    if float(qa @ qb) < 0.0:
        qb = -qb  # the shorter way round
    angle = float(np.arccos(np.clip(abs(float(qa @ qb)), -1.0, 1.0)))
    if angle < 1e-9:
        q = qa
    else:
        q = (np.sin((1.0 - fraction) * angle) * qa + np.sin(fraction * angle) * qb) / np.sin(angle)
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
    out[:3, 3] = (1.0 - fraction) * a[:3, 3] + fraction * b[:3, 3]
    return out


class TfTree:
    """Static edges: child -> (parent, pose of child in parent (4,4), p_parent = T p_child; m); a later static
    transform of the same child replaces the earlier one (tf2's rule).  Dynamic edges: child -> its record of
    stamped transforms (_Edge).  A child with dynamic transforms takes them, not a static one."""

    def __init__(self) -> None:
        self.parents: dict[str, tuple[str, NDArray[np.float64]]] = {}
        self.dynamic: dict[str, _Edge] = {}
        self._samples = 0

    def _check(self, parent: str, child: str, field: str) -> None:
        if parent == child:
            raise CloudError(field, f"a transform from frame {child!r} to itself")
        if child not in self.parents and child not in self.dynamic and \
                len(self.parents) + len(self.dynamic) >= MAX_FRAMES:
            raise CloudError(field, f"more than {MAX_FRAMES} frames")

    def add(self, parent: str, child: str, matrix: NDArray[np.float64], field: str = "tf_static") -> None:
        """Record child's static pose in parent."""
        self._check(parent, child, field)
        self.parents[child] = (parent, np.asarray(matrix, np.float64))

    def add_dynamic(self, parent: str, child: str, stamp_ns: int, matrix: NDArray[np.float64],
                    field: str = "tf") -> None:
        """Record child's pose in parent at stamp_ns (ns)."""
        self._check(parent, child, field)
        if self._samples >= MAX_SAMPLES:
            raise CloudError(field, f"more than {MAX_SAMPLES} /tf transforms")
        edge = self.dynamic.setdefault(child, _Edge([], [], []))
        if edge.stamps and stamp_ns < edge.stamps[-1]:
            edge.ordered = False
        edge.stamps.append(int(stamp_ns))
        edge.parents.append(parent)
        edge.poses.append(np.asarray(matrix, np.float64))
        self._samples += 1

    def __contains__(self, frame: str) -> bool:
        return frame in self.frames()

    def step(self, frame: str, stamp_ns: int | None, field: str = "frame"
             ) -> tuple[str, NDArray[np.float64]] | None:
        """(parent, pose of frame in parent) at stamp_ns, None at a root.  A dynamic edge needs a stamp (None:
        its latest transform) and is looked up as the module says; CloudError naming field when no transform of
        it lies close enough."""
        edge = self.dynamic.get(frame)
        if edge is None:
            return self.parents.get(frame)
        edge.sort()
        stamps = edge.stamps
        if stamp_ns is None:
            return edge.parents[-1], edge.poses[-1]
        i = int(np.searchsorted(stamps, stamp_ns, side="right")) - 1  # the last at or before the stamp
        if i >= 0 and stamps[i] == stamp_ns:
            return edge.parents[i], edge.poses[i]
        if 0 <= i < len(stamps) - 1 and edge.parents[i] == edge.parents[i + 1]:
            fraction = (stamp_ns - stamps[i]) / (stamps[i + 1] - stamps[i])
            return edge.parents[i], interpolate(edge.poses[i], edge.poses[i + 1], fraction)
        near = [k for k in (i, i + 1) if 0 <= k < len(stamps)]
        k = min(near, key=lambda j: abs(stamps[j] - stamp_ns))
        if abs(stamps[k] - stamp_ns) > TF_TOLERANCE_NS:
            raise CloudError(field, f"no /tf transform of {frame!r} in {edge.parents[k]!r} within "
                             f"{_seconds(TF_TOLERANCE_NS)} of the message's stamp {_seconds(stamp_ns)} (the "
                             f"bag's span {_seconds(stamps[0])} to {_seconds(stamps[-1])})")
        return edge.parents[k], edge.poses[k]

    def to_root(self, frame: str, field: str = "frame", stamp_ns: int | None = None
                ) -> tuple[NDArray[np.float64], str]:
        """(pose (4,4) of frame in its root, the root's name) at stamp_ns: the product of every step of the chain,
        root first.  CloudError naming field on a cycle or a dynamic step with no transform near the stamp."""
        pose = np.eye(4)
        seen = {frame}
        while True:
            found = self.step(frame, stamp_ns, field)
            if found is None:
                return pose, frame
            parent, step = found
            pose = step @ pose
            if parent in seen:
                raise CloudError(field, f"the transforms form a cycle through frame {parent!r}")
            seen.add(parent)
            frame = parent

    def pose(self, frame: str, target: str | None = None, field: str = "frame", stamp_ns: int | None = None
             ) -> tuple[NDArray[np.float64], str]:
        """(pose (4,4) of frame in target at stamp_ns, target's name); target None: frame's root.  CloudError
        naming field when target is not in frame's tree."""
        pose, root = self.to_root(frame, field, stamp_ns)
        if target is None or target == root:
            return pose, root
        if target not in self:
            raise CloudError(field, f"frame {target!r} is not in the bag's /tf_static or /tf (frames: "
                             f"{sorted(self.frames())[:20]})")
        target_pose, target_root = self.to_root(target, field, stamp_ns)
        if target_root != root:
            raise CloudError(field, f"frame {target!r} (tree of {target_root!r}) is not connected to {frame!r} "
                             f"(tree of {root!r}) by /tf_static and /tf")
        return np.linalg.inv(target_pose) @ pose, target

    def frames(self) -> set[str]:
        """Every frame named."""
        out = set(self.parents) | {parent for parent, _ in self.parents.values()} | set(self.dynamic)
        for edge in self.dynamic.values():
            out.update(edge.parents)
        return out
