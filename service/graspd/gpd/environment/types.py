"""The environment stage's values: point labels, planes, boxes, its parameters, the surfaces it reports and the
environment of one cloud (cloud frame, metres)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

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
