"""A free-floating parallel-jaw hand built from pybullet boxes to match a HandGeometry, and grasp execution.

Hand frame = grasp frame of graspd.core.grasp: x approach, y closing (binormal), z axis; origin at the centre of
the hand base.  The palm is a box hand.palm_depth deep behind x = 0; two finger boxes span x in
[0, hand_depth] and slide
along y on prismatic joints.  A fixed constraint to the world moves the base (a stiff, force-limited arm).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import pybullet as pb
from scipy.spatial.transform import Rotation

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd_lab.sim.world import SimWorld

PARK = np.array([0.0, 0.0, 2.0])


class Outcome(StrEnum):
    """Result of one grasp attempt (the paper's failure classes)."""

    SUCCESS = "success"
    NO_GRASP = "no_grasp"
    COLLISION = "collision"
    EMPTY = "empty_close"
    SLIPPED = "slipped"


@dataclass(frozen=True)
class ExecutionParams:
    """Motion and force settings: pre-grasp distance (m) back along the approach (the service's default
    approach_distance, as in the common clutter-removal protocols), approach speed (m/s),
    lift height (m), finger force (N) and closing speed (m/s), hold time (s)."""

    pregrasp_distance: float = 0.05
    approach_speed: float = 0.2
    lift_height: float = 0.25
    lift_speed: float = 0.3
    finger_force: float = 40.0
    close_speed: float = 0.1
    hold_seconds: float = 0.5
    arm_force: float = 300.0
    reach_tolerance: float = 0.01
    #: A lifted object that turned more than this (deg) in the fingers between closing and the end of the hold
    #: slipped; None: only a drop is a slip (the clutter protocol: an object lifted out is cleared however it hangs).
    max_turn_deg: float | None = None


@dataclass(frozen=True)
class Attempt:
    """What happened: outcome, the object the hand went for (None if none near), those lifted out, and turn_deg:
    the most any object still in the fingers after the hold turned relative to the hand since closing (deg;
    NaN when nothing was lifted)."""

    outcome: Outcome
    target: int | None
    removed: tuple[int, ...] = ()
    turn_deg: float = float("nan")


def _rot_quat(rotation: F64) -> list[float]:
    return [float(v) for v in Rotation.from_matrix(rotation).as_quat()]


class Gripper:
    """The hand in one world; call execute() once per grasp."""

    def __init__(self, world: SimWorld, hand: HandGeometry, params: ExecutionParams | None = None) -> None:
        self.world = world
        self.hand = hand
        self.params = params or ExecutionParams()
        c = world.client
        fw, od, hd, hh = hand.finger_width, hand.hand_outer_diameter, hand.hand_depth, hand.hand_height
        pd = max(hand.palm_depth, 0.005)  # the hand's body behind the finger roots (a sliver when it has none)
        palm_col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[pd / 2, od / 2, hh / 2],
                                           collisionFramePosition=[-pd / 2, 0, 0], physicsClientId=c)
        palm_vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[pd / 2, od / 2, hh / 2],
                                        visualFramePosition=[-pd / 2, 0, 0],
                                        rgbaColor=[0.2, 0.2, 0.2, 1], physicsClientId=c)
        fing_col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[hd / 2, fw / 2, hh / 2], physicsClientId=c)
        fing_vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[hd / 2, fw / 2, hh / 2],
                                        rgbaColor=[0.3, 0.3, 0.8, 1], physicsClientId=c)
        self.travel = od / 2 - fw  # each finger's stroke from open to the centre line
        y0 = od / 2 - fw / 2
        self.body = pb.createMultiBody(
            baseMass=1.0, baseCollisionShapeIndex=palm_col, baseVisualShapeIndex=palm_vis,
            basePosition=PARK.tolist(),
            linkMasses=[0.05, 0.05], linkCollisionShapeIndices=[fing_col, fing_col],
            linkVisualShapeIndices=[fing_vis, fing_vis],
            linkPositions=[[hd / 2, y0, 0], [hd / 2, -y0, 0]],
            linkOrientations=[[0, 0, 0, 1]] * 2, linkInertialFramePositions=[[0, 0, 0]] * 2,
            linkInertialFrameOrientations=[[0, 0, 0, 1]] * 2, linkParentIndices=[0, 0],
            linkJointTypes=[pb.JOINT_PRISMATIC] * 2, linkJointAxis=[[0, -1, 0], [0, 1, 0]],
            physicsClientId=c)
        for j in (-1, 0, 1):
            pb.changeDynamics(self.body, j, lateralFriction=1.0, spinningFriction=0.01, physicsClientId=c)
        self.constraint = pb.createConstraint(self.body, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0], [0, 0, 0],
                                              PARK.tolist(), physicsClientId=c)
        self.park()

    # --- low-level -----------------------------------------------------------------------------------
    def _teleport(self, position: F64, quat: list[float]) -> None:
        c = self.world.client
        pb.resetBasePositionAndOrientation(self.body, position.tolist(), quat, physicsClientId=c)
        pb.changeConstraint(self.constraint, position.tolist(), quat, maxForce=self.params.arm_force,
                            physicsClientId=c)

    def _set_fingers(self, opening: float, force: float) -> None:
        q = self.travel - opening / 2  # joint value: 0 = open, travel = closed on the centre line
        for j in (0, 1):
            pb.setJointMotorControl2(self.body, j, pb.POSITION_CONTROL, targetPosition=float(q), force=force,
                                     maxVelocity=self.params.close_speed, physicsClientId=self.world.client)

    def _open_now(self) -> None:
        for j in (0, 1):
            pb.resetJointState(self.body, j, 0.0, physicsClientId=self.world.client)
        self._set_fingers(2 * self.travel, self.params.finger_force)

    def remove(self) -> None:
        """Take the hand out of the world (its body and arm constraint); the objects stay as they are."""
        pb.removeConstraint(self.constraint, physicsClientId=self.world.client)
        pb.removeBody(self.body, physicsClientId=self.world.client)

    def park(self) -> None:
        """Move the hand far above the scene, fingers open."""
        self._teleport(PARK, [0.0, 0.0, 0.0, 1.0])
        self._open_now()

    def gap(self) -> float:
        """Current distance (m) between the inner faces of the fingers."""
        q = [pb.getJointState(self.body, j, physicsClientId=self.world.client)[0] for j in (0, 1)]
        return float(2 * self.travel - q[0] - q[1])

    def _contacts(self, link: int | None = None) -> list[tuple]:
        kw = {} if link is None else {"linkIndexA": link}
        return list(pb.getContactPoints(bodyA=self.body, physicsClientId=self.world.client, **kw))

    def _touches_static(self) -> bool:
        return any(c[2] in self.world.static_bodies for c in self._contacts())

    def _in_collision(self) -> bool:
        pb.performCollisionDetection(physicsClientId=self.world.client)
        return any(c[8] < -0.001 for c in self._contacts())

    def _move(self, start: F64, end: F64, quat: list[float], speed: float, stop_on_static: bool) -> bool:
        """Drive the base along a straight line; False if it touched the tray/floor (when asked)."""
        steps = max(int(np.linalg.norm(end - start) / speed * 240), 1)
        for k in range(1, steps + 1):
            pos = start + (end - start) * k / steps
            pb.changeConstraint(self.constraint, pos.tolist(), quat, maxForce=self.params.arm_force,
                                physicsClientId=self.world.client)
            pb.stepSimulation(physicsClientId=self.world.client)
            if stop_on_static and k % 4 == 0 and self._touches_static():
                return False
        self.world.step(0.05)
        return True

    def _held(self) -> set[int]:
        """Objects touched by both fingers."""
        per_finger = [{c[2] for c in self._contacts(link)} for link in (0, 1)]
        return (per_finger[0] & per_finger[1]) & set(self.world.objects)

    def _in_hand(self, body: int) -> Rotation:
        """The object's orientation in the hand's frame (hand-to-world inverse times object-to-world)."""
        c = self.world.client
        hand_q = pb.getBasePositionAndOrientation(self.body, physicsClientId=c)[1]
        obj_q = pb.getBasePositionAndOrientation(body, physicsClientId=c)[1]
        return Rotation.from_quat(hand_q).inv() * Rotation.from_quat(obj_q)

    def _nearest_object(self, point: F64, within: float = 0.05) -> int | None:
        best, best_d = None, within
        for body in self.world.objects:
            pts = pb.getClosestPoints(self.body, body, within, physicsClientId=self.world.client)
            for cp in pts:
                d = float(np.linalg.norm(np.asarray(cp[6]) - point))
                if d < best_d:
                    best, best_d = body, d
        return best

    # --- one attempt ---------------------------------------------------------------------------------
    def execute(self, grasps: GraspSet, index: int = 0, clear: bool = True) -> Attempt:
        """Pre-grasp, approach, close, lift, hold; remove what stayed in the hand.  The grasp is in world frame.
        A lift slips when nothing stays in the fingers above half the lift height, or (params.max_turn_deg) when
        what stays turned more than that in the hand.  clear=False leaves every object in the world and skips
        the settling after (a caller that restores a saved state: graspd_lab.sim.lift)."""
        p = self.params
        pos = grasps.positions[index].astype(np.float64)
        rot = grasps.rotations[index].astype(np.float64)
        approach = rot[:, 0]
        quat = _rot_quat(rot)
        centre = pos + (self.hand.hand_depth - self.hand.init_bite) * approach
        pre = pos - p.pregrasp_distance * approach
        self._teleport(pre, quat)
        self._open_now()
        target = self._nearest_object(centre)
        try:
            if self._in_collision():
                return Attempt(Outcome.COLLISION, target)
            if not self._move(pre, pos, quat, p.approach_speed, stop_on_static=True):
                return Attempt(Outcome.COLLISION, target)
            reached = np.asarray(pb.getBasePositionAndOrientation(self.body, physicsClientId=self.world.client)[0])
            if np.linalg.norm(reached - pos) > p.reach_tolerance:
                return Attempt(Outcome.COLLISION, target)
            target = self._nearest_object(centre) or target
            self._set_fingers(0.0, p.finger_force)
            self.world.step(2 * self.travel / p.close_speed * 0.5 + 0.1)
            for _ in range(10):
                if self.gap() < 0.002:
                    break
                before = self.gap()
                self.world.step(0.05)
                if abs(self.gap() - before) < 1e-4:
                    break
            held = self._held()
            if self.gap() < 0.002 or not held:
                return Attempt(Outcome.EMPTY, target)
            if target not in held:
                target = min(held)
            gripped = {b: self._in_hand(b) for b in self.world.objects}
            up = pos + np.array([0.0, 0.0, p.lift_height])
            self._move(pos, up, quat, p.lift_speed, stop_on_static=False)
            self.world.step(p.hold_seconds)
            still = self._held()
            lifted = tuple(b for b in still if self.world.object_position(b)[2] > 0.5 * p.lift_height)
            if not lifted:
                return Attempt(Outcome.SLIPPED, target)
            turn = max(float(np.degrees((gripped[b].inv() * self._in_hand(b)).magnitude())) for b in lifted)
            if p.max_turn_deg is not None and turn > p.max_turn_deg:
                return Attempt(Outcome.SLIPPED, target, turn_deg=turn)
            ids = tuple(self.world.objects[b] for b in lifted)
            if clear:
                for b in lifted:
                    self.world.remove_object(b)
            return Attempt(Outcome.SUCCESS, target, ids if clear else (), turn)
        finally:
            self.park()
            if clear:
                self.world.settle(max_seconds=1.0)
