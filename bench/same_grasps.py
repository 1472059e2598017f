"""Same grasps as before: the whole detection of saved cases by two checkouts, compared grasp by grasp.

Each side (a git worktree of the base commit, and this tree) runs in its own process with the same virtual
environment and detects on the same inputs with the same model: the real captures in ../shared/data/real (each
file as read by graspd, its own camera), the service's warm-up scene, and rendered tabletop scans; default
parameters except the samples.  The grasps (positions, rotations, widths, scores, in rank order) and the
candidate counts are written to .npz files and compared: a case matches when both sides return the same number
of candidates and grasps and every grasp agrees within the stated tolerance.  Writes bench/results/same-grasps.md.

    PYTHONPATH=service:client:lab python bench/same_grasps.py [--base d7f6f3f] [--model container15]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real"
RESULTS = REPO / "bench" / "results"
#: Agreement asked of two grasps (m, rad-ish on rotation matrix entries, m, score units).
TOLERANCE = {"position": 1e-6, "rotation": 1e-6, "width": 1e-6, "score": 1e-5}


def child(out: Path, model: str, samples: int) -> None:
    """One side: detect on every case with this process's graspd and write one .npz a case."""
    from graspd.core.cloud import ViewpointCloud  # noqa: PLC0415 - the side's own graspd, from its PYTHONPATH
    from graspd.gpd.classifier import load_model  # noqa: PLC0415
    from graspd.gpd.detector import DetectionParams, GraspDetector  # noqa: PLC0415
    from graspd.io.cloud_files import read_cloud  # noqa: PLC0415
    from graspd.server.services.warmup import warmup_cloud  # noqa: PLC0415

    sys.path.insert(0, str(REPO / "bench"))
    from kernels import tabletop_scan  # noqa: PLC0415 - the kernel bench's rendered two-camera tabletop scan

    scorer = load_model(model, REPO / "models", threads=2)
    detector = GraspDetector(scorer)
    cases: list[tuple[str, ViewpointCloud]] = [(f.stem, read_cloud(f)) for f in sorted(REAL.glob("*.pcd"))]
    cases.append(("warmup_scene", warmup_cloud()))
    for n in (100_000, 300_000):
        pts, src, eyes = tabletop_scan(n)
        cases.append((f"scan_{n // 1000}k", ViewpointCloud(points=pts, viewpoints=eyes, camera_source=src)))
    for name, cloud in cases:
        t = time.perf_counter()
        det = detector.detect(cloud, DetectionParams(num_samples=samples))
        g = det.grasps
        np.savez(out / f"{name}.npz", positions=g.positions, rotations=g.rotations, widths=g.widths,
                 scores=g.scores, candidates=np.array(det.num_candidates), points=np.array(det.num_points),
                 seconds=np.array(time.perf_counter() - t))


def run_side(root: Path, out: Path, model: str, samples: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=f"{root / 'service'}:{root / 'client'}:{REPO / 'lab'}")
    subprocess.run([sys.executable, __file__, "--child", str(out), "--model", model, "--samples", str(samples)],
                   env=env, check=True, cwd=REPO)


def compare(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> tuple[bool, dict[str, float]]:
    same_counts = (int(a["candidates"]) == int(b["candidates"]) and len(a["positions"]) == len(b["positions"]))
    diffs = {"position": float("nan"), "rotation": float("nan"), "width": float("nan"), "score": float("nan")}
    if not same_counts:
        return False, diffs
    for key, name in (("positions", "position"), ("rotations", "rotation"), ("widths", "width"),
                      ("scores", "score")):
        diffs[name] = float(np.max(np.abs(a[key] - b[key]), initial=0.0))
    return all(diffs[k] <= TOLERANCE[k] for k in TOLERANCE), diffs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", default="d7f6f3f", help="the commit compared against (a worktree is made)")
    ap.add_argument("--model", default="container15", help="the model both sides score with")
    ap.add_argument("--samples", type=int, default=500)
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        child(args.child, args.model, args.samples)
        return
    base = Path(tempfile.gettempdir()) / f"graspd-same-{args.base}"
    if not base.exists():
        subprocess.run(["git", "worktree", "add", "--detach", str(base), args.base], cwd=REPO, check=True,
                       capture_output=True)
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                          check=True).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        run_side(base, Path(tmp) / "base", args.model, args.samples)
        run_side(REPO, Path(tmp) / "head", args.model, args.samples)
        rows, results = [], {}
        for f in sorted((Path(tmp) / "base").glob("*.npz")):
            a, b = dict(np.load(f)), dict(np.load(Path(tmp) / "head" / f.name))
            ok, diffs = compare(a, b)
            results[f.stem] = {"match": ok, **diffs, "grasps": [len(a["positions"]), len(b["positions"])],
                               "candidates": [int(a["candidates"]), int(b["candidates"])],
                               "seconds": [float(a["seconds"]), float(b["seconds"])]}
            rows.append(f"| {f.stem} | {int(a['points'])} | {int(a['candidates'])} / {int(b['candidates'])} | "
                        f"{len(a['positions'])} / {len(b['positions'])} | "
                        + " | ".join(f"{diffs[k]:.1e}" for k in TOLERANCE)
                        + f" | {float(a['seconds']):.2f} / {float(b['seconds']):.2f} | {'yes' if ok else 'no'} |")
    text = "\n".join([
        "# Same grasps before and after\n",
        f"Command: `PYTHONPATH=service:client:lab python bench/same_grasps.py --base {args.base} --model "
        f"{args.model} --samples {args.samples}`; base {args.base}, head {head}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load average {os.getloadavg()[0]:.1f}.  "
        "The whole detection in-process (no HTTP), both sides with the same model and parameters; "
        f"a case matches when candidates and grasps are as many and every grasp agrees within {TOLERANCE}.\n",
        "| case | points after preprocessing | candidates (base / head) | grasps | max position diff (m) | "
        "max rotation diff | max width diff (m) | max score diff | detect s (base / head, one run) | match |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
        *rows, ""])
    RESULTS.joinpath("same-grasps.md").write_text(text)
    RESULTS.joinpath("same-grasps.json").write_text(json.dumps(results, indent=1) + "\n")
    print(text)


if __name__ == "__main__":
    main()
