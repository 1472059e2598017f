"""Instance-model training jobs of POST /models: one at a time, a bounded queue behind it, each a subprocess
(`python -m graspd_lab.training.instance_cli ... --progress-json`: torch stays out of the server) whose progress
lines update the job; a finished model is loaded into the registry and selectable by name in /detect.

Jobs live in this process's memory (GET /models lists them); the models they make live in the models folder
and load again at the next start like any other.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import importlib.util
import json
import logging
import math
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import graspd
import graspd_client
from graspd.gpd import classifier
from graspd.io.mesh_file import MeshError, MeshLimits, check_declared_counts
from graspd.server.problems import Problem, from_wire
from graspd.server.services.registry import ModelRegistry
from graspd.server.settings import Settings
from graspd.store.database import scrub
from graspd.store.instances import BASE_MODELS, parse_progress

log = logging.getLogger("graspd.server")

#: Finished jobs GET /models keeps listing (the oldest are forgotten first).
KEEP_FINISHED = 50
#: Seconds a job's process gets to stop after SIGTERM before it is killed (shutdown, timeout).
STOP_GRACE_S = 5.0


@dataclass
class InstanceJob:
    """One instance model being made: what was asked, and how far it got."""

    name: str
    category: str | None
    hand: str
    base_model: str | None
    mesh: Path
    work: Path
    id: str = dataclasses.field(default_factory=lambda: uuid.uuid4().hex[:12])
    state: str = "queued"                 # queued, running, done, failed
    stage: str | None = None              # dataset, training, evaluating, loading
    view: int | None = None
    views: int | None = None
    epoch: int | None = None
    epochs: int | None = None
    error: str | None = None
    field: str | None = None
    created_at: float = dataclasses.field(default_factory=time.time)
    started: float | None = None          # monotonic
    finished: float | None = None

    def describe(self) -> dict[str, Any]:
        now = time.monotonic()
        elapsed = 0.0 if self.started is None else (self.finished or now) - self.started
        return {"id": self.id, "name": self.name, "category": self.category, "hand": self.hand,
                "base_model": self.base_model, "state": self.state, "stage": self.stage, "view": self.view,
                "views": self.views, "epoch": self.epoch, "epochs": self.epochs, "created_at": self.created_at,
                "elapsed_s": round(elapsed, 1), "error": self.error, "field": self.field}


def training_available() -> bool:
    """Whether this install can train: the lab distribution graspd-lab (it brings torch and onnx) is installed,
    found without importing it (the server never imports the lab; the job runs it in a subprocess)."""
    return all(importlib.util.find_spec(m) is not None for m in ("graspd_lab", "torch", "onnx"))


def _pythonpath() -> str:
    """PYTHONPATH for the job: where this graspd, graspd_client and graspd_lab come from, then the caller's."""
    roots = [str(Path(graspd.__file__).resolve().parents[1]), str(Path(graspd_client.__file__).resolve().parents[1])]
    lab = importlib.util.find_spec("graspd_lab")
    if lab is not None and lab.origin:
        roots.append(str(Path(lab.origin).resolve().parents[1]))
    extra = os.environ.get("PYTHONPATH", "")
    return os.pathsep.join(dict.fromkeys([*roots, *filter(None, extra.split(os.pathsep))]))


class InstanceJobs:
    """The job queue: submit() checks and enqueues (409 for a name in use, 503 when the queue is full), one
    worker thread runs the jobs in order, describe() lists them."""

    def __init__(self, settings: Settings, registry: ModelRegistry) -> None:
        self.settings = settings
        self.registry = registry
        self.models_dir = settings.resolved_models_dir()
        self._lock = threading.Condition()
        self._jobs: collections.OrderedDict[str, InstanceJob] = collections.OrderedDict()
        self._queue: collections.deque[InstanceJob] = collections.deque()
        self._proc: subprocess.Popen[str] | None = None
        self._closed = False
        self._thread: threading.Thread | None = None
        self.checks = MeshCheckGate(settings.instance_check_workers, settings.instance_check_queue,
                                    settings.max_retry_after_s)

    # ---- requests ----

    def base_model(self, category: str | None) -> str | None:
        """The model a job for this category fine-tunes: the category model (422 naming category when the
        models folder lacks it), else generic15, or None (from scratch) when there is no generic15."""
        name = BASE_MODELS[category]
        if (self.models_dir / f"{name}.onnx").is_file():
            return name
        if category is not None:
            raise Problem(422, f"the category model {name!r} is not in the models folder", "category")
        return None

    def check_name_free(self, name: str) -> None:
        """409 naming name when a model or a queued or running job has it."""
        taken = (name in self.registry.classifiers or name in self.registry.errors
                 or (self.models_dir / f"{name}.onnx").exists() or (self.models_dir / f"{name}.json").exists())
        with self._lock:
            taken = taken or any(j.name == name and j.state in ("queued", "running") for j in self._jobs.values())
        if taken:
            raise Problem(409, f"a model called {name!r} exists or is being made; choose another name", "name")

    def check_can_train(self) -> None:
        """503 when this server cannot train or write models, before the upload is looked at."""
        if not self.settings.instance_training:
            raise Problem(503, "instance training is off on this server (GRASPD_INSTANCE_TRAINING)", None)
        if not training_available():
            raise Problem(503, "this server cannot train: install the lab distribution graspd-lab (pip install "
                                "./lab; it brings torch and onnx)", None)
        try:
            self.models_dir.mkdir(parents=True, exist_ok=True)
            writable = os.access(self.models_dir, os.W_OK | os.X_OK)
        except OSError:
            writable = False
        if not writable:
            raise Problem(503, "the models folder is not writable: set GRASPD_MODELS_DIR to a writable folder "
                               "holding the base models", None)

    def work_dir(self, name: str) -> Path:
        return self.models_dir / ".work" / name

    def submit(self, job: InstanceJob) -> InstanceJob:
        """Queue a job whose mesh is already in job.mesh; 409 (name taken meanwhile) or 503 (queue full)."""
        with self._lock:
            if self._closed:
                raise Problem(503, "the server is shutting down", None, retry_after=self.settings.max_retry_after_s)
            if any(j.name == job.name and j.state in ("queued", "running") for j in self._jobs.values()):
                raise Problem(409, f"a model called {job.name!r} is being made; choose another name", "name")
            busy = bool(self._queue) or any(j.state == "running" for j in self._jobs.values())
            if busy and len(self._queue) >= self.settings.instance_queue:
                raise Problem(503, f"{len(self._queue)} instance models are waiting to be trained; try later",
                              None, retry_after=self.settings.max_retry_after_s)
            self._jobs[job.id] = job
            self._queue.append(job)
            self._forget_old()
            if self._thread is None:
                self._thread = threading.Thread(target=self._worker, name="graspd-instance-jobs", daemon=True)
                self._thread.start()
            self._lock.notify_all()
        log.info("instance job queued", extra={"job": job.id, "model": job.name, "category": job.category,
                                               "base_model": job.base_model})
        return job

    def describe(self) -> list[dict[str, Any]]:
        with self._lock:
            return [j.describe() for j in self._jobs.values()]

    def get(self, job_id: str) -> InstanceJob | None:
        with self._lock:
            return self._jobs.get(job_id)

    def _forget_old(self) -> None:
        finished = [k for k, j in self._jobs.items() if j.state in ("done", "failed")]
        for k in finished[: max(0, len(finished) - KEEP_FINISHED)]:
            del self._jobs[k]

    # ---- the worker ----

    def _worker(self) -> None:
        while True:
            with self._lock:
                while not self._queue and not self._closed:
                    self._lock.wait()
                if self._closed:
                    return
                job = self._queue.popleft()
                job.state, job.started = "running", time.monotonic()
            try:
                self._run(job)
            except Exception as exc:  # a job never takes the worker down
                log.error("instance job failed", exc_info=True, extra={"job": job.id, "model": job.name})
                self._finish(job, f"internal error ({type(exc).__name__}; the server log has the details)", None)

    def command(self, job: InstanceJob) -> list[str]:
        s = self.settings
        cmd = [sys.executable, "-m", "graspd_lab.training.instance_cli", "--instance", str(job.mesh),
               "--name", job.name,
               "--models-dir", str(self.models_dir), "--work-dir", str(job.work), "--hand", job.hand,
               "--views", str(s.instance_views), "--max-minutes", str(s.instance_max_minutes),
               "--threads", str(s.instance_threads), "--base", job.base_model or "none", "--progress-json"]
        if s.instance_per_view is not None:
            cmd += ["--per-view", str(s.instance_per_view)]
        if s.instance_epochs is not None:
            cmd += ["--epochs", str(s.instance_epochs)]
        return cmd + (["--category", job.category] if job.category else [])

    def _run(self, job: InstanceJob) -> None:
        job.work.mkdir(parents=True, exist_ok=True)
        log_path = job.work / "job.log"
        env = {**os.environ, "PYTHONPATH": _pythonpath(), "PYTHONUNBUFFERED": "1"}
        log.info("instance job started", extra={"job": job.id, "model": job.name})  # its log: <work>/job.log
        with open(log_path, "w") as errors:
            proc = subprocess.Popen(self.command(job), stdout=subprocess.PIPE, stderr=errors, text=True, env=env,
                                    start_new_session=True)
            with self._lock:
                self._proc = proc
                closed = self._closed
            if closed:  # close() ran between the pop and the start
                self._stop(proc)
            timer = threading.Timer(self.settings.instance_timeout_s, self._stop, (proc,))
            timer.daemon = True
            timer.start()
            failed: dict[str, Any] | None = None
            assert proc.stdout is not None
            for line in proc.stdout:
                event = parse_progress(line.rstrip("\n"))
                if event is None:
                    continue
                with self._lock:
                    stage = event.get("stage")
                    if stage == "failed":
                        failed = event
                    elif isinstance(stage, str):
                        job.stage = stage
                    for key in ("view", "views", "epoch", "epochs"):
                        if isinstance(event.get(key), int):
                            setattr(job, key, event[key])
            code = proc.wait()
            timer.cancel()
        with self._lock:
            self._proc = None
            closed = self._closed
        if code != 0:
            if failed is not None:
                error, where = scrub(str(failed.get("error"))), failed.get("field")
            elif closed:
                error, where = "the server shut down while training", None
            elif code in (-signal.SIGTERM, -signal.SIGKILL):
                error, where = f"training stopped after the time limit of {self.settings.instance_timeout_s:g} s", None
            else:
                error, where = f"training exited with status {code} (the server log has the details)", None
                log.error("instance job crashed", extra={"job": job.id, "model": job.name, "status": code,
                                                         "stderr": scrub(_tail(log_path))})
            self._finish(job, error, where if isinstance(where, str) else None)
            return
        with self._lock:
            job.stage = "loading"
        try:
            model = classifier.load_model(job.name, self.models_dir, threads=self.settings.model_threads)
            probe = model.score(np.zeros((1, model.channels, model.image_size, model.image_size), np.uint8))
            if probe.shape != (1,):
                raise classifier.ModelError(f"model {job.name!r} does not score one image as one probability")
        except (classifier.ModelError, OSError) as exc:
            log.error("instance model did not load", extra={"job": job.id, "model": job.name,
                                                             "error": scrub(f"{type(exc).__name__}: {exc}")})
            self._finish(job, f"the new model did not load (job {job.id}; the server log has the details)", None)
            return
        self.registry.add(job.name, model)
        self._finish(job, None, None)

    def _finish(self, job: InstanceJob, error: str | None, where: str | None) -> None:
        with self._lock:
            job.finished = time.monotonic()
            job.state = "failed" if error else "done"
            job.error, job.field = error, where
            if job.started is None:
                job.started = job.finished
        extra = {"job": job.id, "model": job.name, "state": job.state, "s": round(job.finished - job.started, 1)}
        if error:
            extra.update(error=error, field=where)
        log.info("instance job finished", extra=extra)

    # ---- shutdown ----

    def _stop(self, proc: subprocess.Popen[str]) -> None:
        """SIGTERM the job's process group, SIGKILL after STOP_GRACE_S."""
        if proc.poll() is not None:
            return
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(STOP_GRACE_S)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass

    def close(self, timeout: float = 10.0) -> None:
        """Stop the running job and fail the queued ones (the server is going down)."""
        with self._lock:
            self._closed = True
            queued, self._queue = list(self._queue), collections.deque()
            proc = self._proc
            self._lock.notify_all()
        for job in queued:
            self._finish(job, "the server shut down before this job started", None)
        if proc is not None:
            self._stop(proc)
        if self._thread is not None:
            self._thread.join(timeout)


class MeshCheckGate:
    """At most `workers` mesh checks at once (each a process of ~300-400 MB), at most `queue` more waiting for
    one; a check beyond that, or one that waited wait_s, gets 503 with Retry-After.  Thread-safe (the route runs
    the check on a worker thread)."""

    def __init__(self, workers: int, queue: int, retry_after_s: float) -> None:
        self.workers, self.queue, self.retry_after_s = workers, queue, retry_after_s
        self._cond = threading.Condition()
        self.running = 0
        self.waiting = 0

    def _busy(self, why: str) -> Problem:
        return Problem(503, f"{why}: {self.workers} mesh check(s) running and {self.waiting} waiting; try later",
                       None, retry_after=self.retry_after_s)

    @contextlib.contextmanager
    def slot(self, wait_s: float) -> Iterator[None]:
        """Hold one of the workers while the with-block runs (waiting at most wait_s s for it)."""
        with self._cond:
            if self.running >= self.workers and self.waiting >= self.queue:
                raise self._busy("too many meshes are being checked")
            self.waiting += 1
            try:
                free = self._cond.wait_for(lambda: self.running < self.workers, wait_s)
            finally:
                self.waiting -= 1
            if not free:
                raise self._busy(f"no mesh check started within {wait_s:g} s")
            self.running += 1
        try:
            yield
        finally:
            with self._cond:
                self.running -= 1
                self._cond.notify()


def check_declared(content: bytes, suffix: str, max_bytes: int) -> None:
    """In this process, before anything is parsed: Problem 422 naming mesh when the file's declared counts
    cannot be backed by its bytes or exceed the limits (graspd.io.mesh_file.check_declared_counts).  Reads
    only the bytes already received: no allocation grows with what a header claims."""
    try:
        check_declared_counts(content, suffix, MeshLimits(max_bytes=max_bytes))
    except MeshError as exc:
        raise from_wire(exc) from None


def check_mesh(path: Path, category: str | None, hand: dict[str, float], max_bytes: int,
               timeout_s: float = 120.0, memory_mb: int = 0) -> None:
    """Check an uploaded mesh (graspd_lab.world.mesh_file) in a process of its own, so that a hostile file cannot take
    the service down: its address space capped at memory_mb MiB (RLIMIT_AS; 0: none), its CPU time and wall
    time at timeout_s, one OpenMP thread; Problem 422 naming the field when the mesh cannot be an instance."""
    cmd = [sys.executable, "-m", "graspd_lab.world.mesh_file", str(path), "--category", category or "other",
           "--hand", json.dumps(hand), "--max-bytes", str(max_bytes), "--max-memory-mb", str(memory_mb),
           "--max-cpu-s", str(max(1, math.ceil(timeout_s)))]
    env = {**os.environ, "PYTHONPATH": _pythonpath(), "OMP_NUM_THREADS": "1", "MALLOC_ARENA_MAX": "2"}
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=env, check=False)
    except subprocess.TimeoutExpired:
        raise Problem(422, f"the mesh could not be checked within {timeout_s:g} s (simplify it)", "mesh") from None
    lines = done.stdout.strip().splitlines()
    try:
        verdict = json.loads(lines[-1]) if lines else None
    except ValueError:
        verdict = None
    if done.returncode != 0 or not isinstance(verdict, dict):
        log.info("mesh check failed", extra={"status": done.returncode, "stderr": scrub(done.stderr[-2000:])})
        if done.returncode in (-signal.SIGXCPU, -signal.SIGKILL):
            raise Problem(422, f"the mesh could not be checked within {timeout_s:g} s of CPU time (simplify it)",
                          "mesh")
        raise Problem(422, "the mesh could not be read (not a valid .obj, .stl or .ply surface mesh, or it needs "
                           f"more than {memory_mb} MiB to read)", "mesh")
    if not verdict.get("ok"):
        raise Problem(422, str(verdict.get("error")), str(verdict.get("field") or "mesh"))


def _tail(path: Path, lines: int = 20) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""
