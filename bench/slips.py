"""Why lifted objects slip: the clutter protocol's rounds, each executed grasp measured against the true object.

Before the simulated hand executes a grasp, the object nearest the middle of its closing region is looked up in
the true scene: its name, mass (kg, the URDF's), and where the grasp holds it: how far the fingertips reach past
the object's centre of mass along the approach (m; negative: the fingertips stop short of it, so the fingers
squeeze only the part of the object nearer the hand, where a rounded or tilted surface wedges it out of them), and
how far the closing line passes from the centre of mass (m; the lever its weight turns in the fingers).  After the
round each record gets its outcome; the report gives the success share by fingertip reach and by mass, and the
objects that failed most.  The rounds are bench/clutter.py's (same seeds and scenes, plain POST /detect with the
service's defaults); the look-up only reads the world.

  PYTHONPATH=service:client .venv/bin/python bench/slips.py --object-set household --scene pile-side \\
      --rounds 30 --tag household-pile
  ... --container tray --rounds 10 --tag household-tray      (bench/containers.py's rounds of one style: 8 objects,
                                                              passive cameras, the style's held-out ranges)
writes bench/results/slips-<tag>.md and .json.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402
import pybullet as pb  # noqa: E402

import clutter  # noqa: E402
from containers import add_scene_arguments, looked_setting  # noqa: E402
from graspd.core.cloud import ViewpointCloud  # noqa: E402
from graspd.core.grasp import GraspSet  # noqa: E402
from graspd_lab.sim.object_sets import object_label  # noqa: E402
from graspd_lab.sim.world import SimWorld  # noqa: E402

#: Bins of the fingertips' reach past the centre of mass along the approach (m), and of the object's mass (kg).
REACH_BINS = (-np.inf, -0.01, 0.0, 0.01, np.inf)
MASS_BINS = (0.0, 0.05, 0.5, 1.5, np.inf)


def measure(world: SimWorld, grasps: GraspSet, pick: int, hand_depth: float, init_bite: float) -> dict[str, Any]:
    """The executed grasp against the true object nearest the middle of its closing region (world frame, m)."""
    c = world.client
    pos, rot = grasps.positions[pick].astype(np.float64), grasps.rotations[pick].astype(np.float64)
    approach, closing = rot[:, 0], rot[:, 1]
    middle = pos + (hand_depth - init_bite) * approach
    body = min(world.objects, key=lambda b: float(np.linalg.norm(world.object_position(b) - middle)))
    com = np.asarray(pb.getBasePositionAndOrientation(body, physicsClientId=c)[0])
    tips = pos + hand_depth * approach
    off = com - middle
    return {"object": object_label(world.objects[body]),
            "mass": float(pb.getDynamicsInfo(body, -1, physicsClientId=c)[0]),
            "width": float(grasps.widths[pick]), "score": float(grasps.scores[pick]),
            "reach_past_com": float((tips - com) @ approach),
            "line_from_com": float(np.linalg.norm(off - (off @ closing) * closing)),
            "approach_from_down": float(np.degrees(np.arccos(np.clip(-approach[2], -1.0, 1.0))))}


def bin_label(lo: float, hi: float, unit: str, scale: float = 1.0) -> str:
    """A bin's label: "< hi", ">= lo" or "lo to hi", scaled, with its unit."""
    return (f"< {hi * scale:g} {unit}" if not np.isfinite(lo) else f">= {lo * scale:g} {unit}"
            if not np.isfinite(hi) else f"{lo * scale:g} to {hi * scale:g} {unit}")


def binned(records: list[dict[str, Any]], key: str, edges: tuple[float, ...], unit: str, scale: float
           ) -> list[str]:
    """Markdown rows: per bin of records[key], the attempts, their success share and their outcomes."""
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sub = [r for r in records if lo <= r[key] < hi]
        if not sub:
            continue
        label = bin_label(lo, hi, unit, scale)
        ok = sum(r["outcome"] == "success" for r in sub)
        rows.append(f"| {label} | {len(sub)} | {100 * ok / len(sub):.0f}% | "
                    f"{', '.join(f'{k} {v}' for k, v in Counter(r['outcome'] for r in sub).most_common())} |")
    return rows


def report(records: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """Markdown: success by fingertip reach past the centre of mass and by mass, and the objects that failed most."""
    lines = ["# Why lifted objects slip (each executed grasp against the true object)", "",
             f"- command: `{meta['command']}`", f"- commit: `{meta['commit']}`, date {meta['date']}, model "
             f"{meta['model']}", "",
             f"Executed grasps: {len(records)}; outcomes {dict(Counter(r['outcome'] for r in records))}.", "",
             "## By how far the fingertips reach past the object's centre of mass (along the approach)", "",
             "| reach | attempts | success | outcomes |", "|---|---|---|---|",
             *binned(records, "reach_past_com", REACH_BINS, "cm", 100.0), "",
             "## By the object's mass", "", "| mass | attempts | success | outcomes |", "|---|---|---|---|",
             *binned(records, "mass", MASS_BINS, "kg", 1.0), "",
             "## Objects with the most failures", "",
             "| object | mass (kg) | attempts | failures | median reach past the centre of mass of failures (cm) |",
             "|---|---|---|---|---|"]
    by: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in records:
        by[r["object"]].append(r)
    worst = sorted(by.items(), key=lambda kv: -sum(r["outcome"] != "success" for r in kv[1]))
    for name, rs in worst[:12]:
        fails = [r for r in rs if r["outcome"] != "success"]
        if not fails:
            break
        reach = 100 * float(np.median([r["reach_past_com"] for r in fails]))
        lines.append(f"| {name} | {rs[0]['mass']:.3f} | {len(rs)} | {len(fails)} | {reach:+.1f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    clutter.add_look_arguments(ap)
    args = ap.parse_args(argv)
    setting = looked_setting(args.object_set, args.scene, args.container, args.split)
    hand = setting.hand
    model = args.model  # None: the service picks, as for any user with this hand

    def look(world: SimWorld, cloud: ViewpointCloud, grasps: GraspSet, pick: int) -> dict[str, Any]:
        return measure(world, grasps, pick, hand.hand_depth, hand.init_bite)

    with clutter.serving(args.service) as service:
        served = clutter.reported_model("gpd", model, service, hand)
        records = clutter.looked_rounds(setting, model, service, range(args.seed, args.seed + args.rounds), look)
    print(clutter.write_looks(args.out, f"slips-{args.tag}", "slips.py", argv, served, records, report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
