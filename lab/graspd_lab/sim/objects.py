"""The simulator's objects: the benchmark's held-out test objects, pybullet_data random_urdfs 900-999
(DESIGN.md), and the training objects 000-899 of the scene training data, loaded through
graspd_lab.world.objects (the one catalogue and held-out guard), scaled to fit the hand.  Which ids a world
holds is the caller's choice: the benchmark passes TEST_OBJECT_IDS, training passes training ids only.

Each mesh is already a set of convex pieces ("o convex_k" groups), which pybullet loads as a compound,
so the simulated contact geometry equals the rendered geometry (concavities included).
"""

from __future__ import annotations

import open3d as o3d

from graspd.core.hand import HandGeometry
from graspd_lab.world import objects as catalogue
from graspd_lab.world.objects import URDF_MESH_SCALE

#: Held-out object ids; never 000-899, which are training objects.
TEST_OBJECT_IDS: tuple[int, ...] = tuple(catalogue.HELD_OUT_URDFS)

__all__ = ["TEST_OBJECT_IDS", "URDF_MESH_SCALE", "body_mesh", "graspable_scale", "mesh_extents", "object_urdf"]


def _check_test_object(object_id: int) -> None:
    if object_id not in TEST_OBJECT_IDS:
        raise ValueError(f"object_id must be a held-out test object in 900..999, got {object_id}")


def object_urdf(object_id: int) -> str:
    """URDF path of a random_urdfs object (held-out test or training); ValueError outside 0..999."""
    _check_object(object_id)
    return str(catalogue.urdf_path(object_id, held_out_ok=object_id in TEST_OBJECT_IDS))


def _check_object(object_id: int) -> None:
    if not 0 <= object_id < TEST_OBJECT_IDS[-1] + 1:
        raise ValueError(f"object_id must be a random_urdfs object in 0..999, got {object_id}")


def mesh_extents(object_id: int) -> tuple[float, float, float]:
    """Sorted extents (m, smallest first) of a held-out test object's mesh at its URDF scale."""
    _check_test_object(object_id)
    return catalogue.mesh_extents(object_id, held_out_ok=True)


def graspable_scale(object_id: int, hand: HandGeometry, fill: float = 0.7) -> float:
    """globalScaling (<= 1) of a held-out test or training object (graspd_lab.world.objects.graspable_scale)."""
    _check_object(object_id)
    return catalogue.graspable_scale(object_id, hand, fill, held_out_ok=object_id in TEST_OBJECT_IDS)


def body_mesh(object_id: int, scale: float) -> o3d.geometry.TriangleMesh:
    """The object's mesh in its body frame as pybullet simulates it at globalScaling scale (m)."""
    _check_object(object_id)
    return catalogue.urdf_mesh(object_id, scale, held_out_ok=object_id in TEST_OBJECT_IDS)
