"""How well a grasp's score survives small errors in where the hand ends up.

A robot never places the hand exactly where it was asked to: calibration, the arm and the object's motion on
contact move it by millimetres and degrees.  A grasp whose score holds when the hand is moved a little is one
that holds in the hand (bench/oracle.py --perturb: copies of held grasps moved 2 mm / turned 3 degrees hold 91%
of the time, copies of failed ones 27%).  robust_scores re-scores each grasp at a fixed set of such moves with
the same classifier and returns the mean score (dimensionless, in [0, 1]).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd.gpd.images import encode_images
from graspd.gpd.scene import Scene

#: Default move (m) along each hand axis and turn (degrees) about each hand axis: the sizes bench/oracle.py's
#: perturbed lifts use (2 mm standard deviation, 3 degrees).
SHIFT = 0.002
TURN_DEG = 3.0


def perturbation_offsets(shift: float = SHIFT, turn_deg: float = TURN_DEG) -> tuple[F64, F64]:
    """The fixed moves: (P, 3) translations and (P, 3, 3) rotations, both in the hand frame (approach, binormal,
    axis): plus and minus shift along each axis, then plus and minus turn_deg about each axis (P = 12)."""
    eye = np.eye(3)
    moves = np.concatenate([eye * shift, -eye * shift, np.zeros((6, 3))])
    vecs = np.concatenate([np.zeros((6, 3)), eye * np.radians(turn_deg), -eye * np.radians(turn_deg)])
    turns = np.asarray(Rotation.from_rotvec(vecs).as_matrix(), np.float64)
    return moves, turns


def perturbed(grasps: GraspSet, shift: float = SHIFT, turn_deg: float = TURN_DEG) -> GraspSet:
    """P moved copies of each of the M grasps, grasp-major ((M * P) hands; copy p of grasp m at m * P + p).  Turns
    are about the grasp position (the hand base's centre, where the arm holds the hand); widths and scores are
    carried over."""
    moves, turns = perturbation_offsets(shift, turn_deg)
    p = len(moves)
    rot = grasps.rotations
    pos = grasps.positions[:, None, :] + np.einsum("mij,pj->mpi", rot, moves)
    new_rot = np.einsum("mij,pjk->mpik", rot, turns)
    return GraspSet(positions=pos.reshape(-1, 3), rotations=new_rot.reshape(-1, 3, 3),
                    widths=np.repeat(grasps.widths, p), scores=np.repeat(grasps.scores, p),
                    samples=np.repeat(grasps.samples, p, axis=0))


def robust_scores(scene: Scene, grasps: GraspSet, hand: HandGeometry, representation: str,
                  score: Callable[[NDArray[np.uint8]], NDArray[np.floating]],
                  shift: float = SHIFT, turn_deg: float = TURN_DEG) -> F64:
    """The mean classifier score (M,) of each grasp's moved copies (perturbed) in the scene, as the detector
    encodes and scores its candidates."""
    if not len(grasps):
        return np.zeros(0)
    copies = perturbed(grasps, shift, turn_deg)
    images = encode_images(scene, copies, hand, representation)
    s = np.asarray(score(images), np.float64).reshape(len(grasps), -1)
    return np.asarray(s.mean(axis=1), np.float64)
