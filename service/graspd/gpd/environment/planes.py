"""Planes in the cloud: the seeded RANSAC plane, the support the objects stand on, and the in-plane measures
(axes, robust spans, gap-free runs, least-area rectangles) the other finders share (cloud frame, metres)."""

from __future__ import annotations

import copy

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

from graspd.core.points import best_plane
from graspd.core.types import F64
from graspd.gpd.environment.types import EnvironmentParams, Plane

FACING_COS = float(np.cos(np.radians(15.0)))  # a point faces a plane's way when its normal is this close to it
UP_SWITCH = 1.25  # how many times more facing points a plane at an angle to the largest needs to be up instead
UP_SWITCH_AREA = 1.5  # and how many times the largest plane's spanned area (the product of its robust spans)


def fit_plane(points: F64, params: EnvironmentParams, rng: np.random.Generator,
              vertical_to: F64 | None = None) -> Plane | None:
    """The plane with most inliers within plane_distance (graspd.core.points.best_plane): RANSAC over
    ransac_iterations point triplets of at most ransac_points points drawn from rng (seeded: the same cloud and
    seed always give the same plane); with vertical_to, only planes within wall_max_tilt_deg of upright."""
    if len(points) < 3:
        return None
    sub = points if len(points) <= params.ransac_points else \
        points[rng.choice(len(points), params.ransac_points, replace=False)]
    triplets = rng.integers(0, len(sub), size=(params.ransac_iterations, 3))
    fit = best_plane(sub, triplets, params.plane_distance, vertical_to, params.wall_max_tilt_deg)
    return None if fit is None else Plane(fit[0][:3], float(fit[0][3]))


def in_plane_axes(normal: F64) -> F64:
    """Two unit vectors (2,3) spanning the plane of normal."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(normal, u)])


def robust_span(values: F64) -> float:
    """The 2nd-98th percentile span of values (m): a few stray inliers do not make a plane large."""
    if len(values) < 10:
        return 0.0
    values = values[:: max(1, len(values) // 4000)]  # a regular thinning: the percentiles barely move
    lo, hi = np.percentile(values, [2.0, 98.0])
    return float(hi - lo)


def gap_free_runs(values: F64, gap: float, min_count: int) -> list[tuple[float, float]]:
    """Intervals of sorted values split where consecutive values are more than gap (m) apart, keeping
    those with at least min_count values."""
    v = np.sort(values)
    breaks = np.flatnonzero(np.diff(v) > gap)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(v) - 1]])
    return [(float(v[a]), float(v[b])) for a, b in zip(starts, ends, strict=True) if b - a + 1 >= min_count]


def find_support(points: F64, cameras: F64, params: EnvironmentParams, min_extent: float,
                 gravity: F64 | None, rng: np.random.Generator, tries: int = 3,
                 normals: F64 | None = None) -> Plane | None:
    """The dominant plane the objects stand on, its normal toward the cameras (or against gravity).

    A plane qualifies when its points span min_extent in both in-plane directions and, with gravity given,
    its normal lies within 30 degrees of up; the largest qualifying plane of a few RANSAC rounds wins.  Without
    gravity (normals given) every round runs and the largest stands unless a plane at an angle to it faces more
    of the scene and spans more of it (most_faced): a shelf's back wall seen head-on can hold more points than
    the table around it."""
    remaining = points
    found: list[Plane] = []
    areas: list[float] = []
    facing: list[int] = []
    draw = rng
    for _ in range(tries):
        plane = fit_plane(remaining, params, draw)
        if plane is None:
            break
        d = plane.distance(remaining)
        inliers = np.abs(d) <= params.plane_distance
        if inliers.sum() < max(50, 0.05 * len(points)):
            break
        toward = cameras.mean(axis=0) @ plane.normal + plane.offset
        if gravity is not None:
            toward = -float(gravity @ plane.normal)
        if toward < 0.0:
            plane = Plane(-plane.normal, -plane.offset)
        axes = in_plane_axes(plane.normal)
        local = remaining[inliers] @ axes.T
        upright = gravity is None or float(-gravity @ plane.normal) >= np.cos(np.radians(30.0))
        spans = (robust_span(local[:, 0]), robust_span(local[:, 1]))
        if upright and min(spans) >= min_extent:
            if gravity is not None or normals is None:
                return plane
            faced = int(((normals @ plane.normal) > FACING_COS).sum())
            if not found:
                if len(normals) - faced < UP_SWITCH * faced:
                    # too few points face elsewhere for a plane at an angle to face more (a point faces one of
                    # two normals more than 30 degrees apart, not both): the largest stands
                    return plane
                # the rounds after the largest plane draw from a copy: the stages after this one see the same
                # draws of rng whether or not a rival is sought
                draw = copy.deepcopy(rng)
            found.append(plane)
            areas.append(spans[0] * spans[1])
            facing.append(faced)
        remaining = remaining[~inliers]
    if not found:
        return None
    return most_faced(found, areas, facing)


def most_faced(planes: list[Plane], areas: list[float], facing: list[int]) -> Plane:
    """Of candidate supports, most inliers first, with their spanned areas (m^2) and how many points face each
    one's way (normals within 15 degrees): the first, unless one more than 30 degrees from it has UP_SWITCH
    times as many facing points and spans UP_SWITCH_AREA times its area.  Gravity makes the table, a
    container's floor, a shelf's board and the objects' tops all face up, and the table spreads under the whole
    scene; a wall faces one side only and ends at its container's height.  Facing alone fails: a deep bin's two
    walls facing the cameras (the near one's outside, the far one's inside) can face more points than its floor
    and the table around it."""
    best = 0
    for i, pl in enumerate(planes[1:], start=1):
        at_angle = abs(float(pl.normal @ planes[0].normal)) < np.cos(np.radians(30.0))
        wider = areas[i] >= UP_SWITCH_AREA * areas[0]
        if at_angle and wider and facing[i] >= UP_SWITCH * facing[0] and facing[i] > facing[best]:
            best = i
    return planes[best]


def min_area_rectangle(xy: F64) -> tuple[F64, F64, F64]:
    """The smallest rectangle around 2-D points (N,2): centre (2,), unit axes (2,2) as rows and half sizes (2,)
    (rotating calipers over the convex hull's edges; a container's floor at any yaw)."""
    pts = xy
    try:
        hull = pts[ConvexHull(pts).vertices] if len(pts) >= 3 else pts
    except (QhullError, ValueError):
        hull = pts
    if len(hull) < 2:
        return (hull.mean(axis=0) if len(hull) else np.zeros(2)), np.eye(2), np.zeros(2)
    edges = np.diff(np.vstack([hull, hull[:1]]), axis=0)
    angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2))
    best: tuple[float, F64, F64, F64] | None = None
    for a in angles:
        axes = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
        local = hull @ axes.T
        lo, hi = local.min(axis=0), local.max(axis=0)
        area = float(np.prod(hi - lo))
        if best is None or area < best[0]:
            best = (area, ((lo + hi) / 2.0) @ axes, axes, (hi - lo) / 2.0)
    assert best is not None
    return best[1], best[2], best[3]


def ratio_confidence(value: float, threshold: float) -> float:
    """Confidence that a measure passed its threshold clearly: 0 at 0.8 x threshold, 1 at 1.5 x or more."""
    if threshold <= 0.0:
        return 1.0
    return float(np.clip((value / threshold - 0.8) / 0.7, 0.0, 1.0))


def plane_spans(points: F64, mask: NDArray[np.bool_], normal: F64) -> tuple[float, float]:
    """The robust in-plane spans (m) of the masked points."""
    local = points[mask] @ in_plane_axes(normal).T
    if len(local) == 0:
        return (0.0, 0.0)
    return (robust_span(local[:, 0]), robust_span(local[:, 1]))
