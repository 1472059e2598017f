"""Physics lift labels: a grasp is labelled 1 only if the object stays in the fingers through the lift without
turning more than MAX_TURN_DEG; a heavy bar held at one end twists out (a slip), held at its middle it holds."""

from __future__ import annotations

import numpy as np
import pybullet as pb

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd_lab.sim.gripper import Outcome
from graspd_lab.sim.lift import MAX_TURN_DEG, lift_labels
from graspd_lab.sim.world import SimWorld

#: A 40 x 3 x 3 cm bar of 1.5 kg (a full bottle's weight on a rolling pin's length), lying along world x.
BAR_HALF = (0.20, 0.015, 0.015)
BAR_MASS = 1.5


def _bar_world() -> tuple[SimWorld, int]:
    """A table with the bar resting on it, centred at the origin; the bar is an object of the world (the hand
    may grasp it) with the scene objects' friction."""
    world = SimWorld.create(has_tray=False)
    body = world._box(list(BAR_HALF), [0.0, 0.0, BAR_HALF[2]], mass=BAR_MASS)
    pb.changeDynamics(body, -1, lateralFriction=1.0, spinningFriction=0.002, rollingFriction=0.0005,
                      physicsClientId=world.client)
    world.objects[body] = -1  # no catalogue id: a box made here
    world.settle()
    return world, body


def _top_down(x: F64, hand: HandGeometry) -> GraspSet:
    """Top-down grasps across the bar at each x (m along the bar): approach -z, fingers closing along y, the
    fingertips 1 cm above the table."""
    xs = np.asarray(x, np.float64)
    rot = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # columns: approach, closing, axis
    z = 0.01 + hand.hand_depth  # the base sits hand_depth above the fingertips
    m = len(xs)
    return GraspSet(positions=np.c_[xs, np.zeros(m), np.full(m, z)], rotations=np.repeat(rot[None], m, 0),
                    widths=np.full(m, 2 * BAR_HALF[1]), scores=np.zeros(m), samples=np.c_[xs, np.zeros((m, 2))])


def test_a_heavy_bar_grasped_at_one_end_twists_out_and_at_its_middle_holds() -> None:
    hand = HandGeometry()
    world, body = _bar_world()
    with world:
        before = pb.getBasePositionAndOrientation(body, physicsClientId=world.client)
        result = lift_labels(world, _top_down(np.array([BAR_HALF[0] - 0.03, 0.0, BAR_HALF[0] - 0.03]), hand), hand)
        after = pb.getBasePositionAndOrientation(body, physicsClientId=world.client)
        n_bodies = pb.getNumBodies(physicsClientId=world.client)
    end, middle = 0, 1
    assert result.outcomes[end] == Outcome.SLIPPED.value, result
    assert not result.held[end]
    assert result.turn_deg[end] > MAX_TURN_DEG  # it stayed in the fingers, twisted: a slip, not a drop
    assert result.outcomes[middle] == Outcome.SUCCESS.value and result.held[middle], result
    assert result.turn_deg[middle] < MAX_TURN_DEG
    # the scene is put back exactly after each lift (the same grasp again twists the same) and the hand taken
    # out: the bar lies where it lay
    assert result.outcomes[2] == result.outcomes[end] and result.turn_deg[2] == result.turn_deg[end]
    np.testing.assert_allclose(after[0], before[0], atol=1e-6)
    assert n_bodies == 2  # the table and the bar
