"""The open hand in a template scene: whether it collides (fingers and palm against the object points, any
corner below the table) and how wide the object is between its fingers.  The hand's body is
HandGeometry's: fingers over [0, hand_depth], the palm palm_depth deep behind them (HandGeometry.swept_boxes)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd.gpd.scene import ball_pairs, closing_region_points
from graspd.templates.geometry import TemplateScene


def hand_collisions(scene: TemplateScene, positions: F64, rotations: F64, hand: HandGeometry) -> NDArray[np.bool_]:
    """Whether each open hand (M) holds an object point inside a finger or the palm (palm_depth deep behind
    the base, as wide as the open hand), or has a finger or palm corner more than 2 mm below the table."""
    m = len(positions)
    hit = np.zeros(m, bool)
    if m == 0:
        return hit
    od, hh = hand.hand_outer_diameter, hand.hand_height
    boxes = hand.swept_boxes()  # [left finger, right finger, palm] x [low, high] corners, hand frame
    lo, hi = boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)
    x_lo, x_hi = float(lo[0]), float(hi[0])  # -palm_depth, hand_depth
    if scene.table is not None:
        corners = np.stack(np.meshgrid(*np.stack([lo, hi], axis=1), indexing="ij"), axis=-1).reshape(-1, 3)
        world = positions[:, None, :] + np.einsum("mij,cj->mci", rotations, corners)
        hit |= (scene.table.height(world) < -0.002).any(axis=1)
    centre = positions + rotations[:, :, 0] * (x_lo + x_hi) / 2
    radius = float(np.linalg.norm([(x_hi - x_lo) / 2, od / 2, hh / 2]))
    gid, idx = ball_pairs(scene.tree, centre, radius)
    d = scene.object_points[idx] - positions[gid]
    loc = np.einsum("tj,tjk->tk", d, rotations[gid])
    hit[np.unique(gid[hand.body_contains(loc)])] = True
    return hit


def closing_widths(scene: TemplateScene, positions: F64, rotations: F64, hand: HandGeometry,
                   fallback: F64) -> F64:
    """Extent (m) along the binormal of the object points between the fingers of each hand (fallback
    where none are)."""
    reg = closing_region_points(scene.tree, scene.object_points.astype(np.float32), positions, rotations, hand)
    out = np.asarray(fallback, np.float64).copy()
    if len(reg.grasp):
        y = reg.local[:, 1].astype(np.float64)
        lo = np.full(len(positions), np.inf)
        hi = np.full(len(positions), -np.inf)
        np.minimum.at(lo, reg.grasp, y)
        np.maximum.at(hi, reg.grasp, y)
        has = np.isfinite(lo)
        out[has] = hi[has] - lo[has]
    return out
