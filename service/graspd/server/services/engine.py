"""The detection engine every entrance shares (HTTP, uploads, Zenoh, ROS 2): admission control, a worker pool
sized to the cores, per-request deadlines, and a parsed request -> detection -> Outcome (services.outcome; each
transport encodes it, services.mapping.response_json for JSON).

Admission is by cost, so that under load the service finishes work instead of timing it all out:

- at the door (admit(), before an HTTP body is read): 503 with Retry-After when the queue is full, or when no
  worker is free and the queue's expected wait (the running detections' expected ends, then each request ahead's
  expected time, over the workers) leaves a typical request no time to end before its deadline;
- in the queue: a request expected not to start in time to end before its deadline (a request not parsed yet is
  expected to take what the detections running now were estimated to, at most what its payload's size allows,
  at least the smallest detection's time) gets 503 with Retry-After the moment that is known (a watchdog
  re-plans the queue whenever it or a running detection's estimate changes), not a 504 at the deadline, and is
  never run;
- on its worker, after parsing: the occupied voxels its detection will keep are counted (budget.occupied_voxels:
  a 5M-point volume keeps ~20x the voxels of a 5M-point surface scan, and costs ~10-20x the time), then the
  memory budget (413 naming the field when it never fits, 503 when not now) and the time: expected seconds =
  work units x the learnt seconds per unit x the detections sharing the cores; 413 naming the field when alone
  it would outlast the whole answer window (ANSWER_DEADLINES deadlines: it never fits, even were the estimate
  twice too high), run as best effort when it would outlast the deadline only and nothing else runs or waits
  (it is answered if it ends within the window, and what it takes is learnt: the estimate may be stale), 503
  otherwise, and 503 when with the detections running now it would not end within the deadline;
- a detection that starts is awaited to its end: the answer is given up (504) only past twice the deadline, a
  guard for a detection that ran far beyond its estimate, not for queued work.
"""

from __future__ import annotations

import contextvars
import heapq
import logging
import math
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from concurrent.futures import Future, InvalidStateError, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from graspd.core.camera import Intrinsics, project_points
from graspd.core.cloud import ViewpointCloud
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.parallel import THREADS
from graspd.gpd.blas import set_blas_threads
from graspd.gpd.detector import DetectionParams
from graspd.gpd.sanity import region_check
from graspd.gpd.target import TargetError
from graspd.io.inputs import CloudInput
from graspd.io.png import encode_png_b64
from graspd.server.logs import current_request
from graspd.server.metrics import Metrics
from graspd.server.problems import CALLER_ERRORS, Problem, busy, deadline_passed, from_wire, gave_up, shutting_down
from graspd.server.services import proposals
from graspd.server.services.allocator import IdleTrimmer, trim_function
from graspd.server.services.budget import (
    DENSEST_POINT_BYTES,
    POINTS_PER_UNIT,
    SAMPLES_PER_UNIT,
    MemoryBudget,
    cost_of,
    occupied_voxels,
    too_slow,
    voxel_units,
    work_parts,
)
from graspd.server.services.mapping import detection_inputs, response_json
from graspd.server.services.outcome import GpdResult, GraspResult, Outcome, Parsed, TemplatesResult
from graspd.server.services.registry import ModelRegistry
from graspd.server.services.templates import TemplateService
from graspd.server.settings import Settings
from graspd.server.wire.detect import CropsRequest, DetectRequest

log = logging.getLogger("graspd.server")


def crops_json(g: GraspSet, hand: HandGeometry, crops: CropsRequest, image: np.ndarray) -> list[dict[str, Any]]:
    """One crop entry per grasp: PNG of the window around the projected point between the fingers (image: the
    request's RGB image, services.mapping.crops_image)."""
    intr = crops.intrinsics
    centres = proposals.finger_centres(g.positions, g.approach, hand.hand_depth)
    pixels, _ = project_points(centres, crops.camera_pose, Intrinsics(intr.fx, intr.fy, intr.cx, intr.cy))
    inside = proposals.inside_image(pixels, image.shape[0], image.shape[1])
    windows = proposals.crop_windows(image, np.where(inside[:, None], pixels, np.nan), crops.size)
    return [{"png": encode_png_b64(windows[i]) if inside[i] else None,
             "pixel": pixels[i].tolist() if np.isfinite(pixels[i]).all() else None,
             "in_image": bool(inside[i])} for i in range(len(g))]


#: A started detection is awaited up to this many deadlines after it was queued (then 504): admission already
#: refused what was expected to end past one deadline, so this only bounds a detection far beyond its estimate.
ANSWER_DEADLINES = 2.0
#: Samples of a request that names none (what _bound assumes of a payload not parsed yet).
DEFAULT_SAMPLES = int(DetectRequest.model_fields["num_samples"].default)


@dataclass(eq=False)
class Ticket:
    """One request from enqueue() to its answer.  future: what every entrance waits on (the engine settles it with
    the Outcome or a Problem); phase: queued -> started, or queued -> refused (503 while queued, never run);
    bound: the most seconds its payload's size allows (inf: not known); began, ends: when a started one began and
    is expected to end, its own estimate once `estimated`; deadline likewise (time.perf_counter() s)."""

    deadline: float
    bound: float = math.inf
    future: Future[Outcome] = field(default_factory=Future)
    phase: str = "queued"
    began: float = 0.0
    ends: float = 0.0
    estimated: bool = False
    work: Future[Any] | None = None  # the executor's future of the job


class DetectionEngine:
    """Runs detections on a thread pool with at most `workers` at once and `queue_size` waiting."""

    def __init__(self, settings: Settings, registry: ModelRegistry, metrics: Metrics) -> None:
        self.settings = settings
        self.registry = registry
        self.metrics = metrics
        self.workers = settings.workers
        self.capacity = self.workers + settings.queue_size
        self.executor = ThreadPoolExecutor(self.workers, thread_name_prefix="graspd-detect")
        # the request-level visibility check (gpd/sanity.py) needs only the request's cloud: it runs beside the
        # detection, in the time the detection's serial stages leave a core idle
        self._checks = ThreadPoolExecutor(self.workers, thread_name_prefix="graspd-check")
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)  # wakes the queue watchdog (_watch)
        self._queued: list[Ticket] = []  # enqueued, not started, in the executor's (FIFO) order
        self._started: set[Ticket] = set()
        self._pending = 0
        self._running = 0
        self._detecting = 0  # running past parsing and admission (what shares the cores)
        self._avg_seconds = 1.0  # EWMA of a request's time on a worker (parse + detect), seconds
        self._avg_detect = 0.0  # EWMA of the time on a worker of the requests that ran a detection, seconds
        self._trimmer = IdleTrimmer(trim_function(), busy=lambda: self._pending > 0)
        self.templates = TemplateService(settings)  # method "templates", and what feedback needs
        self.budget = MemoryBudget(settings.detect_memory_mb, THREADS.cores)  # admission by cost (budget.py)
        self.closed = False
        self._watchdog = threading.Thread(target=self._watch, name="graspd-queue-watch", daemon=True)
        self._watchdog.start()
        # the detections parallelise over THREADS themselves: BLAS threads would only spin beside them
        set_blas_threads(1)
        #: seconds the warm-up took (services/warmup.py: the warm-up request once on each detect worker, before
        #: the first request), None with GRASPD_WARMUP=false
        self.warmup_s: float | None = None
        if settings.warmup:
            from graspd.server.services.warmup import warm_up  # noqa: PLC0415 - the engine imports no warm-up

            self.warmup_s = warm_up(registry, self.executor, self.workers)
            # the voxel count's compiled pass, loaded (or compiled) before the first request needs it
            occupied_voxels(ViewpointCloud(points=np.zeros((2, 3), np.float32),
                                           viewpoints=np.zeros((1, 3), np.float32)), 0.003, None, 1.0)

    # ---- admission -------------------------------------------------------------------------
    def retry_after(self, wait: float | None = None) -> float:
        """Seconds a refused client should wait: `wait` when known, else until a worker is expected to free a
        slot (the measured service time, EWMA, over the workers); at least 1 s and at most
        settings.max_retry_after_s (what the clients wait at most)."""
        if wait is None:
            wait = self._avg_seconds / self.workers
        return float(min(self.settings.max_retry_after_s, max(1, math.ceil(wait))))

    def min_seconds(self) -> float:
        """Expected seconds of the smallest detection (one work unit alone: budget.work_parts)."""
        return self.budget.unit_seconds

    def _free_at(self, now: float) -> list[float]:
        """Seconds from now until each worker is free of the detections started (their expected ends), as a heap
        of `workers` entries.  Under the lock."""
        free = [max(0.0, t.ends - now) for t in self._started][: self.workers]
        free += [0.0] * (self.workers - len(free))
        heapq.heapify(free)
        return free

    def _typical(self) -> float:
        """Under the lock: the seconds on a worker of a request not parsed yet: as the detections running now
        (their own estimates, sharing the cores included), else as the recent ones (EWMA); 0 when none ran."""
        known = [t.ends - t.began for t in self._started if t.estimated]
        return sum(known) / len(known) if known else self._avg_detect

    def _expected(self, ticket: Ticket | None, typical: float) -> float:
        """The seconds a request not parsed yet is expected to need once it starts: the typical request's, at most
        its payload's bound, at least the smallest detection's."""
        own = typical
        if ticket is not None:
            own = min(own, ticket.bound)
        return max(self.min_seconds(), own)

    def _admit(self) -> None:
        """Reserve a place (running or queued) or refuse with 503: when the queue is full, or when no worker is
        free and the queue's expected wait (the running detections' expected ends, then each request ahead's
        expected time, over the workers) leaves no time for a typical request before the deadline."""
        with self._lock:
            if self.closed:
                raise shutting_down()
            if self._pending >= self.capacity:
                raise busy(f"{self._pending} requests queued or running", self.retry_after())
            free = self._free_at(time.perf_counter())
            typical = self._typical()
            for ticket in self._queued:
                heapq.heapreplace(free, free[0] + self._expected(ticket, typical))
            for _ in range(max(0, self._pending - len(self._started) - len(self._queued))):  # reading a body
                heapq.heapreplace(free, free[0] + self._expected(None, typical))
            over = free[0] + self._expected(None, typical) - self.settings.deadline_s
            if free[0] > 0 and over > 0:
                raise busy(f"the {self._pending} requests queued or running would take about {free[0]:.0f} s, too "
                           f"long to start another within the deadline of {self.settings.deadline_s:g} s",
                           self.retry_after(over))
            self._pending += 1
            self.metrics.queue_depth.set(self._pending - self._running)

    def admit(self) -> None:
        """Reserve a place before the request body is read (Problem 503 when full); hand it to enqueue(), or
        give it back with release() if the request ends before."""
        self._admit()

    def release(self) -> None:
        """Give back a place taken by admit() that was not handed to enqueue()."""
        self._release()

    def _release(self, _future: Future[Any] | None = None) -> None:
        with self._lock:
            self._pending -= 1
            self.metrics.queue_depth.set(max(0, self._pending - self._running))

    def trim_after(self, fut: Future[Any]) -> None:
        """Give freed heap memory back to the OS after fut, once the server is idle (allocator.IdleTrimmer)."""
        fut.add_done_callback(lambda _: self._trimmer.request_done())

    @property
    def pending(self) -> int:
        return self._pending

    # ---- the queue ---------------------------------------------------------------------------
    def _late(self) -> Problem:
        """The answer to a request that could not start in time: 503 with Retry-After (the queue was the problem),
        or 504 naming the deadline when not even the smallest detection fits the deadline here."""
        if self.min_seconds() > self.settings.deadline_s:
            return deadline_passed(self.settings.deadline_s)
        return busy(f"the requests ahead leave no time to start this one within the deadline of "
                    f"{self.settings.deadline_s:g} s", self.retry_after())

    @staticmethod
    def _settle(ticket: Ticket, result: Outcome | BaseException) -> None:
        """Give the ticket's waiters their answer (nothing when the caller went away: the future was cancelled)."""
        try:
            if isinstance(result, BaseException):
                ticket.future.set_exception(result)
            else:
                ticket.future.set_result(result)
        except InvalidStateError:
            pass

    def _refuse_late(self, now: float) -> tuple[list[Ticket], float | None]:
        """Under the lock: take out of the queue the requests that cannot start in time to end before their
        deadline: their expected start (the workers' expected free times, then the expected time of each one
        ahead) and their own expected time (_expected) pass it, or, where a worker should be free now (one that
        takes it judges it by its own estimate), even the smallest detection's would.  Returns those and the
        seconds until the next could become late."""
        free = self._free_at(now)
        typical, smallest = self._typical(), self.min_seconds()
        late: list[Ticket] = []
        wake: float | None = None
        for ticket in list(self._queued):
            own = self._expected(ticket, typical)
            slack = ticket.deadline - (now + free[0] + (own if free[0] > 0 else smallest))
            if slack < 0:
                ticket.phase = "refused"
                self._queued.remove(ticket)
                late.append(ticket)
                continue
            wake = slack if wake is None else min(wake, slack)
            heapq.heapreplace(free, free[0] + own)
        return late, wake

    def _watch(self) -> None:
        """The queue watchdog (a thread): answers queued requests that can no longer start in time with 503 as
        soon as that is known, re-planning whenever the queue or a running detection's expected end changes."""
        while True:
            with self._changed:
                if self.closed:
                    return
                late, wake = self._refuse_late(time.perf_counter())
                if not late:
                    self._changed.wait(None if wake is None else wake + 0.001)
                    continue
            for ticket in late:  # outside the lock: the waiters' callbacks run here
                if ticket.work is not None:
                    ticket.work.cancel()  # the executor never runs it; its place is given back (_work_done)
                self._settle(ticket, self._late())

    def _work_done(self, ticket: Ticket, work: Future[Any]) -> None:
        """The executor's job ended, or was cancelled before it ran (refused while queued, or the executor shut
        down): give the place back; a request still waiting for its answer gets 503."""
        self._release()
        if work.cancelled():
            with self._changed:
                waiting = ticket.phase == "queued"
                if waiting:
                    ticket.phase = "refused"
                    self._queued.remove(ticket)
                self._changed.notify()
            if waiting:
                self._settle(ticket, shutting_down())

    def _run(self, ticket: Ticket, parse: Callable[[], Parsed], enqueued: float, timings: dict[str, float]) -> None:
        """The executor's job: start the ticket unless it was refused while queued or its caller went away, run
        it (_job) and settle its future."""
        with self._changed:
            if ticket.phase != "queued":
                return
            self._queued.remove(ticket)
            if not ticket.future.set_running_or_notify_cancel():  # the caller went away while it was queued
                ticket.phase = "refused"
                self._changed.notify()
                return
            ticket.phase = "started"
            ticket.began = time.perf_counter()
            ticket.ends = ticket.began + self._expected(ticket, self._typical())  # until its own estimate is known
            self._started.add(ticket)
            self._changed.notify()
        result: Outcome | BaseException
        try:
            result = self._job(ticket, parse, enqueued, timings)
        except BaseException as exc:  # a Problem, or a fault the entrance reports as 500
            result = exc
        with self._changed:
            self._started.discard(ticket)
            self._changed.notify()
        self._settle(ticket, result)

    # ---- the work --------------------------------------------------------------------------
    @dataclass
    class _Account:
        """What one request on a worker holds: MiB of the memory budget, its work units once admitted by cost
        (0: not), and when it started (time.perf_counter() s)."""

        start: float
        held: float = 0.0
        units: float = 0.0

    @contextmanager
    def _on_worker(self) -> Iterator[DetectionEngine._Account]:
        """The accounting of one request on a worker: running counts and gauges, the memory it holds given back,
        its time learnt (budget.observe, the EWMAs) whatever its end."""
        account = DetectionEngine._Account(time.perf_counter())
        with self._lock:
            self._running += 1
            self.metrics.running.set(self._running)
            self.metrics.queue_depth.set(max(0, self._pending - self._running))
        try:
            yield account
        finally:
            if account.units:
                with self._lock:
                    self._detecting -= 1
            self.budget.give(account.held)
            elapsed = time.perf_counter() - account.start
            self.budget.observe(account.units, elapsed)
            with self._lock:
                self._running -= 1
                self.metrics.running.set(self._running)
                if elapsed > 0.01 or self._avg_seconds < 0.01:  # refusals in microseconds say nothing of the load
                    self._avg_seconds = 0.8 * self._avg_seconds + 0.2 * elapsed
                if account.units:
                    self._avg_detect = elapsed if not self._avg_detect else 0.8 * self._avg_detect + 0.2 * elapsed

    def _job(self, ticket: Ticket, parse: Callable[[], Parsed], enqueued: float, timings: dict[str, float]
             ) -> Outcome:
        """Parse (on this worker, not the event loop), admit by cost and detect: the Outcome, or Problem."""
        with self._on_worker() as account:
            start = account.start
            timings["queue"] = start - enqueued
            before = timings.get("read", 0.0) + timings.get("decode", 0.0)  # spent before enqueue (body read)
            if start + self.min_seconds() > ticket.deadline:  # the watchdog refuses these while queued; one missed
                raise self._late()
            parsed = parse()
            req = parsed.request
            self.budget.check(cost_of(req))  # 413 on the points sent alone, before any work on the cloud
            try:
                hand = req.hand_geometry()
                # the cloud in the frame detection runs in, non-finite rows dropped; the target (a ROS message's
                # own, else the request's), the parameters, the crops' image (services.mapping)
                inputs = detection_inputs(req, parsed.given, parsed.target)
            except CALLER_ERRORS as exc:
                raise from_wire(exc) from None
            given, params = inputs.given, inputs.params
            cloud = given.cloud
            shared = self._admit_by_cost(ticket, account, req, cloud, params)
            timings["decode"] = timings.get("decode", 0.0) + time.perf_counter() - start
            result, detection_id = self._detect(req, given, params, hand)
            request_id = self._request_id(result, detection_id)
            timings.update(result.timings)
            timings["detect"] = timings.get("total", 0.0)  # the detector's own wall time, before the engine's total
            crops = None
            if req.crops is not None and inputs.crops_image is not None:  # method "templates" refuses crops
                t = time.perf_counter()
                crops = crops_json(result.grasps, result.hand, req.crops, inputs.crops_image)
                timings["crops"] = time.perf_counter() - t
            self.metrics.candidates.observe(result.num_candidates)
            self.metrics.grasps.observe(len(result.grasps))
            self.metrics.points.observe(result.num_points)
            fits = self.registry.fits(result.model, result.hand)
            region = None if shared.region is None else shared.region.result()
            result = result.checked(cloud, params.workspace, params.range_window, fits, region)  # request-level
            timings["total"] = time.perf_counter() - enqueued + before
            self.metrics.observe_timings(timings)
            return Outcome(result, req, cloud, request_id, detection_id, given.frame, parsed.header or None,
                           timings, crops, fits, parsed.context, given.received, given.dropped,
                           None if region is None else region.left_out)

    @dataclass
    class _Admitted:
        """A request admitted by cost: the detections sharing the cores with it, and the request-level visibility
        check running beside its detection (None for the templates)."""

        shared: int
        region: Future[Any] | None = None

    def _admit_by_cost(self, ticket: Ticket, account: DetectionEngine._Account, req: DetectRequest,
                       cloud: ViewpointCloud, params: DetectionParams) -> DetectionEngine._Admitted:
        """The memory budget and the time (see the module's text): 413 naming the field when it never fits, 503
        when not now; holds the memory in account and counts the request among the detections sharing the cores.
        Starts the visibility check beside the detection."""
        deadline = ticket.deadline
        # what the detection will work on: the occupied voxels of its region (a volume keeps ~20x a surface's)
        voxels = occupied_voxels(cloud, params.voxel_size, params.workspace, params.range_window)
        wait = min(self.settings.detect_memory_wait_s, max(0.0, deadline - time.perf_counter()))
        account.held = self.budget.take(cost_of(req, voxels), self.retry_after(), wait,  # 413 / 503 before detection
                                        params.voxel_size)
        work = work_parts(req, voxels)
        lone = sum(work.values()) * self.budget.unit_seconds  # expected seconds alone
        if lone > ANSWER_DEADLINES * self.settings.deadline_s:  # never fits, even were the estimate 2x high
            raise self._late() if self.min_seconds() > self.settings.deadline_s else \
                too_slow(req, voxels, self.budget.unit_seconds, ANSWER_DEADLINES * self.settings.deadline_s,
                         self.settings.deadline_s, params.voxel_size)
        with self._changed:
            shared = 1 + self._detecting  # detections sharing the cores (graspd.core.parallel), this one too
            alone = len(self._started) == 1 and not self._queued and self._pending == 1
            now = time.perf_counter()
            if lone > self.settings.deadline_s and not alone:  # best effort only on an idle server
                raise busy(f"this request takes about {lone:.0f} s even alone, more than the deadline of "
                           f"{self.settings.deadline_s:g} s: it runs only when nothing else runs or waits",
                           self.retry_after())
            if lone <= self.settings.deadline_s and now + lone * shared > deadline:  # 503, not start in vain
                raise busy(f"this request takes about {lone * shared:.0f} s now and would not end within the "
                           f"deadline of {self.settings.deadline_s:g} s", self.retry_after())
            self._detecting += 1
            ticket.ends, ticket.estimated = now + lone * shared, True  # the watchdog re-plans the queue
            self._changed.notify()
        account.units = sum(work.values()) * shared  # timed from here on (budget.observe: seconds per lone unit)
        region = None if req.method == "templates" else self._checks.submit(
            region_check, cloud, params.workspace, params.range_window)
        return DetectionEngine._Admitted(shared, region)

    def _detect(self, req: DetectRequest, given: CloudInput, params: DetectionParams, hand: HandGeometry | None
                ) -> tuple[GraspResult, str]:
        """The detection a request asks for, grasp templates or GPD with the resolved model, and the id of the
        detection (GPD grasp ids start with it; the recent GPD detections are remembered by it, for feedback)."""
        ctx = current_request()
        detection_id = ctx.detection_id if ctx is not None else uuid.uuid4().hex[:16]
        result: GraspResult
        model = self.registry.resolve(req.model, req.use_classifier and req.method == "gpd", hand or HandGeometry())
        try:
            with THREADS.request():  # concurrent requests share the cores (graspd.core.parallel)
                if req.method == "templates":
                    det = self.templates.detect(req, given.cloud, hand)
                    result = TemplatesResult(det, self.templates.library.hand, given.warnings,
                                             det.detection_id or uuid.uuid4().hex)
                else:
                    gpd = self.registry.detector(model).detect(given.cloud, params, hand)
                    self.templates.remember(detection_id, given.cloud, gpd)
                    result = GpdResult.of(gpd, given.warnings)
        except TargetError as exc:  # the target selects nothing of the cloud: a 422 naming target.<field>
            raise from_wire(exc) from None
        return result, detection_id

    @staticmethod
    def _request_id(result: GraspResult, detection_id: str) -> str:
        """The request id the answer returns: the client's X-Request-ID when it gave one, else the detection's own
        id when the detector made one (templates; the request's later log lines and X-Request-ID then carry it),
        else the server's id of the request."""
        ctx = current_request()
        if ctx is None:
            return result.own_id or detection_id
        if result.own_id is not None and not ctx.given:
            ctx.id = result.own_id
        return ctx.id

    def submit(self, req: DetectRequest, timings: dict[str, float]) -> tuple[Future[Outcome], float]:
        """Admit a request (Problem 503 when full) and queue it; returns the future and when to give up on it
        (see enqueue)."""
        self._admit()
        return self.enqueue(lambda: Parsed(req), timings)

    def enqueue(self, parse: Callable[[], Parsed], timings: dict[str, float], size: int = 0
                ) -> tuple[Future[Outcome], float]:
        """Queue an admitted request (admit() first): parse() runs on a worker, then the detection.  Returns the
        future, which the engine settles with the Outcome or a Problem (a request that cannot start in time gets
        503 while queued), and the time (time.perf_counter() s) after which a waiter gives up with 504
        (problems.gave_up): ANSWER_DEADLINES deadlines, for a detection that started but ran far past its
        estimate.  The place is given back when the job is done.  size: the payload's bytes when known (0: not),
        which bound what it can cost while it is queued (a small request behind big ones is not judged by
        theirs)."""
        now = time.perf_counter()
        ticket = Ticket(now + self.settings.deadline_s, self._bound(size))
        context = contextvars.copy_context()  # the request id follows the work onto the worker thread
        with self._changed:
            self._queued.append(ticket)
            self._changed.notify()
        try:
            ticket.work = self.executor.submit(context.run, self._run, ticket, parse, now, timings)
        except RuntimeError:  # executor shut down
            with self._changed:
                if ticket in self._queued:
                    self._queued.remove(ticket)
            self._release()
            raise shutting_down() from None
        ticket.work.add_done_callback(lambda work: self._work_done(ticket, work))
        return ticket.future, now + ANSWER_DEADLINES * self.settings.deadline_s

    def detect_sync(self, parse: Callable[[], Parsed], timings: dict[str, float] | None = None) -> Outcome:
        """Admit, parse and detect, blocking: the Outcome, or a Problem (503 when full, 504 past ANSWER_DEADLINES
        deadlines)."""
        self.admit()
        fut, give_up = self.enqueue(parse, timings if timings is not None else {})
        self.trim_after(fut)
        try:
            return fut.result(timeout=max(0.0, give_up - time.perf_counter()))
        except FutureTimeout:
            fut.cancel()
            raise gave_up(self.settings.deadline_s, ANSWER_DEADLINES) from None

    def run_sync(self, req: DetectRequest, timings: dict[str, float] | None = None) -> bytes:
        """Blocking detect of a validated request (benchmarks, tools): the JSON answer, or Problem."""
        return response_json(self.detect_sync(lambda: Parsed(req), timings))

    def _bound(self, size: int) -> float:
        """The most seconds a payload of `size` bytes can take (0: not known, inf): its points at the densest
        encoding, each in a voxel of its own, the default samples, every worker busy."""
        if size <= 0:
            return math.inf
        points = size // DENSEST_POINT_BYTES
        units = 1.0 + points / POINTS_PER_UNIT + voxel_units(points) + DEFAULT_SAMPLES / SAMPLES_PER_UNIT
        return units * self.budget.unit_seconds * self.workers

    def close(self, wait: bool = True) -> None:
        """Refuse new work and let running detections finish (graceful shutdown); queued requests get 503."""
        with self._changed:
            self.closed = True
            self._changed.notify_all()
        self.executor.shutdown(wait=wait, cancel_futures=True)
        self._checks.shutdown(wait=wait, cancel_futures=True)
        self._trimmer.close()
        self.templates.close()
