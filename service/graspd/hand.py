"""Two-finger hand geometry (GPD's parameter names, metres) and named presets for common grippers."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any


@dataclass(frozen=True)
class HandGeometry:
    """A parallel-jaw hand in its own frame: x = approach, y = closing (binormal), z = hand axis.

    The hand base (palm) centre is the frame origin; the fingers span x in [0, hand_depth];
    the outer faces of the open fingers are hand_outer_diameter apart along y; everything is
    hand_height thick along z.  init_bite is the least depth (m) the fingertips must reach past
    the sampled surface point for a candidate to count.
    """

    finger_width: float = 0.01
    hand_outer_diameter: float = 0.12
    hand_depth: float = 0.06
    hand_height: float = 0.02
    init_bite: float = 0.01

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not (value == value) or value < 0.0:  # NaN or negative
                raise ValueError(f"hand.{name} must be a non-negative number, got {value}")
        if self.hand_outer_diameter <= 2.0 * self.finger_width:
            raise ValueError("hand.hand_outer_diameter must exceed twice hand.finger_width")
        if self.hand_depth <= 0.0 or self.hand_height <= 0.0:
            raise ValueError("hand.hand_depth and hand.hand_height must be positive")
        if self.init_bite >= self.hand_depth:
            raise ValueError("hand.init_bite must be smaller than hand.hand_depth")

    @property
    def max_aperture(self) -> float:
        """Largest object width (m) that fits between the open fingers."""
        return self.hand_outer_diameter - 2.0 * self.finger_width

    def with_overrides(self, **overrides: Any) -> HandGeometry:
        """A copy with some fields replaced (validated)."""
        return replace(self, **overrides)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


#: Named hand geometries.  Franka Panda: 80 mm stroke, fingertips ~20 mm wide, ~45 mm reach
#: past the palm; Robotiq 2F-85: 85 mm stroke, 22 mm pads, ~55 mm usable depth.
HAND_PRESETS: dict[str, HandGeometry] = {
    "gpd": HandGeometry(),
    "panda": HandGeometry(
        finger_width=0.01, hand_outer_diameter=0.10, hand_depth=0.045, hand_height=0.02, init_bite=0.01
    ),
    "robotiq_2f85": HandGeometry(
        finger_width=0.012, hand_outer_diameter=0.109, hand_depth=0.055, hand_height=0.022, init_bite=0.01
    ),
}


def hand_preset(name: str) -> HandGeometry:
    """The preset called name; KeyError names the known presets."""
    try:
        return HAND_PRESETS[name]
    except KeyError:
        raise KeyError(f"unknown hand preset {name!r}; known: {sorted(HAND_PRESETS)}") from None
