"""Grasps: the client's numpy-backed view of a detect response (one array per field, best first)."""

from __future__ import annotations

import operator
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray

from .codec import WireError
from .wire import decode_png_bytes

F64 = NDArray[np.float64]


def _column(grasps: list[dict[str, Any]], key: str, width: tuple[int, ...]) -> F64:
    """Stack one response field of every grasp into an array (M, *width); None → NaN."""
    try:
        rows = [np.nan if g[key] is None else g[key] for g in grasps]
        arr = np.array(rows, dtype=np.float64).reshape(len(grasps), *width)
    except KeyError:
        raise WireError(f"grasps.{key}", "missing in the response") from None
    except (TypeError, ValueError) as exc:
        raise WireError(f"grasps.{key}", f"expected numbers of shape {width} per grasp ({exc})") from None
    return arr


@dataclass(frozen=True)
class Grasp:
    """One grasp of a detect response, in the caller's cloud frame (metres): pose (4,4) with rotation columns
    [approach, binormal, axis] and translation = hand-base centre; width = object extent between the fingers;
    score NaN when unscored; id for feedback; rank 0 = best."""

    id: str
    pose: F64
    width: float
    score: float
    rank: int = 0
    sample: F64 = field(default_factory=lambda: np.zeros(3))

    @property
    def position(self) -> F64:
        """Hand-base centre (3,)."""
        return self.pose[:3, 3]

    @property
    def rotation(self) -> F64:
        """(3,3) rotation, columns [approach, binormal, axis]."""
        return self.pose[:3, :3]

    @property
    def approach(self) -> F64:
        return self.pose[:3, 0]

    @property
    def binormal(self) -> F64:
        return self.pose[:3, 1]

    @property
    def axis(self) -> F64:
        return self.pose[:3, 2]


@dataclass(frozen=True)
class Grasps:
    """M grasps in the caller's cloud frame, or the robot frame when the request gave camera poses (frame says
    which; metres), sorted best first as the server sent them.

    poses (M,4,4) have rotation columns [approach, binormal, axis] and translation = hand-base centre.
    scores are NaN when the server ran without a classifier (scored is False); with method "templates"
    they are the match quality 1 / (1 + m) in (0, 1].
    crops[i] is PNG bytes of the object-proposal crop, or None (not asked, or point outside the image).
    """

    ids: list[str]
    positions: F64
    approach: F64
    binormal: F64
    axis: F64
    widths: F64
    scores: F64
    samples: F64
    poses: F64
    quat_xyzw: F64
    model: str | None = None
    scored: bool = False
    method: str = "gpd"
    #: The frame the grasps are in: "robot" when the request gave camera_poses, else "cloud" (as sent).
    frame: str = "cloud"
    timings: dict[str, float] = field(default_factory=dict)
    request_id: str | None = None
    #: What the server could not do right for this request, each {"code", "message"} (empty: nothing; see the
    #: docs/robot/index.md, "On your robot", for the codes).  Check it: a wrong viewpoint or frame still returns grasps.
    warnings: list[dict[str, str]] = field(default_factory=list)
    crops: list[bytes | None] = field(default_factory=list)
    crop_pixels: F64 = field(default_factory=lambda: np.zeros((0, 2)))
    in_image: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    #: The object each grasp closes on, an id into scene_objects (-1: none); method "gpd" only.
    object_ids: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    #: The scene's objects by id, each {"id", "centre", "extent", "num_points", "grasps"} (positions in this list):
    #: a request's target={"object": id} names one.
    scene_objects: list[dict[str, Any]] = field(default_factory=list)
    raw: dict[str, Any] = field(default_factory=dict, repr=False)

    def __len__(self) -> int:
        return len(self.ids)

    @overload
    def __getitem__(self, index: int) -> Grasp: ...

    @overload
    def __getitem__(self, index: slice) -> list[Grasp]: ...

    def __getitem__(self, index: int | slice) -> Grasp | list[Grasp]:
        """grasps[i]: the i-th best Grasp (negative from the end; IndexError past it); grasps[a:b]: a list."""
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        i = operator.index(index)
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(f"grasp {index} of {len(self)}")
        return Grasp(id=self.ids[i], pose=self.poses[i], width=float(self.widths[i]), score=float(self.scores[i]),
                     rank=i, sample=self.samples[i])

    def __iter__(self) -> Iterator[Grasp]:
        """The grasps best first, one Grasp each."""
        return (self[i] for i in range(len(self)))

    @property
    def rotations(self) -> F64:
        """(M,3,3) rotation matrices, columns [approach, binormal, axis]."""
        return self.poses[:, :3, :3]

    @classmethod
    def from_response(cls, body: dict[str, Any]) -> Grasps:
        """Parse the JSON body of a detect response; WireError names a malformed field."""
        if not isinstance(body, dict) or not isinstance(body.get("grasps"), list):
            raise WireError("grasps", "response has no grasps list")
        gs: list[dict[str, Any]] = body["grasps"]
        if not all(isinstance(g, dict) for g in gs):
            raise WireError("grasps", "each grasp must be an object")
        ids = [str(g.get("id", i)) for i, g in enumerate(gs)]
        crops: list[bytes | None] = []
        pixels = np.full((len(gs), 2), np.nan)
        inside = np.zeros(len(gs), bool)
        for i, g in enumerate(gs):
            crop = g.get("crop")
            if isinstance(crop, dict):
                crops.append(decode_png_bytes(crop.get("png")))
                if crop.get("pixel") is not None:
                    pixels[i] = crop["pixel"]
                inside[i] = bool(crop.get("in_image", False))
            else:
                crops.append(None)
        return cls(
            ids=ids,
            positions=_column(gs, "position", (3,)),
            approach=_column(gs, "approach", (3,)),
            binormal=_column(gs, "binormal", (3,)),
            axis=_column(gs, "axis", (3,)),
            widths=_column(gs, "width", ()),
            scores=_column(gs, "score", ()),
            samples=_column(gs, "sample", (3,)),
            poses=_column(gs, "pose", (4, 4)),
            quat_xyzw=_column(gs, "quat_xyzw", (4,)),
            model=body.get("model"),
            scored=bool(body.get("scored", False)),
            method=str(body.get("method", "gpd")),
            frame=str(body.get("frame", "cloud")),
            timings={str(k): float(v) for k, v in (body.get("timings") or {}).items()},
            request_id=body.get("request_id"),
            warnings=[{"code": str(w.get("code")), "message": str(w.get("message"))}
                      for w in body.get("warnings") or () if isinstance(w, dict)],
            crops=crops,
            crop_pixels=pixels,
            in_image=inside,
            object_ids=np.array([-1 if g.get("object") is None else int(g["object"]) for g in gs], np.int64),
            scene_objects=[o for o in body.get("objects") or () if isinstance(o, dict)],
            raw=body,
        )
