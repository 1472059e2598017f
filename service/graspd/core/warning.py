"""Warnings a detection carries instead of staying silent: a stable code and one human sentence each.

Every stage that cannot do the right thing (an unsure environment, a flipped viewpoint, dropped rows, no
candidates) adds one; every transport sends them unchanged in the response's `warnings`.  A correct request
warns of nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

#: An organised cloud with depth on fewer than this share of its pixels warns non_finite_dropped (a covered lens, a
#: scene out of the sensor's range); above it, its NaN pixels are normal and only counted.  Real captures have depth
#: on 68-79% of their pixels (../shared/data/real).
MIN_DEPTH_SHARE = 0.1

#: The codes graspd emits, with what each means (the response schema documents this table).
WARNING_CODES: dict[str, str] = {
    "environment_unsure": "the environment stage is unsure what holds the objects (support, walls, container)",
    "container_as_object": "a large structure that looks like a container or fixture may have been kept as an object",
    "no_support": "no support surface was found; hands are checked against points only",
    "unknown_space": "the best grasps put part of the hand into space no camera saw",
    "viewpoint_flipped": "most surface normals face away from the cameras: the viewpoint is probably wrong",
    "non_finite_dropped": "rows of an unorganised cloud with NaN or infinite coordinates were dropped, or an "
                          "organised cloud has depth on too few of its pixels",
    "few_points": "too few points are left after the workspace crop",
    "model_hand_mismatch": "the model does not serve the requested hand (not trained on its images, not chosen for "
                           "it by the benchmarks); scores are less reliable",
    "no_candidates": "no grasp candidate survived; the stage that removed them is named",
    "target_too_small": "the request's target holds too little of an object to grasp; the message says why",
    "unseen_floor": "no grasp, and part of a container's floor wide enough to hide an object was seen by no camera",
    "flat_objects": "no grasp, and objects lie too flat for the hand's init_bite: the flat_objects option tries them",
}


@dataclass(frozen=True)
class DetectionWarning:
    """One warning: a code from WARNING_CODES and a sentence for a person (what happened, what to do)."""

    code: str
    message: str

    def __post_init__(self) -> None:
        if self.code not in WARNING_CODES:
            raise ValueError(f"unknown warning code {self.code!r}; known: {sorted(WARNING_CODES)}")

    def to_dict(self) -> dict[str, Any]:
        return {"code": self.code, "message": self.message}
