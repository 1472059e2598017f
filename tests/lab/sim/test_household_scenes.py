"""Household models in pybullet: simulated with their mesh's mass, centre of mass and inertia, at true size, and
mixed with the catalogue's random_urdfs into piles and packed scenes that settle."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from graspd.core.hand import HandGeometry
from graspd_lab.sim.world import SimWorld, build_scene
from graspd_lab.world import household

TRAINING_HOUSEHOLD = tuple(household.household_id(n) for n in household.training_names())


def test_pybullet_simulates_the_mesh_mass_centre_of_mass_and_inertia() -> None:
    name = "mug"
    props = household.household_mass_properties(name)
    with SimWorld.create(has_tray=False) as world:
        body = world.add_object(household.household_id(name), np.array([0.0, 0.0, 0.3]),
                                np.array([0.0, 0.0, 0.0, 1.0]), 1.0)
        info = pb.getDynamicsInfo(body, -1, physicsClientId=world.client)
        assert info[0] == pytest.approx(props.mass)
        np.testing.assert_allclose(info[2], props.principal_moments, rtol=1e-6)
        np.testing.assert_allclose(info[3], props.com, atol=1e-8)
        # the ground-truth mesh is posed where pybullet holds the body: its link frame is where it was loaded
        ((_, mesh),) = world.object_meshes()
        placed = np.asarray(household.collision_mesh(name).vertices) + [0.0, 0.0, 0.3]
        np.testing.assert_allclose(np.sort(np.asarray(mesh.vertices), axis=0), np.sort(placed, axis=0), atol=1e-7)


def _assert_settled_and_true_size(world: SimWorld) -> None:
    assert any(household.is_household_id(i) for i in world.objects.values())
    for body, object_id in world.objects.items():
        assert np.linalg.norm(pb.getBaseVelocity(body, physicsClientId=world.client)[0]) < 0.05
        assert world.object_position(body)[2] > 0.0
        if household.is_household_id(object_id):
            assert world.scales[body] == 1.0


@pytest.mark.parametrize("kind", ["pile", "packed"])
def test_a_scene_of_household_and_catalogue_objects_builds_and_settles(kind: str) -> None:
    ids = TRAINING_HOUSEHOLD[:30] + tuple(range(10))
    with build_scene(kind, 6, 2, HandGeometry(), object_ids=ids) as world:
        assert len(world.objects) >= 3
        _assert_settled_and_true_size(world)
        x0, x1, y0, y1 = world.inside_region()
        pos = np.array([world.object_position(b) for b in world.objects])
        assert np.all((pos[:, 0] >= x0) & (pos[:, 0] <= x1) & (pos[:, 1] >= y0) & (pos[:, 1] <= y1))
