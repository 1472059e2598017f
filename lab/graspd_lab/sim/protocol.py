"""The dense-clutter benchmark protocol (IJRR Table 1) and its statistics.

A round: build a scene, then repeat sense -> detect -> choose a feasible grasp -> execute until the tray
is empty or the setting's stop rule ends it (STOP_RULES): the IJRR paper's (no grasp found three times in a row,
or the same failure on the same object three times in a row) or the standard clutter-removal benchmark's (VGN's
clutter_removal: two failed attempts in a row, or a detection without a grasp).  Success rate = successes /
attempts; cleared = objects lifted out / objects in the scene.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.camera import Camera, overhead_camera, sensing_cameras
from graspd.core.cloud import ViewpointCloud
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd_lab.sim.containers import scene_container, style_ranges
from graspd_lab.sim.detectors import InProcessGPD, ServiceGPD, SimDetector, Workspace
from graspd_lab.sim.gripper import Attempt, ExecutionParams, Gripper, Outcome
from graspd_lab.sim.object_sets import object_label, object_set_ids, object_set_stop
from graspd_lab.sim.sensing import observe
from graspd_lab.sim.world import SimWorld, build_scene
from graspd_lab.world.noise import DepthNoise

SENSINGS = ("passive", "active", "side")
#: How a round ends besides an empty table, each rule in words for results files: "ijrr" (IJRR Table 1 step 6) or
#: "standard" (the standard clutter-removal benchmark's: two failed attempts in a row, whatever they failed on).
STOP_RULE_TEXT = {
    "ijrr": "IJRR Table 1's: a round ends after 3 detections in a row without a grasp, or the same failure on the "
            "same object 3 times in a row",
    "standard": "the standard clutter-removal benchmark's: a round ends after 2 failed attempts in a row, or a "
                "detection without a grasp",
}
STOP_RULES = tuple(STOP_RULE_TEXT)
#: Called before each executed grasp with the world, the cloud the detector saw, its grasps and the index picked
#: (diagnostics: bench/approach.py); it must leave the world as it found it.
Probe = Callable[[SimWorld, ViewpointCloud, GraspSet, int], None]
#: Picks the grasp to execute from the world as it is, the detector's grasps and the indices of the feasible ones
#: in their ranked order (diagnostics: bench/oracle.py tries grasps in physics first); it must leave the world as
#: it found it.
Chooser = Callable[[SimWorld, GraspSet, NDArray[np.int64]], int]


@dataclass(frozen=True)
class Setting:
    """One benchmark configuration: scene kind and size, sensing, grasp choice and hand.  Scene "container"
    names a container style (graspd_lab.sim.containers.STYLES) and the split whose parameter ranges it is drawn
    from ("held_out" or "training"); each round's container follows from its seed (scene_container).  objects
    names the held-out object set the scenes draw from (graspd_lab.sim.object_sets)."""

    scene: str = "pour"
    num_objects: int = 10
    sensing: str = "passive"
    choice: str = "best"  # "best": detector's order; "random": uniform among feasible (no selection)
    noise: bool = True
    max_approach_angle_deg: float = 80.0  # feasible approaches lie within this angle of straight down
    max_attempts: int = 30
    hand: HandGeometry = field(default_factory=HandGeometry)
    container: str | None = None
    container_split: str = "held_out"
    objects: str = "scaled"  # the object set, by name (graspd_lab.sim.object_sets.OBJECT_SETS)
    stop: str | None = None  # STOP_RULES; None: the object set's (graspd_lab.sim.object_sets.object_set_stop)
    #: A robot that acts on the answer: when a detection has no feasible grasp and its answer warns that no camera
    #: saw part of the container's floor (unseen_floor), it adds one view straight down into the workspace (a
    #: wrist camera) and asks once more; only that second answer counts.  False: the standard protocol.
    relook: bool = False
    #: The same for objects lying too flat for the hand's init_bite (flat_objects): it asks once more with the
    #: request's flat_objects option on, as the warning says (after a relook, if both apply).
    flat_retry: bool = False

    def __post_init__(self) -> None:
        object_set_ids(self.objects)  # raises for an unknown set
        if self.stop is not None and self.stop not in STOP_RULES:
            raise ValueError(f"stop must be one of {STOP_RULES}, got {self.stop!r}")
        if (self.scene == "container") != (self.container is not None):
            raise ValueError("scene 'container' needs a container style, and only it takes one")
        if self.container is not None:
            style_ranges(self.container, self.container_split)  # raises for an unknown style or split
        if self.sensing not in SENSINGS:
            raise ValueError(f"sensing must be one of {SENSINGS}, got {self.sensing!r}")
        if self.choice not in ("best", "random"):
            raise ValueError(f"choice must be 'best' or 'random', got {self.choice!r}")

    @property
    def stop_rule(self) -> str:
        """The rule that ends a round (STOP_RULES): stop, or the object set's."""
        return self.stop if self.stop is not None else object_set_stop(self.objects)


@dataclass
class RoundResult:
    """Counts of one round and the outcome of every attempt (plus the wall time, s)."""

    seed: int
    num_objects: int
    successes: int = 0
    attempts: int = 0
    cleared: int = 0
    outcomes: list[str] = field(default_factory=list)
    end_reason: str = ""
    #: The objects still in the scene when the round ended (object_sets.object_label: names of household models).
    left: list[str] = field(default_factory=list)
    seconds: float = 0.0
    detect_seconds: float = 0.0
    #: Detections asked again with a view from above (Setting.relook), and with flat_objects on (Setting.flat_retry).
    relooks: int = 0
    flat_retries: int = 0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def warned(detector: SimDetector, code: str) -> bool:
    """True when the detector's last answer carries the warning code (its `warned` codes: ServiceGPD,
    InProcessGPD); a detector without warnings (the top-down baseline) never warns."""
    return code in getattr(detector, "warned", frozenset())


def with_options(detector: SimDetector, **options: Any) -> SimDetector | None:
    """A copy of a detector that sends these request options too (ServiceGPD, InProcessGPD); None for one
    without request options (the top-down baseline)."""
    if isinstance(detector, ServiceGPD | InProcessGPD):
        return replace(detector, options={**detector.options, **options})
    return None


@dataclass
class StopRule:
    """When a round ends (STOP_RULES).  "ijrr": after three detections in a row without a grasp, or the same failure
    on the same object three times in a row (a success or another failure breaks the streak); "standard": after two
    failed attempts in a row, or a detection without a grasp."""

    rule: str = "ijrr"
    no_grasp: int = 0
    streak: tuple[str, int | None] | None = None
    streak_len: int = 0
    failures: int = 0

    def update(self, attempt: Attempt) -> str:
        """Record one attempt; the reason to stop, or "" to go on."""
        if self.rule == "standard":
            if attempt.outcome is Outcome.NO_GRASP:
                return "no grasp found"
            self.failures = 0 if attempt.outcome is Outcome.SUCCESS else self.failures + 1
            return "2 failures in a row" if self.failures >= 2 else ""
        if attempt.outcome is Outcome.NO_GRASP:
            self.no_grasp += 1
            return "no grasp found 3 times" if self.no_grasp >= 3 else ""
        self.no_grasp = 0
        if attempt.outcome is Outcome.SUCCESS:
            self.streak, self.streak_len = None, 0
            return ""
        key = (attempt.outcome.value, attempt.target)
        self.streak_len = self.streak_len + 1 if key == self.streak else 1
        self.streak = key
        return "same failure on same object 3 times" if self.streak_len >= 3 else ""


def feasible(grasps: GraspSet, max_angle_deg: float) -> np.ndarray:
    """Mask of grasps the arm can execute: approach within max_angle_deg of straight down (a robot above
    the table reaches those without IK failures).  The one filter the protocol applies to returned grasps,
    the same for every detector: anything else a robot needs (no grasps of walls or the floor, hands clear
    of the environment) is the detector's job."""
    if len(grasps) == 0:
        return np.zeros(0, bool)
    return np.asarray(-grasps.approach[:, 2] >= np.cos(np.deg2rad(max_angle_deg)))


def cameras_for(setting: Setting) -> list[Camera]:
    """The cameras of the setting's sensing strategy."""
    return sensing_cameras(setting.sensing)


def setting_scene(setting: Setting, seed: int) -> SimWorld:
    """The settled scene of a setting's round `seed` (its container, if any, drawn from the seed too)."""
    container = None if setting.container is None else scene_container(setting.container, seed,
                                                                         setting.container_split)
    return build_scene(setting.scene, setting.num_objects, seed, setting.hand,
                       object_ids=object_set_ids(setting.objects), container=container)


def run_round(detector: SimDetector, setting: Setting, seed: int,
              execution: ExecutionParams | None = None, probe: Probe | None = None,
              choose: Chooser | None = None) -> RoundResult:
    """One round of the protocol with scene, noise and choices all drawn from seed; probe (if any) looks at
    each executed grasp first; choose (if any) picks it instead of the setting's choice."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed + 1_000_003)
    world = setting_scene(setting, seed)
    result = RoundResult(seed=seed, num_objects=len(world.objects))
    # what the cameras keep and the workspace box the robot sends: the scene, tray walls and floor included
    region: Workspace = world.workspace()
    workspace = region
    noise = DepthNoise.benchmark() if setting.noise else DepthNoise.none()
    cams = cameras_for(setting)

    def ask(det: SimDetector, seen: ViewpointCloud) -> tuple[GraspSet, NDArray[np.int64]]:
        """One timed detection and the indices of its grasps the arm can execute."""
        td = time.perf_counter()
        found = det.detect(seen, workspace, setting.hand, seed=int(rng.integers(2**31)))
        result.detect_seconds += time.perf_counter() - td
        return found, np.flatnonzero(feasible(found, setting.max_approach_angle_deg))

    try:
        gripper = Gripper(world, setting.hand, execution)
        stop = StopRule(setting.stop_rule)
        while True:
            if not world.objects:
                result.end_reason = "tray empty"
                break
            if result.attempts >= setting.max_attempts:
                result.end_reason = "attempt limit"
                break
            cloud = observe(world.client, cams, noise, rng, region)
            grasps, ok = ask(detector, cloud)
            if len(ok) == 0 and setting.relook and warned(detector, "unseen_floor"):
                cloud = observe(world.client, [*cams, overhead_camera(region)], noise, rng, region)
                grasps, ok = ask(detector, cloud)
                result.relooks += 1
            if len(ok) == 0 and setting.flat_retry and warned(detector, "flat_objects"):
                flat = with_options(detector, flat_objects=True)
                if flat is not None:
                    grasps, ok = ask(flat, cloud)
                    result.flat_retries += 1
            if len(ok) == 0:
                attempt = Attempt(Outcome.NO_GRASP, None)
            else:
                if choose is not None:
                    pick = int(choose(world, grasps, ok))
                else:
                    pick = int(ok[0] if setting.choice == "best" else rng.choice(ok))
                if probe is not None:
                    probe(world, cloud, grasps, pick)
                attempt = gripper.execute(grasps, pick)
                result.attempts += 1
                world.remove_outside()
            result.outcomes.append(attempt.outcome.value)
            if attempt.outcome is Outcome.SUCCESS:
                result.successes += 1
                result.cleared += len(attempt.removed)
            reason = stop.update(attempt)
            if reason:
                result.end_reason = reason
                break
        result.left = sorted(object_label(o) for o in world.objects.values())
    finally:
        world.close()
    result.seconds = time.perf_counter() - t0
    return result


@dataclass(frozen=True)
class Summary:
    """Totals over rounds with 95% bootstrap intervals (resampling rounds)."""

    rounds: int
    objects: int
    attempts: int
    successes: int
    cleared: int
    success_rate: float
    success_ci: tuple[float, float]
    cleared_rate: float
    cleared_ci: tuple[float, float]
    failures: dict[str, int]
    seconds_per_round: float
    detect_seconds_per_attempt: float
    relooks: int = 0  # detections asked again with a view from above (Setting.relook)
    flat_retries: int = 0  # detections asked again with flat_objects on (Setting.flat_retry)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def summarize(results: list[RoundResult], boot: int = 2000, seed: int = 0) -> Summary:
    """Pooled success and cleared rates with percentile bootstrap 95% intervals over rounds."""
    if not results:
        raise ValueError("summarize needs at least one round")
    succ = np.array([r.successes for r in results], float)
    att = np.array([r.attempts for r in results], float)
    clr = np.array([r.cleared for r in results], float)
    obj = np.array([r.num_objects for r in results], float)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(results), size=(boot, len(results)))

    def ratio(num: np.ndarray, den: np.ndarray) -> tuple[float, tuple[float, float]]:
        point = float(num.sum() / den.sum()) if den.sum() else float("nan")
        with np.errstate(invalid="ignore", divide="ignore"):
            samples = num[idx].sum(1) / den[idx].sum(1)
        samples = samples[np.isfinite(samples)]
        if len(samples) == 0:
            return point, (float("nan"), float("nan"))
        lo, hi = np.percentile(samples, [2.5, 97.5])
        return point, (float(lo), float(hi))

    s, s_ci = ratio(succ, att)
    c, c_ci = ratio(clr, obj)
    fails = Counter(o for r in results for o in r.outcomes if o != Outcome.SUCCESS.value)
    attempts_total = max(int(att.sum()) + fails.get(Outcome.NO_GRASP.value, 0), 1)
    return Summary(
        rounds=len(results), objects=int(obj.sum()), attempts=int(att.sum()), successes=int(succ.sum()),
        cleared=int(clr.sum()), success_rate=s, success_ci=s_ci, cleared_rate=c, cleared_ci=c_ci,
        failures=dict(sorted(fails.items())),
        seconds_per_round=float(np.mean([r.seconds for r in results])),
        detect_seconds_per_attempt=float(sum(r.detect_seconds for r in results) / attempts_total),
        relooks=sum(r.relooks for r in results), flat_retries=sum(r.flat_retries for r in results),
    )
