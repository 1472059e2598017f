"""Request speed through the service, old and new code in the same run: the baseline from a git worktree of an
earlier commit and the current tree, each started with `graspd serve` in its own process, one at a time, and
sent the same requests over HTTP as a robot sends them.

Rows (defaults but the number of samples; the service's default settings, but Zenoh off, a 300 s deadline and
WARNING logs, as bench/perf.py starts it):

- table_mug: the real Kinect capture /work/shared/data/real/table_mug.pcd (104k points, ASCII PCD) sent as the
  file is (its decode counts), 500 samples, the camera from its VIEWPOINT header; the first request after the
  service says ready (/readyz), then warm requests;
- kinect 307k: the organised Kinect cloud milk_cartoon_all_small_clorox.pcd (640x480, binary_compressed), as the
  file is, default samples;
- scan 1M / 5M: synthetic tabletop scans (bench/kernels.py tabletop_scan: two
  cameras 0.8 m above a 1.2 x 0.8 m table, boxes, a sphere and a can, 0.5 mm Gaussian noise), binary PCD with
  both camera positions as viewpoint parameters, 300 samples;
- 16 concurrent: the rendered 66k-point tabletop of bench/load.py (graspd_lab cluttered_tabletop, 8 objects, seed
  7), the client's JSON body, 300 samples; bursts of 16 requests from 16 threads released together, req/s over
  the bursts, errors, and the service's peak RSS (psutil, every 20 ms).

Each side's block: a fixed CPU workload (200 float64 256x256 matmuls + tanh, numpy on one thread, ~0.2 s) timed
3 times with no service running, the service started and the rows run (one untimed request per row before its
--repeats timed ones, table_mug's being the timed first request), the service stopped, the workload timed 3 more
times.  Blocks alternate old/new/new/old... over --rounds.  Every figure is given raw and calibrated: raw x
reference / (the median workload time of its block), the reference being the median of all workload times in
the run; so a block run while the machine was slow is scaled down by as much as the workload was slowed.

    PYTHONPATH=service:client:lab .venv/bin/python bench/speed.py [--quick] [--base d7f6f3f] [--rounds 2]
        [--repeats 10] [--rows table_mug,kinect,scan1m,scan5m,c16]

Writes bench/results/speed.md and speed.json (--out STEM to write elsewhere).
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import os
import platform
import shlex
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
_SERVICE_ENV = dict(os.environ)  # the services get the caller's environment, not the one-thread BLAS below
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"  # the calibration workload runs on one thread

import httpx  # noqa: E402
import numpy as np  # noqa: E402
import psutil  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"
TABLE_MUG = REAL / "table_mug.pcd"
KINECT = REAL / "milk_cartoon_all_small_clorox.pcd"
RESULTS = ROOT / "bench" / "results"
DEFAULT_BASE = "d7f6f3f"
SERVICE_SETTINGS = {"GRASPD_ZENOH_ENABLED": "false", "GRASPD_DEADLINE_S": "300", "GRASPD_LOG_LEVEL": "WARNING"}


# --- calibration workload -------------------------------------------------------------------------------------

_A = np.random.default_rng(1).standard_normal((256, 256)) / 16
WORKLOAD = "200 x (float64 256x256 matmul, then tanh), numpy on one thread (OPENBLAS/OMP/MKL_NUM_THREADS=1)"


def workload() -> float:
    """Seconds of the fixed single-thread CPU workload (~0.2 s on an idle core of this machine)."""
    t = time.perf_counter()
    x = _A
    for _ in range(200):
        x = np.tanh(x @ _A)
    return time.perf_counter() - t


# --- inputs -----------------------------------------------------------------------------------------------------


def tabletop_scan(num_points: int) -> tuple[NDArray[np.float32], NDArray[np.float32], str]:
    """(points, camera positions, which generator): bench/kernels.py's two-camera tabletop scan."""
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        from kernels import tabletop_scan as scan  # noqa: PLC0415 - a sibling bench script
    finally:
        sys.path.remove(str(ROOT / "bench"))
    points, _, eyes = scan(num_points)
    return points, eyes, "bench/kernels.py tabletop_scan"


def binary_pcd(points: NDArray[np.float32], viewpoint: NDArray[np.float32]) -> bytes:
    """A binary PCD v0.7 file (x y z float32) of points with one VIEWPOINT."""
    n = len(points)
    vx, vy, vz = (float(v) for v in viewpoint)
    header = (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n"
              f"COUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT {vx:.6f} {vy:.6f} {vz:.6f} 1 0 0 0\nPOINTS {n}\n"
              "DATA binary\n")
    return header.encode("ascii") + np.ascontiguousarray(points, "<f4").tobytes()


@dataclass
class Row:
    key: str
    label: str
    body: bytes
    content_type: str
    params: list[tuple[str, str]]
    what: str
    target: str = ""
    concurrent: bool = False


def make_rows(wanted: list[str]) -> tuple[list[Row], dict[str, Any]]:
    """The requests of each wanted row, and notes on how the inputs were made."""
    rows: list[Row] = []
    notes: dict[str, Any] = {}
    if "table_mug" in wanted:
        rows.append(Row("table_mug", "table_mug warm p50", TABLE_MUG.read_bytes(), "application/octet-stream",
                        [("num_samples", "500")], "table_mug.pcd as the file is (ASCII), 500 samples",
                        "<= 0.10 s"))
    if "kinect" in wanted:
        rows.append(Row("kinect", "Kinect 307k p50", KINECT.read_bytes(), "application/octet-stream", [],
                        "milk_cartoon_all_small_clorox.pcd as the file is (binary_compressed, 640x480), "
                        "default samples", "<= 0.25 s"))
    for key, n, target in (("scan1m", 1_000_000, "<= 0.20 s"), ("scan5m", 5_000_000, "<= 0.40 s")):
        if key not in wanted:
            continue
        t = time.perf_counter()
        points, eyes, source = tabletop_scan(n)
        body = binary_pcd(points, eyes[0])
        notes[key] = {"points": len(points), "bytes": len(body), "generator": source,
                      "viewpoints": eyes.tolist(), "seconds_to_make": round(time.perf_counter() - t, 2)}
        rows.append(Row(key, f"scan {n // 1_000_000}M p50", body, "application/octet-stream",
                        [("viewpoint", ",".join(f"{v:.6f}" for v in eye)) for eye in eyes]
                        + [("num_samples", "300")],
                        f"tabletop scan, {len(points)} points, binary PCD ({len(body) / 1e6:.1f} MB), "
                        f"two viewpoints, 300 samples ({source})", target))
    if "c16" in wanted:
        from graspd_client import build_detect_request  # noqa: PLC0415 - only this row needs the client and lab
        from graspd_lab.world.scenes import cluttered_tabletop, subsample  # noqa: PLC0415

        cloud = subsample(cluttered_tabletop(num_objects=8, seed=7), 66_000, seed=7)
        body = json.dumps(build_detect_request(cloud.points, cloud.viewpoints, cloud.camera_source,
                                               num_samples=300)).encode()
        notes["c16"] = {"points": len(cloud), "bytes": len(body)}
        rows.append(Row("c16", "16 concurrent 66k", body, "application/json", [],
                        f"bench/load.py's rendered tabletop, {len(cloud)} points, client JSON "
                        f"({len(body) / 1e6:.2f} MB), 300 samples, 16 threads at once",
                        ">= 8 req/s, 0 errors, RSS <= 1 GB", concurrent=True))
    return rows, notes


# --- the service ------------------------------------------------------------------------------------------------


@dataclass
class Side:
    name: str  # "old" or "new"
    root: Path
    commit: str
    subject: str
    dirty: str = ""

    @property
    def pythonpath(self) -> str:
        return f"{self.root / 'service'}:{self.root / 'client'}"


def _git(*args: str, cwd: Path = ROOT) -> str:
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=True).stdout.strip()


def _subject(commit: str) -> str:
    text = _git("log", "-1", "--format=%s", commit)
    return text if len(text) <= 90 else text[:90].rsplit(" ", 1)[0] + " ..."


def base_side(commit: str) -> Side:
    """The baseline: a worktree of commit at /tmp/speed-base (made if missing, moved to the commit if it is
    elsewhere and clean)."""
    full = _git("rev-parse", commit)
    path = Path("/tmp/speed-base")
    if not path.exists():
        subprocess.run(["git", "worktree", "add", "--detach", str(path), full], cwd=ROOT, check=True,
                       capture_output=True)
    elif _git("rev-parse", "HEAD", cwd=path) != full:
        if _git("status", "--porcelain", cwd=path):
            raise SystemExit(f"{path} is at another commit and has changes; remove it or pass its commit")
        subprocess.run(["git", "checkout", "--detach", full], cwd=path, check=True, capture_output=True)
    return Side("old", path, full[:7], _subject(full))


def current_side() -> Side:
    head = _git("rev-parse", "HEAD")
    files = [*_git("diff", "HEAD", "--name-only", "--", "service", "client").splitlines(),
             *(f"{f} (untracked)" for f in _git("ls-files", "--others", "--exclude-standard", "--", "service",
                                                   "client").splitlines())]
    dirty = ""
    if files:
        diff = subprocess.run(["git", "diff", "HEAD", "--", "service", "client"], cwd=ROOT, capture_output=True,
                              check=True).stdout
        dirty = f"uncommitted changes in {', '.join(files)} (diff sha1 {hashlib.sha1(diff).hexdigest()[:10]})"
    return Side("new", ROOT, head[:7], _subject(head), dirty)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Service:
    """`graspd serve` of one side on a free port, ready (/readyz 200) when constructed."""

    def __init__(self, side: Side) -> None:
        env = {**_SERVICE_ENV, "PYTHONPATH": side.pythonpath, **SERVICE_SETTINGS}
        where = subprocess.run([sys.executable, "-c", "import graspd, graspd_client; print(graspd.__file__); "
                                "print(graspd_client.__file__)"], env=env, capture_output=True, text=True,
                               check=True).stdout.split()
        if not all(Path(w).is_relative_to(side.root) for w in where):
            raise SystemExit(f"{side.name}: graspd imports from {where}, not {side.root}")
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        t = time.perf_counter()
        self.proc = subprocess.Popen([sys.executable, "-m", "graspd.cli", "serve", "--host", "127.0.0.1", "--port",
                                      str(self.port)], env=env, cwd=side.root)
        self.ps = psutil.Process(self.proc.pid)
        while time.perf_counter() - t < 300:
            if self.proc.poll() is not None:
                raise SystemExit(f"{side.name}: the service exited ({self.proc.returncode}) before it was ready")
            try:
                if httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.02)
        else:
            self.stop()
            raise SystemExit(f"{side.name}: the service was not ready after 300 s")
        self.ready_s = time.perf_counter() - t
        self.client = httpx.Client(timeout=600)
        self.peak_rss = self.window_peak = 0
        self._sampling = True
        self._sampler = threading.Thread(target=self._sample, daemon=True)
        self._sampler.start()

    def rss(self) -> int:
        try:
            return self.ps.memory_info().rss + sum(c.memory_info().rss for c in self.ps.children(recursive=True))
        except psutil.Error:
            return 0

    def _sample(self) -> None:
        while self._sampling:
            rss = self.rss()
            self.peak_rss = max(self.peak_rss, rss)
            self.window_peak = max(self.window_peak, rss)
            time.sleep(0.02)

    def cpu(self) -> float:
        t = self.ps.cpu_times()
        return float(t.user + t.system)

    def post(self, row: Row, client: httpx.Client | None = None) -> tuple[float, int, dict[str, Any]]:
        """(seconds, status, JSON answer or {}) of one request."""
        t = time.perf_counter()
        try:
            r = (client or self.client).post(f"{self.url}/detect", content=row.body, params=tuple(row.params),
                                             headers={"Content-Type": row.content_type})
        except httpx.HTTPError as exc:
            return time.perf_counter() - t, 0, {"error": repr(exc)}
        dt = time.perf_counter() - t
        try:
            answer = r.json()
        except ValueError:
            answer = {}
        return dt, r.status_code, answer

    def stop(self) -> None:
        self._sampling = False
        if getattr(self, "client", None) is not None:
            self.client.close()
        self.proc.terminate()
        try:
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(60)


# --- one side's block -------------------------------------------------------------------------------------------


@dataclass
class Block:
    side: str
    round: int
    load_before: list[float]
    workload_before: list[float] = field(default_factory=list)
    workload_during: list[float] = field(default_factory=list)
    workload_after: list[float] = field(default_factory=list)
    ready_s: float = 0.0
    rows: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def workload(self) -> float:
        return statistics.median(self.workloads)

    @property
    def workloads(self) -> list[float]:
        return self.workload_before + self.workload_during + self.workload_after


def _answer_summary(answer: dict[str, Any]) -> dict[str, Any]:
    return {k: answer.get(k) for k in ("num_points", "num_candidates", "model")} | {
        "grasps": len(answer.get("grasps") or []), "warnings": [w.get("code") for w in answer.get("warnings") or []]}


def sequential(service: Service, row: Row, repeats: int, first: bool) -> dict[str, Any]:
    """One request (the row's first, timed and kept apart), then repeats timed ones."""
    out: dict[str, Any] = {"times": [], "cpu": [], "timings": [], "errors": 0, "statuses": []}
    for i in range(repeats + 1):
        cpu = service.cpu()
        dt, status, answer = service.post(row)
        cpu = service.cpu() - cpu
        if status != 200:
            out["errors"] += 1
            out["statuses"].append(status)
            out.setdefault("error", str(answer)[:300])
        if i == 0:
            out["first" if first else "untimed_first"] = dt
            out["first_timings"] = answer.get("timings")
            out["answer"] = _answer_summary(answer)
            continue
        out["times"].append(dt)
        out["cpu"].append(cpu)
        out["timings"].append(answer.get("timings") or {})
    return out


def concurrent(service: Service, row: Row, bursts: int, clients: int = 16) -> dict[str, Any]:
    """bursts x (clients requests from clients threads released together): req/s over the bursts' wall time,
    errors, latencies, the service's peak RSS while they ran."""
    service.post(row)  # untimed: this size once before the bursts
    pool = [httpx.Client(timeout=600) for _ in range(clients)]
    for c in pool:  # each thread's connection open before the clock starts, as a robot keeps one
        c.get(f"{service.url}/readyz")
    latencies: list[float] = []
    statuses: list[int] = []
    walls: list[float] = []
    lock = threading.Lock()
    service.window_peak = rss_before = service.rss()
    for _ in range(bursts):
        barrier = threading.Barrier(clients + 1)

        def one(client: httpx.Client, barrier: threading.Barrier = barrier) -> None:
            barrier.wait()
            dt, status, _ = service.post(row, client)
            with lock:
                latencies.append(dt)
                statuses.append(status)

        threads = [threading.Thread(target=one, args=(c,)) for c in pool]
        for th in threads:
            th.start()
        barrier.wait()
        t = time.perf_counter()
        for th in threads:
            th.join()
        walls.append(time.perf_counter() - t)
    for c in pool:
        c.close()
    ok = sum(s == 200 for s in statuses)
    return {"bursts": bursts, "clients": clients, "walls": walls, "req_per_s": len(statuses) / sum(walls),
            "ok": ok, "errors": len(statuses) - ok, "statuses": sorted(set(statuses)),
            "latency_p50": statistics.median(latencies), "latency_max": max(latencies),
            "rss_before": rss_before, "peak_rss": service.window_peak}


def run_block(side: Side, rnd: int, rows: list[Row], repeats: int, bursts: int) -> Block:
    block = Block(side.name, rnd, list(os.getloadavg()))
    block.workload_before = [workload() for _ in range(3)]
    print(f"[{side.name} round {rnd}] load {block.load_before[0]:.2f}, workload "
          f"{statistics.median(block.workload_before) * 1e3:.0f} ms; starting {side.commit}", flush=True)
    service = Service(side)
    try:
        block.ready_s = service.ready_s
        for i, row in enumerate(rows):
            if i:  # the service idle between rows
                block.workload_during.append(workload())
            if row.concurrent:
                r = concurrent(service, row, bursts)
                print(f"  {row.key:10s} {r['req_per_s']:.2f} req/s, {r['errors']} errors, peak RSS "
                      f"{r['peak_rss'] / 2**20:.0f} MB", flush=True)
            else:
                r = sequential(service, row, repeats, first=(i == 0 and row.key == "table_mug"))
                print(f"  {row.key:10s} first {r.get('first', r.get('untimed_first', 0)):.3f} s, p50 "
                      f"{statistics.median(r['times']):.3f} s, errors {r['errors']}, {r['answer']}", flush=True)
            block.rows[row.key] = r
        block.rows["_rss_peak_block"] = {"peak_rss": service.peak_rss}
    finally:
        service.stop()
    block.workload_after = [workload() for _ in range(3)]
    return block


# --- report -----------------------------------------------------------------------------------------------------


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def summarise(blocks: list[Block], rows: list[Row]) -> tuple[float, dict[str, dict[str, Any]]]:
    """The workload reference (median over the run) and, per side, each figure raw and calibrated."""
    reference = statistics.median([w for b in blocks for w in b.workloads])
    out: dict[str, dict[str, Any]] = {}
    for side in ("old", "new"):
        mine = [b for b in blocks if b.side == side]
        s: dict[str, Any] = {}
        for row in rows:
            parts = [(b.rows[row.key], reference / b.workload) for b in mine if row.key in b.rows]
            if not parts:
                continue
            if row.concurrent:
                rps = [p["req_per_s"] for p, _ in parts]
                s[row.key] = {
                    "req_per_s": statistics.median(rps),
                    "req_per_s_cal": statistics.median(p["req_per_s"] / f for p, f in parts),
                    "errors": sum(p["errors"] for p, _ in parts),
                    "peak_rss_mb": max(p["peak_rss"] for p, _ in parts) / 2**20,
                    "latency_p50": statistics.median(p["latency_p50"] for p, _ in parts)}
                continue
            raw = [t for p, _ in parts for t in p["times"]]
            cal = [t * f for p, f in parts for t in p["times"]]
            s[row.key] = {"p50": statistics.median(raw), "p90": _pct(raw, 90), "p50_cal": statistics.median(cal),
                          "p90_cal": _pct(cal, 90), "cpu_p50": statistics.median(c for p, _ in parts for c in p["cpu"]),
                          "n": len(raw), "errors": sum(p["errors"] for p, _ in parts), "answer": parts[-1][0]["answer"]}
            firsts = [(p["first"], f) for p, f in parts if "first" in p]
            if firsts:
                s[row.key]["first"] = statistics.median(t for t, _ in firsts)
                s[row.key]["first_cal"] = statistics.median(t * f for t, f in firsts)
                s[row.key]["first_over_warm"] = statistics.median(
                    p["first"] / statistics.median(p["times"]) for p, _ in parts if "first" in p)
        s["ready_s"] = statistics.median(b.ready_s for b in mine)
        s["block_peak_rss_mb"] = max(b.rows["_rss_peak_block"]["peak_rss"] for b in mine) / 2**20
        out[side] = s
    return reference, out


def _stage_medians(blocks: list[Block], side: str, key: str) -> dict[str, float]:
    timings = [t for b in blocks if b.side == side and key in b.rows for t in b.rows[key]["timings"] if t]
    stages = list(dict.fromkeys(k for t in timings for k in t))
    return {k: statistics.median(t[k] for t in timings if k in t) for k in stages}


def table_lines(summary: dict[str, dict[str, Any]], rows: list[Row]) -> list[str]:
    old, new = summary["old"], summary["new"]
    lines = ["| row | old raw | new raw | old cal. | new cal. | old/new (cal.) | target | met? (new cal.; raw) |",
             "|---|---|---|---|---|---|---|---|"]

    def line(label: str, o: float, n: float, oc: float, nc: float, fmt: str, target: str,
             ok: Callable[[float], bool], higher_better: bool = False) -> None:
        ratio = (nc / oc) if higher_better else (oc / nc)
        met = f"{'yes' if ok(nc) else 'no'}; {'yes' if ok(n) else 'no'}"
        lines.append(f"| {label} | {o:{fmt}} | {n:{fmt}} | {oc:{fmt}} | {nc:{fmt}} | {ratio:.2f}x | {target} "
                     f"| {met} |")

    for row in rows:
        if row.key not in new or row.key not in old:
            continue
        o, n = old[row.key], new[row.key]
        if row.concurrent:
            line("16 concurrent 66k, req/s", o["req_per_s"], n["req_per_s"], o["req_per_s_cal"], n["req_per_s_cal"],
                 ".2f", ">= 8 req/s", lambda v: v >= 8.0, higher_better=True)
            lines.append(f"| 16 concurrent 66k, errors | {o['errors']} | {n['errors']} | | | | 0 "
                         f"| {'yes' if n['errors'] == 0 else 'no'} |")
            lines.append(f"| 16 concurrent 66k, peak service RSS MB | {o['peak_rss_mb']:.0f} | {n['peak_rss_mb']:.0f} "
                         f"| | | | <= 1024 | {'yes' if n['peak_rss_mb'] <= 1024 else 'no'} |")
            continue
        limit = float(row.target.split()[1])

        def within(v: float, limit: float = limit) -> bool:
            return v <= limit

        line(f"{row.label} s", o["p50"], n["p50"], o["p50_cal"], n["p50_cal"], ".3f", row.target, within)
        lines.append(f"| {row.label.replace('p50', 'p90')} s | {o['p90']:.3f} | {n['p90']:.3f} | {o['p90_cal']:.3f} "
                     f"| {n['p90_cal']:.3f} | {o['p90_cal'] / n['p90_cal']:.2f}x | | |")
        if row.key == "table_mug" and "first" in n and "first" in o:
            lines.append(f"| table_mug first request after ready s | {o['first']:.3f} | {n['first']:.3f} "
                         f"| {o['first_cal']:.3f} | {n['first_cal']:.3f} | {o['first_cal'] / n['first_cal']:.2f}x "
                         "| | |")
            fo, fn = o["first_over_warm"], n["first_over_warm"]
            lines.append(f"| table_mug first / warm p50 (same block) | {fo:.2f} | {fn:.2f} | | | | <= 1.2 "
                         f"| {'yes' if fn <= 1.2 else 'no'} |")
    return lines


def write_report(args: argparse.Namespace, command: str, sides: list[Side], blocks: list[Block], rows: list[Row],
                 notes: dict[str, Any], loads: dict[str, list[float]], started: datetime.datetime,
                 out: Path) -> None:
    reference, summary = summarise(blocks, rows)
    old_side, new_side = sides
    load = " ".join(f"{x:.2f}" for x in loads["start"]), " ".join(f"{x:.2f}" for x in loads["end"])
    md = ["# Request speed through the service, old and new code in the same run (bench/speed.py)", "",
          f"Command: `{command}`", "",
          f"{started:%Y-%m-%d %H:%M} UTC, {os.cpu_count()} cores ({platform.processor() or platform.machine()}), "
          f"load average at the start {load[0]}, at the end {load[1]}; "
          f"{'quick smoke run' if args.quick else 'full run'}: {args.rounds} round(s), {args.repeats} timed "
          "requests per row and block after one untimed (table_mug's: the timed first request after ready), "
          f"{args.bursts} burst(s) of 16 for the concurrency row.", "",
          f"- **old**: `{old_side.commit}` ({old_side.subject}), a git worktree at {old_side.root}",
          f"- **new**: `{new_side.commit}` ({new_side.subject}), the working tree {new_side.root}"
          + (f"; {new_side.dirty}" if new_side.dirty else ""), "",
          "Both started the same way, `python -m graspd.cli serve --host 127.0.0.1 --port PORT` from the same venv "
          "with PYTHONPATH=<side>/service:<side>/client and the default settings but "
          + ", ".join(f"{k}={v}" for k, v in SERVICE_SETTINGS.items())
          + ", one at a time (the other stopped), ready when /readyz answers 200.", "",
          f"Calibration workload: {WORKLOAD}, timed 3 times before each block (no service running), once between "
          "its rows (the service idle) and 3 times after it (stopped). Reference: the median of all "
          f"{sum(len(b.workloads) for b in blocks)} timings of the run, "
          f"**{reference * 1e3:.1f} ms**. Calibrated = raw x reference / (the block's median workload time). "
          "The verdict is given on the new side's calibrated figure, then its raw one.", "",
          *table_lines(summary, rows), "",
          "Rows:", "", *(f"- {row.label.replace(' p50', '')}: {row.what}" for row in rows), "",
          "## Blocks", "",
          "| side | round | load (1 min) before | workload before ms | between rows | after | factor (ref / block) "
          "| start-up to ready s | " + " | ".join(f"{r.key} p50 s" if not r.concurrent else f"{r.key} req/s"
                                                  for r in rows) + " |",
          "|---|---|---|---|---|---|---|---|" + "---|" * len(rows)]
    for b in blocks:
        cells = []
        for r in rows:
            x = b.rows.get(r.key)
            cells.append("" if x is None else f"{x['req_per_s']:.2f}" if r.concurrent
                         else f"{statistics.median(x['times']):.3f}")
        md.append(f"| {b.side} | {b.round} | {b.load_before[0]:.2f} | "
                  f"{' '.join(f'{w * 1e3:.0f}' for w in b.workload_before)} | "
                  f"{' '.join(f'{w * 1e3:.0f}' for w in b.workload_during)} | "
                  f"{' '.join(f'{w * 1e3:.0f}' for w in b.workload_after)} | {reference / b.workload:.3f} | "
                  f"{b.ready_s:.2f} | " + " | ".join(cells) + " |")
    md += ["", "Server CPU seconds per request (p50; the service process's user + system time during each "
           "sequential request, less sensitive to other load than wall time):", "",
           "| row | old CPU s | new CPU s | old candidates / grasps / points | new candidates / grasps / points |",
           "|---|---|---|---|---|"]
    for r in rows:
        if r.concurrent or r.key not in summary["new"] or r.key not in summary["old"]:
            continue
        o, n = summary["old"][r.key], summary["new"][r.key]

        def what(a: dict[str, Any]) -> str:
            return f"{a['num_candidates']} / {a['grasps']} / {a['num_points']}"

        md.append(f"| {r.key} | {o['cpu_p50']:.3f} | {n['cpu_p50']:.3f} | {what(o['answer'])} | "
                  f"{what(n['answer'])} |")
    if "table_mug" in summary["new"]:
        stages = {s: _stage_medians(blocks, s, "table_mug") for s in ("old", "new")}
        first = next((b.rows["table_mug"]["first_timings"] for b in blocks
                      if b.side == "new" and "table_mug" in b.rows), None) or {}
        md += ["", "## Stage timings of table_mug (the service's `timings` field, seconds)", "",
               "Medians over the warm requests of each side, and the new side's first request after ready "
               "(its first block):", "",
               "| stage | old warm | new warm | new first |", "|---|---|---|---|"]
        for k in dict.fromkeys([*stages["new"], *stages["old"]]):
            o, n, f = stages["old"].get(k), stages["new"].get(k), first.get(k)
            md.append(f"| {k} | {'' if o is None else f'{o:.4f}'} | {'' if n is None else f'{n:.4f}'} | "
                      f"{'' if f is None else f'{f:.4f}'} |")
    md += ["", f"Peak service RSS over whole blocks: old {summary['old']['block_peak_rss_mb']:.0f} MB, new "
           f"{summary['new']['block_peak_rss_mb']:.0f} MB (sampled every 20 ms, all rows included).",
           ""]
    out.with_suffix(".md").write_text("\n".join(md))
    data = {"command": command, "date_utc": f"{started:%Y-%m-%d %H:%M}", "cores": os.cpu_count(),
            "load_start": loads["start"], "load_end": loads["end"], "quick": args.quick, "rounds": args.rounds,
            "repeats": args.repeats, "bursts": args.bursts,
            "sides": {s.name: {"commit": s.commit, "subject": s.subject, "root": str(s.root), "dirty": s.dirty}
                      for s in sides},
            "settings": SERVICE_SETTINGS, "workload": WORKLOAD, "workload_reference_s": reference,
            "inputs": {r.key: r.what for r in rows} | {"notes": notes}, "summary": summary,
            "stage_timings_table_mug": {s: _stage_medians(blocks, s, "table_mug") for s in ("old", "new")},
            "blocks": [b.__dict__ | {"workload_median": b.workload, "factor": reference / b.workload}
                       for b in blocks]}
    out.with_suffix(".json").write_text(json.dumps(data, indent=1, default=float) + "\n")
    print("\n".join(table_lines(summary, rows)))
    print(f"wrote {out.with_suffix('.md')} and .json")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default=DEFAULT_BASE, help="the baseline commit (a worktree at /tmp/speed-base)")
    ap.add_argument("--quick", action="store_true", help="a smoke run: 1 round, 3 repeats, 1 burst, no 5M row")
    ap.add_argument("--rounds", type=int, default=2, help="old/new blocks per side, alternating old-new, new-old")
    ap.add_argument("--repeats", type=int, default=10, help="timed requests per row and block")
    ap.add_argument("--bursts", type=int, default=3, help="bursts of 16 concurrent requests per block")
    ap.add_argument("--rows", default="table_mug,kinect,scan1m,scan5m,c16")
    ap.add_argument("--out", default=str(RESULTS / "speed"), help="output path without suffix (.md and .json)")
    args = ap.parse_args()
    wanted = args.rows.split(",")
    if args.quick:
        args.rounds, args.repeats, args.bursts = 1, 3, 1
        wanted = [w for w in wanted if w != "scan5m"]
    command = "PYTHONPATH=service:client:lab .venv/bin/python bench/speed.py " + " ".join(
        shlex.quote(a) for a in sys.argv[1:])
    started = datetime.datetime.now(datetime.UTC)
    loads = {"start": list(os.getloadavg())}
    sides = [base_side(args.base), current_side()]
    print(f"old {sides[0].commit} at {sides[0].root}; new {sides[1].commit} {sides[1].dirty}", flush=True)
    rows, notes = make_rows(wanted)
    print(f"inputs ready: {', '.join(f'{r.key} {len(r.body) / 1e6:.1f} MB' for r in rows)}", flush=True)
    blocks = []
    for rnd in range(args.rounds):
        for side in (sides if rnd % 2 == 0 else sides[::-1]):
            blocks.append(run_block(side, rnd, rows, args.repeats, args.bursts))
    loads["end"] = list(os.getloadavg())
    write_report(args, command, sides, blocks, rows, notes, loads, started, Path(args.out))


if __name__ == "__main__":
    main()
