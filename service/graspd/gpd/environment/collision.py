"""Whether a hand, or its approach path, enters the environment: below the support plus clearance, or into a
wall or declared box (oriented-box tests, cloud frame, metres)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd.gpd.environment.types import Box, Environment, Plane


def _box_corners_min(plane: Plane, centres: F64, rotations: F64, half: F64) -> F64:
    """Least signed distance (...,) to plane over each oriented box (centres (...,3), rotations (...,3,3),
    half extents (...,3)): the support function of a box."""
    reach = np.abs(np.einsum("...ji,j->...i", rotations, plane.normal)) * half
    return plane.distance(centres.reshape(-1, 3)).reshape(centres.shape[:-1]) - reach.sum(axis=-1)


def _obb_overlap(ca: F64, ra: F64, ha: F64, box: Box) -> NDArray[np.bool_]:
    """Separating-axis test of many oriented boxes (centres (M,3), rotations (M,3,3), half extents (M,3))
    against one box: True where they overlap."""
    rb, hb = box.rotation, box.half_extents
    t = box.centre - ca  # (M,3)
    axes = [ra[:, :, i] for i in range(3)] + [np.broadcast_to(rb[:, j], ca.shape) for j in range(3)]
    axes += [np.cross(ra[:, :, i], rb[:, j]) for i in range(3) for j in range(3)]
    overlap = np.ones(len(ca), bool)
    for axis in axes:
        norm = np.linalg.norm(axis, axis=1)
        ok = norm > 1e-9  # parallel edges give no axis to test
        u = axis / np.maximum(norm, 1e-12)[:, None]
        proj_a = (np.abs(np.einsum("mji,mj->mi", ra, u)) * ha).sum(axis=1)
        proj_b = (np.abs(u @ rb) * hb).sum(axis=1)
        separated = ok & (np.abs(np.einsum("mj,mj->m", t, u)) > proj_a + proj_b)
        overlap &= ~separated
    return overlap


def hand_hits_environment(positions: F64, rotations: F64, hand: HandGeometry, env: Environment,
                          approach_distance: float) -> NDArray[np.bool_]:
    """Whether each hand (positions (M,3), rotations (M,3,3), grasp convention) or its path from the pre-grasp
    pose approach_distance (m) back along -approach enters the environment: below the support plus
    clearance, or into a wall or declared box.  Fingers are open (hand_outer_diameter apart)."""
    m = len(positions)
    hits = np.zeros(m, bool)
    if m == 0 or not env.active:
        return hits
    boxes = hand.swept_boxes(approach_distance)  # (3, 2, 3) in the hand frame
    local_c = boxes.mean(axis=1)
    half = (boxes[:, 1] - boxes[:, 0]) / 2.0
    centres = positions[:, None, :] + np.einsum("mij,bj->mbi", rotations, local_c)  # (M,3,3)
    rots = np.broadcast_to(rotations[:, None], (m, 3, 3, 3))
    halves = np.broadcast_to(half, (m, 3, 3))
    if env.support is not None:
        hits |= (_box_corners_min(env.support, centres, rots, halves) < env.clearance).any(axis=1)
    for box in env.obstacles:
        for b in range(3):
            hits |= _obb_overlap(centres[:, b], rotations, halves[:, b], box)
    return hits
