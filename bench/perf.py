"""Reproduce Table 2 of the IJRR paper on this machine: time to generate and to encode 1k candidates.

Clouds: a cluttered tabletop of procedural objects rendered by the project's own depth-camera model
(graspd.world.scenes.cluttered_tabletop: two cameras 53 degrees apart, Kinect-like noise), subsampled
uniformly to the paper's ~39k and ~66k points; 3 mm voxels, as GPD.  Also: the real table_mug.pcd
(500 samples, as in the reference C++ run), growth with cloud size (10k -> 300k points) and with the
number of samples, and peak memory.  Prints markdown tables, writes bench/results/perf.md and perf.png.

    python bench/perf.py [--quick] [--repeats 3]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import time
from pathlib import Path

from graspd.candidates import SamplingParams, search_hands
from graspd.cloud import ViewpointCloud
from graspd.cloud_io import read_cloud
from graspd.detector import Detection, DetectionParams, GraspDetector
from graspd.environment import Environment, EnvironmentParams, model_environment
from graspd.hand import HandGeometry
from graspd.images import encode_images
from graspd.preprocess import PreprocessParams, preprocess
from graspd.scene import Scene
from graspd.world.scenes import cluttered_tabletop, subsample

HAND = HandGeometry()
RESULTS = Path(__file__).resolve().parent / "results"
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
    from graspd.classifier import available_models, default_model_name, load_model

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
    args = ap.parse_args()
    repeats = 1 if args.quick else args.repeats
    scorers = _load_scorers()
    score_cols = [f"score_{n}_per_1k" for n in scorers]
    out: list[str] = []

    def emit(text: str = "") -> None:
        print(text, flush=True)
        out.append(text)

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    emit(f"# graspd speed (bench/perf.py, commit {commit}, {time.strftime('%Y-%m-%d')}, 2-core CPU)\n")
    big = cluttered_tabletop(num_objects=8, seed=7, resolution_scale=1.5, table_size=(0.6, 0.6))
    emit(f"Rendered cluttered tabletop: {len(big)} points from two cameras 53 deg apart (960x720 each).\n")

    emit("## Table 2 of the IJRR paper, reproduced (samples on objects, table excluded from sampling)\n")
    rows = []
    for n in (39_000, 66_000):
        r = measure(subsample(big, n), num_samples=600, repeats=repeats, scorers=scorers)
        rows.append(r)
    cols = ["points", "voxelized", "candidates", "sample_per_1k", "encode15_per_1k", "encode3_per_1k", *score_cols,
            "preprocess", "environment", "scene", "unobserved"]
    emit(table(rows, cols))
    emit("\nTargets (2 cores): sample 1k <= 0.3 s, encode 1k 15-channel <= 0.3 s at 66k points; the environment "
         "stage (support plane, walls: graspd.environment.model_environment) <= 0.05 s at 66k points. "
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
    size_rows = [measure(subsample(big, n), 600, repeats) for n in sizes if n <= len(big)]
    emit(table(size_rows, ["points", "voxelized", "candidates", "preprocess", "environment", "scene", "sample",
                           "sample_per_1k",
                           "encode15_per_1k"]))
    samples = [200, 800] if args.quick else [200, 400, 800, 1600, 3200]
    emit("\n## Growth with the number of samples (66k points)\n")
    c66 = subsample(big, 66_000)
    sample_rows = []
    for s in samples:
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
