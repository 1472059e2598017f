"""Grasp labels from physics: does the grasp hold the object through a lift?

Each candidate grasp (world frame) is executed on the settled scene by the clutter benchmark's hand and motion
(graspd_lab.sim.gripper.Gripper.execute: pre-grasp, approach, close with 40 N per finger, lift 25 cm, hold
0.5 s), then the scene is put back exactly as it was (a pybullet saved state) for the next one.  A grasp holds
(label 1) only if something stays in the fingers above half the lift height and turned at most MAX_TURN_DEG in
the hand; slips (a drop, or a heavy or long object grasped far from its centre of mass that twists in the
fingers), empty closes and collisions are 0.  Masses and inertias are the simulator's: a household model's
from its URDF (mesh inertia at uniform density), a random_urdfs object's from pybullet.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np
import pybullet as pb
from numpy.typing import NDArray

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd_lab.sim.gripper import ExecutionParams, Gripper, Outcome
from graspd_lab.sim.world import SimWorld

#: The most (deg) a lifted object may turn in the fingers and still count as held.  An object seats between the
#: flat finger pads by a few degrees as it leaves its support (the analytic positives of household scenes that
#: stay lifted turn a median 5 degrees, three in four under 11); one grasped far from its centre of mass swings
#: until it hangs (a 1.5 kg, 40 cm bar held 3-11 cm from an end: 43-52 degrees).  At 15 degrees the far end of a
#: 20 cm object has moved 5 cm: it no longer sits in the hand where the grasp put it.
MAX_TURN_DEG = 15.0
#: The benchmark's execution (graspd_lab.sim.gripper.ExecutionParams) with turns in the fingers counted as slips.
LIFT_PARAMS = ExecutionParams(max_turn_deg=MAX_TURN_DEG)


@dataclass(frozen=True)
class LiftResult:
    """Per grasp (M,): held (the physics label), outcome name (graspd_lab.sim.gripper.Outcome values), the
    most any lifted object turned in the hand (deg; NaN where nothing was lifted: a drop, empty close or
    collision), the object id (world.objects' values) the hand went for and its body (-1: none near)."""

    held: NDArray[np.bool_]
    outcomes: tuple[str, ...]
    turn_deg: F64
    objects: NDArray[np.int64]
    bodies: NDArray[np.int64]

    def counts(self) -> dict[str, int]:
        """How many grasps ended how: the outcome names, a slip split into "dropped" and "turned"."""
        names = [("turned" if np.isfinite(t) else "dropped") if o == Outcome.SLIPPED.value else o
                 for o, t in zip(self.outcomes, self.turn_deg, strict=True)]
        return dict(sorted(Counter(names).items()))


def lift_labels(world: SimWorld, grasps: GraspSet, hand: HandGeometry,
                params: ExecutionParams = LIFT_PARAMS) -> LiftResult:
    """Execute every grasp of grasps (world frame) on the world as it is now, restoring it after each; the world
    is left exactly as found (the hand taken out again).  params.max_turn_deg sets what a turn in the fingers
    may be (LIFT_PARAMS: MAX_TURN_DEG)."""
    c = world.client
    m = len(grasps)
    outcomes: list[str] = []
    turns = np.full(m, np.nan)
    objects = np.full(m, -1, np.int64)
    bodies = np.full(m, -1, np.int64)
    if m == 0:
        return LiftResult(np.zeros(0, bool), (), turns, objects, bodies)
    gripper = Gripper(world, hand, params)
    state = pb.saveState(physicsClientId=c)
    try:
        for i in range(m):
            attempt = gripper.execute(grasps, i, clear=False)
            outcomes.append(attempt.outcome.value)
            turns[i] = attempt.turn_deg
            if attempt.target is not None:
                objects[i] = world.objects[attempt.target]
                bodies[i] = attempt.target
            pb.restoreState(stateId=state, physicsClientId=c)
    finally:
        pb.removeState(state, physicsClientId=c)
        gripper.remove()
    held = np.array([o == Outcome.SUCCESS.value for o in outcomes], bool)
    return LiftResult(held, tuple(outcomes), turns, objects, bodies)


__all__ = ["LIFT_PARAMS", "MAX_TURN_DEG", "LiftResult", "lift_labels"]
