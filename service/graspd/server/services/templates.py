"""The grasp-template side of the service (Herzog et al. 2012): the library, template detection for
`method: "templates"`, demonstrations, and outcome feedback for the grasps either detector returned.

Where feedback finds a grasp by its id:
- template grasps ("<detection id>.<k>") are recorded in the library store with their candidate
  template and a voxelized copy of the cloud (graspd.templates.library, table detections): they survive
  restarts and are shared by every server using the same library URL; the newest
  `template_detections` are kept, older ones deleted after each detection;
- GPD grasps ("<request id>-<k>") are remembered in this process's memory only: the last
  `feedback_detections` detections (their cloud, poses and widths), at most `feedback_memory_mb`,
  least recently detected forgotten first.  An older, unknown or other process's id answers 404.

The library opens on first use (GRASPD_TEMPLATE_LIBRARY, else an SQLite file in the data folder); a
library that cannot be opened answers 503 naming template_library, and GPD detection is unaffected.  Nothing
that locates the store appears in an answer or a log line: an answer names the component (template_library)
and the request id only; the log line with that id says what failed, with the URL, password, user, host, port,
database and paths masked (graspd.store.database.scrub).
"""

from __future__ import annotations

import logging
import re
import threading
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa
from numpy.typing import NDArray

from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.core.errors import FieldError
from graspd.core.hand import HandGeometry, hand_preset
from graspd.gpd.detector import Detection
from graspd.server.logs import current_request
from graspd.server.problems import CALLER_ERRORS, Problem, from_error, from_wire
from graspd.server.services.mapping import cloud_input
from graspd.server.settings import Settings
from graspd.server.wire.detect import DetectRequest
from graspd.server.wire.templates import DemonstrationRequest, FeedbackRequest
from graspd.store.database import redact_url, scrub
from graspd.store.outcomes import Feedback
from graspd.templates import TemplateDetection, TemplateDetector, TemplateError, TemplateLibrary, UnknownGrasp
from graspd.templates.demonstration import check_hand_pose, grasp_image
from graspd.templates.library import parse_grasp_id

log = logging.getLogger("graspd.server")

#: DetectRequest fields method "templates" uses; any other field set in a request is refused (422).
TEMPLATE_FIELDS = frozenset({"method", "cloud", "workspace", "max_grasps", "hand"})

#: A GPD grasp id, services.outcome.gpd_grasp_id: "<request id>-<k>" (request ids are 16 hex digits).
_GPD_ID = re.compile(r"^([0-9a-f]{16})-(\d+)$")

#: The fields a template error may name: those of the requests this service handles.
_REQUEST_FIELDS = frozenset(DetectRequest.model_fields) | frozenset(DemonstrationRequest.model_fields) | \
    frozenset(FeedbackRequest.model_fields)


def template_problem(exc: ValueError) -> Problem:
    """A Problem from a TemplateError/CloudError (404 for a grasp id no detection returned)."""
    return from_error(exc, _REQUEST_FIELDS, status=404 if isinstance(exc, UnknownGrasp) else 422)


@dataclass(frozen=True)
class RememberedDetection:
    """What feedback needs of one GPD detection: the cloud it ran on, the returned poses (M,4,4, cloud
    frame) and widths (M,) in metres, and the hand."""

    cloud: ViewpointCloud
    poses: NDArray[np.float64]
    widths: NDArray[np.float64]
    hand: HandGeometry

    @property
    def nbytes(self) -> int:
        c = self.cloud
        return int(c.points.nbytes + c.viewpoints.nbytes + c.camera_source.nbytes + self.poses.nbytes
                   + self.widths.nbytes)


class RecentDetections:
    """A thread-safe LRU of GPD detections by request id, bounded by count and by bytes."""

    def __init__(self, max_items: int, max_bytes: int) -> None:
        self.max_items = max_items
        self.max_bytes = max_bytes
        self.nbytes = 0
        self._items: OrderedDict[str, RememberedDetection] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._items)

    def put(self, request_id: str, item: RememberedDetection) -> None:
        """Remember item (if it fits at all), forgetting the oldest until both bounds hold."""
        if self.max_items == 0 or item.nbytes > self.max_bytes:
            return
        with self._lock:
            self._items[request_id] = item
            self.nbytes += item.nbytes
            while len(self._items) > self.max_items or self.nbytes > self.max_bytes:
                _, old = self._items.popitem(last=False)
                self.nbytes -= old.nbytes

    def get(self, request_id: str) -> RememberedDetection | None:
        with self._lock:
            return self._items.get(request_id)


def _see_log() -> str:
    """'request <id>; the server log has the details': what an answer says of an internal failure (the log line
    with that request id says what failed, scrubbed; the answer never holds a URL, host, port, user or path)."""
    ctx = current_request()
    return f"request {ctx.id if ctx is not None else 'unknown'}; the server log has the details"


class TemplateService:
    """The library (opened on first use), its detector, and the memory of recent GPD detections."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.url = settings.resolved_template_library()
        self.safe_url = redact_url(self.url)  # what errors and logs may show
        self.recent = RecentDetections(settings.feedback_detections, int(settings.feedback_memory_mb * 2**20))
        self._library: TemplateLibrary | None = None
        self._detector: TemplateDetector | None = None
        self._open_lock = threading.Lock()

    # ---- the library ---------------------------------------------------------------------------
    @property
    def library(self) -> TemplateLibrary:
        """The library at the configured URL; Problem 503 naming template_library if it cannot be opened."""
        with self._open_lock:
            if self._library is None:
                try:
                    if self.url.startswith("sqlite:///") and self.url != "sqlite:///:memory:":
                        Path(self.url.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
                    hand = None if self.settings.template_hand is None else hand_preset(self.settings.template_hand)
                    self._library = TemplateLibrary(self.url, hand=hand)
                except Exception as exc:  # a bad URL, an unreachable database, a hand mismatch, a read-only disk
                    reason = self._reason(exc)
                    log.error("template library unavailable", extra={"component": "template_library",
                                                                     "error": reason})
                    raise Problem(503, f"the template library cannot be opened ({_see_log()})",
                                  "template_library", retry_after=30) from None
                self._detector = TemplateDetector(self._library)
            return self._library

    def _reason(self, exc: BaseException) -> str:
        """'<type>: <first line of the message>' for the log, with the password, URL, user, host, port, database
        and any path masked (graspd.store.database.scrub: drivers quote the URL or DSN and the server's address;
        SQLAlchemy appends the SQL and its parameters after the first line)."""
        orig = getattr(exc, "orig", None)
        text = str(orig if isinstance(orig, BaseException) else exc).strip()
        first = text.splitlines()[0] if text else ""
        return scrub(f"{type(exc).__name__}: {first}", self.url)

    @contextmanager
    def database(self) -> Iterator[None]:
        """A database that fails after opening (server gone, connection dropped, pool exhausted) answers 503
        naming template_library, its message scrubbed of the password."""
        try:
            yield
        except (sa.exc.OperationalError, sa.exc.InterfaceError, sa.exc.TimeoutError,
                sa.exc.DisconnectionError) as exc:
            reason = self._reason(exc)
            log.error("template library failed", extra={"component": "template_library", "error": reason})
            raise Problem(503, f"the template library failed ({_see_log()})", "template_library",
                          retry_after=5) from None

    @property
    def detector(self) -> TemplateDetector:
        _ = self.library
        assert self._detector is not None
        return self._detector

    def close(self) -> None:
        if self._library is not None:
            self._library.close()

    def _check_hand(self, hand: HandGeometry | None) -> None:
        lib_hand = self.library.hand
        if hand is not None and hand != lib_hand:
            raise Problem(422, f"the template library is made for {lib_hand.to_dict()}, not {hand.to_dict()}",
                          "hand")

    def counts(self) -> dict[str, Any]:
        """The library summary without its entries."""
        summary = self.summary()
        return {k: v for k, v in summary.items() if k.startswith("num_")}

    def summary(self) -> dict[str, Any]:
        """GET /library: counts, hand, template geometry and one line per entry."""
        with self.database():
            return self.library.summary()

    # ---- detection -----------------------------------------------------------------------------
    def detect(self, req: DetectRequest, cloud: ViewpointCloud, hand: HandGeometry | None) -> TemplateDetection:
        """Method "templates": the detection (the engine builds the response).  Grasp ids are
        "<detection id>.<k>", recorded in the library for feedback."""
        unused = sorted(set(req.model_fields_set) - TEMPLATE_FIELDS)
        if unused:
            raise Problem(422, f"not used by method 'templates' (it uses {sorted(TEMPLATE_FIELDS)})", unused[0])
        with self.database():
            return self._detect(req, cloud, hand)

    def _detect(self, req: DetectRequest, cloud: ViewpointCloud, hand: HandGeometry | None) -> TemplateDetection:
        self._check_hand(hand)
        try:
            det = self.detector.detect(cloud, max_grasps=req.max_grasps, workspace=req.workspace_bounds())
        except (TemplateError, CloudError) as exc:
            raise template_problem(exc) from None
        if det.detection_id is not None:  # bound the store: keep the newest template_detections
            self.library.prune_detections(self.settings.template_detections)
        return det

    def remember(self, request_id: str, cloud: ViewpointCloud, det: Detection) -> None:
        """Keep what feedback on this GPD detection's grasps needs (ids "<request_id>-<k>")."""
        if len(det.grasps):
            self.recent.put(request_id, RememberedDetection(cloud, det.grasps.poses, det.grasps.widths, det.hand))

    # ---- demonstrations and feedback -------------------------------------------------------------
    def demonstrate(self, req: DemonstrationRequest) -> dict[str, Any]:
        """POST /demonstrations: add the demonstrated grasp to the library; its entry id and the counts."""
        with self.database():
            return self._demonstrate(req)

    def _demonstrate(self, req: DemonstrationRequest) -> dict[str, Any]:
        try:
            check_hand_pose(req.hand_pose)  # orthonormal, right-handed: the templates' own check
        except FieldError as exc:
            raise Problem(422, exc.message, "hand_pose") from None
        self._check_hand(None if req.hand is None else req.hand.geometry())
        try:
            cloud = cloud_input(req.cloud).cloud
        except CALLER_ERRORS as exc:
            raise from_wire(exc) from None
        ws = req.workspace
        try:
            entry = self.library.add_demonstration(
                cloud, req.hand_pose, label=req.label,
                workspace=None if ws is None else (ws[0], ws[1], ws[2], ws[3], ws[4], ws[5]))
        except (TemplateError, CloudError) as exc:
            raise template_problem(exc) from None
        return {"entry_id": entry, "library": self.counts()}

    def feedback(self, req: FeedbackRequest) -> dict[str, Any]:
        """POST /feedback: store the outcome (with the grasp's 15-channel image); a failed template grasp
        also joins the failure set F_l of its library entry."""
        with self.database():
            return self._feedback(req)

    def _feedback(self, req: FeedbackRequest) -> dict[str, Any]:
        gid = req.grasp_id
        gpd = _GPD_ID.fullmatch(gid)
        if gpd is None:
            try:
                parse_grasp_id(gid)  # the template id form; neither form: 422 naming grasp_id
            except TemplateError:
                raise Problem(422, f"must be an id from a detect response ('<request id>-<k>' for gpd, "
                              f"'<detection id>.<k>' for templates), got {gid!r}", "grasp_id") from None
        try:
            if gpd is None:
                fb = self.library.add_feedback(gid, req.success)
                method = "templates"
            else:
                fb = self._gpd_feedback(gid, gpd.group(1), int(gpd.group(2)), req.success)
                method = "gpd"
        except (TemplateError, CloudError) as exc:
            raise template_problem(exc) from None
        return {**fb.to_dict(), "method": method}

    def _gpd_feedback(self, grasp_id: str, request_id: str, k: int, success: bool) -> Feedback:
        item = self.recent.get(request_id)
        if item is None:
            raise Problem(404, f"{grasp_id!r}: unknown or forgotten detection (this server remembers its last "
                          f"{self.recent.max_items} GPD detections, in memory)", "grasp_id")
        if k >= len(item.poses):
            raise Problem(404, f"{grasp_id!r}: that detection returned {len(item.poses)} grasps", "grasp_id")
        image = grasp_image(item.cloud, item.poses[k], float(item.widths[k]), item.hand, "15")
        return self.library.outcomes.add_outcome(grasp_id, bool(success), item.poses[k], float(item.widths[k]),
                                                 image, "15")
