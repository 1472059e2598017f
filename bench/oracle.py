"""How far a better ranking of the same grasps could go: the clutter protocol's rounds twice, as the service ranks
them and with each executed grasp chosen by trying the service's top --top feasible grasps in physics first.

The rounds are bench/clutter.py's (same seeds and scenes, plain POST /detect with the service's defaults).  In the
"ranked" rounds the robot executes the first feasible grasp, as bench/clutter.py does.  In the "oracle" rounds each
of the first --top feasible grasps is first executed on the world as it is and the world put back
(graspd_lab.sim.lift.lift_labels with the benchmark's own motion: a slip is a drop); the first that held is then
executed for real, or the first grasp when none held.  The gap between the two rows is what a ranking of the
grasps the service already returns could gain; what the oracle still misses is for candidates, reach and physics
to win (objects no returned grasp holds).  Each detection's record says how many of the top grasps held and the
rank of the first that did.  A diagnosis: it reads the true world, which no detector may.

  PYTHONPATH=service:client:lab .venv/bin/python bench/oracle.py --object-set household-training --seed 100 \\
      --rounds 30 --top 5 --tag household-training-pile
  ... --container tray --split training ...      (bench/containers.py's rounds of one style)
  ... --perturb 4 --images data/generated/tried.npz  (each tried grasp's 15-channel image as the service encodes it,
                                                      with its trial and perturbed outcomes: bench/reranker.py)
writes bench/results/oracle-<tag>.md and .json.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from collections import Counter
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "lab", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402
import pybullet as pb  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

import clutter  # noqa: E402
from containers import add_scene_arguments, looked_setting  # noqa: E402
from graspd.core.cloud import ViewpointCloud  # noqa: E402
from graspd.core.grasp import GraspSet  # noqa: E402
from graspd.core.hand import HandGeometry  # noqa: E402
from graspd.gpd.detector import DetectionParams, GraspDetector  # noqa: E402
from graspd.gpd.images import encode_images  # noqa: E402
from graspd.gpd.preprocess import Workspace  # noqa: E402
from graspd.gpd.robustness import COPY_SHIFT, COPY_TURN_DEG, pose_copies  # noqa: E402
from graspd_client import Grasps  # noqa: E402
from graspd_lab.sim.detectors import SimDetector  # noqa: E402
from graspd_lab.sim.gripper import ExecutionParams  # noqa: E402
from graspd_lab.sim.lift import lift_labels  # noqa: E402
from graspd_lab.sim.protocol import Chooser, RoundResult, run_round, summarize  # noqa: E402
from graspd_lab.sim.world import SimWorld  # noqa: E402

#: Each detection's feasible grasps tried in physics before one is executed, by default.
DEFAULT_TOP = 5


def truth(world: SimWorld, grasps: GraspSet, bodies: NDArray[np.int64], hand: HandGeometry) -> list[dict[str, Any]]:
    """Per tried grasp, what the true world says about it (a diagnosis no detector may read): the mass (kg) of the
    object the hand went for and its centre of mass in the hand's frame (m): along the approach from the
    fingertips (positive: beyond them), along the binormal (the closing direction) and along the hand axis."""
    rows: list[dict[str, Any]] = []
    for i, body in enumerate(bodies):
        if body < 0:
            rows.append({"mass": None})
            continue
        com = np.asarray(pb.getBasePositionAndOrientation(int(body), physicsClientId=world.client)[0])
        d = com - (grasps.positions[i] + hand.hand_depth * grasps.approach[i])
        rows.append({"mass": round(float(pb.getDynamicsInfo(int(body), -1, physicsClientId=world.client)[0]), 4),
                     "com_approach": round(float(d @ grasps.approach[i]), 4),
                     "com_binormal": round(float(d @ grasps.binormal[i]), 4),
                     "com_axis": round(float(d @ grasps.axis[i]), 4)})
    return rows


def seen(answer: Grasps | None, grasps: GraspSet, tried: NDArray[np.int64], hand: HandGeometry
         ) -> list[dict[str, Any]]:
    """Per tried grasp, what the answer said about it: its ranking terms and the segmented object it closes on (its
    centre in the hand's frame from the fingertips as in truth(), its extent sorted, m; its point count)."""
    if answer is None:
        return [{} for _ in tried]
    raw = answer.raw.get("grasps") or []
    objects = {int(o["id"]): o for o in answer.scene_objects if "id" in o}
    rows: list[dict[str, Any]] = []
    for i in tried:
        row: dict[str, Any] = {"ranking": raw[i].get("ranking") if i < len(raw) else None}
        obj = objects.get(int(answer.object_ids[i])) if i < len(answer.object_ids) else None
        if obj is not None:
            d = np.asarray(obj["centre"], np.float64) - (grasps.positions[i] + hand.hand_depth * grasps.approach[i])
            row.update(centre_approach=round(float(d @ grasps.approach[i]), 4),
                       centre_binormal=round(float(d @ grasps.binormal[i]), 4),
                       centre_axis=round(float(d @ grasps.axis[i]), 4),
                       extent=sorted(round(float(v), 4) for v in obj["extent"]), points=int(obj["num_points"]))
        rows.append(row)
    return rows


def other_terms(rankings: list[dict[str, Any] | None], scores: NDArray[np.floating[Any]] | list[float]
                ) -> NDArray[np.float64]:
    """The answer's ranking terms besides the classifier's score (utility, width, unknown): each grasp's ranking key
    over its score, 1 where the answer gave no key; what a second score is multiplied by to rank the same grasps."""
    keys = [(r or {}).get("key") for r in rankings]
    return np.array([1.0 if k is None else float(k) / max(float(s), 1e-9) for k, s in zip(keys, scores, strict=True)])


class Watched:
    """A SimDetector that keeps the last cloud and workspace it was asked about (to encode the tried grasps' images
    as the service did); last is the wrapped detector's last parsed answer, if it keeps one."""

    def __init__(self, inner: SimDetector) -> None:
        self.inner = inner
        self.name = inner.name
        self.cloud: ViewpointCloud | None = None
        self.workspace: Workspace | None = None

    def detect(self, cloud: ViewpointCloud, workspace: Workspace, hand: HandGeometry, seed: int) -> GraspSet:
        self.cloud, self.workspace = cloud, workspace
        return self.inner.detect(cloud, workspace, hand, seed)

    @property
    def last(self) -> Grasps | None:
        return getattr(self.inner, "last", None)


def tried_images(cloud: ViewpointCloud, workspace: Workspace, grasps: GraspSet, hand: HandGeometry
                 ) -> NDArray[np.uint8]:
    """The 15-channel images (M, 15, 60, 60) of grasps in the cloud, preprocessed as the service does with its
    defaults and the request's workspace and hand."""
    det = GraspDetector(None, hand)
    scene = det.prepare(cloud, DetectionParams(workspace=workspace), hand).scene
    return encode_images(scene, grasps, hand, "15")


def oracle_chooser(top: int, hand: HandGeometry, records: list[dict[str, Any]],
                   detector: SimDetector | None = None, perturb: int = 0,
                   images: list[NDArray[np.uint8]] | None = None) -> Chooser:
    """A protocol Chooser: try the first `top` feasible grasps in physics with hand (the world restored after
    each), pick the first that held (else the first), and append the detection's record to records.  With perturb,
    each tried grasp is also lifted that many times perturbed (graspd.gpd.robustness.pose_copies) and the share
    that held is recorded; the choice does not change.  images (with a Watched detector): each detection's tried
    grasps' images are appended."""

    def choose(world: SimWorld, grasps: GraspSet, ok: NDArray[np.int64]) -> int:
        tried = ok[:top]
        lifted = lift_labels(world, grasps[tried], hand, params=ExecutionParams())
        robust: list[float] | None = None
        if perturb > 0:
            copies = pose_copies(grasps[tried], perturb, seed=len(records))
            shaken = lift_labels(world, copies, hand, params=ExecutionParams())
            robust = [round(float(v), 3) for v in shaken.held.reshape(len(tried), perturb).mean(axis=1)]
        held = np.flatnonzero(lifted.held)
        first = int(held[0]) if len(held) else None
        if images is not None and isinstance(detector, Watched) and detector.cloud is not None:
            assert detector.workspace is not None
            images.append(tried_images(detector.cloud, detector.workspace, grasps[tried], hand))
        records.append({"feasible": len(ok), "tried": len(tried), "held": int(len(held)),
                        "first_held_rank": None if first is None else first + 1,
                        "trial_outcomes": list(lifted.outcomes),
                        "trial_scores": [round(float(v), 4) for v in grasps.scores[tried]],
                        "trial_widths": [round(float(v), 4) for v in grasps.widths[tried]],
                        "trial_from_down": [round(float(np.degrees(np.arccos(np.clip(-a[2], -1.0, 1.0)))), 1)
                                            for a in grasps.approach[tried]],
                        "predicted": "success" if first is not None else lifted.outcomes[0],
                        "trial_seen": seen(getattr(detector, "last", None), grasps, tried, hand),
                        "trial_truth": truth(world, grasps[tried], lifted.bodies, hand),
                        "trial_objects": [int(v) for v in lifted.objects],
                        **({} if robust is None else {"trial_robust": robust})})
        return int(tried[0] if first is None else tried[first])

    return choose


def save_images(path: Path, shots: list[NDArray[np.uint8]], detections: list[dict[str, Any]]) -> None:
    """The tried grasps' images (N, 15, 60, 60) with, per image, its detection (index into detections), rank among
    the tried (0 = the service's first), round seed, trial outcome held (0/1), share of perturbed copies that held
    (NaN without --perturb), classifier score and the object the hand went for (its id in the object set; -1: none
    near), for folds by object."""
    rows = [(i, r, d) for i, d in enumerate(detections[: len(shots)]) for r in range(d["tried"])]
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        path, images=np.concatenate(shots) if shots else np.zeros((0, 15, 60, 60), np.uint8),
        detection=np.array([i for i, _, _ in rows], np.int32), rank=np.array([r for _, r, _ in rows], np.int32),
        seed=np.array([d.get("seed", -1) for _, _, d in rows], np.int64),
        held=np.array([d["trial_outcomes"][r] == "success" for _, r, d in rows], np.uint8),
        robust=np.array([d["trial_robust"][r] if "trial_robust" in d else np.nan for _, r, d in rows]),
        score=np.array([d["trial_scores"][r] for _, r, d in rows]),
        object=np.array([d.get("trial_objects", [-1] * d["tried"])[r] for _, r, d in rows], np.int64))


def choice_table(rows: dict[str, dict[str, Any]]) -> list[str]:
    """Markdown rows of a table of the same rounds played by different choices ({choice: Summary.to_dict()})."""
    lines = ["| choice | rounds | objects | attempts | success [95% CI] | cleared [95% CI] | failures |",
             "|---|---|---|---|---|---|---|"]
    for name, t in rows.items():
        fails = ", ".join(f"{k} {v}" for k, v in sorted(t["failures"].items()))
        lines.append(f"| {name} | {t['rounds']} | {t['objects']} | {t['attempts']} | {clutter.pct(t['success_rate'])}"
                     f"{clutter.ci(t['success_ci'])} | {clutter.pct(t['cleared_rate'])}{clutter.ci(t['cleared_ci'])} "
                     f"| {fails} |")
    return lines


def report(data: dict[str, Any]) -> str:
    """Markdown: the two rows, and how many of each detection's top grasps held in physics."""
    meta, rows, dets = data["meta"], data["rows"], data["detections"]
    lines = ["# How far a better ranking could go: the service's choice against a physics oracle over its top grasps",
             "", f"- command: `{meta['command']}`", f"- commit: `{meta['commit']}`, date {meta['date']}, model "
             f"{meta['model']}", f"- scenes: {meta['scenes']}",
             f"- oracle: each detection's first {meta['top']} feasible grasps executed in physics from the world as it "
             "is (restored after each), the first that held executed for real (the first grasp when none held)", "",
             *choice_table(rows)]
    n = len(dets)
    if n:
        first = Counter(d["first_held_rank"] for d in dets)
        none = first.pop(None, 0)
        agree = sum(d["predicted"] == d["outcome"] for d in dets)
        lines += ["", f"## The oracle's detections ({n})", "",
                  f"- the service's first grasp held in the trial: {first.get(1, 0)} of {n}; a later one of the top "
                  f"{meta['top']} was the first to hold: {n - none - first.get(1, 0)}; none of them held: {none}",
                  "- rank of the first grasp that held: "
                  + ", ".join(f"{k}: {v}" for k, v in sorted(first.items())),
                  f"- executed outcome as the trial predicted: {agree} of {n} (a replay of the same grasp on the same "
                  "world by another hand body: contact order can differ)"]
        shaken = [d for d in dets if "trial_robust" in d]
        if shaken:
            held_ok = [r for d in shaken for r, o in zip(d["trial_robust"], d["trial_outcomes"], strict=True)
                       if o == "success"]
            held_no = [r for d in shaken for r, o in zip(d["trial_robust"], d["trial_outcomes"], strict=True)
                       if o != "success"]
            lines += [f"- each tried grasp also lifted {meta['perturb']} times, moved {1000 * COPY_SHIFT:.0f} mm "
                      f"(standard deviation on each axis) and turned {COPY_TURN_DEG:.0f} degrees: the share of "
                      "copies that held, on average, for the first grasp "
                      f"{np.mean([d['trial_robust'][0] for d in shaken]):.2f}, "
                      f"for the grasp with the highest share among the tried "
                      f"{np.mean([max(d['trial_robust']) for d in shaken]):.2f}; for grasps whose own trial held "
                      f"{np.mean(held_ok) if held_ok else float('nan'):.2f} ({len(held_ok)}), whose trial failed "
                      f"{np.mean(held_no) if held_no else float('nan'):.2f} ({len(held_no)})"]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    clutter.add_look_arguments(ap)
    ap.add_argument("--top", type=int, default=DEFAULT_TOP, help="feasible grasps tried in physics per detection")
    ap.add_argument("--perturb", type=int, default=0, help="perturbed copies of each tried grasp lifted too")
    ap.add_argument("--images", type=Path, default=None,
                    help="write each tried grasp's image with its records here (.npz; generated data, never committed)")
    args = ap.parse_args(argv)
    if args.top < 1:
        ap.error("--top must be at least 1")
    shots: list[NDArray[np.uint8]] | None = None if args.images is None else []
    setting = looked_setting(args.object_set, args.scene, args.container, args.split)
    seeds = range(args.seed, args.seed + args.rounds)
    ranked: list[RoundResult] = []
    oracle: list[RoundResult] = []
    detections: list[dict[str, Any]] = []
    with clutter.serving(args.service) as service:
        served = clutter.reported_model("gpd", args.model, service, setting.hand)
        for seed in seeds:
            detector = Watched(clutter.make_detector("gpd", args.model, service))
            ranked.append(run_round(detector, setting, seed))
            first = len(detections)
            result = run_round(detector, setting, seed, choose=oracle_chooser(args.top, setting.hand, detections,
                                                                              detector, args.perturb, shots))
            executed = [o for o in result.outcomes if o != "no_grasp"]
            for row, outcome in zip(detections[first:], executed, strict=True):
                row.update(seed=seed, outcome=outcome)
            oracle.append(result)
            if shots is not None and args.images is not None:  # after every round: a stopped run keeps its rounds
                save_images(args.images, shots, detections)
            print(f"seed {seed}: ranked {ranked[-1].outcomes} oracle {result.outcomes}", flush=True)
    meta = {"command": "PYTHONPATH=service:client:lab .venv/bin/python bench/oracle.py "
            + shlex.join(sys.argv[1:] if argv is None else argv), "commit": clutter.git_commit(),
            "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "model": served, "top": args.top,
            "perturb": args.perturb,
            "scenes": (f"{args.container} ({args.split} ranges)" if args.container else args.scene)
            + f", {args.object_set} objects, seeds {seeds.start}-{seeds.stop - 1}"}
    data = {"meta": meta, "rows": {"ranked (the service's first grasp)": summarize(ranked).to_dict(),
                                   f"oracle over the top {args.top}": summarize(oracle).to_dict()},
            "detections": detections,
            "rounds": {"ranked": [r.to_dict() for r in ranked], "oracle": [r.to_dict() for r in oracle]}}
    args.out.mkdir(parents=True, exist_ok=True)
    md = report(data)
    (args.out / f"oracle-{args.tag}.md").write_text(md)
    (args.out / f"oracle-{args.tag}.json").write_text(json.dumps(data, indent=1))
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
