"""What a robot that does not retry the same place right after a failure would clear: the clutter protocol's rounds
twice, as the service ranks them and with a robot-side rule after each failed attempt.

The rounds are bench/clutter.py's (same seeds and scenes, plain POST /detect with the service's defaults).  In the
"ranked" rounds the robot executes the first feasible grasp, as bench/clutter.py does.  In the "elsewhere after a
failure" rounds, when the previous attempt failed (the robot holds nothing: as many objects are left as before it),
the robot executes the first feasible grasp whose position is more than --radius from the failed one's, or the
first when there is none; after a success it executes the first, as ranked.  The rule reads only what a robot knows
(where it grasped and whether it holds something), so it is a client-side loop, not a detector: a slipped object
lies near where it was, and the same grasp on it fails again more often than a grasp on another object; the
standard stop rule ends a round after 2 failures in a row.

  PYTHONPATH=service:client:lab .venv/bin/python bench/retry.py --object-set household-training --seed 100 \\
      --rounds 60 --tag household-training-pile
writes bench/results/retry-<tag>.md and .json.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "lab", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

import clutter  # noqa: E402
from containers import add_scene_arguments, looked_setting  # noqa: E402
from graspd.core.grasp import GraspSet  # noqa: E402
from graspd_lab.sim.protocol import Chooser, RoundResult, run_round, summarize  # noqa: E402
from graspd_lab.sim.world import SimWorld  # noqa: E402
from oracle import choice_table  # noqa: E402

#: How far (m) from a failed grasp's position the next grasp must be, by default: a hand's length, so the next
#: grasp is on another object or another part of a long one.
DEFAULT_RADIUS = 0.05


def elsewhere_chooser(radius: float, records: list[dict[str, Any]]) -> Chooser:
    """A protocol Chooser for one round: after a failed attempt, the first feasible grasp more than radius (m) from
    the failed grasp's position (else the first); otherwise the first.  Appends each pick's record to records."""
    last: dict[str, Any] = {}

    def choose(world: SimWorld, grasps: GraspSet, ok: NDArray[np.int64]) -> int:
        failed = bool(last) and len(world.objects) == last["objects"]
        pick = int(ok[0])
        if failed:
            far = np.linalg.norm(grasps.positions[ok] - last["position"], axis=1) > radius
            if far.any():
                pick = int(ok[int(np.argmax(far))])
        records.append({"after_failure": failed, "moved": pick != int(ok[0]),
                        "rank": int(np.flatnonzero(ok == pick)[0]) + 1})
        last.update(objects=len(world.objects), position=grasps.positions[pick].copy())
        return pick

    return choose


def report(data: dict[str, Any]) -> str:
    meta, rows, picks = data["meta"], data["rows"], data["picks"]
    lines = ["# Elsewhere after a failure: the service's first grasp against a robot that does not retry the same "
             "place right away", "", f"- command: `{meta['command']}`", f"- commit: `{meta['commit']}`, date "
             f"{meta['date']}, model {meta['model']}", f"- scenes: {meta['scenes']}",
             f"- rule: after a failed attempt, the first feasible grasp more than {1000 * meta['radius']:.0f} mm from "
             "the failed grasp's position (the first when none is); otherwise the first", "",
             *choice_table(rows)]
    after = [p for p in picks if p["after_failure"]]
    lines += ["", f"Picks after a failure: {len(after)}; the rule moved {sum(p['moved'] for p in after)} of them "
              "off the first grasp."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    clutter.add_look_arguments(ap)
    ap.add_argument("--radius", type=float, default=DEFAULT_RADIUS, help="m from a failed grasp's position")
    args = ap.parse_args(argv)
    setting = looked_setting(args.object_set, args.scene, args.container, args.split)
    seeds = range(args.seed, args.seed + args.rounds)
    ranked: list[RoundResult] = []
    elsewhere: list[RoundResult] = []
    picks: list[dict[str, Any]] = []
    with clutter.serving(args.service) as service:
        served = clutter.reported_model("gpd", args.model, service, setting.hand)
        for seed in seeds:
            detector = clutter.make_detector("gpd", args.model, service)
            ranked.append(run_round(detector, setting, seed))
            elsewhere.append(run_round(detector, setting, seed, choose=elsewhere_chooser(args.radius, picks)))
            print(f"seed {seed}: ranked {ranked[-1].outcomes} elsewhere {elsewhere[-1].outcomes}", flush=True)
    meta = {"command": "PYTHONPATH=service:client:lab .venv/bin/python bench/retry.py "
            + shlex.join(sys.argv[1:] if argv is None else argv), "commit": clutter.git_commit(),
            "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "model": served, "radius": args.radius,
            "scenes": (f"{args.container} ({args.split} ranges)" if args.container else args.scene)
            + f", {args.object_set} objects, seeds {seeds.start}-{seeds.stop - 1}"}
    data = {"meta": meta, "rows": {"ranked (the service's first grasp)": summarize(ranked).to_dict(),
                                   "elsewhere after a failure": summarize(elsewhere).to_dict()},
            "picks": picks,
            "rounds": {"ranked": [r.to_dict() for r in ranked], "elsewhere": [r.to_dict() for r in elsewhere]}}
    args.out.mkdir(parents=True, exist_ok=True)
    md = report(data)
    (args.out / f"retry-{args.tag}.md").write_text(md)
    (args.out / f"retry-{args.tag}.json").write_text(json.dumps(data, indent=1))
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
