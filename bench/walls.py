"""Container walls the environment stage finds, against the true container: sides found, sides missed, and walls
found that are no side (objects' faces in a line, taken for a wall).

For each seed, the container benchmark's scene of a style is built and seen as its rounds first see it
(bench/containers.py: the same seed, cameras, depth noise and workspace box), and the detector's environment
stage runs with the defaults a request gets.  Each wall box found is matched, in the container's frame, to the
side whose mid-plane its centre lies within MATCH (m) of, inside the container's length; a side with no match
is missed (where hands may close on its top: "closes on nothing"), a wall with no side is an object's face
that the hands will not be sent to.  Only the environment stage runs; no grasp is searched or executed.

  PYTHONPATH=service:client:lab .venv/bin/python bench/walls.py --styles tray deep_bin --split training \\
      --object-set household-training --seed 100 --rounds 20 --tag training-trays
writes bench/results/walls-<tag>.md and .json.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402

from containers import git_commit, style_setting  # noqa: E402
from graspd.gpd.detector import DetectionParams, GraspDetector  # noqa: E402
from graspd_lab.sim.containers import SPLITS, STYLES, ContainerSpec  # noqa: E402
from graspd_lab.sim.object_sets import OBJECT_SETS  # noqa: E402
from graspd_lab.sim.protocol import cameras_for, setting_scene  # noqa: E402
from graspd_lab.sim.sensing import DepthNoise, observe  # noqa: E402

#: How far (m) a wall box's centre may lie from a side's mid-plane, in the container's frame, to be that side.
MATCH = 0.03


def side_of(spec: ContainerSpec, centre: np.ndarray) -> str | None:
    """The container side ('-x', '+x', '-y', '+y') a wall box centred at centre (world frame, m) stands on, or
    None."""
    c = spec.to_container(centre[None])[0]
    hx, hy = spec.inner_x / 2 + spec.wall_thickness / 2, spec.inner_y / 2 + spec.wall_thickness / 2
    for side in spec.walls:
        axis, sign = (0, hx) if side[1] == "x" else (1, hy)
        other = (1, hy) if axis == 0 else (0, hx)
        at = sign if side[0] == "+" else -sign
        if abs(c[axis] - at) <= MATCH and abs(c[other[0]]) <= other[1] + MATCH:
            return side
    return None


def scene_walls(style: str, split: str, object_set: str, seed: int) -> dict[str, Any]:
    """One scene's first view: its sides, those found, and the walls that match none."""
    setting = style_setting(style, split, object_set)
    world = setting_scene(setting, seed)
    try:
        spec = world.container
        assert spec is not None
        region = world.workspace()
        rng = np.random.default_rng(seed + 1_000_003)  # the protocol's first view of the round
        cloud = observe(world.client, cameras_for(setting), DepthNoise.benchmark(), rng, region)
        prep = GraspDetector(None, setting.hand).prepare(cloud, DetectionParams(workspace=region), setting.hand)
        assert prep.environment is not None
        boxes = [s.box for s in prep.environment.surfaces if s.kind == "wall" and s.box is not None]
        sides = [side_of(spec, b.centre) for b in boxes]
        return {"seed": seed, "style": style, "sides": list(spec.walls),
                "found": sorted({s for s in sides if s is not None}),
                "not_sides": [np.round(spec.to_container(b.centre[None])[0], 3).tolist()
                              for b, s in zip(boxes, sides, strict=True) if s is None]}
    finally:
        world.close()


def report(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    lines = ["# Container walls found against the true container (first view of each round)", "",
             f"- command: `{meta['command']}`", f"- commit: `{meta['commit']}`",
             f"- scenes: bench/containers.py's, {meta['split']} ranges, {meta['object_set']} objects, seeds "
             f"{meta['seeds']}; the environment stage with a request's defaults; a wall matches a side when its "
             f"centre lies within {MATCH * 100:.0f} cm of the side's mid-plane", "",
             "| style | scenes | sides | found | missed | scenes with a side missed | walls that are no side "
             "| scenes with one |", "|---|---|---|---|---|---|---|---|"]
    for style in meta["styles"]:
        rs = [r for r in rows if r["style"] == style]
        sides = sum(len(r["sides"]) for r in rs)
        found = sum(len(r["found"]) for r in rs)
        lines.append(f"| {style} | {len(rs)} | {sides} | {found} | {sides - found} | "
                     f"{sum(len(r['found']) < len(r['sides']) for r in rs)} | {sum(len(r['not_sides']) for r in rs)} "
                     f"| {sum(bool(r['not_sides']) for r in rs)} |")
    lines += ["", "| style | seed | sides missed | walls that are no side (centre in the container's frame, m) |",
              "|---|---|---|---|"]
    for r in rows:
        missed = sorted(set(r["sides"]) - set(r["found"]))
        if missed or r["not_sides"]:
            lines.append(f"| {r['style']} | {r['seed']} | {', '.join(missed) or '-'} | {r['not_sides'] or '-'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--styles", nargs="+", choices=STYLES, default=["tray"])
    ap.add_argument("--split", choices=SPLITS, default="training")
    ap.add_argument("--object-set", choices=OBJECT_SETS, default="household-training")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--tag", required=True)
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = ap.parse_args(argv)
    seeds = range(args.seed, args.seed + args.rounds)
    rows = []
    for style in args.styles:
        for seed in seeds:
            rows.append(scene_walls(style, args.split, args.object_set, seed))
            r = rows[-1]
            print(f"{style} {seed}: found {r['found']} of {r['sides']}, not sides {r['not_sides']}", flush=True)
    meta = {"command": "PYTHONPATH=service:client:lab .venv/bin/python bench/walls.py "
                       + " ".join(sys.argv[1:] if argv is None else argv),
            "commit": git_commit(), "styles": args.styles, "split": args.split, "object_set": args.object_set,
            "seeds": f"{seeds.start}-{seeds.stop - 1}"}
    args.out.mkdir(parents=True, exist_ok=True)
    stem = args.out / f"walls-{args.tag}"
    stem.with_suffix(".md").write_text(report(rows, meta))
    stem.with_suffix(".json").write_text(json.dumps({"meta": meta, "scenes": rows}, indent=1))
    print(stem.with_suffix(".md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
