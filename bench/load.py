"""Load test: drive a running graspd server over HTTP and Zenoh from this separate process.

Prints, per transport and concurrency: requests, 503s, errors, p50/p95/p99 latency, throughput and the
server's RSS before/after; then the transport overhead (round trip minus in-process detection of the
same cloud with the same options, and minus the server's own detection of the request) and the RSS growth
over a fixed number of requests.  Writes what it prints, with the command and the machine load, to
<results>/load.md and a latency CDF to <results>/load_latency.png (default bench/results/).

  PYTHONPATH=service:client .venv/bin/python bench/load.py                  # spawns a server
  PYTHONPATH=service:client .venv/bin/python bench/load.py --url http://host:8000 --zenoh tcp/host:7447 --pid N
  # 16 concurrent 66k-point requests with 300 samples over HTTP (req/s, errors, peak server RSS)
  PYTHONPATH=service:client .venv/bin/python bench/load.py --transports http --points 66000 --num-samples 300 \
      --concurrency 16 --duration 30 --overhead-pairs 0 --tag c16-66k-300
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


@dataclass
class Phase:
    transport: str
    concurrency: int
    latencies: list[float] = field(default_factory=list)  # s, successful requests
    server_detect: list[float] = field(default_factory=list)  # s, pipeline stages only (server side)
    busy: int = 0  # 503 answers (backpressure, not errors)
    errors: int = 0  # 5xx other than 503, 4xx, transport failures
    error_samples: list[str] = field(default_factory=list)
    wall: float = 0.0
    rss_before: float = 0.0
    rss_after: float = 0.0
    rss_peak: float = 0.0  # the largest server RSS sampled during the phase (MB)

    def record_error(self, text: str) -> None:
        self.errors += 1
        if len(self.error_samples) < 3:
            self.error_samples.append(text[:200])


PIPELINE = ("preprocess", "scene", "sample", "encode", "score", "select", "crops")


def detect_seconds(body: dict[str, Any]) -> float:
    """The server's own detection time (s): the detector's wall time, else the sum of its stages."""
    t = body["timings"]
    return float(t["detect"]) if "detect" in t else float(sum(t.get(k, 0.0) for k in PIPELINE))


def make_cloud(num_points: int, seed: int) -> Any:
    """A rendered cluttered tabletop (two cameras, depth noise) subsampled to num_points."""
    from graspd_lab.world.scenes import cluttered_tabletop, subsample

    return subsample(cluttered_tabletop(num_objects=8, seed=seed), num_points, seed=seed)


def rss_mb(pid: int | None) -> float:
    if pid is None:
        return float("nan")
    import psutil

    return float(psutil.Process(pid).memory_info().rss) / 2**20


def spawn_server(port: int, zenoh_endpoint: str, workers: int, queue: int, log: Path) -> subprocess.Popen[bytes]:
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'service'}:{ROOT / 'client'}", "GRASPD_LOG_LEVEL": "WARNING",
           "GRASPD_QUEUE_SIZE": str(queue), "GRASPD_ZENOH_STREAM": "false"}
    cmd = [sys.executable, "-m", "graspd.server.cli", "serve", "--port", str(port), "--zenoh-listen", zenoh_endpoint]
    if workers:
        cmd += ["--workers", str(workers)]
    return subprocess.Popen(cmd, env=env, stdout=log.open("wb"), stderr=subprocess.STDOUT)


def wait_ready(url: str, proc: subprocess.Popen[bytes] | None, timeout: float = 120.0) -> dict[str, Any]:
    import httpx

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc is not None and proc.poll() is not None:
            raise SystemExit(f"server exited with {proc.returncode}")
        try:
            r = httpx.get(f"{url}/readyz", timeout=2)
            if r.status_code == 200:
                return dict(r.json())
        except httpx.HTTPError:
            pass
        time.sleep(0.25)
    raise SystemExit(f"server at {url} not ready after {timeout} s")


def http_worker(url: str, payload: bytes, phase: Phase, stop_at: float, lock: threading.Lock,
                budget: list[int] | None) -> None:
    import httpx

    with httpx.Client(base_url=url, timeout=300) as client:
        while time.perf_counter() < stop_at:
            if budget is not None:
                with lock:
                    if budget[0] <= 0:
                        return
                    budget[0] -= 1
            t0 = time.perf_counter()
            try:
                r = client.post("/detect", content=payload, headers={"Content-Type": "application/json"})
                body = r.json() if r.status_code == 200 else None
            except (httpx.HTTPError, ValueError) as exc:
                with lock:
                    phase.record_error(repr(exc))
                continue
            dt = time.perf_counter() - t0
            with lock:
                if r.status_code == 200 and body is not None:
                    phase.latencies.append(dt)
                    phase.server_detect.append(detect_seconds(body))
                elif r.status_code == 503:
                    phase.busy += 1
                else:
                    phase.record_error(f"HTTP {r.status_code}: {r.text}")
            if r.status_code == 503:
                time.sleep(float(r.headers.get("retry-after", "1")) * 0.1)


def zenoh_worker(session: Any, key: str, payload: bytes, phase: Phase, stop_at: float, lock: threading.Lock,
                 budget: list[int] | None) -> None:
    while time.perf_counter() < stop_at:
        if budget is not None:
            with lock:
                if budget[0] <= 0:
                    return
                budget[0] -= 1
        t0 = time.perf_counter()
        replies = list(session.get(key, payload=payload, timeout=300))
        reply = replies[0] if replies else None
        ok_body = json.loads(reply.ok.payload.to_bytes()) if reply is not None and reply.ok is not None else None
        dt = time.perf_counter() - t0
        with lock:
            if ok_body is not None:
                phase.latencies.append(dt)
                phase.server_detect.append(detect_seconds(ok_body))
            elif reply is None:
                phase.record_error("no zenoh reply")
            else:
                err = json.loads(reply.err.payload.to_bytes())
                if err.get("status") == 503:
                    phase.busy += 1
                else:
                    phase.record_error(str(err))
        if ok_body is None and replies:
            time.sleep(0.1)


def run_phase(transport: str, concurrency: int, duration: float, payload: bytes, url: str, session: Any,
              key: str, pid: int | None, max_requests: int | None = None) -> Phase:
    phase = Phase(transport, concurrency)
    lock = threading.Lock()
    budget = [max_requests] if max_requests is not None else None
    phase.rss_before = rss_mb(pid)
    stop_at = time.perf_counter() + duration
    if transport == "http":
        threads = [threading.Thread(target=http_worker, args=(url, payload, phase, stop_at, lock, budget))
                   for _ in range(concurrency)]
    else:
        threads = [threading.Thread(target=zenoh_worker, args=(session, key, payload, phase, stop_at, lock, budget))
                   for _ in range(concurrency)]
    done = threading.Event()

    def sample_rss() -> None:  # the server's peak RSS during the phase, every 0.1 s
        while not done.wait(0.1):
            phase.rss_peak = max(phase.rss_peak, rss_mb(pid))

    sampler = threading.Thread(target=sample_rss, daemon=True) if pid is not None else None
    if sampler is not None:
        sampler.start()
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    phase.wall = time.perf_counter() - t0
    done.set()
    if sampler is not None:
        sampler.join()
    phase.rss_after = rss_mb(pid)
    phase.rss_peak = max(phase.rss_peak, phase.rss_before, phase.rss_after)
    return phase


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) * 1000 if values else float("nan")


def print_phases(phases: list[Phase]) -> None:
    print(f"{'transport':9} {'conc':>4} {'ok':>6} {'503':>5} {'err':>4} {'err%':>6} {'p50 ms':>8} {'p95 ms':>8} "
          f"{'p99 ms':>8} {'req/s':>7} {'RSS MB before->after':>22} {'peak MB':>8}")
    for p in phases:
        n = len(p.latencies) + p.busy + p.errors
        print(f"{p.transport:9} {p.concurrency:>4} {len(p.latencies):>6} {p.busy:>5} {p.errors:>4} "
              f"{100 * p.errors / max(n, 1):>6.2f} {pct(p.latencies, 50):>8.1f} {pct(p.latencies, 95):>8.1f} "
              f"{pct(p.latencies, 99):>8.1f} {len(p.latencies) / p.wall:>7.2f} "
              f"{p.rss_before:>10.1f} -> {p.rss_after:<9.1f} {p.rss_peak:>8.1f}")
        for e in p.error_samples:
            print(f"    error: {e}")


def plot(phases: list[Phase], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for p in phases:
        if p.latencies:
            x = np.sort(np.array(p.latencies) * 1000)
            ax.plot(x, np.arange(1, len(x) + 1) / len(x), label=f"{p.transport} c={p.concurrency}",
                    linestyle="-" if p.transport == "http" else "--")
    ax.set_xscale("log")
    ax.set_xlabel("round-trip latency (ms)")
    ax.set_ylabel("fraction of requests")
    ax.set_title("graspd load test: latency CDF per transport and concurrency")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", help="a running server (default: spawn one)")
    ap.add_argument("--zenoh", help="its Zenoh endpoint, e.g. tcp/127.0.0.1:7447")
    ap.add_argument("--pid", type=int, help="server process id for RSS (spawned: known)")
    ap.add_argument("--points", type=int, default=66_000)
    ap.add_argument("--num-samples", type=int, default=200, help="samples per request")
    ap.add_argument("--concurrency", default="1,4,16")
    ap.add_argument("--duration", type=float, default=20.0, help="seconds per phase")
    ap.add_argument("--soak", type=float, default=0.0, help="extra HTTP phase at the top concurrency (s)")
    ap.add_argument("--rss-requests", type=int, default=0, help="HTTP requests for the RSS-growth check")
    ap.add_argument("--rss-num-samples", type=int, default=50, help="samples per request in the RSS check")
    ap.add_argument("--transports", default="http,zenoh")
    ap.add_argument("--overhead-pairs", type=int, default=20, help="in-process/round-trip pairs per transport")
    ap.add_argument("--settle", type=float, default=0.2, help="pause (s) between the in-process detection and "
                    "the round trip of a pair")
    ap.add_argument("--workers", type=int, default=0, help="spawned server's detect workers (0: cores)")
    ap.add_argument("--queue", type=int, default=32, help="spawned server's queue size")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out", default="out/load", help="server log")
    ap.add_argument("--results", default=str(ROOT / "bench" / "results"),
                    help="where load.md (this output, the command, the machine load) and load_latency.png go")
    ap.add_argument("--tag", help="name the results load-TAG.md and load-TAG_latency.png (default load.md)")
    args = ap.parse_args(argv)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = Path(args.results)
    results.mkdir(parents=True, exist_ok=True)
    report = Tee(sys.stdout)
    sys.stdout = report
    try:
        return run(args, out, results)
    finally:
        sys.stdout = report.stream
        command = " ".join(["python", "bench/load.py", *(sys.argv[1:] if argv is None else argv)])
        load = " ".join(f"{x:.2f}" for x in os.getloadavg())
        name = f"load-{args.tag}" if args.tag else "load"
        (results / f"{name}.md").write_text(
            f"# bench/load.py\n\n`{command}`, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
            f"{os.cpu_count()} cores, load average {load} at the end\n\n```\n{report.text()}```\n")


class Tee:
    """A stdout that also keeps what was written (for the results file)."""

    def __init__(self, stream: Any) -> None:
        self.stream = stream
        self.parts: list[str] = []

    def write(self, text: str) -> int:
        self.parts.append(text)
        return int(self.stream.write(text))

    def flush(self) -> None:
        self.stream.flush()

    def text(self) -> str:
        return "".join(self.parts)


def print_overhead(args: argparse.Namespace, transports: list[str], detector: Any, vc: Any, detect_params: Any,
                   payload: bytes, url: str, session: Any, key: str) -> None:
    """Transport overhead: pairs of an in-process detection of the same request, then one round trip."""
    print(f"\n== transport overhead: {args.overhead_pairs} pairs per transport, each an in-process detection of "
          f"the same cloud in this process then one round trip (target p50 <= 30 ms) ==")
    print("  RTT-inproc: minus this process's detection (another process: detection speed differs too); "
          "RTT-server detect: minus the server's own detection of that request (transport and service only)")
    print(f"{'transport':9} {'RTT p50':>9} {'in-proc p50':>12} {'RTT-inproc p50':>15} {'paired p50':>11} "
          f"{'RTT-server detect p50':>22}")
    for transport in transports:
        rtts, inprocs, server = [], [], []
        for _ in range(args.overhead_pairs):
            t0 = time.perf_counter()
            detector.detect(vc, detect_params)
            inprocs.append(time.perf_counter() - t0)
            time.sleep(args.settle)  # let this process's compute threads go idle before the round trip
            one = run_phase(transport, 1, 1e9, payload, url, session, key, None, max_requests=1)
            if one.latencies:
                rtts.append(one.latencies[0])
                server.append(one.server_detect[0])
            else:
                rtts.append(float("nan"))
                server.append(float("nan"))
        paired = [r - i for r, i in zip(rtts, inprocs, strict=True)]
        own = [r - d for r, d in zip(rtts, server, strict=True)]
        print(f"{transport:9} {pct(rtts, 50):>9.1f} {pct(inprocs, 50):>12.1f} "
              f"{pct(rtts, 50) - pct(inprocs, 50):>15.1f} {pct(paired, 50):>11.1f} {pct(own, 50):>22.1f}")


def run(args: argparse.Namespace, out: Path, results: Path) -> int:
    """The load phases and the overhead and RSS checks against a spawned or given server."""
    print(f"load average at the start: {' '.join(f'{x:.2f}' for x in os.getloadavg())} ({os.cpu_count()} cores)")
    from graspd_client import build_detect_request

    t = time.perf_counter()
    cloud = make_cloud(args.points, args.seed)
    body = build_detect_request(cloud.points, cloud.viewpoints, cloud.camera_source, num_samples=args.num_samples)
    payload = json.dumps(body).encode()
    print(f"cloud: rendered tabletop, {len(cloud)} points, {cloud.num_cameras} cameras; "
          f"request {len(payload) / 1e6:.2f} MB JSON; num_samples {args.num_samples} "
          f"({time.perf_counter() - t:.1f} s to make)")

    proc = None
    url, zenoh_ep, pid = args.url, args.zenoh, args.pid
    if url is None:
        from graspd.server.runner import free_port

        port, zport = free_port(), free_port()
        url, zenoh_ep = f"http://127.0.0.1:{port}", f"tcp/127.0.0.1:{zport}"
        proc = spawn_server(port, zenoh_ep, args.workers, args.queue, out / "server.log")
        pid = proc.pid
    try:
        ready = wait_ready(url, proc)
        print(f"server: {url} zenoh {zenoh_ep} pid {pid}; workers {ready['workers']}, queue capacity "
              f"{ready['queue_capacity']}, models {ready['models']} (scoring {ready['scoring']})")
        session = None
        key = "graspd/detect"
        transports = args.transports.split(",")
        if "zenoh" in transports:
            import zenoh

            from graspd_client.zenoh_client import zenoh_config

            session = zenoh.open(zenoh_config(connect=[zenoh_ep]))
            time.sleep(0.5)

        # in-process detection of the same cloud with the same options (this process, no transport)
        from graspd.core.cloud import ViewpointCloud
        from graspd.server.requests import parse_request
        from graspd.server.services.registry import ModelRegistry
        from graspd.server.settings import Settings

        registry = ModelRegistry.load(Settings().resolved_models_dir())
        req = parse_request(payload)
        detector = registry.detector(registry.default)
        vc = ViewpointCloud(points=req.cloud.points, viewpoints=np.asarray(req.cloud.viewpoints, np.float32),
                            camera_source=(np.zeros(0, np.int32) if req.cloud.camera_source is None
                                           else req.cloud.camera_source))
        from graspd.server.services.mapping import detection_inputs

        detect_params = detection_inputs(req).params
        detector.detect(vc, detect_params)  # warm caches
        print(f"in-process detector ready (model {registry.default})")

        # warm the server (first request imports and allocates)
        run_phase("http", 1, 60, payload, url, session, key, pid, max_requests=2)
        rss_start = rss_mb(pid)
        phases: list[Phase] = []
        for transport in transports:
            for c in [int(x) for x in args.concurrency.split(",")]:
                phases.append(run_phase(transport, c, args.duration, payload, url, session, key, pid))
                print_phases(phases[-1:])
        if args.soak:
            top = max(int(x) for x in args.concurrency.split(","))
            soak = run_phase("http", top, args.soak, payload, url, session, key, pid)
            soak.transport = "http-soak"
            phases.append(soak)
        print("\n== load ==")
        print_phases(phases)
        latency_png = results / (f"load-{args.tag}_latency.png" if args.tag else "load_latency.png")
        plot(phases, latency_png)

        if args.overhead_pairs:
            print_overhead(args, transports, detector, vc, detect_params, payload, url, session, key)
        if args.rss_requests:
            top = max(int(x) for x in args.concurrency.split(","))
            light = json.dumps({**body, "num_samples": args.rss_num_samples}).encode()
            rss = run_phase("http", top, 1e9, light, url, session, key, pid, max_requests=args.rss_requests)
            n = len(rss.latencies) + rss.busy + rss.errors
            print(f"\n== RSS over {n} HTTP requests at concurrency {top}, same cloud, num_samples "
                  f"{args.rss_num_samples} (target growth < 50 MB) ==")
            print(f"RSS {rss.rss_before:.1f} MB -> {rss.rss_after:.1f} MB: growth "
                  f"{rss.rss_after - rss.rss_before:+.1f} MB; {rss.errors} errors, {rss.busy} 503s, "
                  f"p50 {pct(rss.latencies, 50):.1f} ms")
            for e in rss.error_samples:
                print(f"    error: {e}")
            phases.append(rss)
        errors = sum(p.errors for p in phases)
        total = sum(len(p.latencies) + p.busy + p.errors for p in phases)
        print(f"server RSS over the whole run ({total} requests after warm-up): {rss_start:.1f} -> "
              f"{rss_mb(pid):.1f} MB, peak {max((p.rss_peak for p in phases), default=float('nan')):.1f} MB "
              "(sampled every 0.1 s)")
        print(f"\ntotal errors {errors}; 503s {sum(p.busy for p in phases)}; "
              f"latency CDF: {latency_png}")
        if session is not None:
            session.close()
        return 0 if errors == 0 else 1
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(timeout=60)


if __name__ == "__main__":
    raise SystemExit(main())
