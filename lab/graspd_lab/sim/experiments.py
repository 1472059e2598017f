"""The paper's experiments in graspd's pybullet simulation (graspd_lab.sim): scripted demonstrations,
(a) generalisation to held-out objects and (b) improvement over time with failure feedback.

Every trial is one object resting on the floor in a pose drawn from its seed, seen by one noisy depth
camera from the side (graspd_lab.sim.sensing.side_camera, like the paper's head-mounted Kinect), and one grasp
executed by graspd_lab.sim's free-floating hand.  Demonstrations are scripted: on each training object
(pybullet_data random_urdfs 000-899) the top-down baseline's grasps are executed in order until one
lifts the object; that grasp and the cloud seen before it become a library entry.  Tests use the
held-out objects 900-999 only.

    PYTHONPATH=service:client python -m graspd_lab.sim.experiments a --demos 15 --objects 7 --tests 30
    PYTHONPATH=service:client python -m graspd_lab.sim.experiments b --trials 34 --object 905

(bench/templates.py experiment ... runs the same.)
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pybullet as pb
from matplotlib.figure import Figure

from graspd.core.cloud import ViewpointCloud
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.gpd.classifier import default_model_name, load_model
from graspd.templates import TemplateDetector, TemplateError, TemplateLibrary, TemplateParams
from graspd_lab.sim.detectors import InProcessGPD, TopDownBaseline
from graspd_lab.sim.gripper import Gripper
from graspd_lab.sim.objects import graspable_scale
from graspd_lab.sim.protocol import feasible
from graspd_lab.sim.sensing import NO_NOISE, SIM_NOISE, observe, side_camera
from graspd_lab.sim.world import SimWorld, random_quat
from graspd_lab.world import objects as catalogue

NDArrayInt = np.ndarray
REGION = (-0.15, 0.15, -0.15, 0.15, -0.005, 0.4)
TRAINING_IDS = tuple(catalogue.TRAINING_URDFS)


def training_urdf(object_id: int) -> str:
    """A training object's URDF; ValueError for the held-out ids 900-999."""
    if object_id not in TRAINING_IDS:
        raise ValueError(f"object_id must be a training object in 0..899, got {object_id}")
    return str(catalogue.urdf_path(object_id))


@dataclass
class Trial:
    """One object in a settled pose, seen once: the world, the cloud and the workspace."""

    world: Any
    cloud: ViewpointCloud
    object_id: int

    def close(self) -> None:
        self.world.close()


def make_trial(object_id: int, seed: int, hand: HandGeometry, noise: bool = True, view_seed: int | None = None
               ) -> Trial:
    """A world with the object dropped in a random orientation (seed), settled, and its noisy side view
    (sensor noise from view_seed if given: the same pose seen anew)."""
    rng = np.random.default_rng(seed)
    world = SimWorld.create(has_tray=False)
    pos = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), 0.12])
    if object_id in TRAINING_IDS:
        body = pb.loadURDF(training_urdf(object_id), pos.tolist(), random_quat(rng).tolist(),
                           globalScaling=catalogue.graspable_scale(object_id, hand), physicsClientId=world.client)
        pb.changeDynamics(body, -1, lateralFriction=1.0, spinningFriction=0.002, rollingFriction=0.0005,
                          physicsClientId=world.client)
        world.objects[body] = object_id
    else:
        world.add_object(object_id, pos, random_quat(rng), graspable_scale(object_id, hand))
    world.settle()
    view_rng = rng if view_seed is None else np.random.default_rng(view_seed)
    cloud = observe(world.client, side_camera(), SIM_NOISE if noise else NO_NOISE, view_rng, REGION)
    return Trial(world, cloud, object_id)


def execute(trial: Trial, grasps: GraspSet, index: int, hand: HandGeometry) -> str:
    """Execute one grasp in the trial's world; the outcome name (graspd_lab.sim.gripper.Outcome)."""
    return str(Gripper(trial.world, hand).execute(grasps, index).outcome.value)


def feasible_order(grasps: GraspSet, hand: HandGeometry) -> NDArrayInt:
    """Indices of the grasps a robot above the floor could execute, in their order (graspd_lab.sim.protocol)."""
    return np.flatnonzero(feasible(grasps, 80.0))


def scripted_demonstrations(library: TemplateLibrary, object_ids: list[int], demos: int, seed: int = 0,
                            max_tries: int = 6, log: Any = print) -> list[dict[str, Any]]:
    """Teach `demos` grasps spread over the training objects: per demonstration a new resting pose; the
    top-down baseline's feasible grasps are executed in order (the scene rebuilt from the same seed each
    time) until one lifts the object, which is added with the cloud seen before it."""
    hand = library.hand
    taught: list[dict[str, Any]] = []
    k = 0
    while len(taught) < demos and k < demos * 4:
        oid = object_ids[k % len(object_ids)]
        pose_seed = seed * 10_000 + k
        k += 1
        view = make_trial(oid, pose_seed, hand)
        grasps = TopDownBaseline().detect(view.cloud, REGION, hand, seed=pose_seed)
        order = feasible_order(grasps, hand)[:max_tries]
        cloud = view.cloud
        view.close()
        for idx in order:
            trial = make_trial(oid, pose_seed, hand)  # the same settled pose again
            outcome = execute(trial, grasps, int(idx), hand)
            trial.close()
            if outcome != "success":
                continue
            try:
                entry = library.add_demonstration(cloud, grasps.poses[idx], label=f"random_urdfs/{oid:03d}")
            except TemplateError as exc:
                log(f"  demo on {oid:03d} skipped: {exc}")
                continue
            taught.append({"entry": entry, "object": oid, "pose_seed": pose_seed})
            log(f"  demonstration {len(taught)}: object {oid:03d}, entry {entry}")
            break
    return taught


@dataclass
class TrialLog:
    """Outcomes of a sequence of template-detected grasps."""

    outcomes: list[str] = field(default_factory=list)
    objects: list[int] = field(default_factory=list)
    detect_seconds: list[float] = field(default_factory=list)

    @property
    def successes(self) -> NDArrayInt:
        return np.array([o == "success" for o in self.outcomes], bool)


def attempt(detector: TemplateDetector, object_id: int, seed: int, feedback: bool, view_seed: int | None = None
            ) -> tuple[str, float]:
    """One trial: detect on a fresh pose, execute the best feasible grasp, report the outcome if feedback."""
    hand = detector.hand
    trial = make_trial(object_id, seed, hand, view_seed=view_seed)
    try:
        t0 = time.perf_counter()
        det = detector.detect(trial.cloud, max_grasps=50, workspace=REGION)
        spent = time.perf_counter() - t0
        order = feasible_order(det.grasps, hand)
        if len(order) == 0:
            return "no_grasp", spent
        idx = int(order[0])
        outcome = execute(trial, det.grasps, idx, hand)
        if feedback and det.grasp_ids[idx]:
            detector.library.add_feedback(det.grasp_ids[idx], success=outcome == "success")
        return outcome, spent
    finally:
        trial.close()


def other_attempt(detector: Any, object_id: int, seed: int, hand: HandGeometry) -> str:
    """One trial as `attempt`, with a graspd_lab.sim SimDetector (e.g. the top-down baseline or GPD)."""
    trial = make_trial(object_id, seed, hand)
    try:
        grasps = detector.detect(trial.cloud, REGION, hand, seed)
        order = feasible_order(grasps, hand)
        return "no_grasp" if len(order) == 0 else execute(trial, grasps, int(order[0]), hand)
    finally:
        trial.close()


@dataclass
class TemplateSimDetector:
    """Template detection behind graspd_lab.sim's SimDetector interface (bench/clutter.py can run it beside GPD);
    last_ids are the ids of the grasps it returned last, for library.add_feedback after execution."""

    library: TemplateLibrary
    name: str = "templates"
    max_grasps: int = 100
    last_ids: list[str] = field(default_factory=list)

    def detect(self, cloud: ViewpointCloud, workspace: tuple[float, ...], hand: HandGeometry, seed: int) -> GraspSet:
        if hand != self.library.hand:
            raise TemplateError("hand", f"the library was made for {self.library.hand.to_dict()}")
        det = TemplateDetector(self.library, TemplateParams(seed=seed, keep_cloud=False))
        result = det.detect(cloud, max_grasps=self.max_grasps, workspace=workspace)  # type: ignore[arg-type]
        self.last_ids = result.grasp_ids
        return result.grasps


def comparison_detector(name: str) -> Any:
    """A graspd_lab.sim SimDetector by name: "baseline" (top-down) or "gpd" (default shipped classifier)."""
    if name == "baseline":
        return TopDownBaseline()
    if name == "gpd":
        return InProcessGPD(classifier=load_model(default_model_name()))
    raise ValueError(f"compare must name baseline or gpd, got {name!r}")


def generalisation(library: TemplateLibrary, test_ids: list[int], poses: int, seed: int = 0,
                   log: Any = print, compare: Any = None) -> TrialLog:
    """Experiment (a): each held-out object in `poses` resting poses, one grasp each, no feedback; with
    compare (a graspd_lab.sim SimDetector) that detector grasps instead, on the very same poses and views."""
    det = TemplateDetector(library, TemplateParams(keep_cloud=False))
    out = TrialLog()
    for oid in test_ids:
        if oid in TRAINING_IDS:
            raise ValueError(f"test object {oid} is a training object; use the held-out ids 900-999")
        for p in range(poses):
            t_seed = 1_000_000 + seed * 1000 + oid * 10 + p
            if compare is not None:
                t0 = time.perf_counter()
                outcome = other_attempt(compare, oid, t_seed, library.hand)
                spent = time.perf_counter() - t0
            else:
                outcome, spent = attempt(det, oid, t_seed, feedback=False)
            out.outcomes.append(outcome)
            out.objects.append(oid)
            out.detect_seconds.append(spent)
            log(f"  object {oid} pose {p}: {outcome}")
    return out


def improvement(library: TemplateLibrary, object_id: int, trials: int, feedback: bool, seed: int = 0,
                log: Any = print) -> TrialLog:
    """Experiment (b): the same object again and again in new poses, reporting each outcome if feedback."""
    det = TemplateDetector(library, TemplateParams(keep_cloud=False))
    out = TrialLog()
    for t in range(trials):
        outcome, spent = attempt(det, object_id, 2_000_000 + seed * 1000 + t, feedback=feedback)
        out.outcomes.append(outcome)
        out.objects.append(object_id)
        out.detect_seconds.append(spent)
        log(f"  trial {t + 1}: {outcome}")
    return out


def copy_entries(src: TemplateLibrary, dst: TemplateLibrary) -> None:
    """Copy every library entry (not the failure sets) from src to dst."""
    for e in src.snapshot().entry_ids:
        entry = src.entry(int(e))
        dst.insert_entry(entry["heights"].ravel(), entry["types"].ravel(), entry["frame"], entry["grasp"],
                         entry["width"], entry["label"])


def retry_until_success(library: TemplateLibrary, test_ids: list[int], poses: int, retries: int, feedback: bool,
                        seed: int = 0, log: Any = print) -> list[list[str]]:
    """The paper's WAM protocol: each held-out object in `poses` poses; after a failed grasp the object is
    put back in the same pose (seen anew) for up to `retries` more attempts.  The outcomes per pose."""
    det = TemplateDetector(library, TemplateParams(keep_cloud=False))
    out: list[list[str]] = []
    for oid in test_ids:
        for p in range(poses):
            pose_seed = 1_000_000 + seed * 1000 + oid * 10 + p
            tries: list[str] = []
            for r in range(1 + retries):
                outcome, _ = attempt(det, oid, pose_seed, feedback=feedback, view_seed=pose_seed * 7 + r)
                tries.append(outcome)
                if outcome == "success":
                    break
            out.append(tries)
            log(f"  object {oid} pose {p}: {' -> '.join(tries)}")
    return out


def last_ten(successes: NDArrayInt) -> NDArrayInt:
    """Success rate over the last ten trials (fewer at the start) after each trial, as the paper's Fig. 6."""
    s = np.asarray(successes, float)
    c = np.concatenate([[0.0], np.cumsum(s)])
    idx = np.arange(1, len(s) + 1)
    lo = np.maximum(idx - 10, 0)
    return np.asarray((c[idx] - c[lo]) / (idx - lo))


def plot_improvement(with_fb: TrialLog, without: TrialLog, path: Path, object_id: int) -> None:
    """A PNG of the last-ten success curves with and without feedback (the paper's Fig. 6)."""
    fig = Figure(figsize=(6, 4))
    ax = fig.subplots()
    for log_, name in ((with_fb, "with failure feedback"), (without, "without feedback (same poses)")):
        ax.plot(np.arange(1, len(log_.outcomes) + 1), 100 * last_ten(log_.successes), marker="o", ms=3, label=name)
    ax.set_xlabel("trial")
    ax.set_ylabel("success over the last ten trials (%)")
    ax.set_ylim(-5, 105)
    ax.set_title(f"improvement over time, held-out object {object_id} (cf. Herzog Fig. 6)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def pool_improvement(out: Path) -> dict[str, Any]:
    """Pool every (b) result in out: per-run first/last ten, overall success by arm, and a PNG of the
    mean last-ten curves with and without feedback."""
    runs = [json.loads(p.read_text()) for p in sorted(out.glob("templates_experiment_b_*.json"))]
    if not runs:
        raise FileNotFoundError(f"no templates_experiment_b_*.json in {out}")
    arms = {arm: [np.array([o == "success" for o in r[f"outcomes_{arm}"]]) for r in runs]
            for arm in ("feedback", "control")}
    n = min(len(a) for a in arms["feedback"])
    fig = Figure(figsize=(6, 4))
    ax = fig.subplots()
    pooled: dict[str, Any] = {"runs": [{"object": r["object"], "pose_seed": r["pose_seed"],
                                        "first_ten": r["first_ten"], "last_ten": r["last_ten"],
                                        "control_first_ten": r["control_first_ten"],
                                        "control_last_ten": r["control_last_ten"]} for r in runs]}
    for arm, label in (("feedback", "with failure feedback"), ("control", "without feedback (same poses)")):
        curves = np.array([last_ten(a[:n]) for a in arms[arm]])
        ax.plot(np.arange(1, n + 1), 100 * curves.mean(axis=0), marker="o", ms=3, label=label)
        allv = np.concatenate(arms[arm])
        pooled[f"{arm}_success"] = float(allv.mean())
        pooled[f"{arm}_trials"] = len(allv)
    ax.set_xlabel("trial")
    ax.set_ylabel("success over the last ten trials (%), mean of runs")
    ax.set_ylim(-5, 105)
    ax.set_title(f"improvement over time, {len(runs)} runs (cf. Herzog Fig. 6)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "templates_improvement_pooled.png", dpi=110)
    return pooled


def main(argv: list[str] | None = None) -> None:
    """Run one experiment (a, b, retry) or pool the (b) results, from the command line."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("experiment", choices=("a", "b", "retry", "pool"),
                    help="retry: (a) with failed poses retried, with and without feedback; "
                         "pool: summarise every (b) run in OUT")
    ap.add_argument("--retries", type=int, default=2, help="retry: further attempts on a failed pose")
    ap.add_argument("--demos", type=int, default=15)
    ap.add_argument("--objects", type=int, default=7, help="training objects for the demonstrations")
    ap.add_argument("--tests", type=int, default=15, help="held-out test objects (a)")
    ap.add_argument("--poses", type=int, default=2, help="poses per test object (a)")
    ap.add_argument("--trials", type=int, default=34, help="trials on one object (b)")
    ap.add_argument("--object", type=int, default=905, help="held-out object for (b)")
    ap.add_argument("--seed", type=int, default=0, help="demonstration seed (training objects 7*seed ..)")
    ap.add_argument("--pose-seed", type=int, default=None, help="seed of the test poses (default: --seed)")
    ap.add_argument("--compare", default="",
                    help="(a): comma-separated other detectors on the same poses: baseline (graspd_lab.sim's top-down "
                         "baseline), gpd (GraspDetector with the default shipped classifier)")
    ap.add_argument("--library", default=None,
                    help="SQLAlchemy URL of the demonstration library (default OUT/library-seed<seed>.db; "
                         "taught first if empty, reused otherwise)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/graspd-templates-experiments"))
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.experiment == "pool":
        print(json.dumps(pool_improvement(args.out), indent=1))
        return
    hand = HandGeometry()
    tmp = tempfile.mkdtemp()
    url = args.library or f"sqlite:///{args.out / f'library-seed{args.seed}.db'}"
    library = TemplateLibrary(url, hand=hand)
    t0 = time.perf_counter()
    train_ids = list(range(args.seed * 7, args.seed * 7 + args.objects))
    if len(library.snapshot()) == 0:
        print(f"teaching {args.demos} scripted demonstrations on training objects {train_ids}")
        scripted_demonstrations(library, train_ids, args.demos, seed=args.seed)
    pose_seed = args.seed if args.pose_seed is None else args.pose_seed
    result: dict[str, Any] = {"experiment": args.experiment, "library": url, "entries": len(library.snapshot()),
                              "training_objects": train_ids, "pose_seed": pose_seed}
    if args.experiment == "a":
        test_ids = list(range(900, 900 + args.tests))
        log_a = generalisation(library, test_ids, args.poses, seed=pose_seed)
        ok = log_a.successes
        result.update(test_objects=test_ids, poses=args.poses, attempts=len(ok), successes=int(ok.sum()),
                      success_rate=float(ok.mean()) if len(ok) else float("nan"), outcomes=log_a.outcomes,
                      objects=log_a.objects, detect_seconds_median=float(np.median(log_a.detect_seconds)),
                      paper_success_rate=0.87)
        print(f"(a) success {int(ok.sum())}/{len(ok)} = {100 * ok.mean():.0f}% (paper: 83/95 = 87% on the PR2)")
        for name in [c for c in (args.compare or "").split(",") if c]:
            other = comparison_detector(name)
            log_c = generalisation(library, test_ids, args.poses, seed=pose_seed, compare=other)
            okc = log_c.successes
            result[f"{name}_successes"] = int(okc.sum())
            result[f"{name}_success_rate"] = float(okc.mean())
            result[f"{name}_outcomes"] = log_c.outcomes
            print(f"(a) {name} on the same poses: {int(okc.sum())}/{len(okc)} = {100 * okc.mean():.0f}%")
    elif args.experiment == "retry":
        test_ids = list(range(900, 900 + args.tests))
        for arm in ("feedback", "control"):
            arm_lib = TemplateLibrary(f"sqlite:///{os.path.join(tmp, 'retry-' + arm + '.db')}", hand=hand)
            copy_entries(library, arm_lib)
            print(f"{arm}:")
            per_pose = retry_until_success(arm_lib, test_ids, args.poses, args.retries, arm == "feedback",
                                           seed=pose_seed)
            first = float(np.mean([t[0] == "success" for t in per_pose]))
            within = float(np.mean([t[-1] == "success" for t in per_pose]))
            attempts = [len(t) for t in per_pose if t[-1] == "success"]
            result[arm] = {"outcomes": per_pose, "first_attempt": first, "within": within,
                           "attempts": int(sum(len(t) for t in per_pose)),
                           "mean_attempts_to_success": float(np.mean(attempts)) if attempts else float("nan")}
            print(f"(retry, {arm}) first attempt {100 * first:.0f}%, within {1 + args.retries} attempts "
                  f"{100 * within:.0f}% of {len(per_pose)} poses")
        result.update(retries=args.retries, test_objects=test_ids, poses=args.poses)
    else:
        # both arms start from a copy of the demonstrations: one reports every outcome, the control none
        arms = {}
        for arm in ("feedback", "control"):
            arm_lib = TemplateLibrary(f"sqlite:///{os.path.join(tmp, arm + '.db')}", hand=hand)
            copy_entries(library, arm_lib)
            arms[arm] = improvement(arm_lib, args.object, args.trials, feedback=arm == "feedback", seed=pose_seed)
            if arm == "feedback":
                result["failures_in_library"] = arm_lib.summary()["num_failures"]
        with_fb, without = arms["feedback"], arms["control"]
        first = float(with_fb.successes[:10].mean())
        last = float(with_fb.successes[-10:].mean())
        result.update(object=args.object, trials=args.trials, outcomes_feedback=with_fb.outcomes,
                      outcomes_control=without.outcomes, last_ten_feedback=last_ten(with_fb.successes).tolist(),
                      last_ten_control=last_ten(without.successes).tolist(), first_ten=first, last_ten=last,
                      control_first_ten=float(without.successes[:10].mean()),
                      control_last_ten=float(without.successes[-10:].mean()))
        png = args.out / f"templates_improvement_{args.object}_poses{pose_seed}.png"
        plot_improvement(with_fb, without, png, args.object)
        print(f"(b) with feedback: first ten {100 * first:.0f}% -> last ten {100 * last:.0f}%; "
              f"control {100 * result['control_first_ten']:.0f}% -> {100 * result['control_last_ten']:.0f}%; "
              f"wrote {png}")
    result["seconds"] = time.perf_counter() - t0
    tag = f"_{args.object}" if args.experiment == "b" else f"_r{args.retries}" if args.experiment == "retry" else ""
    path = args.out / f"templates_experiment_{args.experiment}{tag}_poses{pose_seed}.json"
    path.write_text(json.dumps(result, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
