"""Walls (near-vertical planar patches longer than anything graspable) and rims (long thin lines of points
above the support: sheet walls seen from above), each modelled as a box (cloud frame, metres)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

from graspd.core.types import F64
from graspd.gpd.environment.planes import fit_plane, gap_free_runs, in_plane_axes
from graspd.gpd.environment.types import Box, EnvironmentParams, Plane

#: A wall found: its box, its visible face's plane, its longest gap-free run (m), its points, its top's height
#: above the support (m), and whether it stands on a support level.
Wall = tuple[Box, Plane, float, int, float, bool]
#: _wall's answer for a face refused only because its top is not level.
UNEVEN_TOP = "uneven top"


def find_walls(points: F64, normals: F64, cameras: F64, support: Plane, params: EnvironmentParams,
               min_length: float, rng: np.random.Generator, candidates: NDArray[np.bool_] | None = None,
               level_heights: tuple[float, ...] = (0.0,), levels: tuple[Box, ...] = (),
               sources: NDArray[np.int32] | None = None) -> list[Wall]:
    """Walls: near-vertical planar patches at least min_length long, among the candidate points.

    Each box spans the patch's longest gap-free run along the support, from below the support to a little
    above the patch's top, and from just in front of the visible face to the far face when the wall's other
    side is seen (its parallel, opposite-facing points), else wall_thickness behind it.  Returns (box, plane,
    length, points, top height, stands) per wall: stands is whether its foot is within wall_base_gap of a
    support level (level_heights: heights above the support, m); a patch that does not stand is still a
    solid larger than anything graspable, and lowers the stage's confidence.  A face standing inside the outline
    of the other walls, or of the raised levels' solids (levels) with fewer than two others, is dropped unless it
    is a divider (_without_inner_faces).  sources: each point's camera (an index into cameras, (K, 3)); with
    them, a face the cameras see through is no wall (_seen_through)."""
    up = support.normal
    height = support.distance(points)
    # only points on steep surfaces can belong to a wall: RANSAC then never wastes rounds on object tops
    steep = np.abs(normals @ up) < 0.5
    pool = (height > params.support_distance) & steep
    if candidates is not None:
        pool &= candidates
    remaining = points[pool]
    remaining_up = normals[pool] @ up  # the vertical component of each remaining point's normal
    remaining_h = height[pool]
    walls: list[Wall] = []
    seen_through: list[bool] = []  # per wall found: whether the cameras see through it (_seen_through)
    # faces refused only for an uneven top: a container's side that objects in front rise above, retried once the
    # walls it meets are known
    uneven: list[tuple[Plane, F64, F64, F64]] = []
    min_points = 30
    # a wall is among the largest planes left: fewer hypotheses on fewer points find it (half the cost)
    wall_ransac = replace(params, ransac_points=min(params.ransac_points, 3000),
                          ransac_iterations=min(params.ransac_iterations, 120))
    scene = _Scene(points, normals, height, steep, cameras, sources, up, support, params, min_length,
                   level_heights)
    for _ in range(params.wall_rounds):
        if len(remaining) < min_points or len(walls) >= params.max_walls:
            break
        plane = fit_plane(remaining, wall_ransac, rng, vertical_to=up)
        if plane is None:
            break
        inliers = np.abs(plane.distance(remaining)) <= params.plane_distance
        if inliers.sum() < params.wall_min_points:
            break  # the largest plane left is too small to be a wall: the rest are objects' faces
        patch, patch_up, patch_h = remaining[inliers], remaining_up[inliers], remaining_h[inliers]
        remaining, remaining_up, remaining_h = remaining[~inliers], remaining_up[~inliers], remaining_h[~inliers]
        if abs(float(plane.normal @ up)) > np.sin(np.radians(params.wall_max_tilt_deg)):
            continue  # not vertical: an object's top, or a second level
        wall = _wall(scene, plane, patch, patch_up, patch_h, walls, corner_side=False)
        if isinstance(wall, tuple):
            walls.append(wall[0])
            seen_through.append(wall[1])
        elif wall == UNEVEN_TOP:
            uneven.append((plane, patch, patch_up, patch_h))
    for plane, patch, patch_up, patch_h in uneven:
        if len(walls) >= params.max_walls:
            break
        if _spans_between_walls(plane, up, [w[0] for w in walls], min_length):
            wall = _wall(scene, plane, patch, patch_up, patch_h, walls, corner_side=True)
            if isinstance(wall, tuple):
                walls.append(wall[0])
                seen_through.append(wall[1])
    # a face seen through stays among the walls a later face meets at its corners (a shelf's open front, where its
    # sides end), but is no wall itself
    solid = [w for w, through in zip(walls, seen_through, strict=True) if not through]
    return _without_inner_faces(solid, list(levels), up)


@dataclass(frozen=True)
class _Scene:
    """What every candidate wall is measured against: the whole cloud (points, normals, heights above the
    support, which points are steep) and find_walls' arguments."""

    points: F64
    normals: F64
    height: F64
    steep: NDArray[np.bool_]
    cameras: F64
    sources: NDArray[np.int32] | None
    up: F64
    support: Plane
    params: EnvironmentParams
    min_length: float
    level_heights: tuple[float, ...]


def _wall(scene: _Scene, plane: Plane, patch: F64, patch_up: F64, patch_h: F64, walls: list[Wall],
          corner_side: bool) -> tuple[Wall, bool] | str | None:
    """The wall a vertical planar patch (its points, their normals' vertical components and heights) makes, with
    whether the cameras see through it below its own top, or None, or UNEVEN_TOP when only its top's levelness
    refused it.  corner_side: the face spans between two walls found, square to both at their ends (a container's
    side), so objects rising above its top in front of it do not refuse it."""
    up, params = scene.up, scene.params
    across = plane.normal - (plane.normal @ up) * up  # the face's horizontal normal, toward the cameras
    across /= np.linalg.norm(across)
    if float((scene.cameras.mean(axis=0) - patch.mean(axis=0)) @ across) < 0.0:
        across = -across
    along = np.cross(up, across)
    patch_along = patch @ along
    runs = gap_free_runs(patch_along, gap=0.04, min_count=10)
    # the whole cloud on the face's axes: for the hidden-gap test and the far-face strip, projected once and only
    # for a patch that gets that far
    projected: tuple[F64, F64] | None = None
    if len(runs) > 1 and _corner_walls(plane, [w[0] for w in walls]):
        # a container's side that meets a wall found at a corner: an object standing in front hides part of
        # it, so its gaps there are no ends
        projected = scene.points @ along, scene.points @ across
        runs = _bridge_hidden_gaps(runs, projected[0], projected[1] - float(np.median(patch @ across)),
                                   scene.height, float(np.percentile(patch_h, 1.0)))
    if not runs or max(b - a for a, b in runs) < scene.min_length:
        return None
    longest = max(b - a for a, b in runs)
    # the longest gap-free run makes it a wall; objects in front may hide parts of it, so it spans all runs
    s0, s1 = min(a for a, _ in runs), max(b for _, b in runs)
    in_run = (patch_along >= s0) & (patch_along <= s1)
    run = patch[in_run]
    h = patch_h[in_run]
    if not corner_side and not _level_top(patch_along[in_run], h):
        # faces of several objects that happen to line up: their tops are at many heights (or a container's
        # side that objects in front rise above)
        return UNEVEN_TOP
    if _curved_flank(h, patch_up[in_run]):
        return None  # a long object lying on its side (a bottle, a cucumber): its flank curves up its height
    foot = float(np.percentile(h, 1.0))
    stands = any(abs(foot - lv) <= params.wall_base_gap or foot <= lv + params.wall_base_gap
                 for lv in scene.level_heights)
    face = float(np.median(run @ across))
    points_along, points_across = projected if projected is not None else (scene.points @ along,
                                                                           scene.points @ across)
    # the wall's other face: steep points just behind this one, facing the other way (a wall seen from both
    # sides, or a thin sheet): the box ends there instead of wall_thickness behind
    behind = points_across - face
    strip = ((points_along >= s0) & (points_along <= s1) & scene.steep & (behind < -params.plane_distance)
             & (behind > -params.wall_thickness - 0.01) & ((scene.normals @ across) < -0.7))
    back = params.wall_thickness
    if strip.sum() >= 20:
        back = min(back, float(-np.percentile(behind[strip], 10.0)) + 0.003)
    front = params.plane_distance + 0.002
    # a side with objects rising above it in front: its own top, not theirs
    own_top = _common_top(patch_along[in_run], h)
    top_h = own_top if corner_side else float(np.percentile(h, 99.0))
    base, top = -0.02, top_h + 0.01
    centre = (along * (s0 + s1) / 2.0 + across * (face + (front - back) / 2.0)
              + up * ((base + top) / 2.0 - scene.support.offset))
    rotation = np.stack([across, along, up], axis=1)
    half = np.array([(front + back) / 2.0, (s1 - s0) / 2.0 + 0.01, (top - base) / 2.0])
    box, face_plane = Box(centre, rotation, half), Plane(across, -face)
    # seen through below its own top (where objects in front rise above it, the lines of sight pass over it)
    through = scene.sources is not None and _seen_through(scene, box, face_plane, own_top,
                                                         (points_along, points_across))
    return (box, face_plane, longest, len(run), top - 0.01, stands), through


#: A wall hides what lies behind it: a face is seen through when SEEN_THROUGH_POINTS of the cloud's points lie
#: behind it, on lines of sight that cross its area SEEN_THROUGH_MARGIN (m) or more inside its edges.
SEEN_THROUGH_POINTS = 30
SEEN_THROUGH_MARGIN = 0.02


def _seen_through(scene: _Scene, box: Box, plane: Plane, top_h: float, projected: tuple[F64, F64]) -> bool:
    """Whether the cameras see through a wall's box (its visible face's plane, its top top_h m above the support):
    SEEN_THROUGH_POINTS of the cloud's points behind the box whose line of sight from their camera crosses the face
    SEEN_THROUGH_MARGIN inside its length and between the support and top_h (the open front of a shelf, where only
    its sides' edges and its floor's lie in one plane; objects' faces with gaps between them).  projected: every
    point's position along the face and across it (m), as _wall measured them."""
    assert scene.sources is not None
    across, along = box.rotation[:, 0], box.rotation[:, 1]  # the face's normal, toward the cameras, and its length
    face = -plane.offset
    back = face - (float(box.centre @ across) - float(box.half_extents[0]))  # how deep the box reaches behind it
    middle, half = float(box.centre @ along), float(box.half_extents[1]) - 0.01
    points_along, points_across = projected
    behind = np.flatnonzero((points_across < face - back - 0.01) & (scene.height < top_h))
    if len(behind) < SEEN_THROUGH_POINTS:
        return False
    eye = scene.cameras[scene.sources[behind]]
    eye_along, eye_across, eye_h = eye @ along, eye @ across, scene.support.distance(eye)
    t = (eye_across - face) / np.maximum(eye_across - points_across[behind], 1e-9)  # where each line crosses the face
    cross_along = eye_along + t * (points_along[behind] - eye_along)
    cross_h = eye_h + t * (scene.height[behind] - eye_h)
    m = SEEN_THROUGH_MARGIN
    inside = ((eye_across > face) & (np.abs(cross_along - middle) < half - m) & (cross_h > m) & (cross_h < top_h - m))
    return bool(np.count_nonzero(inside) >= SEEN_THROUGH_POINTS)


#: A wall's face is flat up its height; a lying object's flank curves: its normals turn upward with height, by
#: more than a radian per CURVED_FLANK_RADIUS (m), with at least CURVED_FLANK_CORRELATION between the two.
CURVED_FLANK_RADIUS = 0.10
CURVED_FLANK_CORRELATION = 0.7


#: In front of a wall (m, toward the cameras): how far an object that hides part of it may stand, and how many of
#: its points in a gap of the wall's face make that gap hidden rather than the wall's end.
HIDING_DEPTH = 0.15
HIDING_POINTS = 10


def _bridge_hidden_gaps(runs: list[tuple[float, float]], along: F64, in_front: F64, height: F64, foot: float
                        ) -> list[tuple[float, float]]:
    """Gap-free runs of a wall's face (m along it), with each gap joined where something stands in front of it
    (HIDING_POINTS of the cloud's points within HIDING_DEPTH in front of the face, above the wall's foot, in the
    gap): what hides the wall there, so the wall goes on behind it.  along, in_front, height: every point's
    position along the face, distance in front of it and height above the support."""
    near = (in_front > 0.01) & (in_front < HIDING_DEPTH) & (height > foot)
    out = [runs[0]]
    for a, b in runs[1:]:
        gap = near & (along > out[-1][1]) & (along < a)
        if np.count_nonzero(gap) >= HIDING_POINTS:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


#: A container's sides meet at corners: square to a wall found (within CORNER_ANGLE_DEG) and within CORNER_REACH
#: (m) of one of its ends.
CORNER_ANGLE_DEG = 10.0
CORNER_REACH = 0.03


def _corner_walls(face: Plane, walls: list[Box]) -> list[Box]:
    """The walls found that a vertical face meets at a corner: square to it (within CORNER_ANGLE_DEG), with one
    of their ends (along their length, at mid-height) within CORNER_REACH of it; a container's next sides."""
    met = []
    for w in walls:
        along = w.rotation[:, 1]
        if abs(float(face.normal @ along)) < np.cos(np.radians(CORNER_ANGLE_DEG)):
            continue
        ends = w.centre + np.outer([-1.0, 1.0], along) * w.half_extents[1]
        if np.min(np.abs(face.distance(ends))) <= CORNER_REACH:
            met.append(w)
    return met


def _spans_between_walls(face: Plane, up: F64, walls: list[Box], min_length: float) -> bool:
    """Whether a vertical face meets two of the walls found at corners at least min_length (m) apart along it: a
    container's side spanning between two of its opposite walls, not a face that ends at one wall (objects'
    faces before a shelf's open front meet its side wall there)."""
    along = np.cross(up, face.normal)
    met = [float(w.centre @ along) for w in _corner_walls(face, walls)]
    return len(met) >= 2 and max(met) - min(met) >= min_length


#: A wall whose middle lies this far (m, horizontally) inside the outline of the other walls (or of a platform)
#: found stands inside the container (or on the platform) they make: a true side lies on that outline, within its
#: thickness.
INNER_DEPTH = 0.03
#: A divider inside a container is seen as one gap-free face over at least this share of its length; objects'
#: faces in a line show gaps.
DIVIDER_SHARE = 0.75


def _without_inner_faces(walls: list[Wall], levels: list[Box], up: F64) -> list[Wall]:
    """The walls found less those standing inside the container that the others make, or, with fewer than two
    others, the platform that the raised levels' solids make (INNER_DEPTH inside their outline): objects' faces
    in a line, unless the face runs gap-free (DIVIDER_SHARE) between walls it meets at both its ends, as a
    divider does.  A container's own walls are its outline: a level seen wider than they stand (a base board, a
    floor measured with the table beside it) must not put them inside."""
    axes = in_plane_axes(up)
    keep = []
    for i, wall in enumerate(walls):
        box, length = wall[0], wall[2]
        met = [w[0] for j, w in enumerate(walls) if j != i]
        inner = _inside_depth(box.centre, met if len(met) >= 2 else met + levels, axes) >= INNER_DEPTH
        divider = (length >= DIVIDER_SHARE * 2.0 * (box.half_extents[1] - 0.01)
                   and _meets_at_both_ends(box, met))
        if divider or not inner:
            keep.append(wall)
    return keep


def _inside_depth(point: F64, boxes: list[Box], axes: F64) -> float:
    """How far (m, horizontally) a point lies inside the convex outline of the boxes' footprints (axes (2, 3): the
    horizontal plane's); negative outside, and -inf when they outline no area."""
    if not boxes:
        return -np.inf
    corners = np.concatenate([b.corners() for b in boxes]) @ axes.T
    try:
        hull = ConvexHull(corners)
    except QhullError:
        return -np.inf
    return float(-np.max(hull.equations[:, :2] @ (axes @ point) + hull.equations[:, 2]))


def _meets_at_both_ends(box: Box, walls: list[Box]) -> bool:
    """Whether each end of a wall box (along its length, at mid-height) lies within CORNER_REACH of a wall square
    to it (within CORNER_ANGLE_DEG): it runs from wall to wall."""
    along = box.rotation[:, 1]
    ends = box.centre + np.outer([-1.0, 1.0], along) * box.half_extents[1]
    square = [w for w in walls if abs(float(w.rotation[:, 0] @ along)) >= np.cos(np.radians(CORNER_ANGLE_DEG))]
    return all(any(bool(w.contains(end[None], margin=CORNER_REACH)[0]) for w in square) for end in ends)


def _curved_flank(height: F64, normal_up: F64) -> bool:
    """Whether a steep patch (its points' heights above the support, m, and their normals' vertical components) is
    the rounded flank of an object lying on its side, not a wall: its normals turn upward with height as a
    cylinder's of radius under CURVED_FLANK_RADIUS do (n . up = (h - axis height) / radius)."""
    hc, nc = height - height.mean(), normal_up - normal_up.mean()
    var_h, var_n, cov = float(hc @ hc), float(nc @ nc), float(hc @ nc)
    if len(height) < 10 or var_h <= 0.0 or var_n <= 0.0:
        return False
    return bool(cov / var_h >= 1.0 / CURVED_FLANK_RADIUS
                and cov / np.sqrt(var_h * var_n) >= CURVED_FLANK_CORRELATION)


def freestanding_sheet(box: Box, length: float, min_length: float, p: EnvironmentParams) -> bool:
    """Whether a lone wall (no other wall, no raised floor) is too short to be more than a long object standing
    on the table: its gap-free run is under 2.5 x min_length (a container shows two walls or a floor, a fence
    or a backboard runs longer)."""
    return bool(length < 2.5 * min_length)


def _slice_tops(along: F64, height: F64, step: float) -> F64:
    """The highest point's height (m) in each step-wide (m) slice along a vertical face that holds points."""
    cells = np.floor((along - along.min()) / step).astype(np.int64)
    tops = np.full(int(cells.max()) + 1, -np.inf)
    np.maximum.at(tops, cells, height)
    return tops[np.isfinite(tops)]


def _level_top(along: F64, height: F64, step: float = 0.02, tolerance: float = 0.015, share: float = 0.7) -> bool:
    """Whether a vertical patch has a straight, level top as a wall has: in step-wide (m) slices along it, the
    highest point lies within tolerance (m) of the median top in at least share of the slices."""
    tops = _slice_tops(along, height, step)
    return bool(len(tops) >= 3 and np.mean(np.abs(tops - np.median(tops)) <= tolerance) >= share)


def _common_top(along: F64, height: F64, step: float = 0.02) -> float:
    """The height (m above the support) of a vertical face's own top where objects in front rise above it along
    much of its length: the first quartile of its step-wide (m) slices' highest points (where objects stand, a
    slice's highest point is theirs)."""
    return float(np.percentile(_slice_tops(along, height, step), 25.0))


#: Rims sought per cloud: a four-walled container seen from above shows four, and each try spends the points of
#: the line it tried (so a refused line, a lying bottle's ridge, does not hide a wall's).
MAX_RIMS = 4
RIM_TRIES = 6

#: Beside a rim's crest (m, horizontally): a lying object's flanks lie RIM_FLANK_OFFSET from it, falling from
#: RIM_FLANK_DEPTH below its height to 1 cm above; a thin wall's own faces lie closer (half its thickness).
RIM_FLANK_OFFSET = (0.010, 0.030)
RIM_FLANK_DEPTH = 0.02


def _crest_offset(lateral: F64, height: F64, step: float = 0.002) -> float:
    """Across a line (m): where the step-wide slice of up-facing points with the highest 90th-percentile height
    lies (a bottle's ridge, a wall's top), so that flanks are measured from the ridge, not from a fitted line."""
    cells = np.floor(lateral / step).astype(np.int64)
    order = np.lexsort((height, cells))
    cells_s = cells[order]
    first = np.flatnonzero(np.r_[True, cells_s[1:] != cells_s[:-1]])
    count = np.diff(np.r_[first, len(cells_s)])
    p90 = height[order][first + np.floor(0.9 * (count - 1)).astype(np.int64)]
    p90 = np.where(count >= 5, p90, -np.inf)
    return float((cells_s[first][int(np.argmax(p90))] + 0.5) * step)


def _has_flanks(tops: F64, objects: F64, origin: F64, direction: F64, up: F64, run: tuple[float, float],
                on_count: int) -> bool:
    """Whether a rim candidate is an object's rounded ridge (a bottle lying on the table): more object points
    (any normal) than 0.3 x its on-line points lie RIM_FLANK_OFFSET beside its crest, from RIM_FLANK_DEPTH below
    its height to 1 cm above, crest and flanks away from its ends (within RIM_FLANK_OFFSET of an end, a
    container's next wall meets it at a corner: its top and face are neither).  tops: the up-facing points along
    its run; objects: all object points."""
    inner = (run[0] + RIM_FLANK_OFFSET[1], run[1] - RIM_FLANK_OFFSET[1])
    if inner[1] <= inner[0]:
        return False
    across = np.cross(up, direction)
    lateral, along = (tops - origin) @ across, (tops - origin) @ direction
    near = (np.abs(lateral) <= RIM_FLANK_OFFSET[1]) & (along >= inner[0]) & (along <= inner[1])
    if np.count_nonzero(near) < 5:
        return False
    crest = _crest_offset(lateral[near], tops[near] @ up)
    rel = objects - origin
    t, dh = rel @ direction, rel @ up
    off = np.abs(rel @ across - crest)
    beside = ((t >= inner[0]) & (t <= inner[1]) & (dh >= -RIM_FLANK_DEPTH) & (dh <= 0.01)
              & (off >= RIM_FLANK_OFFSET[0]) & (off <= RIM_FLANK_OFFSET[1]))
    return bool(np.count_nonzero(beside) > 0.3 * on_count * (inner[1] - inner[0]) / (run[1] - run[0]))


def find_rims(points: F64, normals: F64, support: Plane, params: EnvironmentParams, min_length: float,
              rng: np.random.Generator, candidates: NDArray[np.bool_]) -> list[tuple[Box, F64, F64, float, int]]:
    """Rims: long, thin, horizontal lines of points above the support (a thin wall's top seen from above, its
    faces unseen), each at least min_length gap-free with nothing else at its height beside it, and no object
    falling away beside its crest (_has_flanks: a bottle lying on the table).  Returns (box down to the support,
    point on the line, direction, length, points) per rim."""
    up = support.normal
    h = support.distance(points)
    idx = np.flatnonzero(candidates & (h > 0.015) & (normals @ up > 0.7))  # a rim's top faces up
    rims: list[tuple[Box, F64, F64, float, int]] = []
    if len(idx) < 20:
        return rims
    objects = points[candidates & (h > 0.005)]  # every object point above the support, for _has_flanks
    sub = idx if len(idx) <= 1500 else rng.choice(idx, 1500, replace=False)
    axes2 = in_plane_axes(up)
    for _ in range(RIM_TRIES):
        if len(sub) < 20 or len(rims) >= MAX_RIMS:
            break
        pairs = rng.integers(0, len(sub), size=(150, 2))
        a, b = points[sub[pairs[:, 0]]], points[sub[pairs[:, 1]]]
        dh = (b - a) @ up
        d2 = (b - a) @ axes2.T  # (K,2)
        length = np.linalg.norm(d2, axis=1)
        ok = (length > 0.05) & (np.abs(dh) < 0.01)
        if not ok.any():
            break
        dirs = d2[ok] / length[ok, None]
        origin = a[ok] @ axes2.T
        heights = a[ok] @ up
        pxy = points[sub] @ axes2.T
        ph = points[sub] @ up
        off = np.abs((pxy[None, :, 0] - origin[:, None, 0]) * dirs[:, None, 1]
                     - (pxy[None, :, 1] - origin[:, None, 1]) * dirs[:, None, 0])
        band = (off <= params.rim_width) & (np.abs(ph[None, :] - heights[:, None]) <= 0.01)
        k = int(np.argmax(band.sum(axis=1)))
        d3 = dirs[k] @ axes2
        o3 = a[ok][k]
        # verify on every candidate point
        rel = points[idx] - o3
        t = rel @ d3
        lateral = rel - np.outer(t, d3) - np.outer(rel @ up, up)
        off_all = np.linalg.norm(lateral, axis=1)
        same_h = np.abs(rel @ up) <= 0.01
        on = same_h & (off_all <= params.rim_width)
        beside = same_h & (off_all > 2 * params.rim_width) & (off_all <= 0.03)
        sub = np.setdiff1d(sub, idx[on])
        if on.sum() < 15:
            continue
        runs = gap_free_runs(t[on], gap=0.03, min_count=10)
        if not runs:
            continue
        s0, s1 = max(runs, key=lambda r: r[1] - r[0])
        length_run = s1 - s0
        near_run = (t >= s0) & (t <= s1)
        if length_run < min_length or (beside & near_run).sum() > 0.3 * (on & near_run).sum():
            continue
        if _has_flanks(points[idx[near_run]], objects, o3, d3, up, (s0, s1), int((on & near_run).sum())):
            continue
        top = float(np.percentile(h[idx[on & near_run]], 90.0)) + 0.01
        across = np.cross(up, d3)
        centre = o3 + d3 * (s0 + s1) / 2.0 + up * ((top - 0.02) / 2.0 - float(support.distance(o3[None])[0]))
        rotation = np.stack([across, d3, up], axis=1)
        half = np.array([params.rim_width + 0.004, length_run / 2.0 + 0.01, (top + 0.02) / 2.0])
        rims.append((Box(centre, rotation, half), o3, d3, float(length_run), int((on & near_run).sum())))
    return rims
