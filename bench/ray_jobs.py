"""Wall time of a scene-data job as Ray tasks on 1 and 2 workers, beside one process and a local pool.

One small but not trivial job (graspd_lab.training.scene_data: --scenes scenes of the default mix, one chunk per
scene so the workers share them out) is generated once per runner into a fresh folder; every run must give the
same dataset_sha256 (checked).  A Ray run's wall time includes starting and stopping the local Ray (measured on
its own too).  The machine's load (`uptime`) is written before and after every run: on a shared machine it says
how much of the CPU the job had.  Writes bench/results/ray.md and ray.json.

  PYTHONPATH=service:client:lab .venv/bin/python bench/ray_jobs.py --scenes 10
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "lab"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

from graspd_lab.cluster import Runner, ray_available, start_ray  # noqa: E402
from graspd_lab.training.scene_data import SceneParams, generate_scene_dataset  # noqa: E402

#: (label, runner) of each run, in order.
RUNS: tuple[tuple[str, Runner], ...] = (
    ("one process", Runner()),
    ("pool, 2 processes", Runner(workers=2, context="spawn")),
    ("Ray, 1 worker", Runner(workers=1, ray=True)),
    ("Ray, 2 workers", Runner(workers=2, ray=True)),
)


def uptime() -> str:
    """`uptime`'s line (the load averages), or the load from os.getloadavg where uptime is missing."""
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "load average: " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def ray_start_seconds() -> float:
    """Seconds to start and stop a local Ray of 2 CPUs (part of every Ray run's wall time)."""
    import ray  # noqa: PLC0415 - only when Ray is installed

    t0 = time.perf_counter()
    start_ray(Runner(workers=2, ray=True))
    ray.shutdown()
    return time.perf_counter() - t0


def run_one(label: str, runner: Runner, params: SceneParams, work: Path) -> dict[str, Any]:
    """Generate the dataset with runner into a fresh folder; wall time, sha and load before and after."""
    out = work / label.replace(" ", "_").replace(",", "")
    shutil.rmtree(out, ignore_errors=True)
    before = uptime()
    t0 = time.perf_counter()
    manifest = generate_scene_dataset(out, params, runner=runner)
    wall = time.perf_counter() - t0
    row = {"run": label, "runner": runner.describe(), "workers": runner.workers, "wall_s": round(wall, 1),
           "exemplars": manifest["counts"]["total"], "scenes": len(manifest["objects"]),
           "dataset_sha256": manifest["dataset_sha256"], "uptime_before": before, "uptime_after": uptime()}
    print(f"{label:20s} {wall:7.1f} s  {row['exemplars']} exemplars  sha {row['dataset_sha256'][:12]}  "
          f"[{row['uptime_after']}]", flush=True)
    return row


def markdown(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """The table of runs with speed-ups over one process and over Ray on 1 worker."""
    base = next(r["wall_s"] for r in rows if r["run"] == "one process")
    ray1 = next((r["wall_s"] for r in rows if r["run"] == "Ray, 1 worker"), None)
    lines = [
        "# The lab's jobs on Ray: scene data on 1 and 2 workers",
        "",
        f"- command: `{meta['command']}`",
        f"- commit: `{meta['commit']}`, date: {meta['date']}, {meta['cpus']} CPUs (shared with other jobs), "
        f"Ray {meta['ray_version']}",
        f"- job: {meta['job']}",
        f"- starting and stopping a local Ray (2 CPUs): {meta['ray_start_s']:.1f} s, inside every Ray run's wall time",
        f"- every run's dataset_sha256: `{rows[0]['dataset_sha256']}` "
        + ("(all equal)" if meta["identical"] else "(NOT all equal)"),
        "",
        "| run | wall (s) | vs one process | vs Ray on 1 worker | load before -> after (1, 5, 15 min) |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        vs_ray1 = f"{ray1 / r['wall_s']:.2f}x" if ray1 and r["run"].startswith("Ray") else ""
        load = f"{_load(r['uptime_before'])} -> {_load(r['uptime_after'])}"
        lines.append(f"| {r['run']} | {r['wall_s']:.1f} | {base / r['wall_s']:.2f}x | {vs_ray1} | {load} |")
    loads = [float(_load(r[k]).split(",")[0]) for r in rows for k in ("uptime_before", "uptime_after")]
    lines += ["", f"The 1-minute load average was {min(loads):.1f}-{max(loads):.1f} during these runs, on "
              f"{meta['cpus']} cores shared with other engineers' jobs.  Where the load is above the core count a "
              "second worker finds no free core, and the table shows the runners' overhead and that they write "
              "the same bytes, not what 2 workers gain on idle cores."]
    return "\n".join(lines) + "\n"


def _load(line: str) -> str:
    return line.rsplit("load average:", 1)[-1].strip()


def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True)
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=10)
    ap.add_argument("--views", type=int, default=4, help="views per scene (scene_data's default)")
    ap.add_argument("--samples", type=int, default=150, help="detector num_samples per view (scene_data's default)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--runs", nargs="+", default=[label for label, _ in RUNS], help="which runs, by label")
    ap.add_argument("--work", type=Path, default=None, help="folder for the datasets (default: a temporary one)")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = ap.parse_args(argv)
    if not ray_available():
        ap.error("Ray is not installed: .venv/bin/pip install -e \"./lab[cluster]\"")
    import ray  # noqa: PLC0415

    params = SceneParams(seed=args.seed, scenes=args.scenes, views_per_scene=args.views, num_samples=args.samples,
                         scenes_per_chunk=1)
    work = args.work or Path(tempfile.mkdtemp(prefix="graspd-ray-"))
    start_s = ray_start_seconds()
    rows = [run_one(label, runner, params, work) for label, runner in RUNS if label in args.runs]
    meta = {
        "command": "PYTHONPATH=service:client:lab .venv/bin/python bench/ray_jobs.py "
        + shlex.join(sys.argv[1:] if argv is None else argv),
        "commit": git_commit(), "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "cpus": os.cpu_count(),
        "ray_version": ray.__version__, "ray_start_s": round(start_s, 1),
        "job": f"scene data, {args.scenes} scenes x {args.views} views, {args.samples} samples per view, default mix "
        f"and objects (4-10), one chunk per scene, seed {args.seed}",
        "params": params.to_dict(), "identical": len({r["dataset_sha256"] for r in rows}) == 1,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    md = markdown(rows, meta)
    (args.out / "ray.md").write_text(md)
    (args.out / "ray.json").write_text(json.dumps({"meta": meta, "runs": rows}, indent=1))
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)
    print(md)
    return 0 if meta["identical"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
