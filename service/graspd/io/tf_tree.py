"""A tree of static transforms (a bag's /tf_static), composed along the whole chain: the pose of any frame in its
tree's root, or in any other frame of the same tree (through their common root), not one parent-child step."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudError

#: Most frames a tree may hold (robots have tens to a few hundred).
MAX_FRAMES = 10_000


class TfTree:
    """child -> (parent, pose of child in parent (4,4), p_parent = T p_child; m).  A later transform of the same
    child replaces the earlier one (tf2's rule for static transforms)."""

    def __init__(self) -> None:
        self.parents: dict[str, tuple[str, NDArray[np.float64]]] = {}

    def add(self, parent: str, child: str, matrix: NDArray[np.float64], field: str = "tf_static") -> None:
        """Record child's pose in parent."""
        if parent == child:
            raise CloudError(field, f"a transform from frame {child!r} to itself")
        if child not in self.parents and len(self.parents) >= MAX_FRAMES:
            raise CloudError(field, f"more than {MAX_FRAMES} frames")
        self.parents[child] = (parent, np.asarray(matrix, np.float64))

    def __contains__(self, frame: str) -> bool:
        return frame in self.parents or any(parent == frame for parent, _ in self.parents.values())

    def to_root(self, frame: str, field: str = "tf_static") -> tuple[NDArray[np.float64], str]:
        """(pose (4,4) of frame in its root, the root's name): the product of every step of the chain, root
        first.  CloudError naming field on a cycle."""
        pose = np.eye(4)
        seen = {frame}
        while frame in self.parents:
            parent, step = self.parents[frame]
            pose = step @ pose
            if parent in seen:
                raise CloudError(field, f"the transforms form a cycle through frame {parent!r}")
            seen.add(parent)
            frame = parent
        return pose, frame

    def pose(self, frame: str, target: str | None = None, field: str = "frame") -> tuple[NDArray[np.float64], str]:
        """(pose (4,4) of frame in target, target's name); target None: frame's root.  CloudError naming field
        when target is not in frame's tree."""
        pose, root = self.to_root(frame)
        if target is None or target == root:
            return pose, root
        if target not in self:
            raise CloudError(field, f"frame {target!r} is not in the bag's /tf_static (frames: "
                             f"{sorted(self.frames())[:20]})")
        target_pose, target_root = self.to_root(target)
        if target_root != root:
            raise CloudError(field, f"frame {target!r} (tree of {target_root!r}) is not connected to {frame!r} "
                             f"(tree of {root!r}) by /tf_static")
        return np.linalg.inv(target_pose) @ pose, target

    def frames(self) -> set[str]:
        """Every frame named."""
        return set(self.parents) | {parent for parent, _ in self.parents.values()}
