"""Reproduce Table 2 of the IJRR paper on this machine: time to generate and to encode 1k candidates.

Clouds: a cluttered tabletop of procedural objects rendered by the project's own depth-camera model
(graspd_lab.world.scenes.cluttered_tabletop: two cameras 53 degrees apart, Kinect-like noise), subsampled
uniformly to the paper's ~39k and ~66k points; 3 mm voxels, as GPD.  Also: the real table_mug.pcd
(500 samples, as in the reference C++ run), growth with cloud size (10k -> 300k points) and with the
number of samples, and peak memory.  Prints markdown tables, writes bench/results/perf.md and perf.png.

Also request latency through the service (its own process, as a robot sees it): start-up with and without
the warm-up, the first request against the warm p50, and 10k / 66k / 300k-point clouds; with --reference-gpd
a GPD C++ detect_grasps binary runs on the same cloud and samples and the ratio is printed, otherwise the
reference figures of the GPD C++ run on a quiet machine (12.8 s wall, ~770 candidates) stand.

It also offers: --scaling, the whole detection (the service's default model and cascade) against cloud size
(10k, 66k, 300k, 1M points, 500 samples) and samples (100 to 2,000 at 66k points), wall and CPU seconds with
straight-line fits (bench/results/perf-scaling.md, .png); --profile TAG, warm table_mug requests (500 samples)
through the service's engine in a child process sampled by py-spy (bench/results/profile-TAG.txt); and a GPU row
when onnxruntime offers a GPU provider ("no GPU here" otherwise).

    PYTHONPATH=service:client:lab python bench/perf.py [--quick] [--repeats 3] [--service-only | --no-service]
        [--reference-gpd BIN --reference-gpd-config CFG]
    PYTHONPATH=service:client:lab python bench/perf.py --scaling [--repeats 3]
    PYTHONPATH=service:client:lab python bench/perf.py --profile after [--profile-requests 10]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.core.progress import track
from graspd.gpd.candidates import SamplingParams, search_hands
from graspd.gpd.detector import Detection, DetectionParams, GraspDetector
from graspd.gpd.environment import Environment, EnvironmentParams, model_environment
from graspd.gpd.images import encode_images
from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.gpd.scene import Scene
from graspd.io.cloud_files import read_cloud
from graspd_lab.world.scenes import cluttered_tabletop, subsample

HAND = HandGeometry()
REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "results"
SHARED_MUG = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "table_mug.pcd"


def _median_time(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def _load_scorers() -> dict[str, object]:
    """The shipped default classifier (fast network) and the paper's LeNet, when present in models/."""
    from graspd.gpd.classifier import available_models, default_model_name, load_model

    names = [n for n in (default_model_name(), "lenet15") if n in available_models()]
    if not names:
        print("(no classifier timed: models/ holds no model)")
    return {n: load_model(n) for n in names}


def measure(cloud: ViewpointCloud, num_samples: int, repeats: int, scorers: dict | None = None,
            exclude_table: bool = True) -> dict[str, float]:
    """Per-stage times (s) on one cloud; candidate and encoding times also normalised to 1k candidates."""
    row: dict[str, float] = {"points": len(cloud)}
    t_pre, pre = _median_time(lambda: preprocess(cloud, PreprocessParams(voxel_size=0.003)), repeats)
    assert isinstance(pre, ViewpointCloud)
    row["voxelized"] = len(pre)
    t_env, env = _median_time(lambda: model_environment(pre, HAND, EnvironmentParams(), seed=0), repeats)
    row["support_found"] = float(getattr(env, "support", None) is not None)
    t_scene, scene = _median_time(lambda: Scene.build(pre, HAND), repeats)
    assert isinstance(scene, Scene)
    t_unobs, _ = _median_time(lambda: Scene.build(pre, HAND).unobserved, repeats)
    pool = env.object_mask if exclude_table and isinstance(env, Environment) else None  # as the service samples
    params = SamplingParams(num_samples=num_samples, sample_pool=pool)
    t_sample, res = _median_time(lambda: search_hands(scene, HAND, params), repeats)
    grasps, region = res  # type: ignore[misc]
    m = max(len(grasps), 1)
    t15, images = _median_time(lambda: encode_images(scene, grasps, HAND, "15", region=region), repeats)
    t3, _ = _median_time(lambda: encode_images(scene, grasps, HAND, "3", region=region), repeats)
    row.update(preprocess=t_pre, environment=t_env, scene=t_scene, unobserved=t_unobs, candidates=len(grasps),
               sample=t_sample,
               sample_per_1k=t_sample / m * 1000, encode15_per_1k=t15 / m * 1000, encode3_per_1k=t3 / m * 1000)
    for name, scorer in (scorers or {}).items():
        imgs = encode_images(scene, grasps, HAND, scorer.representation, region=region)
        t_score, _ = _median_time(lambda s=scorer, x=imgs: s.score(x), repeats)
        row[f"score_{name}_per_1k"] = t_score / m * 1000
    return row


def end_to_end(cloud: ViewpointCloud, num_samples: int, repeats: int, scorer) -> dict[str, float]:
    """Wall time of GraspDetector.detect (preprocessing and normals included) and its stage timings (s)."""
    det = GraspDetector(scorer, HAND)
    params = DetectionParams(num_samples=num_samples)
    t, res = _median_time(lambda: det.detect(cloud, params), repeats)
    assert isinstance(res, Detection)
    return {"wall": t, "candidates": res.num_candidates, **{k: v for k, v in res.timings.items() if k != "total"}}


#: The GPD C++ reference run: GPD 2.0 C++ (Eigen LeNet, 2 threads) on table_mug, 500 samples, a quiet machine.
REFERENCE = {"wall": 12.8, "candidates": 770}


def start_service(warmup: bool = True) -> tuple[subprocess.Popen[bytes], str, float]:
    """A graspd HTTP service in its own process (uvicorn, as bench/clutter.py starts it) on a free port; waits
    until /readyz says ready and returns (process, URL, seconds from spawn to ready)."""
    import httpx

    from graspd.server.runner import free_port

    port = free_port()
    env = {**os.environ, "PYTHONPATH": f"{REPO / 'service'}:{REPO / 'client'}", "GRASPD_ZENOH_ENABLED": "false",
           "GRASPD_DEADLINE_S": "300", "GRASPD_LOG_LEVEL": "WARNING", "GRASPD_WARMUP": str(warmup).lower()}
    t = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "uvicorn", "--factory", "graspd.server.app:create_app",
                             "--host", "127.0.0.1", "--port", str(port), "--log-level", "warning"], env=env)
    url = f"http://127.0.0.1:{port}"
    while time.perf_counter() - t < 300:
        if proc.poll() is not None:
            break
        try:
            if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                return proc, url, time.perf_counter() - t
        except httpx.HTTPError:
            pass
        time.sleep(0.05)
    proc.terminate()
    raise SystemExit("the graspd service did not become ready")


def request_body(cloud: ViewpointCloud, num_samples: int) -> bytes:
    """A /detect JSON body for a cloud (binary arrays, as the client sends them)."""
    from graspd_client import build_detect_request

    body = build_detect_request(cloud.points, cloud.viewpoints, cloud.camera_source, num_samples=num_samples)
    return json.dumps(body).encode()


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (s): work done, much less sensitive to other load than wall."""
    import psutil

    t = psutil.Process(pid).cpu_times()
    return float(t.user + t.system)


#: Keep-alive HTTP clients by server URL (httpx.post would build a client, its SSL context included, per request:
#: ~25 ms that no robot pays).
_CLIENTS: dict[str, Any] = {}


def post(url: str, payload: bytes, pid: int | None = None) -> tuple[float, dict]:
    """(round-trip seconds, response JSON) of one /detect over a kept-alive connection; with pid, the response
    also holds "cpu_s", the CPU seconds the server process spent meanwhile."""
    import httpx

    client = _CLIENTS.get(url)
    if client is None:  # one keep-alive client per server, made before the clock starts, as a robot keeps one
        client = _CLIENTS[url] = httpx.Client(timeout=300)
    cpu = cpu_seconds(pid) if pid is not None else 0.0
    t = time.perf_counter()
    r = client.post(f"{url}/detect", content=payload, headers={"Content-Type": "application/json"})
    dt = time.perf_counter() - t
    r.raise_for_status()
    body = r.json()
    if pid is not None:
        body["cpu_s"] = cpu_seconds(pid) - cpu
    return dt, body


def service_latency(mug: ViewpointCloud | None, big: ViewpointCloud, repeats: int, emit) -> float | None:
    """Start-up with and without the warm-up and the first request after each (table_mug, 500 samples; starts
    alternate, medians of `repeats`), the warm p50, and request latency at 10k / 66k / 300k points; returns the
    warm table_mug p50 (s)."""
    payload = request_body(mug if mug is not None else subsample(big, 100_000), 500)
    starts: dict[bool, list[float]] = {False: [], True: []}
    firsts: dict[bool, list[float]] = {False: [], True: []}
    first_cpu: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(repeats):
        for warmup in (False, True):
            proc, url, ready = start_service(warmup=warmup)
            try:
                starts[warmup].append(ready)
                dt, body = post(url, payload, proc.pid)
                firsts[warmup].append(dt)
                first_cpu[warmup].append(body["cpu_s"])
            finally:
                proc.terminate()
                proc.wait(60)
    med = {k: (statistics.median(starts[k]), statistics.median(firsts[k]), statistics.median(first_cpu[k]))
           for k in (False, True)}
    proc, url, _ = start_service(warmup=True)
    try:
        runs = [post(url, payload, proc.pid) for _ in range(max(5, 2 * repeats))]
        warm = [dt for dt, _ in runs]
        warm_p50 = statistics.median(warm)
        warm_cpu = statistics.median(b["cpu_s"] for _, b in runs)
        name = "table_mug" if mug is not None else "tabletop 100k"
        emit(f"Start-up to ready, then the first request ({name}, 500 samples), medians of {repeats} alternating "
             "starts; CPU s: the server process's CPU time during the request (robust to other load):\n")
        emit("| GRASPD_WARMUP | start-up to ready s | first request s | first / warm p50 | first request CPU s "
             "| first / warm CPU |\n|---|---|---|---|---|---|")
        for k in (False, True):
            emit(f"| {str(k).lower()} | {med[k][0]:.2f} | {med[k][1]:.3f} | {med[k][1] / warm_p50:.2f} "
                 f"| {med[k][2]:.2f} | {med[k][2] / warm_cpu:.2f} |")
        emit(f"\nWarm requests ({len(warm)}): p50 {warm_p50:.3f} s wall, {warm_cpu:.2f} CPU s; the warm-up adds "
             f"{med[True][0] - med[False][0]:.2f} s to start-up.\n")
        emit("| cloud | points | candidates | warm p50 s |\n|---|---|---|---|")
        if mug is not None:
            body = post(url, payload)[1]
            emit(f"| table_mug | {len(mug)} | {body['num_candidates']} | {warm_p50:.3f} |")
        for n in (10_000, 66_000, 300_000):
            if n > len(big):
                continue
            sized = request_body(subsample(big, n), 500)
            body = post(url, sized)[1]
            times = [post(url, sized)[0] for _ in range(max(3, repeats))]
            emit(f"| tabletop {n // 1000}k | {n} | {body['num_candidates']} | {statistics.median(times):.3f} |")
        if mug is not None:
            emit(f"\ntable_mug warm p50 {warm_p50:.3f} s through HTTP: {REFERENCE['wall'] / warm_p50:.1f}x faster "
                 f"than the reference GPD C++ figure ({REFERENCE['wall']} s wall, ~{REFERENCE['candidates']} "
                 "candidates, quiet machine).")
    finally:
        proc.terminate()
        proc.wait(60)
    return warm_p50 if mug is not None else None


def reference_gpd(binary: Path, config: Path, emit, graspd_p50: float | None) -> None:
    """Run GPD's detect_grasps on table_mug.pcd with 500 samples (a copy of config with num_samples = 500),
    print its wall time, the candidates it reports and the ratio to graspd's warm request."""
    text = config.read_text()
    text = re.sub(r"(?m)^num_samples\s*=.*$", "num_samples = 500", text)
    with tempfile.NamedTemporaryFile("w", suffix=".cfg", delete=False) as f:
        f.write(text)
    t = time.perf_counter()
    out = subprocess.run([str(binary), f.name, str(SHARED_MUG)], capture_output=True, text=True, timeout=600)
    wall = time.perf_counter() - t
    found = re.findall(r"(\d+)\s+grasp candidates", out.stdout + out.stderr)
    cands = found[0] if found else "?"
    emit(f"\nReference GPD C++ `{binary}` on table_mug.pcd, 500 samples: {wall:.2f} s wall (exit {out.returncode}), "
         f"{cands} candidates" + (f"; graspd warm request is {wall / graspd_p50:.1f}x faster" if graspd_p50 else ""))



SCALING_POINTS = (10_000, 66_000, 300_000, 1_000_000)
SCALING_SAMPLES = (100, 250, 500, 1000, 2000)


def service_detector() -> GraspDetector:
    """The detector a request naming no model gets: the default model with the cascade's first pass (as the
    service loads them, one intra-op thread each), BLAS single-threaded as in the service's engine."""
    from graspd.gpd.blas import set_blas_threads
    from graspd.gpd.classifier import DEFAULT_CASCADE_MODEL, default_models_dir
    from graspd.server.services.registry import ModelRegistry

    set_blas_threads(1)
    registry = ModelRegistry.load(default_models_dir(), cascade=DEFAULT_CASCADE_MODEL)
    return registry.detector(registry.default)


def timed_detection(detector: GraspDetector, cloud: ViewpointCloud, params: DetectionParams, repeats: int
                    ) -> dict[str, float]:
    """Median wall and CPU seconds (this process, all threads) of detector.detect over `repeats` runs after one
    unmeasured run, with the stage timings of the median run and the candidates."""
    detector.detect(cloud, params)
    runs = []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        det = detector.detect(cloud, params)
        runs.append((time.perf_counter() - t, time.process_time() - c, det))
    runs.sort(key=lambda r: r[0])
    wall, _, det = runs[len(runs) // 2]
    cpu = statistics.median(r[1] for r in runs)
    return {"wall": wall, "cpu": cpu, "candidates": det.num_candidates, "voxelized": det.num_points,
            **{k: v for k, v in det.timings.items() if k != "total"}}


def linear_fit(x: list[float], y: list[float]) -> tuple[float, float, float]:
    """Least-squares y = a + b x: (a, b, R^2)."""
    import numpy as np

    b, a = np.polyfit(np.asarray(x, float), np.asarray(y, float), 1)
    pred = a + b * np.asarray(x, float)
    ss = float(np.sum((np.asarray(y) - np.mean(y)) ** 2)) or 1.0
    return float(a), float(b), 1.0 - float(np.sum((np.asarray(y) - pred) ** 2)) / ss


def scaling(repeats: int, emit) -> None:  # noqa: ANN001 - emit prints and records a line
    """Whole detections against cloud size and samples; writes perf-scaling.md and perf-scaling.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    detector = service_detector()
    huge = cluttered_tabletop(num_objects=8, seed=7, resolution_scale=2.0, table_size=(0.6, 0.6))
    emit(f"Rendered cluttered tabletop: {len(huge)} points from two cameras (1280x960 each), subsampled; model "
         f"{getattr(detector.classifier, 'name', None)} with the cascade's first pass "
         f"{getattr(detector.prefilter, 'name', None)}; medians of {repeats} runs after one unmeasured; CPU: this "
         "process's CPU seconds (all threads).\n")
    stages = ["preprocess", "environment", "scene", "sample", "prefilter", "encode", "score", "select"]
    cols = ["points", "voxelized", "candidates", "wall", "cpu", *stages]
    point_rows = []
    for n in track([n for n in SCALING_POINTS if n <= len(huge)], "cloud sizes", "size"):
        row = timed_detection(detector, subsample(huge, n), DetectionParams(num_samples=500), repeats)
        point_rows.append({"points": n, **row})
    emit("## Whole detection against cloud size (500 samples)\n")
    emit(table(point_rows, cols))
    for x_key, unit, scale in (("points", "points sent", 1e6), ("voxelized", "points after 3 mm voxels", 1e5)):
        xs = [r[x_key] for r in point_rows]
        a, b, r2 = linear_fit(xs, [r["cpu"] for r in point_rows])
        a2, b2, r2w = linear_fit(xs, [r["wall"] for r in point_rows])
        per = "1M" if scale == 1e6 else "100k"
        emit(f"\nAgainst the {unit}: CPU s = {a:.3f} + {b * scale:.3f} x ({x_key} / {per}), R^2 {r2:.3f}; wall s = "
             f"{a2:.3f} + {b2 * scale:.3f} x ({x_key} / {per}), R^2 {r2w:.3f}")
    emit("")
    c66 = subsample(huge, 66_000)
    sample_rows = []
    for k in track(list(SCALING_SAMPLES), "sample counts", "count"):
        row = timed_detection(detector, c66, DetectionParams(num_samples=k), repeats)
        sample_rows.append({"samples": k, **row})
    emit("## Whole detection against samples (66k points)\n")
    emit(table(sample_rows, ["samples", *cols[2:]]))
    a, b, r2 = linear_fit([r["samples"] for r in sample_rows], [r["cpu"] for r in sample_rows])
    emit(f"\nCPU s = {a:.3f} + {b * 1000:.3f} x (samples / 1000), R^2 {r2:.3f}")
    a, b, r2w = linear_fit([r["samples"] for r in sample_rows], [r["wall"] for r in sample_rows])
    emit(f"wall s = {a:.3f} + {b * 1000:.3f} x (samples / 1000), R^2 {r2w:.3f}\n")

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2), dpi=110)
    for axis, rows, key, label in ((ax[0], point_rows, "voxelized", "points after 3 mm voxels (10k-1M sent)"),
                                   (ax[1], sample_rows, "samples", "samples (66k points)")):
        x = [r[key] for r in rows]
        for what, style in (("wall", "o-"), ("cpu", "s--")):
            y = [r[what] for r in rows]
            fa, fb, fr2 = linear_fit(x, y)
            line = axis.plot(x, y, style, label=f"{what} (fit R^2 {fr2:.3f})")[0]
            axis.plot([min(x), max(x)], [fa + fb * min(x), fa + fb * max(x)], ":", color=line.get_color())
        for stage in ("preprocess", "sample"):
            axis.plot(x, [r.get(stage, 0.0) for r in rows], ".-", alpha=0.6, label=f"{stage} (wall)")
        axis.set_xlabel(label)
        axis.set_ylabel("s")
        axis.legend(fontsize=8)
    ax[0].set_title("whole detection vs points (500 samples)")
    ax[1].set_title("whole detection vs samples")
    fig.tight_layout()
    fig.savefig(RESULTS / "perf-scaling.png")


def gpu_row(emit) -> None:  # noqa: ANN001
    """Scoring 600 images with the default model on the GPU provider and on the CPU, when onnxruntime offers a
    GPU; else says there is none."""
    import numpy as np
    import onnxruntime as ort

    from graspd.gpd.classifier import CPU_PROVIDER, PROVIDER_ENV, choose_providers, default_model_name, load_model

    providers = choose_providers()
    if providers[0] == CPU_PROVIDER:
        emit(f"\nGPU: no GPU here (onnxruntime {ort.__version__} offers {ort.get_available_providers()}); the "
             "classifier runs on the CPU.")
        return
    gpu = load_model(default_model_name())
    os.environ[PROVIDER_ENV] = "cpu"
    try:
        cpu = load_model(default_model_name(), threads=0)
    finally:
        del os.environ[PROVIDER_ENV]
    shape = (600, gpu.channels, gpu.image_size, gpu.image_size)
    images = ((np.random.default_rng(0).random(shape) < 0.1) * 200).astype(np.uint8)
    t_gpu, s_gpu = _median_time(lambda: gpu.score(images), 5)
    t_cpu, s_cpu = _median_time(lambda: cpu.score(images), 5)
    diff = float(np.max(np.abs(np.asarray(s_gpu) - np.asarray(s_cpu))))
    emit(f"\nGPU ({gpu.provider}): {gpu.name} scores 600 images in {t_gpu * 1000:.1f} ms, against "
         f"{t_cpu * 1000:.1f} ms on the CPU (all cores); largest score difference {diff:.2e}.")


def profile(tag: str, requests: int) -> None:
    """Warm table_mug requests (500 samples) through the service's engine in a child process, sampled by py-spy
    (all threads, idle excluded); the top functions by own and by inclusive time go to profile-TAG.txt."""
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(spy).is_file():
        raise SystemExit("--profile needs py-spy (pip install py-spy into the virtual environment)")
    with tempfile.TemporaryDirectory() as tmp:
        flag, raw = Path(tmp) / "ready", Path(tmp) / "raw.txt"
        child = subprocess.Popen([sys.executable, __file__, "--profile-child", str(flag),
                                  "--profile-requests", str(requests)], stdout=subprocess.PIPE, text=True)
        while not flag.exists():
            if child.poll() is not None:
                raise SystemExit("the profiled process ended before its warm requests")
            time.sleep(0.1)
        subprocess.run([spy, "record", "-p", str(child.pid), "-o", str(raw), "-f", "raw", "-r", "250", "--threads",
                        "--nonblocking"], capture_output=True, check=False)
        out, _ = child.communicate(timeout=600)
        summary = spy_summary(raw.read_text())
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    text = (f"# Profile of warm table_mug requests, 500 samples, through DetectionEngine.run_sync in-process\n"
            f"# {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, commit {commit}, load average "
            f"{' '.join(f'{x:.2f}' for x in os.getloadavg())} at the end\n"
            f"# command: PYTHONPATH=service:client:lab python bench/perf.py --profile {tag} --profile-requests "
            f"{requests}  (py-spy record -r 250 --threads)\n{out}\n{summary}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"profile-{tag}.txt").write_text(text)
    print(text)


def spy_summary(raw: str, top: int = 30) -> str:
    """py-spy's raw stacks summed by function: the top by own time and by inclusive time (% of active samples)."""
    from collections import Counter

    own: Counter[str] = Counter()
    incl: Counter[str] = Counter()
    total = 0
    for line in raw.splitlines():
        if not line.strip():
            continue
        stack, count = line.rsplit(" ", 1)
        frames = [f for f in stack.split(";") if not f.startswith(("thread (", "process "))]
        if not frames:
            continue
        names = [re.sub(r"\((?:.*/(?:site-packages|service)/)?(.*?):\d+\)$", r"(\1)", f) for f in frames]
        total += int(count)
        own[names[-1]] += int(count)
        for name in set(names):
            incl[name] += int(count)
    lines = [f"py-spy samples (all threads, idle excluded): {total}", "", f"Top {top} by own time:"]
    lines += [f"  {100 * v / max(total, 1):5.1f}%  {k}" for k, v in own.most_common(top)]
    lines += ["", f"Top {top + 15} inclusive:"]
    lines += [f"  {100 * v / max(total, 1):5.1f}%  {k}" for k, v in incl.most_common(top + 15)]
    return "\n".join(lines) + "\n"


def profile_child(flag: Path, requests: int) -> None:
    """The profiled process: the service's engine and registry (warm-up included), three unmeasured requests,
    then `requests` measured ones once py-spy is attached; prints wall/CPU seconds and the stage medians."""
    from graspd.server.metrics import Metrics
    from graspd.server.requests import parse_request
    from graspd.server.services.engine import DetectionEngine
    from graspd.server.services.registry import ModelRegistry
    from graspd.server.services.warmup import warm_up
    from graspd.server.settings import Settings

    mug = read_cloud(SHARED_MUG)
    body = request_body(mug, 500)
    settings = Settings()
    registry = ModelRegistry.load(settings.resolved_models_dir(), None, settings.model_threads,
                                  cascade=settings.cascade_model or None)
    engine = DetectionEngine(settings, registry, Metrics())
    warm_up(registry)

    def one() -> tuple[dict[str, float], bytes]:
        timings: dict[str, float] = {}
        return timings, engine.run_sync(parse_request(body), timings)

    for _ in range(3):
        one()
    flag.write_text(str(os.getpid()))
    time.sleep(1.5)  # py-spy attaches
    walls, cpus, stages = [], [], []
    for _ in range(requests):
        t, c = time.perf_counter(), time.process_time()
        timings, out = one()
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
        stages.append(timings)
    res = json.loads(out)
    print(f"{requests} warm requests: median wall {statistics.median(walls):.3f} s, CPU "
          f"{statistics.median(cpus):.3f} s (process, all threads); {res['num_candidates']} candidates, "
          f"{len(res['grasps'])} grasps, model {res.get('model')}")
    keys = [k for k in stages[0] if k != "queue"]
    print("median stage s:", {k: round(statistics.median(x.get(k, 0.0) for x in stages), 4) for k in keys})
    engine.close()


def _fmt(v: float) -> str:
    return f"{v:.0f}" if v >= 100 else f"{v:.3f}"


def table(rows: list[dict[str, float]], cols: list[str]) -> str:
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(_fmt(r[c]) if c in r else "-" for c in cols) + " |" for r in rows]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer sizes and one repeat (smoke run)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--service-only", action="store_true", help="only the request latencies through the service")
    ap.add_argument("--no-service", action="store_true", help="skip the request latencies through the service")
    ap.add_argument("--reference-gpd", type=Path, help="a GPD C++ detect_grasps binary to run on table_mug.pcd")
    ap.add_argument("--reference-gpd-config", type=Path, help="its config file (num_samples is set to 500)")
    ap.add_argument("--scaling", action="store_true", help="only the whole-detection scaling with points and samples "
                    "(perf-scaling.md, .png)")
    ap.add_argument("--profile", metavar="TAG", help="only the py-spy profile of warm table_mug requests "
                    "(profile-TAG.txt)")
    ap.add_argument("--profile-requests", type=int, default=10, help="measured requests of --profile")
    ap.add_argument("--profile-child", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.profile_child is not None:
        profile_child(args.profile_child, args.profile_requests)
        return
    if args.profile:
        profile(args.profile, args.profile_requests)
        return
    if args.reference_gpd is not None and args.reference_gpd_config is None:
        ap.error("--reference-gpd needs --reference-gpd-config (GPD's detect_grasps reads its settings from it)")
    repeats = 1 if args.quick else args.repeats
    scorers = _load_scorers()
    score_cols = [f"score_{n}_per_1k" for n in scorers]
    out: list[str] = []

    def emit(text: str = "") -> None:
        print(text, flush=True)
        out.append(text)

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    emit(f"# graspd speed (bench/perf.py, commit {commit}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
         f"{os.cpu_count()}-core CPU)\n")
    emit(f"Command: `PYTHONPATH=service:client:lab python bench/perf.py {' '.join(sys.argv[1:])}`\n")
    emit(f"Machine load at the start: {' '.join(f'{x:.2f}' for x in os.getloadavg())} ({os.cpu_count()} cores); "
         "compare ratios and medians when other work shares the machine.\n")
    if args.scaling:
        scaling(repeats, emit)
        emit(f"\nMachine load at the end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "perf-scaling.md").write_text("\n".join(out) + "\n")
        print(f"wrote {RESULTS / 'perf-scaling.md'} and {RESULTS / 'perf-scaling.png'}")
        return
    big = cluttered_tabletop(num_objects=8, seed=7, resolution_scale=1.5, table_size=(0.6, 0.6))
    emit(f"Rendered cluttered tabletop: {len(big)} points from two cameras 53 deg apart (960x720 each).\n")
    if not args.no_service:
        emit("## Request latency through the service (HTTP, 500 samples, default model)\n")
        mug_cloud = read_cloud(SHARED_MUG) if SHARED_MUG.exists() else None
        p50 = service_latency(mug_cloud, big, repeats, emit)
        gpu_row(emit)
        if args.reference_gpd is not None:
            reference_gpd(args.reference_gpd, args.reference_gpd_config, emit, p50)
        else:
            emit(f"\nNo --reference-gpd given: the reference is a quiet-machine run of GPD C++ on table_mug, "
                 f"500 samples: {REFERENCE['wall']} s wall, ~{REFERENCE['candidates']} candidates.")
        emit(f"\nMachine load after the service runs: {' '.join(f'{x:.2f}' for x in os.getloadavg())}\n")
        if args.service_only:
            RESULTS.mkdir(parents=True, exist_ok=True)
            (RESULTS / "perf-service.md").write_text("\n".join(out) + "\n")
            return

    emit("## Table 2 of the IJRR paper, reproduced (samples on objects, table excluded from sampling)\n")
    rows = []
    for n in (39_000, 66_000):
        r = measure(subsample(big, n), num_samples=600, repeats=repeats, scorers=scorers)
        rows.append(r)
    cols = ["points", "voxelized", "candidates", "sample_per_1k", "encode15_per_1k", "encode3_per_1k", *score_cols,
            "preprocess", "environment", "scene", "unobserved"]
    emit(table(rows, cols))
    emit("\nTargets (2 cores): sample 1k <= 0.3 s, encode 1k 15-channel <= 0.3 s at 66k points; the environment "
         "stage (support plane, walls: graspd.gpd.environment.model_environment) <= 0.05 s at 66k points. "
         "Paper (4-core desktop + GPU): sample 1k 0.8 s / 1.7 s, classify 1k (15 ch) 4.3 s / 6.2 s at 39k / 66k.\n")

    if SHARED_MUG.exists():
        emit("## Real Kinect cloud table_mug.pcd, 500 samples (reference GPD 2.0 C++, 2 threads: ~700 candidates in "
             "0.9 s, images 2.6 s, classify 4.3 s, ~10 s wall)\n")
        mug_cloud = read_cloud(SHARED_MUG)
        mug = measure(mug_cloud, num_samples=500, repeats=repeats, scorers=scorers, exclude_table=False)
        mug["sample_s"] = mug["sample"]
        emit(table([mug], ["points", "voxelized", "candidates", "sample_s", "sample_per_1k", "encode15_per_1k",
                           *score_cols, "preprocess", "scene"]))
        if scorers:
            name, scorer = next(iter(scorers.items()))
            e2e = end_to_end(mug_cloud, 500, repeats, scorer)
            emit(f"\nWhole pipeline, `GraspDetector.detect` with {name}, 500 samples (s; reference C++: ~10 s wall):\n")
            emit(table([e2e], list(e2e)))
        emit("")

    sizes = [10_000, 30_000, 100_000] if args.quick else [10_000, 30_000, 66_000, 100_000, 200_000, 300_000]
    emit("## Growth with cloud size (600 samples)\n")
    size_rows = [measure(subsample(big, n), 600, repeats)
                 for n in track([n for n in sizes if n <= len(big)], "cloud sizes", "size")]
    emit(table(size_rows, ["points", "voxelized", "candidates", "preprocess", "environment", "scene", "sample",
                           "sample_per_1k",
                           "encode15_per_1k"]))
    samples = [200, 800] if args.quick else [200, 400, 800, 1600, 3200]
    emit("\n## Growth with the number of samples (66k points)\n")
    c66 = subsample(big, 66_000)
    sample_rows = []
    for s in track(samples, "sample counts", "count"):
        r = measure(c66, s, repeats)
        r["samples"] = s
        sample_rows.append(r)
    emit(table(sample_rows, ["samples", "candidates", "sample", "sample_per_1k", "encode15_per_1k"]))
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    emit(f"\nPeak resident memory of this benchmark process: {peak_mb:.0f} MB")

    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "perf.md").write_text("\n".join(out) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2), dpi=110)
    pts = [r["points"] / 1000 for r in size_rows]
    for key, label in (("preprocess", "preprocess"), ("environment", "environment"), ("scene", "scene index"),
                       ("sample", "sample 600 pts")):
        ax[0].plot(pts, [r[key] for r in size_rows], "o-", label=label)
    ax[0].set_xlabel("cloud size (k points)")
    ax[0].set_ylabel("s")
    ax[0].set_title("time vs cloud size")
    ax[0].legend()
    ax[1].plot([r["samples"] for r in sample_rows], [r["sample"] for r in sample_rows], "o-", label="sample")
    ax[1].plot([r["samples"] for r in sample_rows],
               [r["encode15_per_1k"] * r["candidates"] / 1000 for r in sample_rows], "o-", label="encode 15 ch")
    ax[1].set_xlabel("samples")
    ax[1].set_title("time vs samples (66k points)")
    ax[1].legend()
    fig.tight_layout()
    fig.savefig(RESULTS / "perf.png")
    print(f"wrote {RESULTS / 'perf.md'} and {RESULTS / 'perf.png'}")


if __name__ == "__main__":
    main()
