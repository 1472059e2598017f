"""One way for the lab's jobs to run their work items: in this process, on a local process pool, or as Ray tasks.

Every long lab job (scene data, the labelled mesh dataset, the clutter and container benchmarks, an instance
model's views) is a list of independent work items (a chunk of scenes, a benchmark round, a view) and a
picklable function of one item that is deterministic from the item alone.  `imap(fn, items, runner)` maps it:

  - workers <= 1 and no Ray: in this process, in order (the reference path);
  - workers > 1 and no Ray: a multiprocessing pool of `workers` processes (the jobs' existing parallel path);
  - Ray (`--ray`, or `--address ADDR`): one Ray task per item.  Without an address, ray.init() starts Ray on this
    machine with num_cpus = workers; with one it joins a cluster ("auto": the cluster `ray start --head` made on
    this machine; "ray://HOST:10001": a remote head through Ray Client, which needs `pip install "ray[client]"`).

Results come back as they finish (ray.wait), so the caller's graspd.core.progress display moves with the
work and its checkpoint (a chunk file, a line of rounds.jsonl) is written as soon as an item is done; the jobs
order results themselves, so their files do not depend on the runner.  Ray is the optional extra
`graspd-lab[cluster]`: without it every job runs as before and asking for Ray names what to install.
This is no scheduler: Ray (or the pool) schedules; an item that fails stops the job with its error.
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import multiprocessing as mp
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")
R = TypeVar("R")

#: What to install for --ray / --address, said by every job that is asked for Ray without it.
RAY_MISSING = ("Ray is not installed: install the lab's cluster extra, "
               "`.venv/bin/pip install -e \"./lab[cluster]\"` (or `pip install \"ray>=2.9\"`), "
               "or run without --ray / --address (a local process pool)")
#: Object store of a Ray started here: parameters, records and at most an instance model's view rows (a few MB
#: each); Ray spills to disk beyond it.
LOCAL_OBJECT_STORE_BYTES = 512 * 2**20


class RayMissingError(RuntimeError):
    """--ray or --address was asked for where Ray is not installed."""

    def __init__(self) -> None:
        super().__init__(RAY_MISSING)


@dataclass(frozen=True)
class Runner:
    """How a job runs its items: `workers` processes (local pool) or Ray CPUs (a Ray started here); `ray`: as
    Ray tasks; `address`: the Ray cluster to join (implies ray).  `context`: the local pool's start method."""

    workers: int = 1
    ray: bool = False
    address: str | None = None
    context: str = "spawn"

    def __post_init__(self) -> None:
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")

    @property
    def uses_ray(self) -> bool:
        return self.ray or self.address is not None

    def describe(self) -> str:
        """How the job ran, for its timing and results files: 'ray (local, 2 CPUs)', 'pool of 2', 'serial'."""
        if self.uses_ray:
            return f"ray ({self.address})" if self.address else f"ray (local, {self.workers} CPUs)"
        return f"pool of {self.workers}" if self.workers > 1 else "serial"


def ray_available() -> bool:
    """Whether Ray can be imported (the cluster extra is installed)."""
    return importlib.util.find_spec("ray") is not None


def add_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """--ray and --address on a job's command line (its own --workers / --jobs says how many)."""
    parser.add_argument("--ray", action="store_true",
                        help="run the work items as Ray tasks (Ray started on this machine with num_cpus = the "
                        "workers asked; needs graspd-lab[cluster])")
    parser.add_argument("--address", default=None, metavar="ADDR",
                        help="join a Ray cluster instead: 'auto' (a `ray start --head` on this machine) or "
                        "ray://HOST:10001 (implies --ray; output folders must be shared by the nodes)")


def runner_from_args(args: argparse.Namespace, workers: int, context: str = "spawn") -> Runner:
    """The Runner a job's parsed --ray/--address and worker count ask for; RayMissingError if Ray is asked for
    and not installed (checked before any work starts)."""
    runner = Runner(workers=max(1, workers), ray=bool(getattr(args, "ray", False)),
                    address=getattr(args, "address", None), context=context)
    if runner.uses_ray and not ray_available():
        raise RayMissingError()
    return runner


def imap(fn: Callable[[T], R], items: Iterable[T], runner: Runner) -> Iterator[R]:
    """fn(item) for every item, yielded as each finishes (in item order when serial).  fn must be picklable
    (a module-level function) and its result too."""
    work = list(items)
    if not work:
        return iter(())
    if runner.uses_ray:
        return _ray_imap(fn, work, runner)
    if runner.workers <= 1 or len(work) == 1:
        return map(fn, work)
    return _pool_imap(fn, work, runner)


def _pool_imap(fn: Callable[[T], R], work: list[T], runner: Runner) -> Iterator[R]:
    with mp.get_context(runner.context).Pool(min(runner.workers, len(work))) as pool:
        yield from pool.imap_unordered(fn, work, chunksize=1)


def _python_path() -> str:
    """This process's own import folders (the checkout's service, client, lab, bench; not the venv's or the
    standard library's) for Ray's workers, so that they import the same code as the driver."""
    prefixes = {str(Path(p).resolve()) for p in (sys.prefix, sys.base_prefix, sys.exec_prefix)}
    keep: list[str] = []
    for entry in [*sys.path, *os.environ.get("PYTHONPATH", "").split(os.pathsep)]:
        if not entry or not Path(entry).is_dir():
            continue
        full = str(Path(entry).resolve())
        if any(full == p or full.startswith(p + os.sep) for p in prefixes) or full in keep:
            continue
        keep.append(full)
    return os.pathsep.join(keep)


def start_ray(runner: Runner) -> bool:
    """ray.init for the runner unless Ray is already up in this process; True if this call started it."""
    try:
        import ray  # noqa: PLC0415 - the optional cluster extra
    except ImportError:
        raise RayMissingError() from None
    if ray.is_initialized():
        return False
    runtime_env = {"env_vars": {"PYTHONPATH": _python_path()}}
    if runner.address is not None:
        ray.init(address=runner.address, runtime_env=runtime_env, logging_level=logging.WARNING)
    else:
        ray.init(num_cpus=runner.workers, include_dashboard=False, object_store_memory=LOCAL_OBJECT_STORE_BYTES,
                 runtime_env=runtime_env, logging_level=logging.WARNING)
    return True


def _by_value(fn: Callable[..., Any]) -> None:
    """Ship fn's module to Ray's workers by value when they could not import it by name (a script, a module
    loaded from a file path such as bench/clutter.py)."""
    name = getattr(fn, "__module__", None)
    module = sys.modules.get(name or "")
    if module is None or name == "__main__":
        return  # cloudpickle sends __main__'s functions by value already
    try:
        found = importlib.util.find_spec(name or "") is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        from ray import cloudpickle  # noqa: PLC0415

        cloudpickle.register_pickle_by_value(module)


def _ray_imap(fn: Callable[[T], R], work: list[T], runner: Runner) -> Iterator[R]:
    """One Ray task per item (1 CPU each); results as they finish (ray.wait).  Items left when the caller
    stops (an error, Ctrl-C) are cancelled; a Ray this call started is shut down."""
    started = start_ray(runner)
    import ray  # noqa: PLC0415

    _by_value(fn)
    pending: list[Any] = []
    try:
        # this process's import folders now (a script may have added its own since Ray started: bench/)
        task = ray.remote(num_cpus=1, runtime_env={"env_vars": {"PYTHONPATH": _python_path()}})(fn)
        pending = [task.remote(item) for item in work]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield ray.get(ready[0])
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        if started:
            ray.shutdown()


__all__ = ["RAY_MISSING", "RayMissingError", "Runner", "add_arguments", "imap", "ray_available",
           "runner_from_args", "start_ray"]
