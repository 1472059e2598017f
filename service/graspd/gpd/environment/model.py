"""The environment of one cloud: which way is up, the support levels, walls and rims found, what the caller
declared, a label per point, every surface with its confidence and the warnings of an unsure stage."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd.core.warning import DetectionWarning
from graspd.gpd.environment.levels import (
    Level,
    beneath_surface,
    find_inner_floor,
    find_levels,
    in_footprint,
    level_box,
    lined_edges,
)
from graspd.gpd.environment.planes import find_support, plane_spans, ratio_confidence
from graspd.gpd.environment.types import Box, Environment, EnvironmentParams, Label, Plane, Surface
from graspd.gpd.environment.walls import find_rims, find_walls, freestanding_sheet


def model_environment(cloud: ViewpointCloud, hand: HandGeometry, params: EnvironmentParams | None = None,
                      gravity: tuple[float, float, float] | None = None, seed: int | None = 0) -> Environment:
    """Label every point of a preprocessed cloud as object, support, wall or declared, say which way is up
    (against gravity when given, else the dominant plane's normal toward the cameras), report every surface
    found and warn when unsure."""
    p = params or EnvironmentParams()
    n = len(cloud)
    if p.mode == "none":
        return Environment.empty(n, "none")
    pts = cloud.points.astype(np.float64)
    cams = cloud.viewpoints.astype(np.float64)
    normals = np.zeros_like(pts) if cloud.normals is None else cloud.normals.astype(np.float64)
    g = None if gravity is None else np.asarray(gravity, np.float64) / max(float(np.linalg.norm(gravity)), 1e-12)
    rng = np.random.default_rng(seed if seed is not None else 0)
    min_extent = p.min_support_extent if p.min_support_extent is not None else 1.5 * hand.max_aperture
    labels = np.zeros(n, np.int8)
    surfaces: list[Surface] = []
    warnings: list[DetectionWarning] = []
    walls: list[Box] = []
    support = p.support
    up: F64 | None = -g if g is not None else None
    levels: list[Level] = []
    if p.mode == "auto" and n >= 3 and support is None:
        if up is None:  # no gravity: up is the dominant plane's normal, toward the cameras
            dominant = find_support(pts, cams, p, min_extent, None, rng,
                                    normals=None if cloud.normals is None else normals)
            up = None if dominant is None else dominant.normal
        levels = [] if up is None else find_levels(pts, normals, up, p, min_extent)
        if levels:
            support = levels[0].plane
        else:  # no level square to up (gravity off from the table's normal): the largest upright plane
            support = find_support(pts, cams, p, min_extent, g, rng)
    if support is not None:
        d = support.distance(pts)
        labels[d <= p.support_distance] = Label.SUPPORT
        if up is None:
            up = support.normal
        if p.mode == "auto":
            spans = plane_spans(pts, labels == Label.SUPPORT, support.normal)
            surfaces.append(Surface("support", support, None, spans, int((labels == Label.SUPPORT).sum()),
                                    ratio_confidence(min(spans), min_extent)))
            level_heights = [0.0]
            base_height = levels[0].height if levels else -support.offset
            for lv in levels[1:]:
                assert up is not None
                lv_h = _apply_level(lv, up, base_height, pts, normals, labels, walls, surfaces, p, min_extent)
                if lv_h is not None:
                    level_heights.append(lv_h)
            min_length = p.wall_min_length if p.wall_min_length is not None else 1.5 * hand.hand_outer_diameter
            found = find_walls(pts, normals, cams, support, p, min_length, rng, labels == Label.OBJECT,
                               tuple(level_heights), tuple(walls), cloud.camera_source)
            if len(found) == 1 and len(level_heights) == 1 and freestanding_sheet(found[0][0], found[0][2],
                                                                                  min_length, p):
                found = []  # one short face standing alone on the table: a long object (a board, a box), not a wall
            for box, plane, length, count, top, stands in found:
                labels[(labels == Label.OBJECT) & box.contains(pts, margin=0.003)] = Label.WALL
                walls.append(box)
                conf = ratio_confidence(length, min_length) * (1.0 if stands else 0.4)
                surfaces.append(Surface("wall", plane, box, (length, top), count, conf))
                if not stands and not any(w.code == "environment_unsure" for w in warnings):
                    warnings.append(DetectionWarning(
                        "environment_unsure", f"a vertical surface {length:.2f} m long does not stand on any "
                        "support level found; it is treated as environment (too large to grasp), but the "
                        "support may be wrong: declare the support or the container in the request"))
            if up is not None and len(found) >= 2 and len(level_heights) == 1:
                # a floor the level search missed (a deep container's floor is seen only in part): the lowest
                # up-facing surface inside the walls
                inner = find_inner_floor(pts, normals, up, support, [f[0] for f in found], labels, p, min_extent)
                if inner is not None:
                    lv_h = _apply_level(inner, up, base_height, pts, normals, labels, walls, surfaces, p,
                                        0.6 * min_extent)
                    if lv_h is not None:
                        level_heights.append(lv_h)
            rim_length = p.rim_min_length if p.rim_min_length is not None else min_length
            # rims stand for walls whose faces went unseen: with two walls found, a long line of points at one
            # height is the tops of objects in a row, not a rim
            rims = [] if len(found) >= 2 else find_rims(pts, normals, support, p, rim_length, rng,
                                                        labels == Label.OBJECT)
            for box, origin, direction, length, count in rims:
                labels[(labels == Label.OBJECT) & box.contains(pts, margin=0.003)] = Label.WALL
                walls.append(box)
                across = np.cross(support.normal, direction)
                surfaces.append(Surface("rim", Plane(across, -float(across @ origin)), box, (length, 0.0), count,
                                        ratio_confidence(length, rim_length)))
            surfaces = _name_levels(surfaces)
    elif p.mode == "auto" and n >= 3:
        warnings.append(DetectionWarning(
            "no_support", "no support surface (a table, a container floor) was found in the cloud: grasps are "
            "checked against the seen points only; send more of the scene, gravity, or a declared support"))
    for box in p.boxes:
        labels[box.contains(pts)] = Label.DECLARED
        surfaces.append(Surface("declared", Plane(box.rotation[:, 2], -float(box.rotation[:, 2] @ box.centre)),
                                box, (2.0 * float(box.half_extents[0]), 2.0 * float(box.half_extents[1])),
                                int(box.contains(pts).sum()), 1.0))
    if p.mode == "declared" and p.support is not None:
        surfaces.insert(0, Surface("support", p.support, None, (0.0, 0.0),
                                   int((labels == Label.SUPPORT).sum()), 1.0))
    if p.mode == "auto" and support is not None and up is not None:
        lined = [side for lv in levels[1:] for side in lined_edges(pts, labels, lv, up)]
        if lined:
            warnings.append(DetectionWarning(
                "container_as_object", f"object points line {len(lined)} edge(s) of a raised level "
                f"({', '.join(f'{x:.2f} m' for x in lined)} long) like a wall the stage did not recognise: a "
                "container may be among the objects; declare its walls as boxes if grasps land on it"))
    found_conf = [s.confidence for s in surfaces if s.kind != "declared"]
    confidence = 0.0 if (p.mode == "auto" and support is None) else min(found_conf, default=1.0)
    if p.mode == "auto" and support is not None and confidence < 0.3 and not warnings:
        weakest = min((s for s in surfaces if s.kind != "declared"), key=lambda s: s.confidence)
        warnings.append(DetectionWarning(
            "environment_unsure", f"the {weakest.kind} found is barely distinct from an object (confidence "
            f"{weakest.confidence:.2f}); declare the support or the container in the request if grasps look "
            "wrong"))
    up_out = -g if g is not None else (None if support is None else support.normal)
    return Environment(labels=labels, support=support, walls=tuple(walls), boxes=tuple(p.boxes), up=up_out,
                       mode=p.mode, clearance=p.clearance, surfaces=tuple(surfaces), confidence=float(confidence),
                       warnings=tuple(warnings), support_distance=p.support_distance)


def _apply_level(lv: Level, up: F64, base_height: float, pts: F64, normals: F64, labels: NDArray[np.int8],
                 walls: list[Box], surfaces: list[Surface], p: EnvironmentParams, min_extent: float) -> float | None:
    """Label a raised level's points and sides as support and add its solid (a slab down to the support, or a
    thin board when seen room lies beneath it) to walls and its surface to surfaces.  Returns its height above
    the support (m) when objects can stand on it (a floor or platform), None for a board, or for objects' tops
    at one height that only looked like a level (nothing added)."""
    lv_h = lv.height - base_height  # above the lowest support (m)
    dl = lv.plane.distance(pts)
    # seen points well under the level, inside its footprint: it is a board with room beneath (a shelf's
    # ceiling), not a solid down to the table
    beneath = in_footprint(pts, lv, up, -0.02) & (dl < -0.02) & (labels == Label.OBJECT)
    board = int(beneath.sum()) >= 30
    if board and beneath_surface(pts, normals, lv, up, beneath, p.plane_distance) < 30:
        return None  # the room beneath shows only between its parts: objects' tops side by side, no board
    depth = min(lv_h, max(0.02, -float(np.max(dl[beneath])) - 0.005)) if board else lv_h
    slab = level_box(lv, up, lv.height - depth - (0.0 if board else 0.01), 0.005)
    # the level's own points and its sides: over its footprint, from its surface down the slab
    on = in_footprint(pts, lv, up, 0.01) & (dl <= p.support_distance) & (dl >= -depth - 0.005)
    labels[on] = Label.SUPPORT
    walls.append(slab)
    # a floor has walls around it; a platform stands clear (named once the walls are known)
    surfaces.append(Surface("board" if board else "floor", lv.plane, slab, lv.spans, int(on.sum()),
                            ratio_confidence(min(lv.spans), min_extent)))
    return None if board else lv_h


def _name_levels(surfaces: list[Surface]) -> list[Surface]:
    """A raised level with walls or rims standing on or around it is a container's floor; one without is a
    platform."""
    has_walls = any(s.kind in ("wall", "rim") for s in surfaces)
    return [replace(s, kind="platform") if s.kind == "floor" and not has_walls else s for s in surfaces]
