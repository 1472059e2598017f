"""Two-finger hand geometry (GPD's parameter names, metres) and named presets for common grippers."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.errors import FieldError


@dataclass(frozen=True)
class HandGeometry:
    """A parallel-jaw hand in its own frame: x = approach, y = closing (binormal), z = hand axis.

    The hand base (palm) centre is the frame origin; the fingers span x in [0, hand_depth];
    the outer faces of the open fingers are hand_outer_diameter apart along y; everything is
    hand_height thick along z.  init_bite is the least depth (m) the fingertips must reach past
    the sampled surface point for a candidate to count.  palm_depth is the gripper body behind the
    finger roots (x in [-palm_depth, 0], as wide as the open hand): it must stay clear of points and of
    the environment, like the fingers.
    """

    finger_width: float = 0.01
    hand_outer_diameter: float = 0.12
    hand_depth: float = 0.06
    hand_height: float = 0.02
    init_bite: float = 0.01
    palm_depth: float = 0.02

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not (value == value) or value < 0.0:  # NaN or negative
                raise FieldError(f"hand.{name}", f"must be a non-negative number, got {value}")
        if self.hand_outer_diameter <= 2.0 * self.finger_width:
            raise FieldError("hand.hand_outer_diameter", "must exceed twice hand.finger_width")
        for name in ("hand_depth", "hand_height"):
            if getattr(self, name) <= 0.0:
                raise FieldError(f"hand.{name}", "must be positive")
        if self.init_bite >= self.hand_depth:
            raise FieldError("hand.init_bite", "must be smaller than hand.hand_depth")

    @property
    def max_aperture(self) -> float:
        """Largest object width (m) that fits between the open fingers."""
        return self.hand_outer_diameter - 2.0 * self.finger_width

    @property
    def closing_half_width(self) -> float:
        """Half the free span between the open fingers along y (m): the closing region is |y| <= this."""
        return self.hand_outer_diameter / 2.0 - self.finger_width

    def swept_boxes(self, approach_distance: float = 0.0) -> NDArray[np.float64]:
        """The open hand's body as boxes in its own frame, swept back along -x by approach_distance (m)
        (the path from the pre-grasp pose): (3, 2, 3) [left finger, right finger, palm] x [low, high] corners."""
        od, fw, hd, hh, a = self.hand_outer_diameter, self.finger_width, self.hand_depth, self.hand_height, \
            approach_distance
        return np.array([
            [[-a, -od / 2, -hh / 2], [hd, -od / 2 + fw, hh / 2]],
            [[-a, od / 2 - fw, -hh / 2], [hd, od / 2, hh / 2]],
            [[-a - self.palm_depth, -od / 2, -hh / 2], [0.0, od / 2, hh / 2]],
        ])

    def body_contains(self, local: NDArray[np.floating], opening: float | None = None) -> NDArray[np.bool_]:
        """Which hand-frame points (N, 3; m) lie inside the two fingers opened to `opening` (default fully
        open, max_aperture) or inside the palm (palm_depth deep behind the base, as wide as the open hand)."""
        gap = self.max_aperture if opening is None else opening
        x, ay = local[:, 0], np.abs(local[:, 1])
        in_z = np.abs(local[:, 2]) < self.hand_height / 2
        finger = (x >= 0) & (x < self.hand_depth) & (ay > gap / 2) & (ay < gap / 2 + self.finger_width)
        palm = (x < 0) & (x > -self.palm_depth) & (ay < self.hand_outer_diameter / 2)
        return np.asarray(in_z & (finger | palm))

    def with_opening(self, opening: float) -> HandGeometry:
        """A copy whose open fingers stand `opening` (m) apart (max_aperture): the outer faces move, the fingers
        stay as they are (validated)."""
        return replace(self, hand_outer_diameter=opening + 2.0 * self.finger_width)

    def with_overrides(self, **overrides: Any) -> HandGeometry:
        """A copy with some fields replaced (validated)."""
        return replace(self, **overrides)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


#: Named hand geometries.  Franka Panda: 80 mm stroke, fingertips ~20 mm wide, ~45 mm reach
#: past the palm, a hand body ~60 mm deep behind the finger roots; Robotiq 2F-85: 85 mm stroke,
#: 22 mm pads, ~55 mm usable depth, ~60 mm of linkage and base behind the pads.
HAND_PRESETS: dict[str, HandGeometry] = {
    "gpd": HandGeometry(),
    "panda": HandGeometry(
        finger_width=0.01, hand_outer_diameter=0.10, hand_depth=0.045, hand_height=0.02, init_bite=0.01,
        palm_depth=0.06,
    ),
    "robotiq_2f85": HandGeometry(
        finger_width=0.012, hand_outer_diameter=0.109, hand_depth=0.055, hand_height=0.022, init_bite=0.01,
        palm_depth=0.06,
    ),
}


def hand_preset(name: str) -> HandGeometry:
    """The preset called name; KeyError names the known presets."""
    try:
        return HAND_PRESETS[name]
    except KeyError:
        raise KeyError(f"unknown hand preset {name!r}; known: {sorted(HAND_PRESETS)}") from None
