"""The benchmark's objects: the held-out test objects, pybullet_data random_urdfs 900-999 (DESIGN.md),
loaded through graspd.world.objects (the one catalogue and held-out guard) with held_out_ok, scaled to
fit the hand.

Each mesh is already a set of convex pieces ("o convex_k" groups), which pybullet loads as a compound,
so the simulated contact geometry equals the rendered geometry (concavities included).
"""

from __future__ import annotations

from ..hand import HandGeometry
from ..world import objects as catalogue
from ..world.objects import URDF_MESH_SCALE

#: Held-out object ids; never 000-899, which are training objects.
TEST_OBJECT_IDS: tuple[int, ...] = tuple(catalogue.HELD_OUT_URDFS)

__all__ = ["TEST_OBJECT_IDS", "URDF_MESH_SCALE", "graspable_scale", "mesh_extents", "object_urdf"]


def _check_test_object(object_id: int) -> None:
    if object_id not in TEST_OBJECT_IDS:
        raise ValueError(f"object_id must be a held-out test object in 900..999, got {object_id}")


def object_urdf(object_id: int) -> str:
    """URDF path of a held-out test object; ValueError for ids outside 900..999."""
    _check_test_object(object_id)
    return str(catalogue.urdf_path(object_id, held_out_ok=True))


def mesh_extents(object_id: int) -> tuple[float, float, float]:
    """Sorted extents (m, smallest first) of a held-out test object's mesh at its URDF scale."""
    _check_test_object(object_id)
    return catalogue.mesh_extents(object_id, held_out_ok=True)


def graspable_scale(object_id: int, hand: HandGeometry, fill: float = 0.7) -> float:
    """globalScaling (<= 1) of a held-out test object (graspd.world.objects.graspable_scale)."""
    _check_test_object(object_id)
    return catalogue.graspable_scale(object_id, hand, fill, held_out_ok=True)
