"""The detection engine shared by HTTP and Zenoh: admission control (bounded queue, 503 when full),
a worker pool sized to the cores, per-request deadlines, and request -> detection -> response JSON."""

from __future__ import annotations

import asyncio
import contextvars
import logging
import math
import threading
import time
import uuid
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import replace
from typing import Any

import numpy as np

from graspd.core.camera import Intrinsics, project_points
from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.core.parallel import THREADS
from graspd.gpd.blas import set_blas_threads
from graspd.gpd.detector import Detection, DetectionParams
from graspd.gpd.sanity import check_detection, region_check
from graspd.gpd.target import TargetError
from graspd.io.png import encode_png_b64
from graspd.server.logs import current_request
from graspd.server.metrics import Metrics
from graspd.server.problems import CALLER_ERRORS, Problem, from_wire
from graspd.server.schemas import CropsRequest, DetectRequest, DetectResponse
from graspd.server.services import proposals
from graspd.server.services.allocator import IdleTrimmer, trim_function
from graspd.server.services.budget import TIME_MARGIN, MemoryBudget, cost_of, work_units
from graspd.server.services.registry import ModelRegistry
from graspd.server.services.templates import TemplateService
from graspd.server.settings import Settings
from graspd.templates import TemplateDetection

log = logging.getLogger("graspd.server")
#: Called on the worker with a finished detection, the cloud it ran on and the hand used (engine.enqueue).
OnDetection = Callable[[Detection | TemplateDetection, ViewpointCloud, HandGeometry], None]


def crops_json(det: Detection, crops: CropsRequest) -> list[dict[str, Any]]:
    """One crop entry per grasp: PNG of the window around the projected point between the fingers."""
    image = crops.image  # a PNG was decoded into image when the request was validated
    assert image is not None
    intr = crops.intrinsics
    g = det.grasps
    centres = proposals.finger_centres(g.positions, g.approach, det.hand.hand_depth)
    pixels, _ = project_points(centres, crops.camera_pose, Intrinsics(intr.fx, intr.fy, intr.cx, intr.cy))
    inside = proposals.inside_image(pixels, image.shape[0], image.shape[1])
    windows = proposals.crop_windows(image, np.where(inside[:, None], pixels, np.nan), crops.size)
    return [{"png": encode_png_b64(windows[i]) if inside[i] else None,
             "pixel": pixels[i].tolist() if np.isfinite(pixels[i]).all() else None,
             "in_image": bool(inside[i])} for i in range(len(g))]


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
        self._pending = 0
        self._running = 0
        self._detecting = 0  # running past parsing and admission (what shares the cores)
        self._avg_seconds = 1.0  # EWMA of a request's time on a worker (parse + detect), seconds
        self._trimmer = IdleTrimmer(trim_function(), busy=lambda: self._pending > 0)
        self.templates = TemplateService(settings)  # method "templates", and what feedback needs
        self.budget = MemoryBudget(settings.detect_memory_mb)  # admission by estimated cost (budget.py)
        self.closed = False
        # the detections parallelise over THREADS themselves: BLAS threads would only spin beside them
        set_blas_threads(1)
        #: seconds the warm-up took (services/warmup.py: the warm-up request once on each detect worker, before
        #: the first request), None with GRASPD_WARMUP=false
        self.warmup_s: float | None = None
        if settings.warmup:
            from graspd.server.services.warmup import warm_up  # noqa: PLC0415 - the engine imports no warm-up

            self.warmup_s = warm_up(registry, self.executor, self.workers)

    # ---- admission -------------------------------------------------------------------------
    def retry_after(self) -> float:
        """Seconds until a worker is expected to free a slot: the measured service time (EWMA) over the
        workers, at least 1 s and at most settings.max_retry_after_s (what the clients wait at most)."""
        wait = self._avg_seconds / self.workers
        return float(min(self.settings.max_retry_after_s, max(1, math.ceil(wait))))

    def _admit(self) -> None:
        """Reserve a place (running or queued) or refuse with 503: when the queue is full, or when the queue's
        expected wait (measured service time x requests ahead / workers) would pass the deadline."""
        with self._lock:
            if self.closed:
                raise Problem(503, "server is shutting down", retry_after=1.0)
            ahead = self._pending - self.workers + 1  # requests a new one would wait for
            if self._pending >= self.capacity:
                raise Problem(503, f"server busy ({self._pending} requests queued or running)",
                              retry_after=self.retry_after())
            if ahead > 0 and self._avg_seconds * ahead / self.workers > self.settings.deadline_s:
                raise Problem(503, f"server busy: {self._pending} requests ahead would take longer than the "
                              f"deadline of {self.settings.deadline_s:g} s", retry_after=self.retry_after())
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

    # ---- the work --------------------------------------------------------------------------
    def _job(self, parse: Callable[[], DetectRequest], enqueued: float, deadline: float,
             timings: dict[str, float], header: dict[str, Any] | None,
             on_detection: OnDetection | None = None) -> bytes:
        """Parse (on this worker, not the event loop) and detect; the response JSON bytes, or Problem.  header:
        the ROS header of a CDR payload, which parse() may fill in (Zenoh); it goes into the response.
        on_detection(det, cloud, hand) is called on the worker with the detection (ROS outputs, the viewer)."""
        start = time.perf_counter()
        held = 0.0  # MiB of the memory budget this request holds (budget.MemoryBudget)
        units = 0.0  # its work units (budget.work_units), known once parsed
        with self._lock:
            self._running += 1
            self.metrics.running.set(self._running)
            self.metrics.queue_depth.set(max(0, self._pending - self._running))
        try:
            timings["queue"] = start - enqueued
            before = timings.get("read", 0.0) + timings.get("decode", 0.0)  # spent before enqueue (body read)
            if start > deadline:
                if self._avg_seconds < self.settings.deadline_s:  # requests fit the deadline: the queue was long
                    raise Problem(503, f"server busy: queued past the deadline of {self.settings.deadline_s:g} s",
                                  retry_after=self.retry_after())
                raise Problem(504, f"deadline of {self.settings.deadline_s} s passed while queued", "deadline")
            req = parse()
            wait = min(self.settings.detect_memory_wait_s, max(0.0, deadline - time.perf_counter()))
            held = self.budget.take(cost_of(req), self.retry_after(), wait)  # 413 / 503 before detection work
            shared = 1 + self._detecting  # detections sharing the cores (graspd.core.parallel), this one included
            lone = work_units(req) * self.budget.unit_seconds  # 503 rather than start what cannot end in time
            margin = TIME_MARGIN if shared > 1 or timings["queue"] > 1.0 else 1.0  # under load: a safety margin
            if lone <= self.settings.deadline_s and time.perf_counter() + margin * lone * shared > deadline:
                raise Problem(503, f"server busy: this request takes about {lone * shared:.0f} s now and would not "
                              f"end within the deadline of {self.settings.deadline_s:g} s",
                              retry_after=self.retry_after())
            with self._lock:
                self._detecting += 1
            units = work_units(req) * shared  # timed from here on (budget.observe learns seconds per lone unit)
            timings["decode"] = timings.get("decode", 0.0) + time.perf_counter() - start
            try:
                hand = req.hand_geometry()
                given = req.to_input()  # in the frame detection runs in; non-finite rows dropped (graspd.io.inputs)
                cloud = given.cloud
                params = req.to_params()
            except CALLER_ERRORS as exc:
                raise from_wire(exc) from None
            model = self.registry.resolve(req.model, req.use_classifier and req.method == "gpd",
                                          hand or HandGeometry())
            det: Detection | TemplateDetection
            ctx = current_request()
            region = None if req.method == "templates" else self._checks.submit(
                region_check, cloud, params.workspace, params.range_window)
            try:
                with THREADS.request():  # concurrent requests share the cores (graspd.core.parallel)
                    det = self._detect(req, cloud, params, hand, model)
            except TargetError as exc:  # the target selects nothing of the cloud: a 422 naming target.<field>
                raise from_wire(exc) from None
            input_warnings = given.warnings  # the input's own (non-finite rows dropped), first
            if isinstance(det, Detection):
                det = replace(det, warnings=(*input_warnings, *det.warnings))
                input_warnings = ()
            # request_id: the client's X-Request-ID, else made here; detection_id (GPD grasp ids) always made here
            detection_id = ctx.detection_id if ctx is not None else uuid.uuid4().hex[:16]
            if isinstance(det, TemplateDetection):
                request_id = det.detection_id or uuid.uuid4().hex
                if ctx is not None and ctx.given:
                    request_id = ctx.id  # the client's id stays; the grasp ids name the detection
                elif ctx is not None:
                    ctx.id = request_id  # the request's later log lines and X-Request-ID carry the returned id
                used_hand = self.templates.library.hand
            else:
                request_id = ctx.id if ctx is not None else detection_id
                self.templates.remember(detection_id, cloud, det)
                used_hand = det.hand
            if on_detection is not None:
                on_detection(det, cloud, used_hand)
            timings.update(det.timings)
            timings["detect"] = timings.get("total", 0.0)  # the detector's own wall time, before the engine's total
            crops = None
            if req.crops is not None and isinstance(det, Detection):  # method "templates" refuses crops
                t = time.perf_counter()
                crops = crops_json(det, req.crops)
                timings["crops"] = time.perf_counter() - t
            self.metrics.candidates.observe(det.num_candidates)
            self.metrics.grasps.observe(len(det.grasps))
            self.metrics.points.observe(det.num_points)
            fits = None if isinstance(det, TemplateDetection) else self.registry.fits(det.model, used_hand)
            if isinstance(det, Detection):  # the request-level checks (graspd.gpd.sanity), after the detector's own
                det = det.warned(*check_detection(det, cloud, params.workspace, params.range_window, fits,
                                                  None if region is None else region.result()))
            timings["total"] = time.perf_counter() - enqueued + before
            self.metrics.observe_timings(timings)
            return DetectResponse.from_detection(det, request_id=request_id, timings=timings, hand=used_hand,
                                                 crops=crops, header=header or None,
                                                 model_fits_hand=fits, detection_id=detection_id,
                                                 frame=given.frame, warnings=input_warnings).to_json()
        finally:
            if units:
                with self._lock:
                    self._detecting -= 1
            self.budget.give(held)
            elapsed = time.perf_counter() - start
            self.budget.observe(units, elapsed)
            with self._lock:
                self._running -= 1
                self.metrics.running.set(self._running)
                if elapsed > 0.01 or self._avg_seconds < 0.01:  # refusals in microseconds say nothing of the load
                    self._avg_seconds = 0.8 * self._avg_seconds + 0.2 * elapsed

    def _detect(self, req: DetectRequest, cloud: ViewpointCloud, params: DetectionParams, hand: HandGeometry | None,
                model: str | None) -> Detection | TemplateDetection:
        """The detection a request asks for: grasp templates, or GPD with the resolved model."""
        if req.method == "templates":
            return self.templates.detect(req, cloud, hand)
        return self.registry.detector(model).detect(cloud, params, hand)

    def submit(self, req: DetectRequest, timings: dict[str, float], header: dict[str, Any] | None = None,
               on_detection: OnDetection | None = None) -> tuple[Future[bytes], float]:
        """Admit a request (Problem 503 when full) and queue it; returns the future and its deadline."""
        self._admit()
        return self.enqueue(lambda: req, timings, header, on_detection)

    def enqueue(self, parse: Callable[[], DetectRequest], timings: dict[str, float],
                header: dict[str, Any] | None = None, on_detection: OnDetection | None = None
                ) -> tuple[Future[bytes], float]:
        """Queue an admitted request (admit() first): parse() runs on a worker, then the detection.  Returns
        the future and its deadline; the place is given back when the future is done.  header: a ROS header
        for the response (Zenoh, CDR input), read after parse() ran."""
        now = time.perf_counter()
        deadline = now + self.settings.deadline_s
        context = contextvars.copy_context()  # the request id follows the work onto the worker thread
        try:
            fut = self.executor.submit(context.run, self._job, parse, now, deadline, timings, header, on_detection)
        except RuntimeError:  # executor shut down
            self._release()
            raise Problem(503, "server is shutting down", retry_after=1.0) from None
        fut.add_done_callback(self._release)
        return fut, deadline

    def run_sync(self, req: DetectRequest, timings: dict[str, float] | None = None,
                 header: dict[str, Any] | None = None, on_detection: OnDetection | None = None) -> bytes:
        """Blocking detect (Zenoh callbacks, CLI): response JSON bytes, or Problem."""
        fut, deadline = self.submit(req, timings if timings is not None else {}, header, on_detection)
        self.trim_after(fut)
        try:
            return fut.result(timeout=max(0.0, deadline - time.perf_counter()))
        except FutureTimeout:
            fut.cancel()
            raise Problem(504, f"no result within the deadline of {self.settings.deadline_s} s", "deadline") from None

    async def run(self, req: DetectRequest, timings: dict[str, float]) -> bytes:
        """Awaitable detect for the HTTP app: the work runs off the event loop."""
        fut, deadline = self.submit(req, timings)
        return await self._wait(fut, deadline)

    async def run_admitted(self, parse: Callable[[], DetectRequest], timings: dict[str, float],
                           on_detection: OnDetection | None = None) -> bytes:
        """Awaitable parse + detect of a request admitted with admit(): both run on a worker thread."""
        fut, deadline = self.enqueue(parse, timings, None, on_detection)
        return await self._wait(fut, deadline)

    async def _wait(self, fut: Future[bytes], deadline: float) -> bytes:
        waiter = asyncio.wrap_future(fut)
        self.trim_after(fut)
        try:
            return await asyncio.wait_for(waiter, timeout=max(0.0, deadline - time.perf_counter()))
        except TimeoutError:
            fut.cancel()
            raise Problem(504, f"no result within the deadline of {self.settings.deadline_s} s", "deadline") from None

    def close(self, wait: bool = True) -> None:
        """Refuse new work and let running detections finish (graceful shutdown)."""
        with self._lock:
            self.closed = True
        self.executor.shutdown(wait=wait, cancel_futures=True)
        self._checks.shutdown(wait=wait, cancel_futures=True)
        self._trimmer.close()
        self.templates.close()
