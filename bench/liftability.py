"""How liftable each object of an object set is, alone on the table, by the clutter benchmark's simulated hand.

The ceiling any grasp ranking can reach on an object: of the analytic positives (the detector's candidates that the
geometric labeller accepts) on object X lying alone on the table, what share hold through the benchmark's lift?
Each object is dropped alone on the table (a one-object VGN pile: graspd_lab.sim.world.build_scene, one settle seed
per object from --seed and its index), seen once by the benchmark's cameras (--sensing, default the household
piles' side camera) with its Kinect noise (DepthNoise.benchmark()); the detector's candidates are what the service
scores on that cloud (GraspDetector.prepare and search, default DetectionParams, no classifier), labelled against the
true meshes as the scene datasets label them (graspd_lab.training.labels, scene_data.scene_labels()).  Up to --grasps
positives (a seeded uniform draw) are lifted by the set's hand (Panda-like for the household sets: 7.5 cm opening,
40 N per finger) with the clutter benchmark's own motion, graspd_lab.sim.gripper.ExecutionParams(): a slip is a drop
only, however the object hangs (not lift.LIFT_PARAMS, which also fails a turn of more than 15 degrees in the
fingers).  The report gives each object's held share, the shares by mass band, and how many objects have at least
one / at least half of their lifted positives held.

  PYTHONPATH=service:client:lab .venv/bin/python bench/liftability.py --object-set household-training-heavy \\
      --objects 12 --grasps 15 --tag heavy12
writes bench/results/liftability-<tag>.md and .json (tag default: the object set's name).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "lab", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402
import pybullet as pb  # noqa: E402

import clutter  # noqa: E402
from graspd.core.camera import sensing_cameras  # noqa: E402
from graspd.core.hand import HandGeometry  # noqa: E402
from graspd.gpd.detector import DetectionParams, GraspDetector  # noqa: E402
from graspd_lab.sim.gripper import ExecutionParams  # noqa: E402
from graspd_lab.sim.lift import lift_labels  # noqa: E402
from graspd_lab.sim.object_sets import OBJECT_SETS, object_label, object_set_hand, object_set_ids  # noqa: E402
from graspd_lab.sim.object_sets import describe as describe_objects  # noqa: E402
from graspd_lab.sim.protocol import SENSINGS, Setting, feasible  # noqa: E402
from graspd_lab.sim.sensing import observe  # noqa: E402
from graspd_lab.sim.world import build_scene  # noqa: E402
from graspd_lab.training.labels import label_grasps  # noqa: E402
from graspd_lab.training.scene_data import scene_labels  # noqa: E402
from graspd_lab.world.noise import DepthNoise  # noqa: E402
from graspd_lab.world.render import MeshScene  # noqa: E402
from slips import MASS_BINS, bin_label  # noqa: E402

#: The arm's approach cone of the clutter protocol (deg from straight down): the grasps a round may execute.
MAX_APPROACH_DEG = Setting().max_approach_angle_deg


def set_objects(object_set: str, count: int | None = None) -> list[tuple[int, str]]:
    """(simulator id, name) of the set's objects sorted by name; the first count of them (None: all)."""
    named = sorted(((object_label(i), i) for i in object_set_ids(object_set)), key=lambda t: t[0])
    return [(i, name) for name, i in named[:count]]


def object_liftability(object_id: int, index: int, seed: int, hand: HandGeometry, grasps: int = 20,
                       sensing: str = "side", num_samples: int | None = None,
                       flat_objects: bool = False) -> dict[str, Any]:
    """One object alone on the table (settled from seed * 100_003 + index), one view of it, the detector's
    candidates, their analytic labels, and up to `grasps` analytic positives (a uniform draw seeded by seed and
    index) lifted with the clutter benchmark's ExecutionParams(): the object's record.  flat_objects: the
    request option (DetectionParams.flat_objects)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng([seed, index, 13])
    row: dict[str, Any] = {"object": object_label(object_id), "id": int(object_id), "index": index, "mass": None,
                           "points": 0, "candidates": 0, "antipodal": 0, "positives": 0, "positives_in_cone": 0,
                           "tried": 0, "held": 0, "tried_in_cone": 0, "held_in_cone": 0, "outcomes": {},
                           "note": ""}
    world = build_scene("pile", 1, seed * 100_003 + index, hand, object_ids=(int(object_id),))
    try:
        if not world.objects:
            row["note"] = "left the table while settling"
            return _timed(row, t0)
        body = next(iter(world.objects))
        row["mass"] = float(pb.getDynamicsInfo(body, -1, physicsClientId=world.client)[0])
        region = world.workspace()
        cloud = observe(world.client, sensing_cameras(sensing), DepthNoise.benchmark(), rng, region)
        row["points"] = len(cloud)
        if len(cloud) < 50:
            row["note"] = "fewer than 50 points seen"
            return _timed(row, t0)
        det = GraspDetector(None, hand)
        p = DetectionParams(workspace=region, seed=int(rng.integers(2**31)), flat_objects=flat_objects)
        if num_samples is not None:
            p = replace(p, num_samples=num_samples)
        prep = det.prepare(cloud, p, hand)
        cands, _ = det.search(prep, prep.sampling, p, hand)
        row["candidates"] = len(cands)
        if len(cands) == 0:
            row["note"] = "no candidates"
            return _timed(row, t0)
        static = world.static_meshes()
        posed = [m for _, m in world.object_meshes()]
        graspable = np.r_[np.zeros(len(static), bool), np.ones(len(posed), bool)]
        lab = label_grasps(MeshScene(static + posed), cands, hand, scene_labels(), graspable=graspable)
        pos = np.flatnonzero(lab.grasp)
        cone = feasible(cands, MAX_APPROACH_DEG)
        row.update(antipodal=int(lab.antipodal.sum()), positives=len(pos), positives_in_cone=int(cone[pos].sum()))
        if len(pos) == 0:
            row["note"] = "no analytic positive"
            return _timed(row, t0)
        pick = np.sort(rng.choice(pos, size=min(grasps, len(pos)), replace=False))
        lifted = lift_labels(world, cands[pick], hand, params=ExecutionParams())
        in_cone = cone[pick]
        row.update(tried=len(pick), held=int(lifted.held.sum()), tried_in_cone=int(in_cone.sum()),
                   held_in_cone=int(lifted.held[in_cone].sum()), outcomes=lifted.counts())
    finally:
        world.close()
    return _timed(row, t0)


def _timed(row: dict[str, Any], t0: float) -> dict[str, Any]:
    row["seconds"] = round(time.perf_counter() - t0, 2)
    return row


def share(held: int, tried: int) -> float | None:
    """held / tried, None where nothing was tried."""
    return held / tried if tried else None


def pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.0f}%"


def kg(mass: float | None) -> str:
    return "n/a" if mass is None else f"{mass:.3f}"


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Over the objects: how many, how many had no analytic positive, how many have at least one / at least half
    of their lifted positives held, and the pooled held share of all lifted positives."""
    tried = sum(r["tried"] for r in rows)
    held = sum(r["held"] for r in rows)
    return {"objects": len(rows), "no_positive": sum(r["tried"] == 0 for r in rows),
            "at_least_one": sum(r["held"] >= 1 for r in rows),
            "at_least_half": sum(r["tried"] > 0 and 2 * r["held"] >= r["tried"] for r in rows),
            "positives": sum(r["positives"] for r in rows), "tried": tried, "held": held,
            "held_share": share(held, tried),
            "tried_in_cone": sum(r["tried_in_cone"] for r in rows),
            "held_in_cone": sum(r["held_in_cone"] for r in rows)}


def bands(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """summary() of each mass band (bench/slips.py's MASS_BINS) that holds an object, with its label."""
    out = []
    for lo, hi in zip(MASS_BINS[:-1], MASS_BINS[1:], strict=True):
        sub = [r for r in rows if r["mass"] is not None and lo <= r["mass"] < hi]
        if sub:
            out.append({"band": bin_label(lo, hi, "kg"), **summary(sub)})
    return out


def summary_line(s: dict[str, Any]) -> str:
    return (f"{s['at_least_one']} of {s['objects']} objects have at least one analytic positive held, "
            f"{s['at_least_half']} at least half of those lifted ({s['no_positive']} had no analytic positive); "
            f"{s['held']} of {s['tried']} lifted positives held ({pct(s['held_share'])}), in the arm's cone "
            f"{s['held_in_cone']} of {s['tried_in_cone']} ({pct(share(s['held_in_cone'], s['tried_in_cone']))})")


def report(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """Markdown: the summary line, the mass bands and the per-object table."""
    s = summary(rows)
    lines = ["# Liftability: analytic positives that hold through the benchmark's lift (each object alone)", "",
             f"- command: `{meta['command']}`", f"- commit: `{meta['commit']}`, date {meta['date']}",
             f"- objects: {meta['objects']}",
             f"- per object: one settled drop on the table, one view ({meta['sensing']} sensing, Kinect noise), the "
             f"detector's candidates (default DetectionParams, num_samples {meta['num_samples']}"
             f"{', flat_objects' if meta.get('flat_objects') else ''}), analytic labels "
             f"(scene_data.scene_labels()), up to {meta['grasps']} positives lifted with the clutter benchmark's "
             "ExecutionParams() (a slip is a drop only)",
             f"- in the arm's cone: approach within {MAX_APPROACH_DEG:g} degrees of straight down, the grasps a "
             "clutter round may execute", "",
             f"**{summary_line(s)}.**", "",
             "## By mass", "",
             "| mass | objects | no positive | >= 1 held | >= half held | positives | lifted | held | held share "
             "| held share in cone |", "|---|---|---|---|---|---|---|---|---|---|"]
    for b in bands(rows):
        lines.append(f"| {b['band']} | {b['objects']} | {b['no_positive']} | {b['at_least_one']} | "
                     f"{b['at_least_half']} | {b['positives']} | {b['tried']} | {b['held']} | "
                     f"{pct(b['held_share'])} | {pct(share(b['held_in_cone'], b['tried_in_cone']))} |")
    lines += ["", "## Objects", "",
              "| object | mass (kg) | points | candidates | antipodal | positives (in cone) | lifted (in cone) | "
              "held (in cone) | held share | outcomes | s |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        outcomes = ", ".join(f"{k} {v}" for k, v in r["outcomes"].items()) or r["note"]
        lines.append(f"| {r['object']} | {kg(r['mass'])} | {r['points']} | {r['candidates']} | {r['antipodal']} | "
                     f"{r['positives']} ({r['positives_in_cone']}) | {r['tried']} ({r['tried_in_cone']}) | "
                     f"{r['held']} ({r['held_in_cone']}) | {pct(share(r['held'], r['tried']))} | {outcomes} | "
                     f"{r['seconds']:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--object-set", choices=OBJECT_SETS, default="household-training-heavy")
    ap.add_argument("--objects", type=int, default=None, help="the first N objects of the set by name (default all)")
    ap.add_argument("--grasps", type=int, default=20, help="most analytic positives lifted per object")
    ap.add_argument("--sensing", choices=SENSINGS, default="side", help="the benchmark's cameras (default: the "
                    "household piles' side camera)")
    ap.add_argument("--samples", type=int, default=None, help="detector num_samples (default: DetectionParams')")
    ap.add_argument("--flat-objects", action="store_true", help="the request option flat_objects (objects lying "
                    "flat are grasped by their edges; off by default)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tag", default=None, help="output file stem after liftability- (default: the object set)")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = ap.parse_args(argv)
    if args.grasps < 1 or (args.objects is not None and args.objects < 1):
        ap.error("--grasps and --objects must be >= 1")
    hand = object_set_hand(args.object_set)
    objects = set_objects(args.object_set, args.objects)
    rows = []
    for index, (object_id, name) in enumerate(objects):
        row = object_liftability(object_id, index, args.seed, hand, args.grasps, args.sensing, args.samples,
                                 args.flat_objects)
        rows.append(row)
        print(f"[{index + 1}/{len(objects)}] {name}: {kg(row['mass'])} kg, {row['positives']} positives, "
              f"{row['held']}/{row['tried']} held {row['outcomes'] or row['note']} "
              f"({row['seconds']:.0f} s)", flush=True)
    meta = {"command": "PYTHONPATH=service:client:lab .venv/bin/python bench/liftability.py "
            + shlex.join(sys.argv[1:] if argv is None else argv), "commit": clutter.git_commit(),
            "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "object_set": args.object_set,
            "objects": describe_objects(args.object_set) + (f"; the first {len(objects)} by name"
                                                            if len(objects) < len(object_set_ids(args.object_set))
                                                            else ""),
            "sensing": args.sensing, "grasps": args.grasps, "seed": args.seed,
            "num_samples": args.samples or DetectionParams().num_samples, "execution": "ExecutionParams()",
            "flat_objects": args.flat_objects,
            "hand": hand.to_dict()}
    md = report(rows, meta)
    stem = f"liftability-{args.tag or args.object_set}"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{stem}.md").write_text(md)
    (args.out / f"{stem}.json").write_text(json.dumps(
        {"meta": meta, "summary": summary(rows), "bands": bands(rows), "objects": rows}, indent=1))
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
