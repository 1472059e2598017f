"""Light objects squeezed by 40 N fingers stay in the hand: a 5 g and a 20 g packet lying flat, grasped top-down
across their middle, are lifted out.  With pybullet's default 50 solver iterations both squirted out of the
closed hand (slipped, or the fingers closed on nothing), a failure no real hand has; the standard
clutter-removal benchmark's simulator runs 150 (graspd_lab.sim.world.SOLVER_ITERATIONS)."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd_lab.sim.gripper import Gripper, Outcome
from graspd_lab.sim.world import SOLVER_ITERATIONS, SimWorld

#: The household objects' hand: a Panda-like 7.5 cm opening.
HAND = HandGeometry(finger_width=0.01, hand_outer_diameter=0.095, hand_depth=0.045, hand_height=0.02,
                    init_bite=0.01, palm_depth=0.06)


@pytest.mark.parametrize(("half", "mass"), [((0.045, 0.0275, 0.016), 0.020),  # a 9 x 5.5 x 3.2 cm packet, 20 g
                                            ((0.040, 0.025, 0.012), 0.005)])  # an 8 x 5 x 2.4 cm sachet, 5 g
def test_a_light_packet_grasped_across_its_middle_is_lifted_out(half: tuple[float, float, float],
                                                                 mass: float) -> None:
    world = SimWorld.create(has_tray=False)
    with world:
        assert pb.getPhysicsEngineParameters(physicsClientId=world.client)["numSolverIterations"] == SOLVER_ITERATIONS
        body = world._box(list(half), [0.0, 0.0, half[2]], mass=mass)
        pb.changeDynamics(body, -1, lateralFriction=1.0, spinningFriction=0.002, rollingFriction=0.0005,
                          physicsClientId=world.client)
        world.objects[body] = -1  # no catalogue id: a box made here
        world.settle()
        # top-down, fingers closing along y across the packet, fingertips 1 cm below its top
        rot = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
        z = 2 * half[2] - 0.01 + HAND.hand_depth
        grasp = GraspSet(positions=np.array([[0.0, 0.0, z]]), rotations=rot[None], widths=np.array([2 * half[1]]),
                         scores=np.zeros(1), samples=np.zeros((1, 3)))
        attempt = Gripper(world, HAND).execute(grasp, 0)
    assert attempt.outcome is Outcome.SUCCESS, attempt
