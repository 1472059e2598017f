"""Would a fine-tuned model do better as a second stage?  The clutter protocol's rounds twice: as the service ranks
them, and with the service's first --top feasible grasps re-scored by another model (the rest of the ranking
terms kept) and the best of them executed.

A fine-tune on the oracle's tried grasps (bench/reranker.py) learned from the few grasps the default model puts
first; asked to rank every candidate of a scene (a request naming it as the model) it meets grasps it never saw
the like of.  Here it only re-orders the default model's first few, which is what its cross-validated table
measured.  The images are the service's (bench/oracle.py's tried_images); nothing reads the true world.

  PYTHONPATH=service:client:lab .venv/bin/python bench/two_stage.py --object-set household-training \\
      --container tray --split training --seed 100 --rounds 10 --second triedall15 --tag household-training-tray
writes bench/results/two-stage-<tag>.md and .json.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from datetime import UTC, datetime
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "lab", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

import clutter  # noqa: E402
from containers import add_scene_arguments, looked_setting  # noqa: E402
from graspd.core.grasp import GraspSet  # noqa: E402
from graspd.core.hand import HandGeometry  # noqa: E402
from graspd.gpd.classifier import GraspClassifier, load_model  # noqa: E402
from graspd_lab.sim.protocol import Chooser, RoundResult, run_round, summarize  # noqa: E402
from graspd_lab.sim.world import SimWorld  # noqa: E402
from oracle import Watched, choice_table, other_terms, tried_images  # noqa: E402

#: Feasible grasps the second model re-orders, by default: the oracle's and the fine-tune's records' top.
DEFAULT_TOP = 5


def second_stage(top: int, hand: HandGeometry, detector: Watched, model: GraspClassifier,
                 blend: float = 1.0) -> Chooser:
    """A protocol Chooser: of the first `top` feasible grasps, the one with the highest second-model score times
    its other ranking terms (the answer's key over its score).  blend < 1 weighs the two models' scores
    geometrically: first ** (1 - blend) * second ** blend."""

    def choose(world: SimWorld, grasps: GraspSet, ok: NDArray[np.int64]) -> int:
        tried = ok[:top]
        if len(tried) < 2 or detector.cloud is None or detector.workspace is None:
            return int(ok[0])
        scores = model.score(tried_images(detector.cloud, detector.workspace, grasps[tried], hand))
        answer = detector.last
        raw = (answer.raw.get("grasps") or []) if answer is not None else []
        terms = other_terms([raw[i].get("ranking") if i < len(raw) else None for i in tried], grasps.scores[tried])
        first = np.clip(np.asarray(grasps.scores[tried], np.float64), 1e-6, 1.0)
        mixed = first ** (1.0 - blend) * np.clip(np.asarray(scores, np.float64), 1e-6, 1.0) ** blend
        return int(tried[int(np.argmax(mixed * terms))])

    return choose


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    clutter.add_look_arguments(ap)
    ap.add_argument("--top", type=int, default=DEFAULT_TOP, help="feasible grasps the second model re-orders")
    ap.add_argument("--second", required=True, help="the second model (models/NAME.onnx)")
    ap.add_argument("--blend", type=float, default=1.0,
                    help="weight of the second model's score: first ** (1 - w) * second ** w (1: the second alone)")
    args = ap.parse_args(argv)
    setting = looked_setting(args.object_set, args.scene, args.container, args.split)
    second = load_model(args.second, threads=1)
    seeds = range(args.seed, args.seed + args.rounds)
    ranked: list[RoundResult] = []
    staged: list[RoundResult] = []
    with clutter.serving(args.service) as service:
        served = clutter.reported_model("gpd", args.model, service, setting.hand)
        for seed in seeds:
            detector = Watched(clutter.make_detector("gpd", args.model, service))
            ranked.append(run_round(detector, setting, seed))
            staged.append(run_round(detector, setting, seed,
                                    choose=second_stage(args.top, setting.hand, detector, second, args.blend)))
            print(f"seed {seed}: ranked {ranked[-1].outcomes} two-stage {staged[-1].outcomes}", flush=True)
    meta = {"command": "PYTHONPATH=service:client:lab .venv/bin/python bench/two_stage.py "
            + shlex.join(sys.argv[1:] if argv is None else argv), "commit": clutter.git_commit(),
            "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "model": served, "second": args.second,
            "top": args.top, "blend": args.blend,
            "scenes": (f"{args.container} ({args.split} ranges)" if args.container else args.scene)
            + f", {args.object_set} objects, seeds {seeds.start}-{seeds.stop - 1}"}
    rows = {"ranked (the service's first grasp)": summarize(ranked).to_dict(),
            f"{args.second} re-orders the first {args.top}": summarize(staged).to_dict()}
    lines = ["# A fine-tuned model as a second stage: it re-orders the service's first feasible grasps", "",
             f"- command: `{meta['command']}`", f"- commit: `{meta['commit']}`, date {meta['date']}, model "
             f"{served}, second stage {args.second} over the first {args.top} (blend {args.blend:g})",
             f"- scenes: {meta['scenes']}", "",
             *choice_table(rows)]
    md = "\n".join(lines) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"two-stage-{args.tag}.md").write_text(md)
    data = {"meta": meta, "rows": rows, "rounds": {"ranked": [r.to_dict() for r in ranked],
                                                   "two-stage": [r.to_dict() for r in staged]}}
    (args.out / f"two-stage-{args.tag}.json").write_text(json.dumps(data, indent=1))
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
