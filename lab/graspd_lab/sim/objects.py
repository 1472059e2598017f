"""The simulator's objects: the benchmark's held-out test objects, pybullet_data random_urdfs 900-999
(the project's design notes), and the training objects 000-899 of the scene training data, loaded through
graspd_lab.world.objects (the one catalogue and held-out guard), scaled to fit the hand; and the household
models (ids graspd_lab.world.household.HOUSEHOLD_ID_BASE + k) at their true size (scale 1), with the inertia
and centre of mass of their collision mesh (pybullet reads them from the URDF: load_flags).  Which ids a world
holds is the caller's choice: the benchmark passes TEST_OBJECT_IDS (or household.HELD_OUT's ids), training
passes training ids only (graspd_lab.training.scene_data checks every id against the held-out rules).

Each mesh is already a set of convex pieces ("o convex_k" groups), which pybullet loads as a compound,
so the simulated contact geometry equals the rendered geometry (concavities included).
"""

from __future__ import annotations

import open3d as o3d
import pybullet as pb

from graspd.core.hand import HandGeometry
from graspd_lab.world import household
from graspd_lab.world import objects as catalogue
from graspd_lab.world.objects import URDF_MESH_SCALE

#: Held-out object ids; never 000-899, which are training objects.
TEST_OBJECT_IDS: tuple[int, ...] = tuple(catalogue.HELD_OUT_URDFS)

__all__ = ["TEST_OBJECT_IDS", "URDF_MESH_SCALE", "body_mesh", "graspable_scale", "load_flags", "mesh_extents",
           "object_urdf"]


def _check_test_object(object_id: int) -> None:
    if object_id not in TEST_OBJECT_IDS:
        raise ValueError(f"object_id must be a held-out test object in 900..999, got {object_id}")


def object_urdf(object_id: int) -> str:
    """URDF path of a random_urdfs object (held-out test or training) or a household model (any: the caller
    guards training); ValueError for any other id."""
    _check_object(object_id)
    if household.is_household_id(object_id):
        return str(household.household_urdf(household.household_name(object_id), held_out_ok=True))
    return str(catalogue.urdf_path(object_id, held_out_ok=object_id in TEST_OBJECT_IDS))


def load_flags(object_id: int) -> int:
    """pybullet.loadURDF flags of an object: a household model's URDF carries its mesh's inertia
    (URDF_USE_INERTIA_FROM_FILE; without it pybullet recomputes one from the collision shape's box)."""
    return int(pb.URDF_USE_INERTIA_FROM_FILE) if household.is_household_id(object_id) else 0


def _check_object(object_id: int) -> None:
    if not (0 <= object_id < TEST_OBJECT_IDS[-1] + 1 or household.is_household_id(object_id)):
        raise ValueError(f"object_id must be a random_urdfs object in 0..999 or a household model "
                         f"({household.HOUSEHOLD_ID_BASE}+k), got {object_id}")


def mesh_extents(object_id: int) -> tuple[float, float, float]:
    """Sorted extents (m, smallest first) of a held-out test object's mesh at its URDF scale."""
    _check_test_object(object_id)
    return catalogue.mesh_extents(object_id, held_out_ok=True)


def graspable_scale(object_id: int, hand: HandGeometry, fill: float = 0.7) -> float:
    """globalScaling (<= 1) of a held-out test or training object (graspd_lab.world.objects.graspable_scale);
    1 for a household model (true size, never rescaled for the hand)."""
    _check_object(object_id)
    if household.is_household_id(object_id):
        return 1.0
    return catalogue.graspable_scale(object_id, hand, fill, held_out_ok=object_id in TEST_OBJECT_IDS)


def body_mesh(object_id: int, scale: float) -> o3d.geometry.TriangleMesh:
    """The object's mesh in its body frame as pybullet simulates it at globalScaling scale (m): the frame
    getBasePositionAndOrientation poses (for a household model its inertial frame: centre of mass, principal
    axes; scale must be 1)."""
    _check_object(object_id)
    if household.is_household_id(object_id):
        if scale != 1.0:
            raise ValueError(f"household models keep their true size (scale 1), got scale {scale}")
        return household.body_frame_mesh(household.household_name(object_id), held_out_ok=True)
    return catalogue.urdf_mesh(object_id, scale, held_out_ok=object_id in TEST_OBJECT_IDS)
