"""Step 2 of the pipeline: the environment model, which tells the objects from what holds them.

Per request, on the preprocessed cloud, from the cameras and geometry alone (no container's dimensions):
- "up": against gravity when given, else the normal of the dominant plane, oriented toward the cameras;
- support levels: large up-facing planes at any height (the table; a container's floor raised above it; a
  platform's top), each larger than anything the hand could lift.  The lowest is `support` (a half-space the
  hand stays above, in closed form); each raised level is a solid slab down to the level below it;
- walls: near-vertical planar patches longer than any graspable object that rise from a level (tray, bin,
  box and shelf walls, either face; two-wall corners), modelled as boxes down to the lowest support;
- rims: long, thin horizontal lines of points above a level (thin sheet walls seen from above), modelled as
  thin walls down to the lowest support;
- what the caller declares (a support plane, boxes), which overrides what is found.
Every surface is reported (kind, plane, extent, confidence), and when the stage is unsure it says so in
`warnings`.  Candidates are sampled on object points only, their closing region must hold no environment
point, and no part of the hand or its approach path may enter the environment (see hand_hits_environment).
Everything is in the cloud frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import IntEnum
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.core.parallel import THREADS
from graspd.core.types import F64
from graspd.core.warning import DetectionWarning

EnvironmentMode = Literal["auto", "declared", "none"]
ENVIRONMENT_MODES: tuple[str, ...] = ("auto", "declared", "none")


class Label(IntEnum):
    """What a point is: part of an object, or part of the environment (support, wall, declared box)."""

    OBJECT = 0
    SUPPORT = 1
    WALL = 2
    DECLARED = 3


@dataclass(frozen=True)
class Plane:
    """The plane normal . x + offset = 0 with a unit normal; signed distance is positive on the normal's side
    (above a support, toward the cameras)."""

    normal: F64
    offset: float

    def distance(self, points: NDArray[np.floating]) -> F64:
        """Signed distance (m) of points (N,3) from the plane."""
        return np.asarray(points, np.float64) @ self.normal + self.offset

    @staticmethod
    def from_coefficients(abcd: tuple[float, float, float, float] | NDArray[np.floating]) -> Plane:
        """The plane a x + b y + c z + d = 0 (normalised; the normal points along (a, b, c))."""
        c = np.asarray(abcd, np.float64).reshape(4)
        n = float(np.linalg.norm(c[:3]))
        if not np.isfinite(c).all() or n < 1e-9:
            raise ValueError("a plane needs finite coefficients [a, b, c, d] with (a, b, c) non-zero")
        return Plane(c[:3] / n, float(c[3] / n))

    def to_dict(self) -> dict[str, Any]:
        return {"normal": self.normal.tolist(), "offset": self.offset}


@dataclass(frozen=True)
class Box:
    """An oriented box: centre (3,), rotation (3,3) whose columns are the box axes, half extents (3,) (m)."""

    centre: F64
    rotation: F64
    half_extents: F64

    @staticmethod
    def from_bounds(bounds: tuple[float, ...] | list[float]) -> Box:
        """The axis-aligned box [xmin, xmax, ymin, ymax, zmin, zmax] (cloud frame)."""
        b = np.asarray(bounds, np.float64).reshape(3, 2)
        if not np.isfinite(b).all() or np.any(b[:, 1] < b[:, 0]):
            raise ValueError("a box is [xmin, xmax, ymin, ymax, zmin, zmax] with each max >= its min")
        return Box(b.mean(axis=1), np.eye(3), (b[:, 1] - b[:, 0]) / 2.0)

    #: Corner signs (8, 3) along the box axes, in the order corners() returns them.
    CORNER_SIGNS: ClassVar[F64] = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                                           np.float64)

    def corners(self) -> F64:
        """The 8 corners (8, 3) of the box in the cloud frame (m), in the order of CORNER_SIGNS."""
        return np.asarray(self.centre + (self.CORNER_SIGNS * self.half_extents) @ self.rotation.T)

    def contains(self, points: NDArray[np.floating], margin: float = 0.0) -> NDArray[np.bool_]:
        """Whether each point (N,3) lies inside the box grown by margin (m)."""
        local = (np.asarray(points, np.float64) - self.centre) @ self.rotation
        return np.asarray(np.all(np.abs(local) <= self.half_extents + margin, axis=1))

    def to_dict(self) -> dict[str, Any]:
        return {"centre": self.centre.tolist(), "rotation": self.rotation.tolist(),
                "half_extents": self.half_extents.tolist()}


@dataclass(frozen=True)
class EnvironmentParams:
    """How the environment is found.  mode "auto": detect the support and walls, plus what is declared;
    "declared": only the declared support and boxes; "none": no environment (every point is an object).

    support_distance (m): points this close to the support plane, or below it, are support.
    min_support_extent (m): a plane is a support only if its points span this much in both directions
    (None: 1.5 x the hand's aperture), so an object's own face is never taken for the table.
    wall_min_length (m): a wall patch is at least this long (None: 1.5 x the hand's outer diameter).
    wall_thickness (m): how far behind its visible face a wall is assumed solid.
    clearance (m): the least height of any part of the hand above the support.
    max_levels: at most this many support levels (table, container floor, platform top); a level above
    another must cover level_min_fill of its footprint (1 cm cells), so rims at one height are no level.
    rim_min_length (m): a rim line is at least this long (None: wall_min_length).
    """

    mode: EnvironmentMode = "auto"
    support: Plane | None = None
    boxes: tuple[Box, ...] = ()
    support_distance: float = 0.006
    min_support_extent: float | None = None
    wall_min_length: float | None = None
    wall_thickness: float = 0.02
    wall_max_tilt_deg: float = 20.0
    max_walls: int = 6
    wall_rounds: int = 12
    plane_distance: float = 0.005
    ransac_points: int = 6000
    ransac_iterations: int = 200
    clearance: float = 0.003
    max_levels: int = 4
    level_min_points: int = 60
    level_min_fill: float = 0.3
    level_points: int = 8000
    wall_base_gap: float = 0.04
    rim_min_length: float | None = None
    rim_width: float = 0.006
    wall_min_points: int = 60

    def __post_init__(self) -> None:
        if self.mode not in ENVIRONMENT_MODES:
            raise ValueError(f"environment.mode must be one of {ENVIRONMENT_MODES}, got {self.mode!r}")


SurfaceKind = Literal["support", "floor", "platform", "board", "wall", "rim", "declared"]


@dataclass(frozen=True)
class Surface:
    """One piece of environment the stage found or was given: its kind, plane (normal toward the free side),
    the solid box the hand must not enter (None for the lowest support, a half-space), the extent of its
    points (m, the two in-plane spans, 2nd-98th percentile), how many points it holds and a confidence in
    [0, 1] (how clearly it passed the tests that made it environment)."""

    kind: SurfaceKind
    plane: Plane
    box: Box | None
    extent: tuple[float, float]
    num_points: int
    confidence: float

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "plane": self.plane.to_dict(),
                "box": None if self.box is None else self.box.to_dict(),
                "extent": [float(self.extent[0]), float(self.extent[1])], "num_points": int(self.num_points),
                "confidence": float(self.confidence)}


@dataclass(frozen=True)
class Environment:
    """The environment found in one cloud: a label per point (Label), the lowest support plane (a half-space),
    wall boxes (walls, rims and raised support levels: every solid the hand must not enter), declared boxes,
    "up" (unit, cloud frame; None when nothing says which way is up), every surface found with its kind and
    confidence, an overall confidence in [0, 1] and the warnings of an unsure stage."""

    labels: NDArray[np.int8]
    support: Plane | None = None
    walls: tuple[Box, ...] = ()
    boxes: tuple[Box, ...] = ()
    up: F64 | None = None
    mode: str = "auto"
    clearance: float = 0.003
    surfaces: tuple[Surface, ...] = ()
    confidence: float = 1.0
    warnings: tuple[DetectionWarning, ...] = ()
    support_distance: float = 0.006

    @staticmethod
    def empty(num_points: int, mode: str = "none") -> Environment:
        """No environment: every point is an object point."""
        return Environment(labels=np.zeros(num_points, np.int8), mode=mode)

    @property
    def object_mask(self) -> NDArray[np.bool_]:
        return np.asarray(self.labels == Label.OBJECT)

    @property
    def obstacles(self) -> tuple[Box, ...]:
        """Every box the hand must not enter: walls, then declared boxes."""
        return self.walls + self.boxes

    @property
    def active(self) -> bool:
        return self.support is not None or bool(self.obstacles)

    def closed_form_mask(self, points: NDArray[np.floating]) -> NDArray[np.bool_]:
        """Support points the lowest support's half-space stands for (the hand search tests the plane in
        closed form instead of them): SUPPORT points within support_distance of it, or below it."""
        mask = self.labels == Label.SUPPORT
        if self.support is None:
            return np.zeros(len(self.labels), bool)
        return np.asarray(mask & (self.support.distance(points) <= self.support_distance))

    def counts(self) -> dict[str, int]:
        """Points per label, by label name in lower case."""
        n = np.bincount(self.labels.astype(np.int64), minlength=len(Label))
        return {label.name.lower(): int(n[label]) for label in Label}

    def to_dict(self) -> dict[str, Any]:
        """The JSON report of what the stage found (the /detect response's "environment")."""
        return {
            "mode": self.mode,
            "support": None if self.support is None else self.support.to_dict(),
            "walls": [w.to_dict() for w in self.walls],
            "boxes": [b.to_dict() for b in self.boxes],
            "up": None if self.up is None else self.up.tolist(),
            "counts": self.counts(),
            "surfaces": [f.to_dict() for f in self.surfaces],
            "confidence": float(self.confidence),
        }


#: RANSAC hypotheses scored together by one task of _inlier_counts.
HYPOTHESES_PER_TASK = 50


def _inlier_counts(points: F64, normals: F64, offsets: F64, distance: float) -> NDArray[np.int64]:
    """How many of the points (N,3) lie within distance (m) of each plane (K normals, K offsets), in chunks of
    HYPOTHESES_PER_TASK planes on the process's thread budget (each plane's count depends on that plane alone)."""

    def part(a: int) -> NDArray[np.int64]:
        b = a + HYPOTHESES_PER_TASK
        return np.asarray((np.abs(points @ normals[a:b].T + offsets[a:b]) <= distance).sum(axis=0), np.int64)

    return np.concatenate(THREADS.map(part, range(0, len(normals), HYPOTHESES_PER_TASK)))


def _ransac_plane(points: F64, params: EnvironmentParams, rng: np.random.Generator,
                  vertical_to: F64 | None = None) -> Plane | None:
    """The plane with most inliers within plane_distance: RANSAC over ransac_iterations point triplets of at
    most ransac_points points, all hypotheses scored at once (numpy, seeded: the same cloud and seed always
    give the same plane, which open3d's multi-threaded RANSAC did not), refined by least squares."""
    if len(points) < 3:
        return None
    sub = points if len(points) <= params.ransac_points else \
        points[rng.choice(len(points), params.ransac_points, replace=False)]
    tri = sub[rng.integers(0, len(sub), size=(params.ransac_iterations, 3))]  # (K, 3 points, xyz)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-9
    if not ok.any():
        return None
    normals = normals[ok] / length[ok, None]
    offsets = -np.einsum("kj,kj->k", normals, tri[ok, 0])
    if vertical_to is not None:  # only planes standing up (walls): a slice across a wall would eat its points
        upright = np.abs(normals @ vertical_to) <= np.sin(np.radians(params.wall_max_tilt_deg))
        if not upright.any():
            return None
        normals, offsets = normals[upright], offsets[upright]
    counts = _inlier_counts(sub, normals, offsets, params.plane_distance)
    best = int(np.argmax(counts))
    inliers = sub[np.abs(sub @ normals[best] + offsets[best]) <= params.plane_distance]
    if len(inliers) < 3:
        return None
    centre = inliers.mean(axis=0)
    _, _, vt = np.linalg.svd(inliers - centre, full_matrices=False)
    normal = vt[-1] / np.linalg.norm(vt[-1])
    return Plane(normal, -float(normal @ centre))


def _in_plane_axes(normal: F64) -> F64:
    """Two unit vectors (2,3) spanning the plane of normal."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(normal, u)])


def _robust_span(values: F64) -> float:
    """The 2nd-98th percentile span of values (m): a few stray inliers do not make a plane large."""
    if len(values) < 10:
        return 0.0
    values = values[:: max(1, len(values) // 4000)]  # a regular thinning: the percentiles barely move
    lo, hi = np.percentile(values, [2.0, 98.0])
    return float(hi - lo)


def _runs(values: F64, gap: float, min_count: int) -> list[tuple[float, float]]:
    """Intervals of sorted values split where consecutive values are more than gap (m) apart, keeping
    those with at least min_count values."""
    v = np.sort(values)
    breaks = np.flatnonzero(np.diff(v) > gap)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(v) - 1]])
    return [(float(v[a]), float(v[b])) for a, b in zip(starts, ends, strict=True) if b - a + 1 >= min_count]


def find_support(points: F64, cameras: F64, params: EnvironmentParams, min_extent: float,
                 gravity: F64 | None, rng: np.random.Generator, tries: int = 3) -> Plane | None:
    """The dominant plane the objects stand on, its normal toward the cameras (or against gravity).

    A plane qualifies when its points span min_extent in both in-plane directions and, with gravity given,
    its normal lies within 30 degrees of up; the largest qualifying plane of a few RANSAC rounds wins."""
    remaining = points
    for _ in range(tries):
        plane = _ransac_plane(remaining, params, rng)
        if plane is None:
            return None
        d = plane.distance(remaining)
        inliers = np.abs(d) <= params.plane_distance
        if inliers.sum() < max(50, 0.05 * len(points)):
            return None
        toward = cameras.mean(axis=0) @ plane.normal + plane.offset
        if gravity is not None:
            toward = -float(gravity @ plane.normal)
        if toward < 0.0:
            plane = Plane(-plane.normal, -plane.offset)
        axes = _in_plane_axes(plane.normal)
        local = remaining[inliers] @ axes.T
        upright = gravity is None or float(-gravity @ plane.normal) >= np.cos(np.radians(30.0))
        if upright and min(_robust_span(local[:, 0]), _robust_span(local[:, 1])) >= min_extent:
            return plane
        remaining = remaining[~inliers]
    return None


def _min_area_rectangle(xy: F64) -> tuple[F64, F64, F64]:
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
    upf_all = (normals @ up) > np.cos(np.radians(25.0))
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
    axes2 = _in_plane_axes(up)
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
        wxy = points[window][:: max(1, int(window.sum()) // 2000)] @ _in_plane_axes(up).T
        if min(_robust_span(wxy[:, 0]), _robust_span(wxy[:, 1])) < min_extent:
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
        spans = (_robust_span(xy[:, 0]), _robust_span(xy[:, 1]))
        if min(spans) < min_extent:
            continue
        centre, axes, half = _min_area_rectangle(xy[:: max(1, len(xy) // 2000)])
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


def _in_footprint(points: F64, level: Level, up: F64, grow: float) -> NDArray[np.bool_]:
    """Whether each point (N,3) lies over the level's footprint grown by grow (m), at any height."""
    local = (points @ _in_plane_axes(up).T - level.centre) @ level.axes.T
    return np.asarray(np.all(np.abs(local) <= level.half + grow, axis=1))


def _level_box(level: Level, up: F64, bottom: float, grow: float) -> Box:
    """The solid under a raised level: its footprint grown by grow (m), from height bottom up to just below the
    level's surface (fingers may touch a floor, as they touch the table)."""
    a2 = _in_plane_axes(up)
    ax3 = level.axes @ a2  # (2,3): the footprint's axes in the cloud frame
    top = level.height - 0.002
    centre = (level.centre @ a2) + up * ((top + bottom) / 2.0)
    rotation = np.stack([ax3[0], ax3[1], np.cross(ax3[0], ax3[1])], axis=1)
    if float(rotation[:, 2] @ up) < 0.0:
        rotation[:, 1] *= -1.0
        rotation[:, 2] *= -1.0
    return Box(centre, rotation, np.array([level.half[0] + grow, level.half[1] + grow, (top - bottom) / 2.0]))


def find_walls(points: F64, normals: F64, cameras: F64, support: Plane, params: EnvironmentParams,
               min_length: float, rng: np.random.Generator, candidates: NDArray[np.bool_] | None = None,
               level_heights: tuple[float, ...] = (0.0,)) -> list[tuple[Box, Plane, float, int, float, bool]]:
    """Walls: near-vertical planar patches at least min_length long, among the candidate points.

    Each box spans the patch's longest gap-free run along the support, from below the support to a little
    above the patch's top, and from just in front of the visible face to the far face when the wall's other
    side is seen (its parallel, opposite-facing points), else wall_thickness behind it.  Returns (box, plane,
    length, points, top height, stands) per wall: stands is whether its foot is within wall_base_gap of a
    support level (level_heights: heights above the support, m); a patch that does not stand is still a
    solid larger than anything graspable, and lowers the stage's confidence."""
    up = support.normal
    height = support.distance(points)
    # only points on steep surfaces can belong to a wall: RANSAC then never wastes rounds on object tops
    steep = np.abs(normals @ up) < 0.5
    pool = (height > params.support_distance) & steep
    if candidates is not None:
        pool &= candidates
    remaining = points[pool]
    walls: list[tuple[Box, Plane, float, int, float, bool]] = []
    min_points = 30
    # a wall is among the largest planes left: fewer hypotheses on fewer points find it (half the cost)
    wall_ransac = replace(params, ransac_points=min(params.ransac_points, 3000),
                          ransac_iterations=min(params.ransac_iterations, 120))
    for _ in range(params.wall_rounds):
        if len(remaining) < min_points or len(walls) >= params.max_walls:
            break
        plane = _ransac_plane(remaining, wall_ransac, rng, vertical_to=up)
        if plane is None:
            break
        inliers = np.abs(plane.distance(remaining)) <= params.plane_distance
        if inliers.sum() < params.wall_min_points:
            break  # the largest plane left is too small to be a wall: the rest are objects' faces
        patch = remaining[inliers]
        remaining = remaining[~inliers]
        if abs(float(plane.normal @ up)) > np.sin(np.radians(params.wall_max_tilt_deg)):
            continue  # not vertical: an object's top, or a second level
        across = plane.normal - (plane.normal @ up) * up  # the face's horizontal normal, toward the cameras
        across /= np.linalg.norm(across)
        if float((cameras.mean(axis=0) - patch.mean(axis=0)) @ across) < 0.0:
            across = -across
        along = np.cross(up, across)
        runs = _runs(patch @ along, gap=0.04, min_count=10)
        if not runs or max(b - a for a, b in runs) < min_length:
            continue
        longest = max(b - a for a, b in runs)
        # the longest gap-free run makes it a wall; objects in front may hide parts of it, so it spans all runs
        s0, s1 = min(a for a, _ in runs), max(b for _, b in runs)
        run = patch[(patch @ along >= s0) & (patch @ along <= s1)]
        h = support.distance(run)
        if not _level_top(run @ along, h):
            continue  # faces of several objects that happen to line up: their tops are at many heights
        foot = float(np.percentile(h, 1.0))
        stands = any(abs(foot - lv) <= params.wall_base_gap or foot <= lv + params.wall_base_gap
                     for lv in level_heights)
        face = float(np.median(run @ across))
        # the wall's other face: steep points just behind this one, facing the other way (a wall seen from both
        # sides, or a thin sheet): the box ends there instead of wall_thickness behind
        behind = (points @ across) - face
        strip = ((points @ along >= s0) & (points @ along <= s1) & steep & (behind < -params.plane_distance)
                 & (behind > -params.wall_thickness - 0.01) & ((normals @ across) < -0.7))
        back = params.wall_thickness
        if strip.sum() >= 20:
            back = min(back, float(-np.percentile(behind[strip], 10.0)) + 0.003)
        front = params.plane_distance + 0.002
        base, top = -0.02, float(np.percentile(h, 99.0)) + 0.01
        centre = (along * (s0 + s1) / 2.0 + across * (face + (front - back) / 2.0)
                  + up * ((base + top) / 2.0 - support.offset))
        rotation = np.stack([across, along, up], axis=1)
        half = np.array([(front + back) / 2.0, (s1 - s0) / 2.0 + 0.01, (top - base) / 2.0])
        walls.append((Box(centre, rotation, half), Plane(across, -face), longest, len(run), top - 0.01, stands))
    return walls


def _freestanding_sheet(box: Box, length: float, min_length: float, p: EnvironmentParams) -> bool:
    """Whether a lone wall (no other wall, no raised floor) is too short to be more than a long object standing
    on the table: its gap-free run is under 2.5 x min_length (a container shows two walls or a floor, a fence
    or a backboard runs longer)."""
    return bool(length < 2.5 * min_length)


def _level_top(along: F64, height: F64, step: float = 0.02, tolerance: float = 0.015, share: float = 0.7) -> bool:
    """Whether a vertical patch has a straight, level top as a wall has: in step-wide (m) slices along it, the
    highest point lies within tolerance (m) of the median top in at least share of the slices."""
    cells = np.floor((along - along.min()) / step).astype(np.int64)
    tops = np.full(int(cells.max()) + 1, -np.inf)
    np.maximum.at(tops, cells, height)
    tops = tops[np.isfinite(tops)]
    return bool(len(tops) >= 3 and np.mean(np.abs(tops - np.median(tops)) <= tolerance) >= share)


def find_rims(points: F64, normals: F64, support: Plane, params: EnvironmentParams, min_length: float,
              rng: np.random.Generator, candidates: NDArray[np.bool_]) -> list[tuple[Box, F64, F64, float, int]]:
    """Rims: long, thin, horizontal lines of points above the support (a thin wall's top seen from above, its
    faces unseen), each at least min_length gap-free with nothing else at its height beside it.  Returns (box
    down to the support, point on the line, direction, length, points) per rim."""
    up = support.normal
    h = support.distance(points)
    idx = np.flatnonzero(candidates & (h > 0.015) & (normals @ up > 0.7))  # a rim's top faces up
    rims: list[tuple[Box, F64, F64, float, int]] = []
    if len(idx) < 20:
        return rims
    sub = idx if len(idx) <= 1500 else rng.choice(idx, 1500, replace=False)
    axes2 = _in_plane_axes(up)
    for _ in range(3):
        if len(sub) < 20:
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
        runs = _runs(t[on], gap=0.03, min_count=10)
        if not runs:
            continue
        s0, s1 = max(runs, key=lambda r: r[1] - r[0])
        length_run = s1 - s0
        near_run = (t >= s0) & (t <= s1)
        if length_run < min_length or (beside & near_run).sum() > 0.3 * (on & near_run).sum():
            continue
        top = float(np.percentile(h[idx[on & near_run]], 90.0)) + 0.01
        across = np.cross(up, d3)
        centre = o3 + d3 * (s0 + s1) / 2.0 + up * ((top - 0.02) / 2.0 - float(support.distance(o3[None])[0]))
        rotation = np.stack([across, d3, up], axis=1)
        half = np.array([params.rim_width + 0.004, length_run / 2.0 + 0.01, (top + 0.02) / 2.0])
        rims.append((Box(centre, rotation, half), o3, d3, float(length_run), int((on & near_run).sum())))
    return rims


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
            dominant = find_support(pts, cams, p, min_extent, None, rng)
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
            spans = _plane_spans(pts, labels == Label.SUPPORT, support.normal)
            surfaces.append(Surface("support", support, None, spans, int((labels == Label.SUPPORT).sum()),
                                    _ratio_conf(min(spans), min_extent)))
            level_heights = [0.0]
            base_height = levels[0].height if levels else -support.offset
            for lv in levels[1:]:
                assert up is not None
                lv_h = _apply_level(lv, up, base_height, pts, labels, walls, surfaces, p, min_extent)
                if lv_h is not None:
                    level_heights.append(lv_h)
            min_length = p.wall_min_length if p.wall_min_length is not None else 1.5 * hand.hand_outer_diameter
            found = find_walls(pts, normals, cams, support, p, min_length, rng, labels == Label.OBJECT,
                               tuple(level_heights))
            if len(found) == 1 and len(level_heights) == 1 and _freestanding_sheet(found[0][0], found[0][2],
                                                                                  min_length, p):
                found = []  # one short face standing alone on the table: a long object (a board, a box), not a wall
            for box, plane, length, count, top, stands in found:
                labels[(labels == Label.OBJECT) & box.contains(pts, margin=0.003)] = Label.WALL
                walls.append(box)
                conf = _ratio_conf(length, min_length) * (1.0 if stands else 0.4)
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
                    lv_h = _apply_level(inner, up, base_height, pts, labels, walls, surfaces, p, 0.6 * min_extent)
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
                                        _ratio_conf(length, rim_length)))
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
        lined = [side for lv in levels[1:] for side in _lined_edges(pts, labels, lv, up)]
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


def _apply_level(lv: Level, up: F64, base_height: float, pts: F64, labels: NDArray[np.int8], walls: list[Box],
                 surfaces: list[Surface], p: EnvironmentParams, min_extent: float) -> float | None:
    """Label a raised level's points and sides as support and add its solid (a slab down to the support, or a
    thin board when seen room lies beneath it) to walls and its surface to surfaces.  Returns its height above
    the support (m) when objects can stand on it (a floor or platform), None for a board."""
    lv_h = lv.height - base_height  # above the lowest support (m)
    dl = lv.plane.distance(pts)
    # seen points well under the level, inside its footprint: it is a board with room beneath (a shelf's
    # ceiling), not a solid down to the table
    beneath = _in_footprint(pts, lv, up, -0.02) & (dl < -0.02) & (labels == Label.OBJECT)
    board = int(beneath.sum()) >= 30
    depth = min(lv_h, max(0.02, -float(np.max(dl[beneath])) - 0.005)) if board else lv_h
    slab = _level_box(lv, up, lv.height - depth - (0.0 if board else 0.01), 0.005)
    # the level's own points and its sides: over its footprint, from its surface down the slab
    on = _in_footprint(pts, lv, up, 0.01) & (dl <= p.support_distance) & (dl >= -depth - 0.005)
    labels[on] = Label.SUPPORT
    walls.append(slab)
    # a floor has walls around it; a platform stands clear (named once the walls are known)
    surfaces.append(Surface("board" if board else "floor", lv.plane, slab, lv.spans, int(on.sum()),
                            _ratio_conf(min(lv.spans), min_extent)))
    return None if board else lv_h


def find_inner_floor(points: F64, normals: F64, up: F64, support: Plane, wall_boxes: list[Box],
                     labels: NDArray[np.int8], params: EnvironmentParams, min_extent: float) -> Level | None:
    """A container's floor the level search missed: the lowest well-populated height of up-facing object points
    inside the rectangle the walls enclose, between the support and 6 cm above it, one connected surface spanning
    at least 0.6 x min_extent both ways and covering level_min_fill of the enclosure (objects rest on the floor,
    so nothing of theirs lies below it)."""
    a2 = _in_plane_axes(up)
    corners = np.concatenate([b.corners() @ a2.T for b in wall_boxes])
    centre, axes, half = _min_area_rectangle(corners)
    local = (points @ a2.T - centre) @ axes.T
    h = support.distance(points)
    cand = ((labels == Label.OBJECT) & ((normals @ up) > np.cos(np.radians(25.0)))
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
        spans = (_robust_span(xy[:, 0]), _robust_span(xy[:, 1]))
        if min(spans) < 0.6 * min_extent or cells < params.level_min_fill * float(np.prod(2.0 * half / 0.01)):
            continue  # too small a share of the container to be its floor: flat objects' tops
        plane = Plane(support.normal, support.offset - height_above)
        height = float(np.median(points[on[island]] @ up))
        return Level(plane, height, centre, axes, half, spans, int(island.sum()), 1.0)
    return None


def _lined_edges(points: F64, labels: NDArray[np.int8], level: Level, up: F64, rise: float = 0.02,
                 share: float = 0.8, step: float = 0.02) -> list[float]:
    """Lengths (m) of the sides of a raised level's footprint along which object points stand more than rise (m)
    above the level in at least share of the step-wide (m) slices, within 2 cm of the side: a wall kept as
    objects (a platform's edge has nothing standing along all of it)."""
    obj = labels == Label.OBJECT
    local = (points[obj] @ _in_plane_axes(up).T - level.centre) @ level.axes.T
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


def _ratio_conf(value: float, threshold: float) -> float:
    """Confidence that a measure passed its threshold clearly: 0 at 0.8 x threshold, 1 at 1.5 x or more."""
    if threshold <= 0.0:
        return 1.0
    return float(np.clip((value / threshold - 0.8) / 0.7, 0.0, 1.0))


def _plane_spans(points: F64, mask: NDArray[np.bool_], normal: F64) -> tuple[float, float]:
    """The robust in-plane spans (m) of the masked points."""
    local = points[mask] @ _in_plane_axes(normal).T
    if len(local) == 0:
        return (0.0, 0.0)
    return (_robust_span(local[:, 0]), _robust_span(local[:, 1]))


def _name_levels(surfaces: list[Surface]) -> list[Surface]:
    """A raised level with walls or rims standing on or around it is a container's floor; one without is a
    platform."""
    has_walls = any(s.kind in ("wall", "rim") for s in surfaces)
    return [replace(s, kind="platform") if s.kind == "floor" and not has_walls else s for s in surfaces]


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
