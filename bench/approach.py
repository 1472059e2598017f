"""Why hands hit things on the way in: the clutter protocol's rounds, each executed grasp swept first.

Before the simulated hand executes a grasp, the open hand is stepped (kinematically, 2 mm steps) from the
pre-grasp pose to the grasp pose through the true scene, and the first step where it enters a body by more than
1 mm (the simulator's collision threshold) is recorded: where (pre-grasp pose or approach path), what (a
neighbouring object, the object grasped, or a static body: table, walls), which part of the hand (palm or a
finger) and how far behind the finger roots.  The point it enters is then looked up in what the detector was
given: the nearest cloud point, whether the hand's swept outline held cloud points at all, and whether the point
lies in space no camera saw (the service's unobserved volume: shadow_length = the hand's opening, and a long one).
The rounds are bench/clutter.py's (same seeds and scenes, plain POST /detect with the service's defaults); the
sweep only looks, but its hand is a body of its own for a moment, which can change later physics slightly.
--top K instead sweeps the K best grasps of each scene's first detection (bench/containers.py's P@k view: more
hands per minute, no execution).  --container STYLE replays bench/containers.py's rounds of one style instead (8
objects, passive cameras, the style's --split ranges: training ones for a diagnosis that may guide tuning).

  PYTHONPATH=service:client .venv/bin/python bench/approach.py --object-set household --scene pile-side \\
      --rounds 30 --tag household-pile
writes bench/results/approach-<tag>.md and .json.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402
import pybullet as pb  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

import clutter  # noqa: E402
from containers import add_scene_arguments, first_detection, looked_setting  # noqa: E402
from graspd.core.cloud import ViewpointCloud  # noqa: E402
from graspd.core.grasp import GraspSet  # noqa: E402
from graspd.core.hand import HandGeometry  # noqa: E402
from graspd.gpd.scene import unobserved_grid  # noqa: E402
from graspd_lab.sim.gripper import ExecutionParams, Gripper  # noqa: E402
from graspd_lab.sim.world import SimWorld  # noqa: E402

F64 = NDArray[np.float64]
#: Penetration (m) the simulator's pre-grasp check calls a collision (Gripper._in_collision).
ENTER = 0.001
#: Step (m) of the kinematic sweep from the pre-grasp pose to the grasp.
STEP = 0.002
#: A hit point this close (m) to a cloud point counts as seen (sensor noise, voxel size).
SEEN_WITHIN = 0.005
#: The long shadow (m) of the unobserved-volume lookup: unseen space far behind a surface.
LONG_SHADOW = 0.3


def first_hit(world: SimWorld, hand: HandGeometry, position: F64, rotation: F64, pregrasp: float
              ) -> dict[str, Any] | None:
    """The first pose from the pre-grasp pose to the grasp (STEP apart) where the open hand enters a body by more
    than ENTER (m): stage, body, hand link, travelled distance (m) and the deepest point on the body (world, m);
    None when the path is clear.  The sweep's hand is a body of its own, removed again afterwards."""
    c = world.client
    gripper = Gripper(world, hand)
    approach = rotation[:, 0]
    quat = [float(v) for v in Rotation.from_matrix(rotation).as_quat()]
    steps = int(np.ceil(pregrasp / STEP))
    names = {**{b: "object" for b in world.objects}, **{b: world.static_names.get(b, "static")
                                                        for b in world.static_bodies}}
    try:
        for j in (0, 1):
            pb.resetJointState(gripper.body, j, 0.0, physicsClientId=c)
        for k in range(steps + 1):
            pos = position - (pregrasp - min(k * STEP, pregrasp)) * approach
            pb.resetBasePositionAndOrientation(gripper.body, pos.tolist(), quat, physicsClientId=c)
            pb.performCollisionDetection(physicsClientId=c)
            worst: tuple[float, int, int, Any] | None = None
            for body in names:
                for cp in pb.getClosestPoints(gripper.body, body, 0.0, physicsClientId=c):
                    if cp[8] < -ENTER and (worst is None or cp[8] < worst[0]):
                        worst = (float(cp[8]), body, int(cp[3]), cp[6])
            if worst is not None:
                depth, body, link, point = worst
                return {"stage": "pre-grasp" if k == 0 else "grasp pose" if k == steps else "approach",
                        "travelled": min(k * STEP, pregrasp), "body": body, "what": names[body],
                        "link": {-1: "palm", 0: "finger", 1: "finger"}.get(link, "?"), "penetration": -depth,
                        "point": [float(v) for v in point]}
        return None
    finally:
        pb.removeConstraint(gripper.constraint, physicsClientId=c)
        pb.removeBody(gripper.body, physicsClientId=c)


def look_up(hit: dict[str, Any], cloud: ViewpointCloud, tree: cKDTree, grids: dict[str, Any],
            position: F64, rotation: F64, hand: HandGeometry, pregrasp: float) -> dict[str, Any]:
    """What the detector had of a hit point: nearest cloud point (m), the point in the hand frame (m), whether it
    lies in unseen space (each grid), and how many cloud points the hand's swept outline held."""
    q = np.asarray(hit["point"])
    dist, _ = tree.query(q)
    local = (q - position) @ rotation
    boxes = hand.swept_boxes(pregrasp)
    pts_local = (cloud.points.astype(np.float64) - position) @ rotation
    inside = np.zeros(len(pts_local), bool)
    for lo, hi in boxes:
        inside |= np.all((pts_local > lo) & (pts_local < hi), axis=1)
    out = {"nearest_cloud_point": float(dist), "local": [float(v) for v in local],
           "cloud_points_in_swept_hand": int(inside.sum())}
    for name, grid in grids.items():
        out[f"unseen_{name}"] = bool(grid.contains(q[None].astype(np.float32))[0])
    return out


def cause(hit: dict[str, Any]) -> str:
    """The diagnosis of one hit: seen points in the hand's path, a hit point near a seen point (noise margin),
    unseen space within the opening's shadow, unseen space beyond it, or none of these."""
    if hit["cloud_points_in_swept_hand"] > 0 and hit["nearest_cloud_point"] <= SEEN_WITHIN:
        return "seen points in the swept hand"
    if hit["nearest_cloud_point"] <= SEEN_WITHIN:
        return "within 5 mm of a seen point"
    if hit["unseen_short"]:
        return "unseen (within the opening's shadow)"
    if hit["unseen_long"]:
        return "unseen (beyond the opening's shadow)"
    return "seen by no camera and not behind a surface"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_arguments(ap)
    clutter.add_look_arguments(ap)
    ap.add_argument("--top", type=int, default=0, help="sweep the top K grasps of each scene's first detection "
                    "instead of running rounds")
    args = ap.parse_args(argv)
    setting = looked_setting(args.object_set, args.scene, args.container, args.split)
    hand = setting.hand
    pregrasp = ExecutionParams().pregrasp_distance
    model = args.model  # None: the service picks, as for any user with this hand

    def look(world: SimWorld, cloud: ViewpointCloud, grasps: GraspSet, pick: int) -> dict[str, Any]:
        """Sweep the grasp picked for execution; its record gets the seed and outcome once the round is over."""
        pos, rot = grasps.positions[pick].astype(np.float64), grasps.rotations[pick].astype(np.float64)
        hit = first_hit(world, hand, pos, rot, pregrasp)
        row: dict[str, Any] = {"hit": hit, "position": pos.tolist(), "rotation": rot.tolist()}
        if hit is not None:
            grids = {"short": unobserved_grid(cloud.points, cloud.viewpoints, 0.004, hand.max_aperture),
                     "long": unobserved_grid(cloud.points, cloud.viewpoints, 0.004, LONG_SHADOW)}
            centre = pos + (hand.hand_depth - hand.init_bite) * rot[:, 0]
            near = min(world.objects, key=lambda b: float(np.linalg.norm(world.object_position(b) - centre)))
            hit.update(look_up(hit, cloud, cKDTree(cloud.points), grids, pos, rot, hand, pregrasp))
            hit["grasped_object"] = hit["what"] == "object" and hit["body"] == near
            hit["cause"] = cause(hit)
        return row

    seeds = range(args.seed, args.seed + args.rounds)
    records: list[dict[str, Any]] = []
    with clutter.serving(args.service) as service:
        served = clutter.reported_model("gpd", model, service, hand)
        if not args.top:
            records = clutter.looked_rounds(setting, model, service, seeds, look)
        else:
            for seed in seeds:
                first = len(records)
                world, cloud, grasps, _ = first_detection(clutter.make_detector("gpd", model, service), setting,
                                                          seed)
                try:
                    for k in range(min(args.top, len(grasps))):
                        records.append({**look(world, cloud, grasps, k), "seed": seed, "outcome": f"top{k + 1}"})
                finally:
                    world.close()
                print(f"seed {seed}: {sum(1 for r in records[first:] if r['hit'])} of {len(records) - first} "
                      "swept hands enter a body", flush=True)
    print(clutter.write_looks(args.out, f"approach-{args.tag}", "approach.py", argv, served, records, report))
    return 0


def report(records: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """Markdown: outcomes, where the swept hand first entered a body, and why the detector did not see it."""
    hits = [r for r in records if r["hit"] is not None]
    coll = [r for r in records if r["outcome"] == "collision"]

    def kind(h: dict[str, Any]) -> str:
        return "grasped object" if h["grasped_object"] else "neighbour" if h["what"] == "object" else h["what"]

    lines = ["# Why hands hit things on the way in (kinematic sweep of each executed grasp)", "",
             f"- command: `{meta['command']}`", f"- commit: `{meta['commit']}`, date {meta['date']}, model "
             f"{meta['model']}", "",
             f"Executed grasps: {len(records)}; outcomes {dict(Counter(r['outcome'] for r in records))}; "
             f"swept hand enters a body (> {1000 * ENTER:.0f} mm): {len(hits)}; simulator collisions: {len(coll)} "
             f"(of them swept hits: {sum(1 for r in coll if r['hit'])}).", "",
             "| stage | what | link | cause | all hits | of them sim collisions |", "|---|---|---|---|---|---|"]
    groups = Counter((h["hit"]["stage"], kind(h["hit"]), h["hit"]["link"], h["hit"]["cause"]) for h in hits)
    for (stage, what, link, why), n in groups.most_common():
        nc = sum(1 for r in hits if (r["hit"]["stage"], kind(r["hit"]), r["hit"]["link"], r["hit"]["cause"])
                 == (stage, what, link, why) and r["outcome"] == "collision")
        lines.append(f"| {stage} | {what} | {link} | {why} | {n} | {nc} |")
    lines += ["", "Hit points in the hand frame (x along the approach from the finger roots, m): "
              + ", ".join(f"{h['hit']['local'][0]:+.3f}" for h in hits), ""]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
