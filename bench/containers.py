"""Containers benchmark: the clutter protocol and precision@1/5 on the container family's held-out
styles, graspd beside the top-down baseline, one table per style and a headline over held-out styles only.

Scenes: graspd_lab.sim.containers (the split is written down there, once): each round's container is drawn
from the seed (scene_container: style, size, walls, floor height, yaw), the held-out test objects
(random_urdfs 900-999) are dropped into it, and the passive cameras see it with the table around it.
Per round and detector:

  (a) the clutter protocol (graspd_lab.sim.protocol.run_round, IJRR Table 1): detect, execute the first feasible
      grasp with the simulated hand, repeat until the container is empty or the stopping rules end the
      round; success = successes / attempts, cleared = objects lifted out / objects in the scene, both with
      95% bootstrap intervals over rounds.  A hand that touches a container body or the table on its way in
      is a collision.
  (b) precision@1 / @5 of the first detection of the scene (the same cloud the round starts with): each of
      the top 5 returned grasps, best first, is checked against the true meshes with the training labels
      (graspd_lab.training.labels.label_grasps with scene_labels(): contacts antipodal within friction cones on
      one object, nothing hit by the hand or on its approach path), and fails as well when the open hand,
      swept along its approach path, enters a static body (walls, floor slab, platform, ceiling, table) by
      more than 2 mm or a finger's first contact is a static body.  Failure classes: "environment" (touches
      the container or support), "collision" (the hand hits an object), "no pinch" (no antipodal pair on one
      object).  P@k is the mean over scenes that returned grasps; "no grasp" counts the others.

The gpd detector is called as a user calls it: plain POST /detect through graspd_client (cloud, cameras,
hand, the workspace box: the container plus 5 cm of table, from just below the table to 0.4 m), on a
service started on a free port unless --service names one (bench/clutter.py's start_service and
make_detector).  --in-process runs GraspDetector in this process (developer runs; without the service's
cascade).  The headline row counts only held-out styles; a training style (tuned on) gets its own rows,
marked so, and never enters the headline.  Every finished round is appended to
containers-<tag>.rounds.jsonl; rerunning the same command resumes from it.

Examples:
  PYTHONPATH=service:client .venv/bin/python bench/containers.py --rounds 30 --tag heldout
  ... --rounds 2 --in-process --tag smoke
  ... --object-set household --rounds 30 --tag household   (8 held-out household models at true size per
                                       scene, Panda-like hand: graspd_lab.sim.object_sets)
  ... --split training --styles tray tote --rounds 10 --tag tuned   (training styles and ranges: "tuned on")
  ... --jobs 2 --ray                  (rounds as Ray tasks on this machine; graspd-lab[cluster]; --address: a
                                       cluster, with --in-process or a --service URL the nodes reach)
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

import clutter  # noqa: E402  (bench/clutter.py: service start, detectors, round log, formatting)
from graspd.core.grasp import GraspSet  # noqa: E402
from graspd.core.hand import HandGeometry  # noqa: E402
from graspd.core.progress import Progress  # noqa: E402
from graspd_lab.cluster import RayMissingError, imap, runner_from_args  # noqa: E402
from graspd_lab.cluster import add_arguments as add_cluster_arguments  # noqa: E402
from graspd_lab.sim.containers import (  # noqa: E402
    HELD_OUT_STYLES,
    SPLITS,
    STYLES,
    TRAINING_STYLES,
    TUNED_ON,
    scene_container,
)
from graspd_lab.sim.detectors import SimDetector  # noqa: E402
from graspd_lab.sim.object_sets import OBJECT_SETS, object_set_hand, object_set_stop  # noqa: E402
from graspd_lab.sim.object_sets import describe as describe_objects  # noqa: E402
from graspd_lab.sim.protocol import (  # noqa: E402
    SENSINGS,
    STOP_RULE_TEXT,
    RoundResult,
    Setting,
    Summary,
    cameras_for,
    run_round,
    setting_scene,
    summarize,
)
from graspd_lab.sim.sensing import observe, render_rgb  # noqa: E402
from graspd_lab.sim.world import SimWorld  # noqa: E402
from graspd_lab.training.labels import label_grasps  # noqa: E402
from graspd_lab.training.scene_data import scene_labels  # noqa: E402
from graspd_lab.training.scene_eval import precision_at_k  # noqa: E402
from graspd_lab.world.noise import DepthNoise  # noqa: E402

DETECTORS = ("gpd", "baseline", "gpd-noclass", "gpd-flat", "gpd-robust")
TOP_K = 5
#: How deep (m) the open hand may enter a static body before the check calls it a touch: the labels'
#: approach tolerance (a hand placed against a noisy cloud stops a little short).
ENTER_TOLERANCE = 0.002
#: The targets on held-out styles (service defaults, 30 rounds): success, cleared, P@1, P@5.
TARGETS = {"success": 0.90, "cleared": 0.85, "p@1": 0.90, "p@5": 0.85}
REASONS = ("ok", "environment", "collision", "no pinch")


# --- precision@k against the true meshes -----------------------------------------------------------------
def hand_points(hand: HandGeometry, approach_path: float, spacing: float = 0.004) -> NDArray[np.float64]:
    """Points (P, 3) filling the open hand's body swept back along its approach by approach_path (m), in the
    hand frame (HandGeometry.swept_boxes: two fingers and the palm), on a grid of about spacing (m)."""
    out = []
    for lo, hi in hand.swept_boxes(approach_path):
        axes = [np.linspace(a, b, max(int(np.ceil((b - a) / spacing)) + 1, 2)) for a, b in zip(lo, hi, strict=True)]
        out.append(np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3))
    return np.concatenate(out)


def check_grasps(world: SimWorld, grasps: GraspSet, hand: HandGeometry) -> list[str]:
    """The verdict on each grasp (world frame) against the world's true meshes: "ok", "environment" (the
    swept open hand enters a static body by more than ENTER_TOLERANCE, or a finger's first contact is a
    static body, or a finger collides with one), "collision" (the hand hits an object) or "no pinch"."""
    if len(grasps) == 0:
        return []
    params = scene_labels()
    static = world.static_meshes()
    posed = [m for _, m in world.object_meshes()]
    graspable = np.r_[np.zeros(len(static), bool), np.ones(len(posed), bool)]
    full = label_grasps(static + posed, grasps, hand, params, graspable=graspable)
    env_only = label_grasps(static, grasps, hand, params)
    first_static = ((np.isfinite(env_only.left_contact) & (env_only.left_contact <= full.left_contact + 1e-4))
                    | (np.isfinite(env_only.right_contact) & (env_only.right_contact <= full.right_contact + 1e-4)))
    local = hand_points(hand, params.approach_path)
    world_pts = grasps.positions[:, None, :] + np.einsum("mij,pj->mpi", grasps.rotations, local)
    enters = (world.static_labels(world_pts.reshape(-1, 3), tol=-ENTER_TOLERANCE) >= 0).reshape(len(grasps), -1)
    env = enters.any(axis=1) | first_static | env_only.collision
    return [("environment" if e else "ok" if g else "collision" if c else "no pinch")
            for g, e, c in zip(full.grasp, env, full.collision, strict=True)]


def default_objects(object_set: str) -> int:
    """Objects per container scene: 8 household objects at true size, 5 scaled ones."""
    return 8 if object_set.startswith("household") else 5


def style_setting(style: str, split: str, object_set: str, objects: int | None = None, sensing: str = "passive",
                  hand: HandGeometry | None = None) -> Setting:
    """The benchmark's setting of one container style: the split's parameter ranges, objects of the set (default 8
    household objects or 5 scaled ones), the sensing, and the hand (default: the set's).  ValueError for an unknown
    style."""
    if objects is None:
        objects = default_objects(object_set)
    return Setting(scene="container", container=style, container_split=split, num_objects=objects, sensing=sensing,
                   objects=object_set, hand=object_set_hand(object_set) if hand is None else hand)


def add_scene_arguments(ap: argparse.ArgumentParser) -> None:
    """The scene options of a looked-rounds bench (bench/approach.py, bench/slips.py): a clutter scene, or a
    container style and its parameter ranges."""
    ap.add_argument("--scene", choices=list(clutter.SCENES), default="pile-side")
    ap.add_argument("--container", choices=STYLES, default=None, help="a container style instead of --scene "
                    "(this benchmark's setting: 8 objects of a household set, passive cameras)")
    ap.add_argument("--split", choices=SPLITS, default="held_out", help="the container's parameter ranges "
                    "(training: a diagnosis that may guide tuning)")


def looked_setting(object_set: str, scene: str, container: str | None, split: str) -> Setting:
    """The rounds a looked-rounds bench replays: bench/clutter.py's scene, or with a container style this
    benchmark's setting of it (8 household objects or 5 scaled ones, passive cameras, the split's parameter
    ranges); the set's hand."""
    if container is None:
        return replace(clutter.SCENES[scene], objects=object_set, hand=object_set_hand(object_set))
    return style_setting(container, split, object_set)


def first_detection(detector: SimDetector, setting: Setting, seed: int
                    ) -> tuple[SimWorld, Any, GraspSet, tuple[float, float, float, float, float, float]]:
    """The scene of round seed, its first cloud and the detector's grasps on it: exactly the round's first
    view (run_round draws noise and the detector's seed from the same generator).  The caller closes the
    world."""
    world = setting_scene(setting, seed)
    rng = np.random.default_rng(seed + 1_000_003)
    region = world.workspace()
    noise = DepthNoise.benchmark() if setting.noise else DepthNoise.none()
    cloud = observe(world.client, cameras_for(setting), noise, rng, region)
    grasps = detector.detect(cloud, region, setting.hand, seed=int(rng.integers(2**31)))
    return world, cloud, grasps, region


def scene_precision(detector: SimDetector, setting: Setting, seed: int) -> dict[str, Any]:
    """The precision record of one scene: the container, how many grasps came back and the verdict on each of
    the top TOP_K."""
    world, _, grasps, _ = first_detection(detector, setting, seed)
    try:
        verdicts = check_grasps(world, grasps[:TOP_K], setting.hand)
        container = None if world.container is None else world.container.to_dict()
        return {"container": container, "returned": len(grasps), "verdicts": verdicts}
    finally:
        world.close()


def _one_round(args: tuple[str, str | None, str | None, Setting, int]) -> tuple[RoundResult, dict[str, Any]]:
    detector_name, model, service, setting, seed = args
    detector = clutter.make_detector(detector_name, model, service)
    precision = scene_precision(detector, setting, seed)
    return run_round(detector, setting, seed), precision


# --- summaries and tables ---------------------------------------------------------------------------------
def precision_summary(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean P@1 and P@5 over scenes that returned grasps, scenes without grasps, and top-k verdict counts."""
    per = [precision_at_k(np.array([v == "ok" for v in r["verdicts"]], float), (1, TOP_K)) for r in records
           if r["verdicts"]]
    counts = {k: sum(r["verdicts"].count(k) for r in records) for k in REASONS}
    top1 = {k: sum(1 for r in records if r["verdicts"][:1] == [k]) for k in REASONS}
    return {"scenes": len(records), "no_grasp": sum(1 for r in records if not r["verdicts"]),
            "p@1": float(np.mean([p["p@1"] for p in per])) if per else float("nan"),
            f"p@{TOP_K}": float(np.nanmean([p[f"p@{TOP_K}"] for p in per])) if per else float("nan"),
            "top1": top1, f"top{TOP_K}": counts}


def _fails(s: Summary) -> str:
    f = s.failures
    return (f"coll {f.get('collision', 0)}, empty {f.get('empty_close', 0)}, slip {f.get('slipped', 0)}, "
            f"none {f.get('no_grasp', 0)}" + (f", relooks {s.relooks}" if s.relooks else "")
            + (f", flat retries {s.flat_retries}" if s.flat_retries else ""))


def _top_fails(p: dict[str, Any]) -> str:
    c = p[f"top{TOP_K}"]
    return f"env {c['environment']}, coll {c['collision']}, no pinch {c['no pinch']}, no grasp {p['no_grasp']}"


def table(rows: dict[str, tuple[Summary, dict[str, Any]]]) -> list[str]:
    """A markdown table with one row per detector."""
    lines = ["| detector | rounds | objects | attempts | success [95% CI] | cleared [95% CI] | P@1 | P@5 | "
             "clutter failures | top-5 failures | s/round |", "|---|" + "---|" * 10]
    for name, (s, p) in rows.items():
        lines.append(f"| {name} | {s.rounds} | {s.objects} | {s.attempts} | {clutter.pct(s.success_rate)}"
                     f"{clutter.ci(s.success_ci)} | {clutter.pct(s.cleared_rate)}{clutter.ci(s.cleared_ci)} | "
                     f"{clutter.pct(p['p@1'])} | {clutter.pct(p[f'p@{TOP_K}'])} | {_fails(s)} | {_top_fails(p)} | "
                     f"{s.seconds_per_round:.0f} |")
    return lines


def markdown(per_style: dict[str, dict[str, tuple[Summary, dict[str, Any]]]],
             headline: dict[str, tuple[Summary, dict[str, Any]]], meta: dict[str, Any]) -> str:
    lines = [
        "# Containers benchmark: clutter protocol and precision@k per container style", "",
        f"- command: `{meta['command']}`",
        f"- commit: `{meta['commit']}`, date: {meta['date']}, {meta['cpus']} CPUs, jobs: {meta['jobs']}",
        f"- gpd: {meta['gpd']}; models: " + (", ".join(f"{k}: {v}" for k, v in meta["models"].items() if v)
                                            or "none"),
        f"- split: {meta['split']} parameter ranges (graspd_lab.sim.containers.RANGES); held-out styles "
        f"{', '.join(HELD_OUT_STYLES)}; training styles {', '.join(TRAINING_STYLES)} are marked \"tuned on\"",
        f"- scenes: {meta['objects']} of {describe_objects(meta.get('object_set', 'scaled'))}, dropped into each "
        "round's container, "
        f"{meta['sensing']} cameras, benchmark depth noise; workspace = container + 5 cm of table",
        *clutter.advice_lines(meta),
        *([f"- hand: {clutter.describe_hand(meta['hand'])}"] if meta.get("hand") else []),
        f"- stop rule: {STOP_RULE_TEXT[meta.get('stop', 'ijrr')]}",
        "- P@k: the top 5 of each scene's first detection checked against the true meshes (label_grasps with the "
        "training labels; a hand that touches a container or support fails); mean over scenes with grasps",
        "",
    ]
    if headline:
        lines += [f"## Headline: held-out styles only ({', '.join(meta['headline_styles'])})", ""]
        lines += table(headline)
        lines += ["", "Targets (service defaults, 30 rounds): success >= 90%, cleared >= 85%, P@1 >= 90%, "
                  "P@5 >= 85%.", ""]
    else:
        lines += ["## Headline: none (no held-out style in this run)", ""]
    for style, rows in per_style.items():
        tag = "held out" if style in HELD_OUT_STYLES else \
            "tuned on (held out at first, then tuned on)" if style in TUNED_ON else "tuned on (training style)"
        lines += [f"## {style} ({tag}, {meta['split']} ranges)", ""]
        lines += table(rows)
        lines.append("")
    return "\n".join(lines)


# --- pictures ---------------------------------------------------------------------------------------------
def scene_pictures(path: Path, styles: list[str], setting_for: dict[str, Setting], detector: SimDetector,
                   seed: int) -> None:
    """One column per style: the scene from camera 0 (pybullet render), and the cloud from above (environment
    in greys by height, objects blue, by the true static bodies) with the detector's top 5 grasps (green:
    pass the check, red: fail; numbered by rank)."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.collections import LineCollection  # noqa: PLC0415

    from graspd.viz.plot import gripper_segments  # noqa: PLC0415

    fig, axes = plt.subplots(2, len(styles), figsize=(4.6 * len(styles), 8.6), squeeze=False)
    for col, style in enumerate(styles):
        setting = setting_for[style]
        world, cloud, grasps, region = first_detection(detector, setting, seed)
        try:
            axes[0, col].imshow(render_rgb(world.client, cameras_for(setting)[0]))
            top = grasps[:TOP_K]
            verdicts = check_grasps(world, top, setting.hand)
            env = world.static_labels(cloud.points, tol=0.006) >= 0
            spec = world.container
        finally:
            world.close()
        ax = axes[1, col]
        pts = cloud.points[:: max(len(cloud) // 40_000, 1)]
        lab = env[:: max(len(cloud) // 40_000, 1)]
        ax.scatter(pts[lab, 0], pts[lab, 1], s=0.5, c=pts[lab, 2], cmap="Greys", vmin=-0.15, vmax=0.4,
                   rasterized=True)
        ax.scatter(pts[~lab, 0], pts[~lab, 1], s=0.5, c="#1f4e9c", rasterized=True)
        segs = gripper_segments(top, setting.hand, stem=0.03)[..., :2].reshape(-1, 2, 2)
        colours = np.repeat(["#1a9641" if v == "ok" else "#d7191c" for v in verdicts], 4)
        ax.add_collection(LineCollection(list(segs), colors=list(colours), linewidths=1.6))
        for rank, (p, a) in enumerate(zip(top.positions, top.approach, strict=True)):
            tip = p - 0.03 * a
            ax.text(tip[0], tip[1], str(rank + 1), fontsize=8, weight="bold")
        ax.set_xlim(region[0], region[1])
        ax.set_ylim(region[2], region[3])
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        assert spec is not None
        mark = "held out" if style in HELD_OUT_STYLES else "tuned on"
        axes[0, col].set_title(f"{style} ({mark}), seed {seed}\nyaw {np.rad2deg(spec.yaw):.0f} deg, floor "
                               f"{100 * spec.floor_height:.1f} cm, walls {100 * spec.wall_height:.0f} cm", fontsize=9)
        axes[0, col].axis("off")
        ax.set_title(f"{detector.name}: top {len(top)} ({sum(v == 'ok' for v in verdicts)} pass); "
                     f"{len(cloud)} points", fontsize=9)
    from matplotlib.lines import Line2D  # noqa: PLC0415

    handles = [Line2D([], [], ls="", marker="o", ms=4, color="#1f4e9c", label="object points (true meshes)"),
               Line2D([], [], ls="", marker="o", ms=4, color="#999999",
                      label="container and table points (grey: darker is higher)"),
               Line2D([], [], color="#1a9641", lw=1.6, label="gripper (number = rank): passes the analytic check"),
               Line2D([], [], color="#d7191c", lw=1.6, label="gripper: fails it (environment, collision, no pinch)")]
    fig.legend(handles=handles, loc="lower center", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0.0, 0.06, 1.0, 1.0))
    fig.savefig(path, dpi=80)
    plt.close(fig)


def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True)
        own = ["service", "client", "models", "bench/clutter.py", "bench/containers.py"]
        dirty = subprocess.run(["git", "status", "--porcelain", "--", *own], cwd=REPO,
                               capture_output=True, text=True).stdout.strip()
        return out.stdout.strip() + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=30, help="rounds per style and detector (seeds seed..)")
    ap.add_argument("--split", choices=SPLITS, default="held_out", help="which parameter ranges the containers "
                    "are drawn from (graspd_lab.sim.containers.RANGES)")
    ap.add_argument("--styles", nargs="+", default=None, help=f"container styles {STYLES} (default: the held-out "
                    "styles; with --split training, the training styles)")
    ap.add_argument("--detectors", default="gpd,baseline", help=f"comma-separated, of {DETECTORS}")
    ap.add_argument("--objects", type=int, default=None, help="objects per scene (default: 5; 8 with "
                    "--object-set household)")
    ap.add_argument("--object-set", choices=OBJECT_SETS, default="scaled", help="scaled: random_urdfs 900-999 "
                    "scaled to the hand (default hand); household: the held-out household models at true size "
                    "(Panda-like hand, 7.5 cm opening)")
    clutter.add_hand_argument(ap)
    ap.add_argument("--sensing", choices=SENSINGS, default="passive")
    clutter.add_advice_arguments(ap)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1, help="rounds run in parallel processes (Ray CPUs with --ray)")
    add_cluster_arguments(ap)
    ap.add_argument("--model", default=None, help="classifier for gpd (default: the service's default model)")
    ap.add_argument("--service", default=None, help="URL of a running graspd service (default: start one)")
    ap.add_argument("--in-process", action="store_true", help="run gpd in this process, without HTTP (developer "
                    "runs; not what a robot gets)")
    ap.add_argument("--fresh", action="store_true", help="ignore rounds recorded by an earlier run of this tag")
    ap.add_argument("--no-pictures", action="store_true", help="skip the scene pictures")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--tag", default="run", help="output files: containers-<tag>.md/.json/.png/.rounds.jsonl")
    args = ap.parse_args(argv)
    if args.rounds < 1:
        ap.error("--rounds must be >= 1")
    detectors = [d.strip() for d in args.detectors.split(",") if d.strip()]
    bad = [d for d in detectors if d not in DETECTORS]
    if bad or not detectors:
        ap.error(f"--detectors must name some of {DETECTORS}, got {args.detectors!r}")
    styles = args.styles or list(HELD_OUT_STYLES if args.split == "held_out" else TRAINING_STYLES)
    if args.objects is None:
        args.objects = default_objects(args.object_set)
    hand = clutter.run_hand(args.object_set, args.hand)
    settings: dict[str, Setting] = {}
    for style in styles:
        try:
            base = style_setting(style, args.split, args.object_set, args.objects, args.sensing, hand)
            settings[style] = replace(base, relook=args.relook, flat_retry=args.flat_retry)
        except ValueError as exc:
            ap.error(f"--styles {style}: {exc}")
    if args.in_process and args.service:
        ap.error("--in-process and --service exclude each other")
    try:
        runner = runner_from_args(args, args.jobs, context="fork")
    except RayMissingError as exc:
        ap.error(str(exc))
    proc = None
    service = args.service
    if service is None and not args.in_process and any(d != "baseline" for d in detectors):
        proc, service = clutter.start_service()
    models = {d: clutter.model_for(d, args.model, service) for d in detectors}
    reported = {d: clutter.reported_model(d, m, service, hand) for d, m in models.items()}
    stem = f"containers-{args.tag}"
    meta: dict[str, Any] = {
        "command": "PYTHONPATH=service:client .venv/bin/python bench/containers.py "
        + shlex.join(sys.argv[1:] if argv is None else argv),
        "commit": git_commit(), "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "cpus": os.cpu_count(),
        "jobs": args.jobs, "runner": runner.describe(),
        "gpd": "in-process GraspDetector" if args.in_process else f"POST /detect to {service}",
        "models": reported, "split": args.split, "objects": args.objects, "object_set": args.object_set,
        "stop": object_set_stop(args.object_set), "hand": args.hand,
        "sensing": args.sensing, "relook": args.relook, "flat_retry": args.flat_retry,
        "styles": styles, "headline_styles": [s for s in styles if s in HELD_OUT_STYLES],
        "containers": {s: [scene_container(s, args.seed + i, args.split).to_dict() for i in range(args.rounds)]
                       for s in styles},
    }
    args.out.mkdir(parents=True, exist_ok=True)
    log = args.out / f"{stem}.rounds.jsonl"
    if args.fresh:
        log.unlink(missing_ok=True)
    seeds = [args.seed + i for i in range(args.rounds)]
    per_style: dict[str, dict[str, tuple[Summary, dict[str, Any]]]] = {}
    pooled: dict[str, tuple[list[RoundResult], list[dict[str, Any]]]] = {d: ([], []) for d in detectors}
    data: dict[str, Any] = {}
    md = ""
    try:
        for style, setting in settings.items():
            per_style[style] = {}
            for det in detectors:
                spec = f"{det}@{style}-{args.split}"
                done = {} if args.fresh else clutter.load_rows(log, spec, setting)
                jobs = [(det, models[det], service, setting, s) for s in seeds if s not in done]
                t0 = time.perf_counter()
                if done:
                    print(f"{spec}: resuming, {len(seeds) - len(jobs)} of {len(seeds)} rounds recorded", flush=True)

                # rounds come back as they finish (a pool or Ray tasks: graspd_lab.cluster), each logged at once
                with Progress(len(jobs), spec, "round") as bar:  # a bar on a terminal, a line a minute in logs
                    for rnd, check in imap(_one_round, jobs, runner):
                        clutter.record_round(log, spec, setting, rnd, precision=check)
                        done[rnd.seed] = {"round": rnd.to_dict(), "precision": check}
                        bar.update(1)
                results = [RoundResult(**done[s]["round"]) for s in seeds]
                precision = [done[s]["precision"] for s in seeds]
                summary, psum = summarize(results), precision_summary(precision)
                per_style[style][det] = (summary, psum)
                data[spec] = {"summary": summary.to_dict(), "precision": psum, "rounds": [done[s] for s in seeds]}
                if style in HELD_OUT_STYLES:
                    pooled[det][0].extend(results)
                    pooled[det][1].extend(precision)
                print(f"{spec:32s} success {clutter.pct(summary.success_rate)}{clutter.ci(summary.success_ci)}  "
                      f"cleared {clutter.pct(summary.cleared_rate)}{clutter.ci(summary.cleared_ci)}  "
                      f"P@1 {clutter.pct(psum['p@1'])}  P@5 {clutter.pct(psum[f'p@{TOP_K}'])}  "
                      f"({time.perf_counter() - t0:.0f} s)", flush=True)
        headline = {d: (summarize(r), precision_summary(p)) for d, (r, p) in pooled.items() if r}
        md = markdown(per_style, headline, meta)
        (args.out / f"{stem}.md").write_text(md)
        (args.out / f"{stem}.json").write_text(json.dumps(
            {"meta": meta, "headline": {d: {"summary": s.to_dict(), "precision": p} for d, (s, p) in headline.items()},
             "settings": data}, indent=1))
        if not args.no_pictures:
            det = detectors[0]
            scene_pictures(args.out / f"{stem}.png", styles, settings, clutter.make_detector(det, models[det], service),
                           args.seed)
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(timeout=10)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
