"""A family of containers and supports for the simulated world: trays, deep bins, thin-walled
boxes, two-wall corners, raised platforms, shelves and lidless totes, each with a random size, wall
height, wall thickness, floor height and yaw drawn from ranges.

Frames and units: metres and radians.  World frame as in graspd_lab.sim.world: z up, the table's top face
at z = 0, the container centred on the origin.  The container frame is the world frame turned by
ContainerSpec.yaw about z: its interior is [-inner_x/2, inner_x/2] x [-inner_y/2, inner_y/2] above a floor
whose top lies floor_height above the table (0: the table is the floor).  Walls stand on the table around
the interior (named by the side they close: "-x", "+x", "-y", "+y" in the container frame) and rise
wall_height above the floor.  A shelf's open front is its -x side, which faces the cameras of
graspd.core.camera (they stand on the world's -x side) at yaw 0.  The table extends far around every
container, so the cameras see table around it, as in a robot cell.

This module holds only geometry (no pybullet): graspd_lab.sim.world builds the bodies from
ContainerSpec.boxes() and drops the objects in.

THE SPLIT (the one place it is written down; the design notes: the benchmark's headline counts only styles and
parameter ranges held out of training and tuning):

- TRAINING_STYLES = ("tray", "deep_bin", "platform", "tote", "shelf"): scene data for training and any tuning draw
  these styles with their "training" ranges (RANGES[style]["training"]) only.
- HELD_OUT_STYLES = ("thin_box", "corner"): benchmark only; they have no "training" ranges, so
  sample_container(style, rng, "training") raises for them.
- TUNED_ON = ("shelf",): held out at first, then looked at while the environment stage was tuned; it is a
  training style now (its training ranges are its former held-out ones) and has its own benchmark rows.
- A training style also has "held_out" ranges that lie outside its training ranges in at least one
  parameter (a tray floor raised 3-4.5 cm, deep-bin walls 20-24 cm, platforms 8-11 cm high, tote floors
  2-3.5 cm): a benchmark row of a training style is still marked "tuned on" (the style was seen).

Style by style ("training" ranges; held-out styles: their "held_out" ranges):

| style    | inner x x y (cm)  | walls above floor (cm) | wall thickness | floor above table | walls          |
|----------|-------------------|------------------------|----------------|-------------------|----------------|
| tray     | 24-36 x 20-30     | 3-7                    | 8-15 mm        | 0-3 cm slab       | four           |
| deep_bin | 24-34 x 20-28     | 12-20                  | 6-12 mm        | 0-2 cm            | four           |
| platform | 20-32 x 16-26     | none                   | -              | 2-8 cm (the slab) | none           |
| tote     | 32-42 x 26-34     | 8-14                   | 5-10 mm        | 1-2 cm            | four           |
| thin_box | 20-34 x 18-28     | 6-14                   | 2-4 mm (sheet) | 0-1 cm            | four           |
| corner   | 26-36 x 26-36     | 8-20                   | 10-20 mm       | table or 1-3 cm   | +x and +y      |
| shelf    | 20-28 x 28-38     | 15-25 (or to ceiling)  | 10-18 mm       | 1-4 cm slab       | +x, -y, +y     |

Yaw is uniform over the full turn for every style except the shelf (its open front within 40 degrees of
the cameras' side: a robot faces a shelf's opening); half of the shelves carry a ceiling board whose
underside is 30-36 cm above the table.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.types import F64

STYLES = ("tray", "deep_bin", "thin_box", "corner", "platform", "shelf", "tote")
TRAINING_STYLES: tuple[str, ...] = ("tray", "deep_bin", "platform", "tote", "shelf")
HELD_OUT_STYLES: tuple[str, ...] = ("thin_box", "corner")
#: Styles first held out and then looked at while the environment stage was tuned: the shelf (its ceiling board
#: was taken for a platform until a board with seen room beneath it became its own kind).  They moved to the
#: training styles, so the headline never counts them.
TUNED_ON: tuple[str, ...] = ("shelf",)
SPLITS = ("training", "held_out")
WALL_SIDES = ("-x", "+x", "-y", "+y")
#: Thickness (m) of a shelf's ceiling board.
CEILING_THICKNESS = 0.015
#: Table around the container that the robot's workspace box holds (m).
WORKSPACE_MARGIN = 0.05
#: Top of the workspace box above the table (m): as for the other scene kinds.
WORKSPACE_TOP = 0.4

Range = tuple[float, float]


@dataclass(frozen=True)
class StyleRanges:
    """Uniform ranges of one style's parameters (m, rad).  slab_probability: chance that the floor is a
    slab of floor_height (else the table is the floor, floor_height 0); ceiling_probability and
    ceiling_height (the board's underside above the table): shelves only."""

    inner_x: Range
    inner_y: Range
    wall_height: Range
    wall_thickness: Range
    floor_height: Range
    walls: tuple[str, ...]
    yaw: Range = (-np.pi, np.pi)
    slab_probability: float = 1.0
    ceiling_probability: float = 0.0
    ceiling_height: Range = (0.0, 0.0)


_FOUR = WALL_SIDES
_NONE: tuple[str, ...] = ()

#: RANGES[style][split]: the parameter ranges of each style in each split (see the module docstring).
RANGES: dict[str, dict[str, StyleRanges]] = {
    "tray": {
        "training": StyleRanges((0.24, 0.36), (0.20, 0.30), (0.03, 0.07), (0.008, 0.015), (0.0, 0.03), _FOUR),
        "held_out": StyleRanges((0.22, 0.34), (0.20, 0.30), (0.03, 0.07), (0.008, 0.015), (0.03, 0.045), _FOUR),
    },
    "deep_bin": {
        "training": StyleRanges((0.24, 0.34), (0.20, 0.28), (0.12, 0.20), (0.006, 0.012), (0.0, 0.02), _FOUR),
        "held_out": StyleRanges((0.24, 0.34), (0.20, 0.28), (0.20, 0.24), (0.006, 0.012), (0.0, 0.02), _FOUR),
    },
    "platform": {
        "training": StyleRanges((0.20, 0.32), (0.16, 0.26), (0.0, 0.0), (0.0, 0.0), (0.02, 0.08), _NONE),
        "held_out": StyleRanges((0.20, 0.32), (0.16, 0.26), (0.0, 0.0), (0.0, 0.0), (0.08, 0.11), _NONE),
    },
    "tote": {
        "training": StyleRanges((0.32, 0.42), (0.26, 0.34), (0.08, 0.14), (0.005, 0.010), (0.01, 0.02), _FOUR),
        "held_out": StyleRanges((0.32, 0.42), (0.26, 0.34), (0.08, 0.14), (0.005, 0.010), (0.02, 0.035), _FOUR),
    },
    "thin_box": {
        "held_out": StyleRanges((0.20, 0.34), (0.18, 0.28), (0.06, 0.14), (0.002, 0.004), (0.0, 0.01), _FOUR),
    },
    "corner": {
        "held_out": StyleRanges((0.26, 0.36), (0.26, 0.36), (0.08, 0.20), (0.010, 0.020), (0.01, 0.03),
                                ("+x", "+y"), slab_probability=0.5),
    },
    "shelf": {  # tuned on (see TUNED_ON): its training ranges are its held-out ones
        "training": StyleRanges((0.20, 0.28), (0.28, 0.38), (0.15, 0.25), (0.010, 0.018), (0.01, 0.04),
                                ("+x", "-y", "+y"), yaw=(-np.deg2rad(40), np.deg2rad(40)),
                                ceiling_probability=0.5, ceiling_height=(0.30, 0.36)),
        "held_out": StyleRanges((0.20, 0.28), (0.28, 0.38), (0.15, 0.25), (0.010, 0.018), (0.01, 0.04),
                                ("+x", "-y", "+y"), yaw=(-np.deg2rad(40), np.deg2rad(40)),
                                ceiling_probability=0.5, ceiling_height=(0.30, 0.36)),
    },
}


@dataclass(frozen=True)
class StaticBox:
    """One static box of a container: name ("floor", "wall-x", ..., "ceiling"), centre in the world frame
    (m), half extents along its own axes (m) and yaw about world z (rad)."""

    name: str
    centre: tuple[float, float, float]
    half: tuple[float, float, float]
    yaw: float


@dataclass(frozen=True)
class ContainerSpec:
    """One container (see the module docstring for the frames).  inner_x, inner_y: interior size (m, in the
    container frame); wall_height: wall tops above the floor's top (m; 0 = no walls); wall_thickness (m);
    floor_height: the floor's top above the table (m; 0 = the table is the floor); yaw (rad about world z);
    walls: which sides have a wall; ceiling_height: underside of a ceiling board above the table (m; 0 =
    none)."""

    style: str
    inner_x: float
    inner_y: float
    wall_height: float
    wall_thickness: float
    floor_height: float
    yaw: float
    walls: tuple[str, ...] = field(default=WALL_SIDES)
    ceiling_height: float = 0.0

    def __post_init__(self) -> None:
        if self.style not in STYLES:
            raise ValueError(f"container style must be one of {STYLES}, got {self.style!r}")
        if self.inner_x <= 0 or self.inner_y <= 0:
            raise ValueError(f"container inner size must be positive, got {self.inner_x} x {self.inner_y}")
        if self.floor_height < 0 or self.wall_height < 0:
            raise ValueError("container floor_height and wall_height must be >= 0")
        bad = [w for w in self.walls if w not in WALL_SIDES]
        if bad:
            raise ValueError(f"container walls must be among {WALL_SIDES}, got {bad}")
        if self.walls and (self.wall_thickness <= 0 or self.wall_height <= 0):
            raise ValueError("a container with walls needs positive wall_thickness and wall_height")
        if self.ceiling_height and self.ceiling_height <= self.floor_height + 0.1:
            raise ValueError("a ceiling must lie more than 10 cm above the floor")

    # --- frames -------------------------------------------------------------------------------------
    def rotation(self) -> F64:
        """Container-to-world rotation (3, 3): a turn by yaw about z."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def to_container(self, points: NDArray[np.floating]) -> F64:
        """World points (N, 3) in the container frame (the centre is the world origin)."""
        return np.asarray(points, np.float64).reshape(-1, 3) @ self.rotation()

    def to_world(self, points: NDArray[np.floating]) -> F64:
        """Container-frame points (N, 3) in the world frame."""
        return np.asarray(points, np.float64).reshape(-1, 3) @ self.rotation().T

    @property
    def wall_top(self) -> float:
        """Height of the wall tops above the table (m); the floor's top when there are no walls."""
        return self.floor_height + (self.wall_height if self.walls else 0.0)

    def interior_contains(self, points: NDArray[np.floating], margin: float = 0.0) -> NDArray[np.bool_]:
        """Which world points (N, 3) lie above the interior's footprint (container frame, grown by margin,
        m); height is not tested."""
        local = self.to_container(points)
        return np.asarray((np.abs(local[:, 0]) <= self.inner_x / 2 + margin)
                          & (np.abs(local[:, 1]) <= self.inner_y / 2 + margin))

    def interior_corners(self) -> F64:
        """The interior footprint's four corners (4, 2) in world xy (m)."""
        hx, hy = self.inner_x / 2, self.inner_y / 2
        local = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]])
        return self.to_world(local)[:, :2]

    def footprint_corners(self) -> F64:
        """Corners (4, 2) in world xy (m) of the container's outer footprint, walls included."""
        t = self.wall_thickness
        lo = [-self.inner_x / 2 - (t if "-x" in self.walls else 0.0),
              -self.inner_y / 2 - (t if "-y" in self.walls else 0.0)]
        hi = [self.inner_x / 2 + (t if "+x" in self.walls else 0.0),
              self.inner_y / 2 + (t if "+y" in self.walls else 0.0)]
        local = np.array([[lo[0], lo[1], 0.0], [hi[0], lo[1], 0.0], [hi[0], hi[1], 0.0], [lo[0], hi[1], 0.0]])
        return self.to_world(local)[:, :2]

    def workspace(self, margin: float = WORKSPACE_MARGIN) -> tuple[float, float, float, float, float, float]:
        """The axis-aligned box [xmin, xmax, ymin, ymax, zmin, zmax] (world, m) a robot sends: the container's
        footprint (any yaw) plus margin of table around it, from just below the table to WORKSPACE_TOP."""
        xy = self.footprint_corners()
        lo, hi = xy.min(axis=0) - margin, xy.max(axis=0) + margin
        return (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]), -0.005, WORKSPACE_TOP)

    # --- bodies -------------------------------------------------------------------------------------
    def boxes(self) -> list[StaticBox]:
        """The container's static boxes in the world frame: the floor slab (if floor_height > 0) over the
        interior, the walls standing on the table around it (x walls span the corners) and the ceiling."""
        hx, hy, t, fh = self.inner_x / 2, self.inner_y / 2, self.wall_thickness, self.floor_height
        top = self.ceiling_height if self.ceiling_height else self.wall_top
        local: list[tuple[str, tuple[float, float, float], tuple[float, float, float]]] = []
        if fh > 0:
            local.append(("floor", (0.0, 0.0, fh / 2), (hx, hy, fh / 2)))
        for side in self.walls:
            sign = -1.0 if side[0] == "-" else 1.0
            if side[1] == "x":  # spans the corners where a y wall meets it
                y0 = -hy - (t if "-y" in self.walls else 0.0)
                y1 = hy + (t if "+y" in self.walls else 0.0)
                local.append((f"wall{side}", (sign * (hx + t / 2), (y0 + y1) / 2, top / 2),
                              (t / 2, (y1 - y0) / 2, top / 2)))
            else:
                local.append((f"wall{side}", (0.0, sign * (hy + t / 2), top / 2), (hx, t / 2, top / 2)))
        if self.ceiling_height:
            ex = hx + (t if "+x" in self.walls else 0.0)
            cx = (t / 2 if "+x" in self.walls else 0.0)
            ey = hy + (t if self.walls else 0.0)
            local.append(("ceiling", (cx, 0.0, self.ceiling_height + CEILING_THICKNESS / 2),
                          (ex - cx, ey, CEILING_THICKNESS / 2)))
        out = []
        for name, centre, half in local:
            c = self.to_world(np.asarray(centre))[0]
            out.append(StaticBox(name, (float(c[0]), float(c[1]), float(c[2])), half, float(self.yaw)))
        return out

    def open_sides(self) -> tuple[str, ...]:
        """Sides of the interior without a wall (objects dropped in are held there by temporary walls)."""
        return tuple(s for s in WALL_SIDES if s not in self.walls)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _uniform(rng: np.random.Generator, r: Range) -> float:
    return float(r[0]) if r[0] == r[1] else float(rng.uniform(r[0], r[1]))


def style_ranges(style: str, split: str) -> StyleRanges:
    """The parameter ranges of a style in a split; ValueError for an unknown style or split, or a held-out
    style asked for training."""
    if split not in SPLITS:
        raise ValueError(f"container split must be one of {SPLITS}, got {split!r}")
    if style not in RANGES:
        raise ValueError(f"container style must be one of {STYLES}, got {style!r}")
    if split not in RANGES[style]:
        raise ValueError(f"container style {style!r} is held out: it has no {split!r} ranges "
                         f"(training styles: {TRAINING_STYLES})")
    return RANGES[style][split]


def sample_container(style: str, rng: np.random.Generator, split: str = "training") -> ContainerSpec:
    """A container of the style with every parameter drawn from the split's ranges (RANGES)."""
    r = style_ranges(style, split)
    inner_x, inner_y = _uniform(rng, r.inner_x), _uniform(rng, r.inner_y)
    wall_height, thickness = _uniform(rng, r.wall_height), _uniform(rng, r.wall_thickness)
    floor = _uniform(rng, r.floor_height)
    if rng.random() >= r.slab_probability:
        floor = 0.0
    yaw = _uniform(rng, r.yaw)
    ceiling = 0.0
    if rng.random() < r.ceiling_probability:
        ceiling = _uniform(rng, r.ceiling_height)
        wall_height = ceiling - floor  # the walls carry the board
    return ContainerSpec(style=style, inner_x=inner_x, inner_y=inner_y, wall_height=wall_height if r.walls else 0.0,
                         wall_thickness=thickness if r.walls else 0.0, floor_height=floor, yaw=yaw, walls=r.walls,
                         ceiling_height=ceiling)


def scene_container(style: str, seed: int, split: str = "held_out") -> ContainerSpec:
    """The container of benchmark scene `seed` (deterministic; independent of the scene's object draw)."""
    if style not in STYLES:
        raise ValueError(f"container style must be one of {STYLES}, got {style!r}")
    return sample_container(style, np.random.default_rng([seed, 22, STYLES.index(style)]), split)


__all__ = ["CEILING_THICKNESS", "HELD_OUT_STYLES", "RANGES", "SPLITS", "STYLES", "TRAINING_STYLES", "TUNED_ON",
           "WALL_SIDES", "WORKSPACE_MARGIN", "ContainerSpec", "StaticBox", "StyleRanges", "sample_container",
           "scene_container", "style_ranges"]
