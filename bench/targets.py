"""Targets and the covering top list on held-out tabletop scenes, judged against the meshes.

Each scene is a table of --objects held-out objects (random_urdfs 900-999: evaluation only, never training or
tuning; graspd_lab.world.scenes.random_tabletop(held_out=True)) or, with --tuning, of training objects (what
defaults such as max_per_object are chosen on: bench/results/targets-tuning.md), rendered with depth noise by two
cameras (graspd_lab.world.render.render_scene_with_ids, which also says which mesh each point is on).  The detector runs
in this process with the default model and the service's defaults.

- With a target (each object seen with at least --min-points points, named by its rows: target.indices): P@1 on
  the targeted object (the first grasp is an antipodal, collision-free grasp of that mesh:
  graspd_lab.training.labels.label_grasps with only that mesh graspable, the scene labels of the training data)
  and the share of returned grasps (top 10) whose closing region holds points of another object.
- Without one: the ranked list reordered by selection.cover_order for each max_per_object: objects covered in the
  top 10 (the mesh each grasp's closing region holds most points of), P@1 and P@5 (any object).
- The time a target adds (median over requests): the detector's target stage, and parsing a request's mask (PNG
  and COCO RLE) or indices against the same request without one.

  PYTHONPATH=service:client:lab .venv/bin/python bench/targets.py --scenes 12 --objects 8
  PYTHONPATH=service:client:lab .venv/bin/python bench/targets.py --scenes 12 --objects 8 --tuning --seed 100
Writes bench/results/targets.md and targets.json (targets-tuning.* with --tuning).
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "lab"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from graspd.core.camera import tabletop_cameras  # noqa: E402
from graspd.core.grasp import GraspSet  # noqa: E402
from graspd.core.hand import HandGeometry  # noqa: E402
from graspd.gpd.classifier import default_model_name, load_model  # noqa: E402
from graspd.gpd.detector import DetectionParams, GraspDetector  # noqa: E402
from graspd.gpd.scene import closing_region_points  # noqa: E402
from graspd.gpd.selection import DEFAULT_MAX_PER_OBJECT, cover_order  # noqa: E402
from graspd.gpd.target import Target  # noqa: E402
from graspd.server.requests import parse_request  # noqa: E402
from graspd.server.services.mapping import detection_inputs  # noqa: E402
from graspd_client.wire import build_detect_request, rle_counts  # noqa: E402
from graspd_lab.training.labels import label_grasps  # noqa: E402
from graspd_lab.training.scene_data import scene_labels  # noqa: E402
from graspd_lab.world.render import MeshScene, render_scene_with_ids  # noqa: E402
from graspd_lab.world.scenes import random_tabletop  # noqa: E402

CAPS = (0, 1, 2, 3, 5)
WORKSPACE = (-0.35, 0.35, -0.35, 0.35, -0.05, 0.4)


def grasp_meshes(points: np.ndarray, ids: np.ndarray, grasps: GraspSet, hand: HandGeometry) -> list[set[int]]:
    """The meshes (ids >= 1: objects) whose points lie in each grasp's closing region."""
    region = closing_region_points(cKDTree(points), points, grasps.positions, grasps.rotations, hand)
    out: list[set[int]] = [set() for _ in range(len(grasps))]
    for g, i in zip(region.grasp.tolist(), ids[region.index].tolist(), strict=True):
        if i >= 1:
            out[g].add(i)
    return out


def main_mesh(points: np.ndarray, ids: np.ndarray, grasps: GraspSet, hand: HandGeometry) -> np.ndarray:
    """The object mesh each grasp's closing region holds most points of (-1: none)."""
    region = closing_region_points(cKDTree(points), points, grasps.positions, grasps.rotations, hand)
    lab = ids[region.index]
    out = np.full(len(grasps), -1)
    for g in range(len(grasps)):
        on = lab[(region.grasp == g) & (lab >= 1)]
        if len(on):
            out[g] = int(np.bincount(on).argmax())
    return out


def parse_extra(points: np.ndarray, viewpoints: np.ndarray, target: dict[str, Any], repeats: int) -> float:
    """Median extra seconds to parse (validate, decode) a request with the target and make its detector
    parameters, over the same request without it (the two timed alternately)."""
    bodies = [json.dumps(build_detect_request(points, viewpoints, target=t)).encode() for t in (None, target)]
    extra = []
    for _ in range(repeats):
        times = []
        for body in bodies:
            t = time.perf_counter()
            detection_inputs(parse_request(body))
            times.append(time.perf_counter() - t)
        extra.append(times[1] - times[0])
    return float(np.median(extra))


def organised(points: np.ndarray, ids: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The cloud padded to a width x height image (NaN rows), for the mask parse timings."""
    h = -(-len(points) // width)
    pad = h * width - len(points)
    return (np.vstack([points, np.full((pad, 3), np.nan, np.float32)]), np.concatenate([ids, np.full(pad, -1)]))


def run(args: argparse.Namespace) -> dict[str, Any]:
    hand = HandGeometry()
    det = GraspDetector(load_model(default_model_name()), hand)
    labels = scene_labels()
    rows: list[dict[str, Any]] = []
    targeted: list[dict[str, Any]] = []
    stage: list[float] = []
    parse_png: list[float] = []
    parse_rle: list[float] = []
    parse_idx: list[float] = []
    s, seed = 0, args.seed - 1
    while s < args.scenes:
        seed += 1
        try:
            meshes = random_tabletop(args.objects, seed=seed, held_out=not args.tuning, hand=hand)
        except ValueError:  # the objects do not fit on the table: the next seed
            continue
        s += 1
        truth = MeshScene(meshes)
        cams = tabletop_cameras(2, distance=0.75, elevation_deg=55.0, azimuth_deg=float(37 * s % 360),
                                width=320, height=240)
        cloud, ids = render_scene_with_ids(truth, cams, seed=seed)
        points = cloud.points
        n_obj = len(meshes) - 1
        p = DetectionParams(num_samples=args.samples, workspace=WORKSPACE, max_grasps=1000, max_per_object=0,
                            seed=seed)
        full = det.detect(cloud, p, hand)
        g = full.grasps
        if not len(g):
            continue
        good = label_grasps(truth, g[: min(len(g), 200)], hand, labels,
                            np.array([False] + [True] * n_obj)).grasp
        mesh_of = main_mesh(points, ids, g[: min(len(g), 200)], hand)
        graspable = {int(m) for m in mesh_of[good] if m >= 1}
        row: dict[str, Any] = {"scene": seed, "objects": n_obj, "graspable": len(graspable)}
        for cap in CAPS:
            order = cover_order(g.object_ids, cap)[: min(len(g), 200)]
            order = order[order < len(good)]
            top = order[:10]
            row[f"covered@{cap}"] = len({int(m) for m in mesh_of[top] if m >= 1})
            row[f"p@1@{cap}"] = float(good[order[:1]].mean())
            row[f"p@5@{cap}"] = float(good[order[:5]].mean())
        rows.append(row)
        for k in range(1, n_obj + 1):
            if np.count_nonzero(ids == k) < args.min_points:
                continue
            t0 = time.perf_counter()
            d = det.detect(cloud, DetectionParams(num_samples=args.samples, workspace=WORKSPACE, seed=seed,
                                                  target=Target("indices", rows=ids == k)), hand)
            wall = time.perf_counter() - t0
            stage.append(d.timings.get("target", 0.0))
            entry: dict[str, Any] = {"scene": seed, "mesh": k, "points": int(np.count_nonzero(ids == k)),
                                     "returned": len(d.grasps), "seconds": wall}
            if len(d.grasps):
                only_k = np.zeros(len(meshes), bool)
                only_k[k] = True
                entry["p@1"] = bool(label_grasps(truth, d.grasps[:1], hand, labels, only_k).grasp[0])
                touched = grasp_meshes(points, ids, d.grasps[:10], hand)
                entry["touch_other"] = float(np.mean([bool(m - {k}) for m in touched]))
            targeted.append(entry)
        if s <= args.timing_scenes:
            img_pts, img_ids = organised(points, ids, 320)
            k = int(np.bincount(ids[ids >= 1]).argmax())
            mask = (img_ids == k).reshape(-1, 320)
            buf = io.BytesIO()
            Image.fromarray(mask.astype(np.uint8) * 255, "L").save(buf, format="PNG")
            parse_png.append(parse_extra(img_pts, cloud.viewpoints, {"mask": buf.getvalue()}, args.repeats))
            parse_rle.append(parse_extra(img_pts, cloud.viewpoints, {"mask": {"size": list(mask.shape),
                                                                              "counts": rle_counts(mask)}},
                                         args.repeats))
            parse_idx.append(parse_extra(img_pts, cloud.viewpoints, {"indices": np.flatnonzero(img_ids == k)},
                                         args.repeats))
        print(f"scene {seed}: {row}", flush=True)
    with_grasps = [t for t in targeted if "p@1" in t]
    summary: dict[str, Any] = {
        "scenes": len(rows),
        "targets": len(targeted),
        "targets_with_grasps": len(with_grasps),
        "target_p@1": float(np.mean([t["p@1"] for t in with_grasps])) if with_grasps else float("nan"),
        "target_touch_other": float(np.mean([t["touch_other"] for t in with_grasps])) if with_grasps else float("nan"),
        "target_stage_ms_median": 1e3 * float(np.median(stage)) if stage else float("nan"),
        "parse_extra_ms_median": {name: 1e3 * float(np.median(v)) if v else float("nan")
                                  for name, v in (("mask_png", parse_png), ("mask_rle", parse_rle),
                                                  ("indices", parse_idx))},
        "default_list": {str(cap): {m: float(np.mean([r[f"{m}@{cap}"] for r in rows]))
                                    for m in ("covered", "p@1", "p@5")} for cap in CAPS},
        "graspable_objects_mean": float(np.mean([r["graspable"] for r in rows])) if rows else float("nan"),
    }
    return {"summary": summary, "scenes": rows, "targeted": targeted}


def markdown(result: dict[str, Any], meta: dict[str, Any]) -> str:
    s = result["summary"]
    lines = [
        f"# Targets and the covering top list ({meta['object_set']} objects)",
        "",
        f"`{meta['command']}` at commit `{meta['commit']}`: {s['scenes']} tables of {meta['objects']} objects "
        f"({meta['object_set']}), two noisy 320x240 cameras, the default model in process, "
        f"{meta['samples']} samples.  Labels against the meshes (bench/targets.py).",
        "",
        "## With a target (target.indices: the object's rows)",
        "",
        "| targets | with grasps | P@1 on the targeted object | top-10 grasps touching another object | "
        "target stage (median) |",
        "|---|---|---|---|---|",
        f"| {s['targets']} | {s['targets_with_grasps']} | {100 * s['target_p@1']:.1f}% | "
        f"{100 * s['target_touch_other']:.1f}% | {s['target_stage_ms_median']:.2f} ms |",
        "",
        "Parsing a request with a target, extra time over the same request without one (median; the scene's "
        "cloud padded to a 320-wide organised image): "
        + ", ".join(f"{k} {v:.2f} ms" for k, v in s["parse_extra_ms_median"].items()) + ".",
        "",
        "## The default list, by max_per_object",
        "",
        f"Graspable objects per scene (an object with a true grasp among the first 200): "
        f"{s['graspable_objects_mean']:.1f} on average.",
        "",
        "| max_per_object | objects in the top 10 | P@1 | P@5 |",
        "|---|---|---|---|",
    ]
    for cap, m in s["default_list"].items():
        mark = " (default)" if int(cap) == DEFAULT_MAX_PER_OBJECT else " (off)" if cap == "0" else ""
        lines.append(f"| {cap}{mark} | {m['covered']:.2f} | {100 * m['p@1']:.1f}% | {100 * m['p@5']:.1f}% |")
    lines.append("")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=12)
    ap.add_argument("--objects", type=int, default=8)
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=9000, help="first scene seed (held-out scenes only)")
    ap.add_argument("--min-points", type=int, default=150, help="objects seen with fewer points are not targeted")
    ap.add_argument("--timing-scenes", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--tuning", action="store_true", help="scenes of training objects (procedural and random_urdfs "
                    "000-899), for choosing defaults such as max_per_object; the report uses held-out ones")
    ap.add_argument("--out", type=Path, default=None, help="default bench/results/targets (targets-tuning)")
    args = ap.parse_args()
    if args.out is None:
        args.out = REPO / "bench" / "results" / ("targets-tuning" if args.tuning else "targets")
    result = run(args)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout
    meta = {"command": "python bench/targets.py " + " ".join(sys.argv[1:]), "commit": commit.strip(),
            "objects": args.objects, "samples": args.samples,
            "object_set": "training (tuning)" if args.tuning else "held-out (random_urdfs 900-999)"}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps({**meta, **result}, indent=1))
    args.out.with_suffix(".md").write_text(markdown(result, meta))
    print(markdown(result, meta))


if __name__ == "__main__":
    main()
