"""What the engine takes and gives: a Parsed request in, an Outcome out, with the detection behind one result
protocol (GraspResult) that both detectors' answers satisfy (GPD's Detection as GpdResult, the grasp templates'
TemplateDetection as TemplatesResult).  Every transport encodes an Outcome its own way (JSON:
services.mapping.response_json; ROS messages: the ROS 2 node and the Zenoh streams) and never needs to know
which detector answered."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from graspd.core.cloud import ViewpointCloud
from graspd.core.grasp import RANKING_RULE, GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd.core.warning import DetectionWarning
from graspd.gpd.detector import Detection
from graspd.gpd.objects import SceneObject
from graspd.gpd.sanity import RegionCheck, check_detection
from graspd.gpd.target import Target
from graspd.io.inputs import CloudInput
from graspd.server.wire.detect import DetectRequest
from graspd.templates import TemplateDetection


def gpd_grasp_id(detection_id: str, k: int) -> str:
    """The id of the k-th GPD grasp of a detection ("<detection id>-<k>", the detection id 16 hex digits made
    by the server: the request id unless the client chose its own X-Request-ID; feedback parses it back)."""
    return f"{detection_id}-{k}"


@dataclass(frozen=True)
class Parsed:
    """A request as a transport parsed it: the validated request, plus what a ROS message brought with it: the
    cloud already decoded (`given`, in the frame detection runs in), its target (rows, sample points or a box),
    the message's ROS header as the JSON answer shows it, and `context`, whatever the transport keeps for
    encoding the answer (the Outcome carries it back)."""

    request: DetectRequest
    given: CloudInput | None = None
    target: Target | None = None
    header: dict[str, Any] | None = None
    context: Any = None


class GraspResult(Protocol):
    """A detection as every transport reads it.  Positions and directions in the frame detection ran in (m);
    timings in seconds."""

    @property
    def method(self) -> str:
        """"gpd" or "templates"."""

    @property
    def grasps(self) -> GraspSet: ...

    @property
    def hand(self) -> HandGeometry:
        """The hand the grasps are for."""

    @property
    def model(self) -> str | None:
        """The classifier that scored the grasps (None: unscored, or templates)."""

    @property
    def scored(self) -> bool: ...

    @property
    def timings(self) -> dict[str, float]: ...

    @property
    def num_candidates(self) -> int: ...

    @property
    def num_points(self) -> int: ...

    @property
    def warnings(self) -> tuple[DetectionWarning, ...]: ...

    @property
    def objects(self) -> tuple[SceneObject, ...]:
        """The scene's objects the grasps' object ids refer to (templates: none)."""

    @property
    def up(self) -> F64 | None:
        """The environment stage's "up" (unit, cloud frame); None when not found."""

    @property
    def own_id(self) -> str | None:
        """An id the detector gave this detection (the templates' library id); None: the server makes one."""

    def grasp_ids(self, detection_id: str) -> list[str]:
        """One id per grasp, for feedback."""
        ...

    def checked(self, cloud: ViewpointCloud, workspace: Any, range_window: float, fits: bool | None,
                region: RegionCheck | None) -> GraspResult:
        """This result with the request-level checks' warnings added (graspd.gpd.sanity)."""
        ...

    def grasp_fields(self) -> list[dict[str, Any]]:
        """The method's own fields of each grasp in the JSON answer."""
        ...

    def answer_fields(self) -> dict[str, Any]:
        """The method's own fields of the JSON answer."""
        ...


class _Detected:
    """What both results read off the detection they wrap: the grasps, the timings (s), how many candidates and
    points the detector saw."""

    detection: Detection | TemplateDetection

    @property
    def grasps(self) -> GraspSet:
        return self.detection.grasps

    @property
    def timings(self) -> dict[str, float]:
        return self.detection.timings

    @property
    def num_candidates(self) -> int:
        return self.detection.num_candidates

    @property
    def num_points(self) -> int:
        return self.detection.num_points


@dataclass(frozen=True)
class GpdResult(_Detected):
    """GPD's Detection behind GraspResult; warnings: the input's (non-finite rows dropped), then the detector's,
    then the request-level checks'."""

    detection: Detection
    warnings: tuple[DetectionWarning, ...]
    method: str = "gpd"
    own_id: str | None = None

    @classmethod
    def of(cls, det: Detection, input_warnings: tuple[DetectionWarning, ...] = ()) -> GpdResult:
        return cls(det, (*input_warnings, *det.warnings))

    @property
    def hand(self) -> HandGeometry:
        return self.detection.hand

    @property
    def model(self) -> str | None:
        return self.detection.model

    @property
    def scored(self) -> bool:
        return self.detection.scored

    @property
    def objects(self) -> tuple[SceneObject, ...]:
        return self.detection.objects

    @property
    def up(self) -> F64 | None:
        env = self.detection.environment
        return None if env is None or env.up is None else np.asarray(env.up, np.float64)

    def grasp_ids(self, detection_id: str) -> list[str]:
        return [gpd_grasp_id(detection_id, k) for k in range(len(self.detection.grasps))]

    def checked(self, cloud: ViewpointCloud, workspace: Any, range_window: float, fits: bool | None,
                region: RegionCheck | None) -> GpdResult:
        det = replace(self.detection, warnings=self.warnings)
        det = det.warned(*check_detection(det, cloud, workspace, range_window, fits, region))
        return replace(self, detection=det, warnings=det.warnings)

    def grasp_fields(self) -> list[dict[str, Any]]:
        g = self.detection.grasps
        out: list[dict[str, Any]] = [{"object": oid if oid >= 0 else None} for oid in g.object_ids.tolist()]
        if g.ranking is not None:  # the terms selection ranked by (graspd.core.grasp.Ranking); NaN goes as null
            for fields, terms in zip(out, g.ranking.to_dicts(), strict=True):
                fields["ranking"] = {k: v if math.isfinite(v) else None for k, v in terms.items()}
        return out

    def answer_fields(self) -> dict[str, Any]:
        det = self.detection
        env = det.environment
        out: dict[str, Any] = {
            "environment": None if env is None else env.to_dict(), "max_per_object": det.max_per_object,
            "objects": [{**o.to_dict(), "grasps": ks} for o, ks in zip(det.objects, det.object_grasps(), strict=True)]}
        if det.grasps.ranking is not None:
            out["ranking_rule"] = RANKING_RULE
        return out


@dataclass(frozen=True)
class TemplatesResult(_Detected):
    """The grasp templates' TemplateDetection behind GraspResult, with the library's hand and the input's
    warnings (the templates add none of their own)."""

    detection: TemplateDetection
    hand: HandGeometry
    warnings: tuple[DetectionWarning, ...] = ()
    own_id: str | None = None
    method: str = "templates"
    model: str | None = None
    scored: bool = True  # match quality, always
    objects: tuple[SceneObject, ...] = ()
    up: F64 | None = None

    def grasp_ids(self, detection_id: str) -> list[str]:
        return list(self.detection.grasp_ids)

    def checked(self, cloud: ViewpointCloud, workspace: Any, range_window: float, fits: bool | None,
                region: RegionCheck | None) -> TemplatesResult:
        return self

    def grasp_fields(self) -> list[dict[str, Any]]:
        det = self.detection
        return [{"template_entry": e, "mismatch": m if math.isfinite(m) else None}
                for e, m in zip(det.entry_ids.tolist(), det.mismatch.tolist(), strict=True)]

    def answer_fields(self) -> dict[str, Any]:
        return {"num_entries": self.detection.num_entries}


@dataclass(frozen=True)
class Outcome:
    """One answered request: the result, the request and cloud it ran on, its frame ("robot" with camera poses,
    else "cloud") and ROS header (a ROS input's), the ids (request_id: the one the client and the log lines see;
    detection_id: what GPD grasp ids start with), the timings (s), the crops (one dict per grasp, or None), whether
    the model fits the hand, the transport's own context (Parsed.context), the rows the request's cloud had
    (received) and those dropped for a NaN or infinite value (graspd.io.inputs.CloudInput), and the finite ones
    the range window left out (GPD only: graspd.gpd.sanity.RegionCheck.left_out; None for the templates)."""

    result: GraspResult
    request: DetectRequest
    cloud: ViewpointCloud
    request_id: str
    detection_id: str
    frame: str = "cloud"
    header: dict[str, Any] | None = None
    timings: dict[str, float] = field(default_factory=dict)
    crops: list[dict[str, Any]] | None = None
    model_fits_hand: bool | None = None
    context: Any = None
    received: int = 0
    dropped: int = 0
    out_of_range: int | None = None

    @property
    def warnings(self) -> tuple[DetectionWarning, ...]:
        return self.result.warnings
