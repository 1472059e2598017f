"""The held-out test objects: pybullet_data random_urdfs 900-999 (DESIGN.md), scaled to fit the hand.

Each mesh is already a set of convex pieces ("o convex_k" groups), which pybullet loads as a compound,
so the simulated contact geometry equals the rendered geometry (concavities included).
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pybullet_data

from ..hand import HandGeometry

#: Held-out object ids; never 000-899, which are training objects.
TEST_OBJECT_IDS: tuple[int, ...] = tuple(range(900, 1000))

#: Scale of the meshes in their own URDF files (mesh units -> metres).
URDF_MESH_SCALE = 0.015


def object_dir(object_id: int) -> Path:
    """Folder of one random_urdfs object; ValueError for ids outside the held-out test set."""
    if object_id not in TEST_OBJECT_IDS:
        raise ValueError(f"object_id must be a held-out test object in 900..999, got {object_id}")
    return Path(pybullet_data.getDataPath()) / "random_urdfs" / f"{object_id:03d}"


def object_urdf(object_id: int) -> str:
    return str(object_dir(object_id) / f"{object_id:03d}.urdf")


@cache
def mesh_extents(object_id: int) -> tuple[float, float, float]:
    """Sorted extents (m, smallest first) of the object's mesh at its URDF scale."""
    path = object_dir(object_id) / f"{object_id:03d}.obj"
    verts = np.array(
        [ln.split()[1:4] for ln in path.read_text().splitlines() if ln.startswith("v ")], np.float64
    )
    ext = np.sort(np.ptp(verts, axis=0)) * URDF_MESH_SCALE
    return float(ext[0]), float(ext[1]), float(ext[2])


def graspable_scale(object_id: int, hand: HandGeometry, fill: float = 0.7) -> float:
    """globalScaling (<= 1) so the object's middle extent is at most fill * the hand's max aperture:
    every object then has a way to fit between the open fingers, as the paper chose its test set."""
    middle = mesh_extents(object_id)[1]
    return float(min(1.0, fill * hand.max_aperture / middle))
