"""Big clouds under load: admission by cost, measured from outside.

Starts the real service (`graspd serve` from --service-root's sources, a subprocess on a free port, a token,
Zenoh off, default settings otherwise; a fresh one per load) and has 8 clients send 16 requests in all (2 each,
back to back; a 503's Retry-After is waited out before the client's next request, a refused request is not sent
again) of big clouds as binary PCDs, num_samples=300, the loads one after the other:

- volumetric: 5M points of random blobs (40 Gaussian blobs of 2-6 cm in a 60 x 60 x 30 cm box 70 cm from the
  camera), which keep about half their points after 3 mm voxelisation (~2.4M occupied voxels);
- tabletop: a 5M-point honest organised scan (a depth image ray-cast from one camera: a table with boxes,
  cylinders and spheres on it, 0.5 mm depth noise), which keeps ~0.13M voxels;
- volumetric 1M: the blobs with 1M points (~0.8M voxels): volumes the server can finish within the deadline.

For each load: the statuses and times, the slowest answer (s), whether each 503 carried Retry-After, the 4xx
fields, the peak RSS of the service process (psutil, every 2 ms) and /healthz latencies (every 100 ms on a fresh
connection from another process while the load runs; p50, p99).  Targets: every answer within 60 s, no 504, at
least half 200, peak RSS <= 4 GB, /healthz p99 <= 1 s.  Puts a section into bench/results/big-clouds.md (--label
names it, e.g. before or after a change; a section of the same label is replaced) with the command, the commit
and the machine's load.

  PYTHONPATH=service:client .venv/bin/python bench/big_clouds.py --label after [--service-root DIR] [--loads ...]
"""

from __future__ import annotations

import argparse
import datetime
import json
import multiprocessing
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hostile import RssPeak, free_port, pcd  # noqa: E402  (the bench folder's own helpers)

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "big-clouds-bench-" + os.urandom(6).hex()
AUTH = {"Authorization": f"Bearer {TOKEN}"}
GB = float(1 << 30)
#: The targets: every answer within ANSWER_S, peak RSS within RSS_GB, /healthz p99 within HEALTH_P99_S.
ANSWER_S, RSS_GB, HEALTH_P99_S = 60.0, 4.0, 1.0


def volumetric_blobs(points: int, seed: int = 0) -> np.ndarray:
    """points (N,3 float32, m, camera frame, the camera at the origin looking along +z) in 40 Gaussian blobs of
    2-6 cm sigma, centred in a 60 x 60 x 30 cm box 70 cm away: a volume, not a surface, so voxelisation keeps
    about half of 5M points."""
    rng = np.random.default_rng(seed)
    k = 40
    centres = rng.uniform(-0.5, 0.5, (k, 3)) * np.array([0.6, 0.6, 0.3]) + [0.0, 0.0, 0.7]
    sigma = rng.uniform(0.02, 0.06, k)
    label = rng.integers(0, k, points)
    out = np.empty((points, 3), np.float32)
    step = 1_000_000
    for a in range(0, points, step):  # in blocks: no (N,3) float64 temporaries for 5M points
        lab = label[a:a + step]
        out[a:a + step] = centres[lab] + rng.normal(size=(len(lab), 3)) * sigma[lab, None]
    return out


@dataclass(frozen=True)
class Shape:
    """A box (half extents), an upright cylinder (radius, half height) or a sphere (radius) resting on the table."""

    kind: str
    centre: tuple[float, float, float]
    size: tuple[float, ...]


def tabletop_shapes(seed: int, table_z: float) -> list[Shape]:
    """Twelve objects of 4-16 cm on the table plane z = table_z (the camera looks down +z at it)."""
    rng = np.random.default_rng(seed)
    shapes = []
    for i in range(12):
        x, y = rng.uniform(-0.35, 0.35), rng.uniform(-0.25, 0.25)
        kind = ("box", "cylinder", "sphere")[i % 3]
        if kind == "box":
            half = tuple(float(v) for v in rng.uniform(0.02, 0.08, 3))
            shapes.append(Shape(kind, (x, y, table_z - half[2]), half))
        elif kind == "cylinder":
            r, h = float(rng.uniform(0.02, 0.05)), float(rng.uniform(0.04, 0.1))
            shapes.append(Shape(kind, (x, y, table_z - h), (r, h)))
        else:
            r = float(rng.uniform(0.03, 0.06))
            shapes.append(Shape(kind, (x, y, table_z - r), (r,)))
    return shapes


def _hit(shape: Shape, d: np.ndarray) -> np.ndarray:
    """Distance along unit rays d (N,3) from the origin to shape (inf where missed)."""
    c = np.asarray(shape.centre)
    t = np.full(len(d), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        if shape.kind == "sphere":
            b = d @ c
            disc = b * b - (c @ c - shape.size[0] ** 2)
            near = b - np.sqrt(np.maximum(disc, 0.0))
            return np.where((disc >= 0) & (near > 0), near, t)
        if shape.kind == "box":
            lo, hi = c - np.asarray(shape.size), c + np.asarray(shape.size)
            t1, t2 = lo / d, hi / d
            enter = np.nanmax(np.minimum(t1, t2), axis=1)
            leave = np.nanmin(np.maximum(t1, t2), axis=1)
            return np.where((enter <= leave) & (enter > 0), enter, t)
        r, h = shape.size  # upright cylinder: side wall (x, y) and top cap (z = centre z - h)
        dx, dy = d[:, 0], d[:, 1]
        a = dx * dx + dy * dy
        b = dx * c[0] + dy * c[1]
        disc = b * b - a * (c[0] ** 2 + c[1] ** 2 - r * r)
        side = (b - np.sqrt(np.maximum(disc, 0.0))) / a
        z = side * d[:, 2]
        side = np.where((disc >= 0) & (z >= c[2] - h) & (z <= c[2] + h), side, np.inf)
        top = (c[2] - h) / d[:, 2]
        px, py = top * dx - c[0], top * dy - c[1]
        top = np.where(px * px + py * py <= r * r, top, np.inf)
        return np.minimum(side, top)


def tabletop_scan(points: int, seed: int = 0, noise: float = 0.0005) -> np.ndarray:
    """An organised depth scan of about `points` points (N,3 float32, m, camera frame): one camera at the origin
    looking down +z at a table 80 cm away (60 x 48 degrees field of view: the table fills the image) with twelve
    boxes, cylinders and spheres on it; each pixel's ray hits the nearest surface, then Gaussian noise of `noise`
    m along the ray (a good depth camera's).  Surfaces only: voxelisation keeps ~0.1-0.2M of 5M points."""
    table_z = 0.8
    width = int(round(np.sqrt(points * 1.25)))
    height = int(np.ceil(points / width))
    u = np.tan(np.radians(30.0)) * np.linspace(-1, 1, width)
    v = np.tan(np.radians(24.0)) * np.linspace(-1, 1, height)
    shapes = tabletop_shapes(seed, table_z)
    rng = np.random.default_rng(seed + 1)
    out = np.empty((height * width, 3), np.float32)
    rows = max(1, 400_000 // width)
    for r0 in range(0, height, rows):  # a block of image rows at a time
        uu, vv = np.meshgrid(u, v[r0:r0 + rows])
        d = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], axis=1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        t = table_z / d[:, 2]
        for shape in shapes:
            t = np.minimum(t, _hit(shape, d))
        t += rng.normal(0.0, noise, len(t))
        out[r0 * width:r0 * width + len(t)] = d * t[:, None]
    return out[:points]


@dataclass
class Answer:
    """One request's answer: HTTP status (-1: no answer), seconds, Retry-After (503), field (4xx), error text."""

    status: int
    seconds: float
    retry_after: str | None = None
    field: str | None = None
    error: str = ""


@dataclass
class LoadResult:
    name: str
    voxels: int
    answers: list[Answer] = field(default_factory=list)
    health: list[float] = field(default_factory=list)
    peak_rss: int = 0
    wall: float = 0.0


def run_load(url: str, pid: int, name: str, body: bytes, clients: int, per_client: int, num_samples: int
             ) -> LoadResult:
    """`clients` threads each sending `per_client` requests of body back to back (a 503's Retry-After is waited
    out before the client's next request; a refused request is not sent again); /healthz every 100 ms on a fresh
    connection meanwhile, from another process; the server's peak RSS."""
    result = LoadResult(name, 0)
    lock = threading.Lock()

    def client() -> None:
        with httpx.Client(base_url=url, timeout=180) as c:
            for _ in range(per_client):
                t0 = time.perf_counter()
                try:
                    r = c.post(f"/detect?num_samples={num_samples}&viewpoint=0,0,0", content=body,
                               headers={"Content-Type": "application/octet-stream", **AUTH})
                    info = r.json() if r.headers.get("content-type", "").startswith("application/json") else {}
                    answer = Answer(r.status_code, time.perf_counter() - t0, r.headers.get("retry-after"),
                                    info.get("field") if r.status_code >= 400 else None,
                                    str(info.get("error", ""))[:200] if r.status_code >= 400 else "")
                except httpx.HTTPError as exc:
                    answer = Answer(-1, time.perf_counter() - t0, error=type(exc).__name__)
                with lock:
                    result.answers.append(answer)
                if answer.status == 503 and answer.retry_after:
                    time.sleep(float(answer.retry_after))

    rss = RssPeak(pid)
    stop = multiprocessing.Event()
    latencies: multiprocessing.Queue[list[float]] = multiprocessing.Queue()
    prober = multiprocessing.Process(target=probe_health, args=(url, stop, latencies), daemon=True)
    prober.start()  # its own process: the clients' uploads here do not delay it
    t0 = time.perf_counter()
    threads = [threading.Thread(target=client, daemon=True) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    result.wall = time.perf_counter() - t0
    stop.set()
    result.health = latencies.get(timeout=30)
    prober.join(timeout=30)
    result.peak_rss = rss.peak()
    rss.close()
    return result


def probe_health(url: str, stop: Any, out: Any) -> None:
    """GET /healthz on a fresh connection every 100 ms until stop is set; puts the latencies (s; inf: failed)."""
    latencies: list[float] = []
    while not stop.is_set():
        h0 = time.perf_counter()
        try:
            ok = httpx.get(f"{url}/healthz", timeout=10).status_code == 200
        except httpx.HTTPError:
            ok = False
        latencies.append(time.perf_counter() - h0 if ok else float("inf"))
        stop.wait(0.1)
    out.put(latencies)


def start_server(service_root: Path, work: Path) -> tuple[subprocess.Popen[bytes], str]:
    """`graspd serve` from service_root's sources on a free port, with the token, Zenoh off and default settings
    otherwise; returns the process and its URL once /readyz answers 200."""
    port = free_port()
    env = {**os.environ, "PYTHONPATH": f"{service_root / 'service'}:{service_root / 'client'}",
           "GRASPD_TOKEN": TOKEN, "XDG_DATA_HOME": str(work), "GRASPD_ZENOH_ENABLED": "false",
           "GRASPD_LOG_LEVEL": "WARNING"}
    log = open(work / "server.log", "wb")  # noqa: SIM115  (the server's; closed when it exits)
    server = subprocess.Popen([sys.executable, "-m", "graspd.server.cli", "serve", "--port", str(port)], env=env,
                              stdout=log, stderr=log, cwd=service_root)
    url = f"http://127.0.0.1:{port}"
    give_up = time.monotonic() + 300
    while time.monotonic() < give_up and server.poll() is None:
        try:
            if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                return server, url
        except httpx.TransportError:
            pass
        time.sleep(0.5)
    server.kill()
    raise SystemExit(f"the server did not become ready (log: {work / 'server.log'})")


def p(values: list[float], q: float) -> float:
    finite = [v for v in values if np.isfinite(v)]
    return float(np.percentile(finite, q)) if finite else float("inf")


def summary(r: LoadResult, clients: int) -> tuple[list[str], dict[str, bool]]:
    """Table rows of one load and its targets (met or not)."""
    statuses: dict[int, int] = {}
    for a in r.answers:
        statuses[a.status] = statuses.get(a.status, 0) + 1
    slowest = max((a.seconds for a in r.answers), default=0.0)
    busy = [a for a in r.answers if a.status == 503]
    with_retry = sum(a.retry_after is not None for a in busy)
    fields = sorted({f"{a.status} {a.field}" for a in r.answers if 400 <= a.status < 500})
    ok = statuses.get(200, 0)
    times = {s: sorted(a.seconds for a in r.answers if a.status == s) for s in statuses}
    spread = "; ".join(f"{s}: {t[0]:.1f}-{t[-1]:.1f} s" for s, t in sorted(times.items()))
    failed = sum(not np.isfinite(h) for h in r.health)
    met = {f"every answer within {ANSWER_S:g} s": all(a.status > 0 and a.seconds <= ANSWER_S for a in r.answers),
           "no 504 (no 5xx but 503)": not any(a.status >= 500 and a.status != 503 or a.status < 0
                                              for a in r.answers),
           "at least half 200": 2 * ok >= len(r.answers),
           "every 503 with Retry-After": with_retry == len(busy),
           f"peak RSS <= {RSS_GB:g} GB": r.peak_rss <= RSS_GB * GB,
           f"/healthz p99 <= {HEALTH_P99_S:g} s": p(r.health, 99) <= HEALTH_P99_S and not failed}
    row = (f"| {r.name} | {r.voxels / 1e6:.2f}M | {clients} x {len(r.answers) // clients} | "
           f"{json.dumps({str(k): v for k, v in sorted(statuses.items())})} | {spread} | {slowest:.1f} | "
           f"{with_retry}/{len(busy)} | {', '.join(fields) or '-'} | {r.peak_rss / GB:.2f} | "
           f"{1e3 * p(r.health, 50):.0f} / {1e3 * p(r.health, 99):.0f} ({failed} failed of {len(r.health)}) | "
           f"{r.wall:.0f} |")
    return [row], met


def voxels_of(points: np.ndarray) -> int:
    """Occupied 3 mm voxels of points (the detector's grid; every point is within its range window here)."""
    from graspd.core.points import voxel_groups  # noqa: PLC0415  (the bench's own checkout)

    return len(voxel_groups(points, 0.003)[1])


def write_section(out: Path, label: str, text: str) -> None:
    """Put `text` into out as the section headed `## label`, replacing one of that label, else appended."""
    head = ("# Big clouds under load: admission by cost\n\n"
            "8 clients send 16 requests in all (2 each, back to back; a 503's Retry-After is waited out before the "
            "client's next request, a refused request is not sent again) of big clouds as binary PCDs (5M points: "
            "60 MB; num_samples=300) to a fresh `graspd serve` per load (default settings: workers = cores, queue "
            "32, deadline 30 s, detection memory budget 2048 MiB; Zenoh off), one load after the other: 5M points "
            "of volumetric random blobs, a 5M-point honest tabletop scan, 1M points of the blobs "
            "(bench/big_clouds.py says how each is made).  Peak RSS: the service process, every 10 ms; /healthz: "
            "every 100 ms on a fresh connection from another process while the load runs.  "
            f"Targets: every answer within {ANSWER_S:g} s, no 504, at least half 200, peak RSS <= {RSS_GB:g} GB, "
            f"/healthz p99 <= {HEALTH_P99_S:g} s.\n")
    sections = out.read_text().split("\n## ") if out.exists() else [head]
    body = [sec for sec in sections[1:] if not sec.startswith(f"{label}:") and not sec.startswith(f"{label}\n")]
    out.write_text("\n## ".join([sections[0].rstrip("\n") + "\n", *body, text.lstrip("# ")]).rstrip("\n") + "\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--label", default="after", help="the results section's name (before, after, ...)")
    ap.add_argument("--service-root", type=Path, default=ROOT,
                    help="checkout whose service/ and client/ the server runs from (e.g. a git worktree of an "
                         "older commit); this checkout's bench makes the load")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "big-clouds.md")
    ap.add_argument("--points", type=int, default=5_000_000)
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--per-client", type=int, default=2)
    ap.add_argument("--num-samples", type=int, default=300)
    ap.add_argument("--loads", default="volumetric,tabletop,volumetric:1000000",
                    help="comma-separated loads, each volumetric or tabletop, with :points for another size than "
                         "--points")
    ap.add_argument("--note", default="", help="a line under the section's title (what the checkout is)")
    args = ap.parse_args(argv)
    root = args.service_root.resolve()
    commit = subprocess.run(["git", "-C", str(root), "log", "-1", "--format=%h %s"], capture_output=True,
                            text=True, check=False).stdout.strip()[:100]
    dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                           capture_output=True, text=True, check=False).stdout.strip()
    makers = {"volumetric": volumetric_blobs, "tabletop": tabletop_scan}
    work = Path(os.environ.get("TMPDIR", "/tmp")) / f"graspd-big-clouds-{os.getpid()}"
    work.mkdir(parents=True, exist_ok=True)
    rows = ["| load | 3 mm voxels | clients x requests | statuses | time by status | slowest (s) | 503 with "
            "Retry-After | 4xx fields | peak RSS (GB) | /healthz p50 / p99 (ms) | wall (s) |",
            "|---|---:|---|---|---|---:|---:|---|---:|---|---:|"]
    verdicts = []
    notes = []
    for load in args.loads.split(","):
        kind, _, size = load.partition(":")
        count = int(size or args.points)
        name = kind if count == 5_000_000 else f"{kind} {count / 1e6:g}M"
        points = makers[kind](count)
        voxels = voxels_of(points)
        body = pcd(points, len(points))
        del points
        server, url = start_server(root, work)  # a fresh server per load: nothing learnt from the other
        try:
            result = run_load(url, server.pid, name, body, args.clients, args.per_client, args.num_samples)
        finally:
            server.terminate()
            try:
                server.wait(timeout=60)
            except subprocess.TimeoutExpired:
                server.kill()
        result.voxels = voxels
        more, met = summary(result, args.clients)
        rows += more
        print(more[0], flush=True)
        verdicts.append(f"{name}: " + "; ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in met.items()))
        examples = {}
        for a in result.answers:
            if a.status >= 400 and a.status not in examples:
                examples[a.status] = a.error
        notes += [f"- {name} {status}: \"{text}\"" for status, text in sorted(examples.items())]
    load = os.getloadavg()
    command = (f"PYTHONPATH=service:client .venv/bin/python bench/big_clouds.py --label {args.label}"
               + (f" --service-root {args.service_root}" if root != ROOT else "")
               + (f" --points {args.points}" if args.points != 5_000_000 else "")
               + (f" --loads {args.loads}" if args.loads != ap.get_default("loads") else "")
               + (f" --clients {args.clients} --per-client {args.per_client}"
                  if (args.clients, args.per_client) != (8, 2) else ""))
    text = (f"## {args.label}: {commit}{' (with uncommitted changes)' if dirty else ''}\n\n"
            + (f"{args.note}\n\n" if args.note else "") +
            f"Command: `{command}`, {datetime.date.today().isoformat()}.  Machine: {os.cpu_count()} cores, load "
            f"average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at the end (shared with other work: times are "
            "noisy).\n\n" + "\n".join(rows) + "\n\nTargets: " + ".  ".join(verdicts) + ".\n\n"
            "First answer of each refusal:\n\n" + ("\n".join(notes) or "- none") + "\n")
    write_section(args.out, args.label, text)
    print(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
