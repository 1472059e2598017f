"""Step 2 of the pipeline: the environment model, which tells the objects from what holds them.

Per request, on the preprocessed cloud: the support surface (the dominant plane the objects stand on,
oriented toward the cameras; a tray's or bin's floor), container walls (planar patches that stand on the
support and are longer than anything the hand could lift, modelled as boxes), and static geometry the
caller declares (a support plane, boxes).  Candidates are sampled on object points only, their closing
region must hold no environment point, and no part of the hand or its approach path may enter the
environment (see hand_hits_environment).  Everything is in the cloud frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from .cloud import ViewpointCloud
from .hand import HandGeometry

F64 = NDArray[np.float64]
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

    def __post_init__(self) -> None:
        if self.mode not in ENVIRONMENT_MODES:
            raise ValueError(f"environment.mode must be one of {ENVIRONMENT_MODES}, got {self.mode!r}")


@dataclass(frozen=True)
class Environment:
    """The environment found in one cloud: a label per point (Label), the support plane, wall boxes,
    declared boxes and "up" (unit, cloud frame; None when nothing says which way is up)."""

    labels: NDArray[np.int8]
    support: Plane | None = None
    walls: tuple[Box, ...] = ()
    boxes: tuple[Box, ...] = ()
    up: F64 | None = None
    mode: str = "auto"
    clearance: float = 0.003

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
        }


def _ransac_plane(points: F64, params: EnvironmentParams, rng: np.random.Generator) -> Plane | None:
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
    counts = (np.abs(sub @ normals.T + offsets) <= params.plane_distance).sum(axis=0)
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


def find_walls(points: F64, normals: F64, cameras: F64, support: Plane, params: EnvironmentParams,
               min_length: float, rng: np.random.Generator) -> tuple[Box, ...]:
    """Wall boxes: near-vertical planar patches standing on the support, at least min_length long.

    Each box spans the patch's longest gap-free run along the support, from below the support to a little
    above the patch's top, and from just in front of the visible face to wall_thickness behind it."""
    up = support.normal
    height = support.distance(points)
    # only points on steep surfaces can belong to a wall: RANSAC then never wastes rounds on object tops
    steep = np.abs(normals @ up) < 0.5
    remaining = points[(height > params.support_distance) & steep]
    walls: list[Box] = []
    min_points = 30
    for _ in range(params.wall_rounds):
        if len(remaining) < min_points or len(walls) >= params.max_walls:
            break
        plane = _ransac_plane(remaining, params, rng)
        if plane is None:
            break
        inliers = np.abs(plane.distance(remaining)) <= params.plane_distance
        if inliers.sum() < min_points:
            break
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
        # the longest gap-free run makes it a wall; objects in front may hide parts of it, so it spans all runs
        s0, s1 = min(a for a, _ in runs), max(b for _, b in runs)
        run = patch[(patch @ along >= s0) & (patch @ along <= s1)]
        h = support.distance(run)
        if float(h.min()) > 0.03:
            continue  # does not stand on the support (a shelf edge, a lid)
        # the visible face points toward the cameras, so the wall's body lies behind it
        face = float(np.median(run @ across))
        front, back = params.plane_distance + 0.002, params.wall_thickness
        base, top = -0.02, float(np.percentile(h, 99.0)) + 0.01
        centre = (along * (s0 + s1) / 2.0 + across * (face + (front - back) / 2.0)
                  + up * ((base + top) / 2.0 - support.offset))
        rotation = np.stack([across, along, up], axis=1)
        half = np.array([(front + back) / 2.0, (s1 - s0) / 2.0 + 0.01, (top - base) / 2.0])
        walls.append(Box(centre, rotation, half))
    return tuple(walls)


def model_environment(cloud: ViewpointCloud, hand: HandGeometry, params: EnvironmentParams | None = None,
                      gravity: tuple[float, float, float] | None = None, seed: int | None = 0) -> Environment:
    """Label every point of a preprocessed cloud as object, support, wall or declared, and say which way is up
    (against gravity when given, else the support's normal)."""
    p = params or EnvironmentParams()
    n = len(cloud)
    if p.mode == "none":
        return Environment.empty(n, "none")
    pts = cloud.points.astype(np.float64)
    g = None if gravity is None else np.asarray(gravity, np.float64) / max(float(np.linalg.norm(gravity)), 1e-12)
    rng = np.random.default_rng(seed if seed is not None else 0)
    support = p.support
    if support is None and p.mode == "auto" and n >= 3:
        min_extent = p.min_support_extent if p.min_support_extent is not None else 1.5 * hand.max_aperture
        support = find_support(pts, cloud.viewpoints.astype(np.float64), p, min_extent, g, rng)
    labels = np.zeros(n, np.int8)
    walls: tuple[Box, ...] = ()
    if support is not None:
        d = support.distance(pts)
        labels[d <= p.support_distance] = Label.SUPPORT
        if p.mode == "auto":
            min_length = p.wall_min_length if p.wall_min_length is not None else 1.5 * hand.hand_outer_diameter
            normals = np.zeros_like(pts) if cloud.normals is None else cloud.normals.astype(np.float64)
            walls = find_walls(pts, normals, cloud.viewpoints.astype(np.float64), support, p, min_length, rng)
            for wall in walls:
                labels[(labels == Label.OBJECT) & wall.contains(pts, margin=0.003)] = Label.WALL
    for box in p.boxes:
        labels[box.contains(pts)] = Label.DECLARED
    up = -g if g is not None else (None if support is None else support.normal)
    return Environment(labels=labels, support=support, walls=walls, boxes=tuple(p.boxes), up=up, mode=p.mode,
                       clearance=p.clearance)


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
