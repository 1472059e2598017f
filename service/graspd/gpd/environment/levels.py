"""Support levels: the table, a container's floor and a platform's top, found as up-facing planes from a height
histogram, and the solids under raised ones (cloud frame, metres)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from graspd.core.types import F64
from graspd.gpd.environment.planes import in_plane_axes, min_area_rectangle, robust_span
from graspd.gpd.environment.types import Box, EnvironmentParams, Label, Plane

#: A point faces up when its normal lies within 25 degrees of up: the points a level is made of.
UP_FACING_COS = float(np.cos(np.radians(25.0)))


@dataclass(frozen=True)
class Level:
    """A support level: its plane (normal up), height along up (m), the 2-D footprint of its points in the
    plane axes (centre, axes rows, half sizes; m), spans (m) and point count."""

    plane: Plane
    height: float
    centre: F64
    axes: F64
    half: F64
    spans: tuple[float, float]
    num_points: int
    fill: float


def find_levels(points: F64, normals: F64, up: F64, params: EnvironmentParams, min_extent: float
                ) -> list[Level]:
    """Support levels, lowest first: up-facing planes (normal within 15 degrees of up) whose points span
    min_extent in both in-plane directions.  Candidate heights are the peaks of a histogram of up-facing
    points' heights; each peak is refined by a least-squares plane, so a level may tilt a little from up."""
    upf_all = (normals @ up) > UP_FACING_COS
    if upf_all.sum() < params.level_min_points:
        return []
    # only up-facing points can be a level: everything below runs on them (a third of a tabletop cloud), thinned
    # regularly to at most level_points (a 1 cm grid of a 50 cm table still holds a few per cell)
    points = points[upf_all]
    points = points[:: max(1, len(points) // params.level_points)]
    h = points @ up
    upf = np.ones(len(points), bool)
    bin_w = params.plane_distance
    hu = h[upf]
    lo = float(hu.min()) - bin_w
    smooth = _smoothed_counts(hu - lo, bin_w)
    axes2 = in_plane_axes(up)
    levels: list[Level] = []
    ref_normal: F64 | None = None
    for _ in range(2 * params.max_levels + 2):
        if len(levels) >= params.max_levels or smooth.max() < params.level_min_points:
            break
        b = int(np.argmax(smooth))
        centre_h = lo + (b + 0.5) * bin_w
        smooth[max(0, b - 1): b + 2] = 0  # this peak is spent, whatever it turns out to be
        # refine from the horizontal plane at the peak: inliers within plane_distance, least squares, three times
        # (a level may tilt a little from up; neighbouring levels a few mm apart are not averaged together)
        # the first level found sets the normal of every other (a container's floor or a platform is parallel to
        # the table): later levels refine their height only, in a narrower band, so two levels a few mm apart
        # are never fitted as one tilted plane
        window = np.abs(h - centre_h) <= 2.0 * bin_w
        if window.sum() < params.level_min_points:
            continue
        wxy = points[window][:: max(1, int(window.sum()) // 2000)] @ in_plane_axes(up).T
        if min(robust_span(wxy[:, 0]), robust_span(wxy[:, 1])) < min_extent:
            continue  # the points at this height span less than a level must: objects' tops
        plane = Plane(up if ref_normal is None else ref_normal, -centre_h)
        band = params.plane_distance if ref_normal is None else 0.6 * params.plane_distance
        inliers = upf & (np.abs(plane.distance(points)) <= band)
        c = np.zeros(3)
        for _ in range(3):
            if inliers.sum() < params.level_min_points:
                break
            sub = points[inliers][:: max(1, int(inliers.sum()) // 5000)]
            c = sub.mean(axis=0)
            if ref_normal is None:
                _, _, vt = np.linalg.svd(sub - c, full_matrices=False)
                normal = vt[-1] if float(vt[-1] @ up) > 0.0 else -vt[-1]
                if float(normal @ up) < np.cos(np.radians(15.0)):
                    normal = up
            else:
                normal = ref_normal
                c = normal * float(np.median(sub @ normal)) + (c - normal * float(c @ normal))
            plane = Plane(normal, -float(normal @ c))
            inliers = upf & (np.abs(plane.distance(points)) <= band)
        if inliers.sum() < params.level_min_points:
            continue
        xy = points[inliers] @ axes2.T
        # one connected surface (1 cm cells, gaps of a cell bridged): objects' tops at one height are islands
        island, occupied = _largest_island(xy)
        xy = xy[island]
        spans = (robust_span(xy[:, 0]), robust_span(xy[:, 1]))
        if min(spans) < min_extent:
            continue
        centre, axes, half = min_area_rectangle(xy[:: max(1, len(xy) // 2000)])
        if 2.0 * float(half.min()) < min_extent:
            continue
        # how much of its footprint the level covers (1 cm cells): a raised level is a filled surface, not a
        # ring of rims or scattered object tops at one height
        fill = occupied / max(float(np.prod(np.ceil(2.0 * half / 0.01))), 1.0)
        height = float(c @ up)
        if any(abs(height - lv.height) < 0.7 * params.support_distance for lv in levels):
            continue
        levels.append(Level(plane, height, centre, axes, half, spans, int(inliers.sum()), float(fill)))
        ref_normal = plane.normal if ref_normal is None else ref_normal
    levels.sort(key=lambda lv: lv.height)
    return levels[:1] + [lv for lv in levels[1:] if lv.fill >= params.level_min_fill]


def _smoothed_counts(heights: F64, bin_w: float) -> NDArray[np.int64]:
    """Counts of non-negative heights (m) in bin_w-wide bins from 0, each summed with its two neighbours: the
    histogram whose peaks are candidate levels."""
    counts = np.bincount((heights / bin_w).astype(np.int64))
    return np.asarray(counts + np.concatenate([[0], counts[:-1]]) + np.concatenate([counts[1:], [0]]))


def _largest_island(xy: F64, cell: float = 0.01) -> tuple[NDArray[np.bool_], int]:
    """The points (N,2; m) of the largest connected patch of occupied cells (gaps of one cell bridged), and how
    many cells it occupies: a floor or a table is one patch, objects' tops at one height are islands."""
    ij = np.floor((xy - xy.min(axis=0)) / cell).astype(np.int64)
    grid = np.zeros(tuple(ij.max(axis=0) + 1), bool)
    grid[ij[:, 0], ij[:, 1]] = True
    parts, count = ndimage.label(ndimage.binary_dilation(grid), structure=np.ones((3, 3), bool))
    cell_part = parts[ij[:, 0], ij[:, 1]]
    largest = int(np.argmax(np.bincount(cell_part)[1:])) + 1 if count > 1 else 1
    return cell_part == largest, int((grid & (parts == largest)).sum())


def footprint_coordinates(points: F64, level: Level, up: F64) -> F64:
    """Each point (N,3) in the level's footprint frame (N,2; m from its centre along its rectangle's axes)."""
    return np.asarray((points @ in_plane_axes(up).T - level.centre) @ level.axes.T)


def in_footprint(points: F64, level: Level, up: F64, grow: float) -> NDArray[np.bool_]:
    """Whether each point (N,3) lies over the level's footprint grown by grow (m), at any height."""
    return np.asarray(np.all(np.abs(footprint_coordinates(points, level, up)) <= level.half + grow, axis=1))


def beneath_surface(points: F64, normals: F64, level: Level, up: F64, beneath: NDArray[np.bool_], band: float,
                    cell: float = 0.01) -> int:
    """How many of the points beneath (a mask) lie under the level's own surface, not in its gaps: under the cell
    (m) grid its up-facing points within band (m) of its plane occupy, less a cell at every edge (an object's
    side lies under its top's edge).  Room seen under a board (a shelf's ceiling) lies there; objects' tops at
    one height, the floor seen between them, have none (under a top is its object's unseen body)."""
    ij = np.floor((footprint_coordinates(points, level, up) + level.half) / cell).astype(np.int64)
    shape = tuple(int(v) for v in np.ceil(2.0 * level.half / cell).astype(np.int64) + 1)
    inside = np.all((ij >= 0) & (ij < np.array(shape)), axis=1)
    top = inside & (np.abs(level.plane.distance(points)) <= band) & ((normals @ up) > UP_FACING_COS)
    grid = np.zeros(shape, bool)
    grid[ij[top, 0], ij[top, 1]] = True
    core = ndimage.binary_erosion(grid, structure=np.ones((3, 3), bool))
    under = beneath & inside
    return int(core[ij[under, 0], ij[under, 1]].sum())


def level_box(level: Level, up: F64, bottom: float, grow: float) -> Box:
    """The solid under a raised level: its footprint grown by grow (m), from height bottom up to just below the
    level's surface (fingers may touch a floor, as they touch the table)."""
    a2 = in_plane_axes(up)
    ax3 = level.axes @ a2  # (2,3): the footprint's axes in the cloud frame
    top = level.height - 0.002
    centre = (level.centre @ a2) + up * ((top + bottom) / 2.0)
    rotation = np.stack([ax3[0], ax3[1], np.cross(ax3[0], ax3[1])], axis=1)
    if float(rotation[:, 2] @ up) < 0.0:
        rotation[:, 1] *= -1.0
        rotation[:, 2] *= -1.0
    return Box(centre, rotation, np.array([level.half[0] + grow, level.half[1] + grow, (top - bottom) / 2.0]))


def find_inner_floor(points: F64, normals: F64, up: F64, support: Plane, wall_boxes: list[Box],
                     labels: NDArray[np.int8], params: EnvironmentParams, min_extent: float) -> Level | None:
    """A container's floor the level search missed: the lowest well-populated height of up-facing object points
    inside the rectangle the walls enclose, between the support and 6 cm above it, one connected surface spanning
    at least 0.6 x min_extent both ways and covering level_min_fill of the enclosure (objects rest on the floor,
    so nothing of theirs lies below it)."""
    a2 = in_plane_axes(up)
    corners = np.concatenate([b.corners() @ a2.T for b in wall_boxes])
    centre, axes, half = min_area_rectangle(corners)
    local = (points @ a2.T - centre) @ axes.T
    h = support.distance(points)
    cand = ((labels == Label.OBJECT) & ((normals @ up) > UP_FACING_COS)
            & np.all(np.abs(local) <= half - 0.01, axis=1) & (h > params.support_distance) & (h < 0.06))
    if cand.sum() < 3 * params.level_min_points:
        return None
    bin_w = params.plane_distance
    smooth = _smoothed_counts(h[cand], bin_w)
    for b in np.flatnonzero(smooth >= params.level_min_points):  # lowest first: objects rest on the floor
        near = cand & (np.abs(h - (b + 0.5) * bin_w) <= 1.5 * bin_w)
        height_above = float(np.median(h[near]))
        on = np.flatnonzero(cand & (np.abs(h - height_above) <= 0.6 * params.plane_distance))
        if len(on) < params.level_min_points:
            continue
        xy = points[on] @ a2.T
        island, cells = _largest_island(xy)
        xy = xy[island]
        spans = (robust_span(xy[:, 0]), robust_span(xy[:, 1]))
        if min(spans) < 0.6 * min_extent or cells < params.level_min_fill * float(np.prod(2.0 * half / 0.01)):
            continue  # too small a share of the container to be its floor: flat objects' tops
        plane = Plane(support.normal, support.offset - height_above)
        height = float(np.median(points[on[island]] @ up))
        return Level(plane, height, centre, axes, half, spans, int(island.sum()), 1.0)
    return None


def lined_edges(points: F64, labels: NDArray[np.int8], level: Level, up: F64, rise: float = 0.02,
                 share: float = 0.8, step: float = 0.02) -> list[float]:
    """Lengths (m) of the sides of a raised level's footprint along which object points stand more than rise (m)
    above the level in at least share of the step-wide (m) slices, within 2 cm of the side: a wall kept as
    objects (a platform's edge has nothing standing along all of it)."""
    obj = labels == Label.OBJECT
    local = footprint_coordinates(points[obj], level, up)
    high = (points[obj] @ up) > level.height + rise
    out = []
    for axis in (0, 1):
        other = 1 - axis
        for sign in (-1.0, 1.0):
            near = high & (np.abs(local[:, axis] - sign * level.half[axis]) <= 0.02)
            slices = np.floor((local[near, other] + level.half[other]) / step).astype(np.int64)
            total = int(np.ceil(2.0 * level.half[other] / step))
            covered = len(np.unique(slices[(slices >= 0) & (slices < total)]))
            if total >= 5 and covered >= share * total:
                out.append(2.0 * float(level.half[other]))
    return out
