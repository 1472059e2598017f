"""Dense-clutter benchmark in simulation: IJRR Table 1 protocol, Table 3 ablations, VGN pile/packed scenes.

One command runs N rounds per setting and writes a markdown table like the paper's Table 3, a PNG bar
chart and a JSON file (with the git commit) into bench/results/.  A setting is DETECTOR@SCENE-SENSING:

  detectors: baseline (top-down, no learning), gpd-noclass (GPD, no classification), gpd (GPD with the
             --model classifier, default: graspd's default model), gpd-noselect (same, random order instead
             of selection), gpd-cluster (same, GPD's cluster-sum ranking instead of the default), gpd-flat
             (same, with the request option flat_objects: objects lying flat grasped by their edges), gpd-robust
             (same, with robust_copies 4: the first grasps ranked by their score over 4 moved copies),
             gpd-rep15 / gpd-rep12 / gpd-rep3 (the first model in models/ of that representation)
  scenes:    pour-passive, pour-active (10 objects poured into a tray), pile-side, packed-side (5 objects)
  objects:   --object-set scaled (default: random_urdfs 900-999 scaled to the hand, graspd's default hand) or
             household (the held-out household models at their true size, a Panda-like hand: 7.5 cm opening;
             graspd_lab.sim.object_sets)

The gpd detectors call the detector exactly as a robot does: plain POST /detect requests through
graspd_client to a graspd service (started on a free local port unless --service names one), with the
cloud, its cameras, the hand and a workspace box around the scene, and the service's defaults for the
rest.  The only filter on returned grasps is the arm's approach cone (sim/protocol.py: feasible).
Every finished round is appended to <tag>.rounds.jsonl; rerunning the same command resumes from it.

Examples:
  PYTHONPATH=service:client .venv/bin/python bench/clutter.py --rounds 5 --settings baseline@pour-passive
  PYTHONPATH=service:client .venv/bin/python bench/clutter.py --rounds 30 --settings gpd@pile-side --tag pile
  ... --object-set household --precision --settings gpd@pile-side baseline@pile-side --tag clutter-household-pile
                                        (--precision: P@1/P@5 of each round's first detection, as
                                         bench/containers.py checks them against the true meshes)
  ... --service http://127.0.0.1:8000   (use a running service instead of starting one)
  ... --in-process                      (developer runs: GraspDetector in this process, no HTTP)
  ... --jobs 2 --ray                    (rounds as Ray tasks on this machine; graspd-lab[cluster])
  ... --ray --address auto --in-process (rounds on a Ray cluster: the gpd detectors need --in-process or a
                                         --service URL the nodes reach; rounds.jsonl stays on this machine)
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import shlex
import socket
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402

from graspd.core.camera import Camera  # noqa: E402
from graspd.core.cloud import ViewpointCloud  # noqa: E402
from graspd.core.grasp import GraspSet  # noqa: E402
from graspd.core.hand import HAND_PRESETS, HandGeometry, hand_preset  # noqa: E402
from graspd.core.progress import Progress  # noqa: E402
from graspd.gpd.classifier import available_models, default_model_name, load_model, read_card  # noqa: E402
from graspd.gpd.classifier import default_models_dir as models_dir  # noqa: E402
from graspd_client import GraspClient  # noqa: E402
from graspd_lab.cluster import RayMissingError, imap, runner_from_args  # noqa: E402
from graspd_lab.cluster import add_arguments as add_cluster_arguments  # noqa: E402
from graspd_lab.sim.detectors import InProcessGPD, ServiceGPD, SimDetector, TopDownBaseline  # noqa: E402
from graspd_lab.sim.object_sets import OBJECT_SETS, object_set_hand, object_set_stop  # noqa: E402
from graspd_lab.sim.object_sets import describe as describe_objects  # noqa: E402
from graspd_lab.sim.protocol import (  # noqa: E402
    STOP_RULE_TEXT,
    STOP_RULES,
    RoundResult,
    Setting,
    Summary,
    cameras_for,
    run_round,
    summarize,
)
from graspd_lab.sim.sensing import observe, render_rgb  # noqa: E402
from graspd_lab.sim.world import SimWorld, build_scene  # noqa: E402
from graspd_lab.world.noise import DepthNoise  # noqa: E402

#: Detectors that score no grasp with a model.
UNSCORED = ("baseline", "gpd-noclass")
DETECTORS = ("baseline", "gpd-noclass", "gpd", "gpd-noselect", "gpd-cluster", "gpd-flat", "gpd-robust", "gpd-rep15",
             "gpd-rep12", "gpd-rep3")
#: The request option of the gpd-robust ablation: copies of each of the first grasps (graspd.gpd.robustness).
ROBUST_ABLATION_COPIES = 4
SCENES: dict[str, Setting] = {
    "pour-passive": Setting(scene="pour", num_objects=10, sensing="passive"),
    "pour-active": Setting(scene="pour", num_objects=10, sensing="active"),
    "pile-side": Setting(scene="pile", num_objects=5, sensing="side"),
    "packed-side": Setting(scene="packed", num_objects=5, sensing="side"),
}
DEFAULT_SETTINGS = ("baseline@pour-passive", "baseline@pour-active", "baseline@pile-side",
                    "gpd-noclass@pour-passive", "gpd-noclass@pour-active", "gpd-noclass@pile-side")
#: (success, cleared) targets of what a robot gets by default (service defaults, no benchmark-side filters).
TARGETS = {"pour-passive": (0.90, 0.85), "pour-active": (0.90, 0.85), "pile-side": (0.90, 0.95)}


def parse_setting(spec: str) -> tuple[str, str]:
    """'DETECTOR@SCENE' -> (detector, scene); ValueError names what is unknown."""
    det, _, scene = spec.partition("@")
    if det not in DETECTORS:
        raise ValueError(f"setting {spec!r}: detector must be one of {DETECTORS}")
    if scene not in SCENES:
        raise ValueError(f"setting {spec!r}: scene must be one of {tuple(SCENES)}")
    return det, scene


def model_for(detector: str, model: str | None, service: str | None = None) -> str | None:
    """The classifier name a detector sends or loads (None for baseline and gpd-noclass).  Through the service
    with no model named: None, and the service picks as it does for any user (its default model, or the one
    trained for the request's hand)."""

    if detector in UNSCORED:
        return None
    if detector.startswith("gpd-rep"):
        rep = detector.removeprefix("gpd-rep")
        for name in available_models():
            if str(read_card(models_dir() / f"{name}.json").get("representation")) == rep:
                return name
        raise SystemExit(f"{detector}: no model of representation {rep} in {models_dir()}")
    if model is None and service is not None:
        return None
    if model is None:
        names = available_models()
        if not names:
            raise SystemExit(f"{detector}: no classifier in {models_dir()}; pass --model or train one")
        return default_model_name() if default_model_name() in names else names[0]
    return model


@functools.cache
def served_model(service: str, hand: HandGeometry) -> str | None:
    """The model the service answers a request carrying `hand` with, asked with one small request (a 5 cm cube
    on a 30 cm table seen from 50 cm above): what a user with that hand gets by default."""
    u = np.linspace(-0.15, 0.15, 31)
    table = np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)
    v = np.linspace(-0.025, 0.025, 11)
    top = np.stack(np.meshgrid(v, v), -1).reshape(-1, 2)
    points = np.r_[np.c_[table, np.zeros(len(table))], np.c_[top, np.full(len(top), 0.05)]]
    with GraspClient(service, timeout=120.0) as client:
        answer = client.detect(points, np.array([[0.0, 0.0, 0.5]]), np.zeros(len(points), np.int64),
                               hand=hand.to_dict(), seed=0)
    return answer.model


def reported_model(detector: str, model: str | None, service: str | None, hand: HandGeometry) -> str | None:
    """The model a results file names for a detector: the one the bench names (or loads in process), else the one
    the service answers requests carrying `hand` with; None for a detector that scores with none."""
    if detector in UNSCORED or model is not None or service is None:
        return model
    return f"{served_model(service, hand)} (the service's default for this hand)"


def make_detector(detector: str, model: str | None, service: str | None) -> SimDetector:
    """The detector object for a setting (built inside each worker process)."""
    if detector == "baseline":
        return TopDownBaseline()
    options: dict[str, Any] = {}
    if detector == "gpd-noselect":
        options["use_selection"] = False
    if detector == "gpd-cluster":
        options["use_clustering"] = True
    if detector == "gpd-flat":
        options["flat_objects"] = True
    if detector == "gpd-robust":
        options["robust_copies"] = ROBUST_ABLATION_COPIES
    if service is not None:
        # named ablations only; everything else is the service's default
        options = {"gpd-noselect": {"selection": False}, "gpd-noclass": {"use_classifier": False},
                   "gpd-cluster": {"clustering": True}, "gpd-flat": {"flat_objects": True},
                   "gpd-robust": {"robust_copies": ROBUST_ABLATION_COPIES}}.get(detector, {})
        return ServiceGPD(url=service, name=detector, model=model, options=options)
    classifier = None
    if model is not None:
        classifier = load_model(model, threads=1)
    return InProcessGPD(name=detector, classifier=classifier, options=options)


#: A look at the grasp about to be executed (world, the cloud the detector saw, its grasps, the index picked): the
#: record of it; it must leave the world as it found it.
Look = Callable[[SimWorld, ViewpointCloud, GraspSet, int], dict[str, Any]]


def looked_rounds(setting: Setting, model: str | None, service: str | None, seeds: range, look: Look
                  ) -> list[dict[str, Any]]:
    """The protocol's rounds of `seeds` with the gpd detector, each executed grasp looked at first; every record
    gets its round's seed and the grasp's outcome (bench/approach.py, bench/slips.py)."""
    records: list[dict[str, Any]] = []

    def probe(world: SimWorld, cloud: ViewpointCloud, grasps: GraspSet, pick: int) -> None:
        records.append(look(world, cloud, grasps, pick))

    for seed in seeds:
        first = len(records)
        result = run_round(make_detector("gpd", model, service), setting, seed, probe=probe)
        executed = [o for o in result.outcomes if o != "no_grasp"]
        for row, outcome in zip(records[first:], executed, strict=True):
            row.update(seed=seed, outcome=outcome)
        print(f"seed {seed}: {Counter(executed)}", flush=True)
    return records


def _one_round(args: tuple[str, str | None, str | None, Setting, int, bool]
               ) -> tuple[RoundResult, dict[str, Any] | None]:
    detector_name, model, service, setting, seed, precision = args
    detector = make_detector(detector_name, model, service)
    check = None
    if precision:
        from containers import scene_precision  # noqa: PLC0415  (bench/containers.py imports this module)

        check = scene_precision(detector, setting, seed)
    return run_round(detector, setting, seed), check


def _setting_key(spec: str, setting: Setting) -> str:
    key = f"{spec}/{setting.num_objects}"
    key = key if setting.objects == "scaled" else f"{key}/{setting.objects}"
    if setting.hand != object_set_hand(setting.objects):  # another hand than the set's: never resume across hands
        key += "/hand-" + "-".join(f"{v:g}" for v in setting.hand.to_dict().values())
    if setting.scene == "container" and setting.sensing != "passive":  # the spec names a container, not cameras
        key += f"/sensing-{setting.sensing}"
    if setting.relook:
        key += "/relook"
    if setting.flat_retry:
        key += "/flat-retry"
    return key if setting.stop_rule == "ijrr" else f"{key}/stop-{setting.stop_rule}"


def load_rows(log: Path, spec: str, setting: Setting) -> dict[int, dict[str, Any]]:
    """The rows of this setting already recorded in log (one JSON object per line: "setting", "round" and any
    extra fields record_round was given), by seed."""
    out: dict[int, dict[str, Any]] = {}
    if not log.exists():
        return out
    key = _setting_key(spec, setting)
    for line in log.read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue  # a line cut by an interrupted run
        if row.get("setting") == key:
            out[int(row["round"]["seed"])] = row
    return out


def load_rounds(log: Path, spec: str, setting: Setting) -> dict[int, RoundResult]:
    """Rounds of this setting already recorded in log (one JSON object per line), by seed."""
    return {seed: RoundResult(**row["round"]) for seed, row in load_rows(log, spec, setting).items()}


def record_round(log: Path, spec: str, setting: Setting, result: RoundResult, **extra: Any) -> RoundResult:
    """Append one finished round to log (the checkpoint a rerun resumes from); extra: more JSON fields of the
    row (bench/containers.py: the round's precision@k check)."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("a") as f:
        f.write(json.dumps({"setting": _setting_key(spec, setting), "round": result.to_dict(), **extra}) + "\n")
    return result


def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True)
        own = ["service", "client", "models", "bench/clutter.py"]
        dirty = subprocess.run(["git", "status", "--porcelain", "--", *own], cwd=REPO,
                               capture_output=True, text=True).stdout.strip()
        return out.stdout.strip() + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def pct(x: float) -> str:
    return "n/a" if x != x else f"{100 * x:.0f}%"


def ci(lo_hi: tuple[float, float]) -> str:
    lo, hi = lo_hi
    return "" if lo != lo else f" [{100 * lo:.0f}, {100 * hi:.0f}]"


def left_unfound(rounds: list[dict[str, Any]]) -> Counter[str]:
    """The objects left in the scene by rounds that ended because a detection returned no feasible grasp, by name:
    what the detector could not take (round dicts as RoundResult.to_dict() writes them)."""
    return Counter(name for r in rounds if "no grasp" in r.get("end_reason", "") for name in r.get("left", ()))


def add_hand_argument(ap: argparse.ArgumentParser) -> None:
    """--hand: a hand preset instead of the object set's (bench/clutter.py, bench/containers.py)."""
    ap.add_argument("--hand", choices=sorted(HAND_PRESETS), default=None, help="a hand preset for the requests "
                    "and the simulated fingers instead of the object set's (what a user who sends that preset gets)")


def add_advice_arguments(ap: argparse.ArgumentParser) -> None:
    """--relook and --flat-retry: a robot that does what a grasp-less answer advises (not the standard protocol;
    graspd_lab.sim.protocol.Setting.relook and flat_retry)."""
    ap.add_argument("--relook", action="store_true", help="after a detection without a grasp whose answer warns "
                    "of unseen floor, add one view from straight above and ask once more")
    ap.add_argument("--flat-retry", action="store_true", help="after a detection without a grasp whose answer "
                    "warns of objects lying flat, ask once more with flat_objects on")


def advice_lines(meta: dict[str, Any]) -> list[str]:
    """The results file's lines on the robot's advice-following (none for the standard protocol)."""
    lines = []
    if meta.get("relook"):
        lines.append("- relook: after a detection without a grasp whose answer warns of unseen floor, the robot adds "
                     "one view from straight above and asks once more (graspd_lab.sim.protocol.Setting.relook; not "
                     "the standard protocol); only that answer counts")
    if meta.get("flat_retry"):
        lines.append("- flat retry: after a detection without a grasp whose answer warns of objects lying flat, the "
                     "robot asks once more with flat_objects on (Setting.flat_retry; not the standard protocol); "
                     "only that answer counts")
    return lines


def run_hand(object_set: str, preset: str | None) -> HandGeometry:
    """The hand a run requests and executes with: the preset when given, else the object set's."""
    return object_set_hand(object_set) if preset is None else hand_preset(preset)


def describe_hand(preset: str) -> str:
    """One line for a results file whose requests and simulated fingers use a hand preset instead of the object
    set's hand: its name and opening."""
    opening = hand_preset(preset).max_aperture
    return (f"the `{preset}` preset ({opening * 100:.1f} cm opening; graspd.core.hand.HAND_PRESETS) in every request "
            "and in the simulated fingers, instead of the object set's hand")


def markdown(summaries: dict[str, Summary], meta: dict[str, Any],
             rounds: dict[str, list[dict[str, Any]]] | None = None) -> str:
    """A Table-3-like markdown table, one column per setting; with the rounds, the objects left where a detection
    found no grasp."""
    names = list(summaries)
    rows = [
        ("Rounds", lambda s: str(s.rounds)),
        ("Num objects", lambda s: str(s.objects)),
        ("Num grasp attempts", lambda s: str(s.attempts)),
        ("Num grasp successes", lambda s: str(s.successes)),
        ("% grasps successful [95% CI]", lambda s: pct(s.success_rate) + ci(s.success_ci)),
        ("% objects removed [95% CI]", lambda s: pct(s.cleared_rate) + ci(s.cleared_ci)),
        ("Failures: collision", lambda s: str(s.failures.get("collision", 0))),
        ("Failures: empty close", lambda s: str(s.failures.get("empty_close", 0))),
        ("Failures: slipped", lambda s: str(s.failures.get("slipped", 0))),
        ("No grasp found (detections)", lambda s: str(s.failures.get("no_grasp", 0))),
        *([("Asked again: relooks / flat retries", lambda s: f"{s.relooks} / {s.flat_retries}")]
          if meta.get("relook") or meta.get("flat_retry") else []),
        ("Wall time per round (s)", lambda s: f"{s.seconds_per_round:.0f}"),
        ("Detection time per call (s)", lambda s: f"{s.detect_seconds_per_attempt:.1f}"),
    ]
    lines = [
        "# Simulated dense-clutter benchmark (IJRR Table 1 protocol, Table 3 layout)",
        "",
        f"- command: `{meta['command']}`",
        f"- commit: `{meta['commit']}`, date: {meta['date']}, {meta['cpus']} CPUs, jobs: {meta['jobs']}",
        f"- objects: {describe_objects(meta.get('object_set', 'scaled'))}",
        *([f"- hand: {describe_hand(meta['hand'])}"] if meta.get("hand") else []),
        f"- stop rule: {STOP_RULE_TEXT[meta.get('stop', 'ijrr')]}",
        *advice_lines(meta),
        "- models: " + (", ".join(f"{k}: {v}" for k, v in meta["models"].items() if v) or "none"),
        "",
        "| | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    lines += ["| " + label + " | " + " | ".join(fn(summaries[n]) for n in names) + " |" for label, fn in rows]
    precision = meta.get("precision") or {}
    if precision:
        lines += ["| P@1 / P@5 (first detection, true meshes) | " + " | ".join(
            f"{pct(precision[n]['p@1'])} / {pct(precision[n]['p@5'])}" if n in precision else "" for n in names)
            + " |"]
        lines += ["| Top-5 failures (first detection) | " + " | ".join(
            ", ".join(f"{k} {v}" for k, v in precision[n]["top5"].items() if k != "ok") + f", no grasp "
            f"{precision[n]['no_grasp']}" if n in precision else "" for n in names) + " |"]
    for name, rows_of in (rounds or {}).items():
        left = left_unfound(rows_of)
        if left:
            lines += ["", f"{name}: objects left where a detection found no grasp ({sum(left.values())}): "
                      + ", ".join(f"{k} x{v}" if v > 1 else k for k, v in left.most_common())]
    lines += ["", "Targets (service defaults): piles success >= 90% and cleared >= 95%; trays of 10"
              " success >= 90% and cleared >= 85%.  CIs: percentile bootstrap over rounds."]
    return "\n".join(lines) + "\n"


def bar_chart(summaries: dict[str, Summary], path: Path, title: str) -> None:
    """Grasp success and objects removed per setting with 95% intervals and the targets."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    names = list(summaries)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * len(names) + 2), 4.5))
    for k, (key, ci_key, label) in enumerate([("success_rate", "success_ci", "grasp success"),
                                              ("cleared_rate", "cleared_ci", "objects removed")]):
        vals = np.array([getattr(summaries[n], key) for n in names]) * 100
        lo = np.array([getattr(summaries[n], ci_key)[0] for n in names]) * 100
        hi = np.array([getattr(summaries[n], ci_key)[1] for n in names]) * 100
        err = np.nan_to_num(np.vstack([vals - lo, hi - vals]))
        ax.bar(x + (k - 0.5) * 0.38, np.nan_to_num(vals), 0.38, yerr=err, capsize=3, label=label)
    for i, n in enumerate(names):
        target = TARGETS.get(n.split("@")[1])
        if target:
            ax.hlines(target[0] * 100, i - 0.4, i, colors="k", linestyles="--", linewidth=1)
            if target[1]:
                ax.hlines(target[1] * 100, i, i + 0.4, colors="k", linestyles=":", linewidth=1)
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=25, ha="right", fontsize=8)
    ax.set_ylim(0, 105)
    ax.set_ylabel("%")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_results(out: Path, tag: str, summaries: dict[str, Summary], rounds: dict[str, list[dict[str, Any]]],
                  meta: dict[str, Any]) -> str:
    """Write <tag>.md, <tag>.json and <tag>.png into out; the markdown."""
    out.mkdir(parents=True, exist_ok=True)
    md = markdown(summaries, meta, rounds)
    (out / f"{tag}.md").write_text(md)
    (out / f"{tag}.json").write_text(json.dumps(
        {"meta": meta, "summaries": {k: v.to_dict() for k, v in summaries.items()}, "rounds": rounds}, indent=1))
    bar_chart(summaries, out / f"{tag}.png", f"{tag} @ {meta['commit'][:12]}")
    return md


def scene_pictures(path: Path, seed: int) -> None:
    """One picture per scene kind (seed's scene, after settling) and the cloud its cameras send, from above."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(2, len(SCENES), figsize=(4.2 * len(SCENES), 7))
    for col, (name, setting) in enumerate(SCENES.items()):
        with build_scene(setting.scene, setting.num_objects, seed, setting.hand) as world:
            view = Camera((-0.42, -0.3, 0.42), (0.0, 0.0, 0.02), width=480, height=360, fov_deg=45.0,
                          fov_axis="vertical")
            axes[0, col].imshow(render_rgb(world.client, view))
            cams = cameras_for(setting)
            cloud = observe(world.client, cams, DepthNoise.benchmark(), np.random.default_rng(seed),
                            (-0.2, 0.2, -0.17, 0.17, 0.002, 0.4))
        pts = cloud.points
        axes[1, col].scatter(pts[:, 0], pts[:, 1], c=pts[:, 2], s=0.2, cmap="viridis")
        axes[1, col].set_aspect("equal")
        axes[1, col].set_title(f"{len(pts)} points from {len(cams)} camera(s), z colour", fontsize=8)
        axes[0, col].set_title(name, fontsize=9)
        axes[0, col].axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_service() -> tuple[subprocess.Popen[bytes], str]:
    """Run the graspd HTTP app under uvicorn on a free local port; wait until it is ready."""
    port = free_port()
    env = {**os.environ, "PYTHONPATH": f"{REPO / 'service'}:{REPO / 'client'}", "GRASPD_ZENOH_ENABLED": "false",
           "GRASPD_DEADLINE_S": "300", "GRASPD_LOG_LEVEL": "WARNING"}
    proc = subprocess.Popen([sys.executable, "-m", "uvicorn", "--factory", "graspd.server.app:create_app",
                             "--host", "127.0.0.1", "--port", str(port), "--log-level", "warning"], env=env)
    url = f"http://127.0.0.1:{port}"
    with GraspClient(url, timeout=2.0, retries=0) as client:
        for _ in range(120):
            if client.ready():
                return proc, url
            if proc.poll() is not None:
                break
            time.sleep(0.5)
    proc.terminate()
    raise SystemExit("the graspd service did not become ready")


def add_look_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of a looked-rounds bench (bench/approach.py, bench/slips.py): object set, rounds, first seed,
    model, a running service, output folder and tag."""
    ap.add_argument("--object-set", choices=OBJECT_SETS, default="household")
    ap.add_argument("--rounds", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--model", default=None)
    ap.add_argument("--service", default=None, help="URL of a running graspd service (default: start one)")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--tag", default="household-pile")


@contextmanager
def serving(url: str | None) -> Iterator[str]:
    """url, or the address of a graspd service started for the block and stopped after it."""
    if url is not None:
        yield url
        return
    proc, started = start_service()
    try:
        yield started
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def write_looks(out: Path, stem: str, script: str, argv: list[str] | None, model: str | None,
                records: list[dict[str, Any]], report: Callable[[list[dict[str, Any]], dict[str, Any]], str]) -> str:
    """Write a looked-rounds bench's <stem>.md (report of the records with the command, commit, date and model of
    bench/<script>) and <stem>.json (the records) into out; the markdown (bench/approach.py, bench/slips.py)."""
    md = report(records, {"command": f"PYTHONPATH=service:client .venv/bin/python bench/{script} "
                          + shlex.join(sys.argv[1:] if argv is None else argv), "commit": git_commit(),
                          "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "model": model})
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.md").write_text(md)
    (out / f"{stem}.json").write_text(json.dumps({"records": records}, indent=1))
    return md


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--settings", nargs="+", default=list(DEFAULT_SETTINGS), help="DETECTOR@SCENE-SENSING ...")
    ap.add_argument("--rounds", type=int, default=30, help="rounds per setting (seeds seed..seed+rounds-1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--objects", type=int, default=None, help="objects per round (default: 10 pour, 5 pile)")
    ap.add_argument("--object-set", choices=OBJECT_SETS, default="scaled", help="scaled: random_urdfs 900-999 "
                    "scaled to the hand (default hand); household: the held-out household models at true size "
                    "(Panda-like hand, 7.5 cm opening)")
    add_hand_argument(ap)
    add_advice_arguments(ap)
    ap.add_argument("--stop", choices=STOP_RULES, default=None, help="how a round ends (default: the object set's: "
                    "standard for household objects, ijrr for scaled ones)")
    ap.add_argument("--precision", action="store_true", help="also check the top 5 of each round's first "
                    "detection against the true meshes (P@1/P@5, bench/containers.py's check)")
    ap.add_argument("--jobs", type=int, default=1, help="rounds run in parallel processes (Ray CPUs with --ray)")
    add_cluster_arguments(ap)
    ap.add_argument("--model", default=None, help="classifier for gpd / gpd-noselect (default: first in models/)")
    ap.add_argument("--service", default=None, help="URL of a running graspd service for the gpd detectors "
                    "(default: start one on a free local port for the run)")
    ap.add_argument("--in-process", action="store_true", help="run the gpd detectors in this process, without "
                    "HTTP (developer ablations; not what a robot gets)")
    ap.add_argument("--fresh", action="store_true", help="ignore rounds recorded by an earlier run of this tag")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--tag", default="clutter", help="output file stem")
    ap.add_argument("--pictures", action="store_true", help="also write <tag>-scenes.png (scenes and clouds)")
    args = ap.parse_args(argv)
    if args.rounds < 1:
        ap.error("--rounds must be >= 1")
    try:
        parsed = [parse_setting(s) for s in args.settings]
    except ValueError as exc:
        ap.error(str(exc))
    if args.in_process and args.service:
        ap.error("--in-process and --service exclude each other")
    try:
        runner = runner_from_args(args, args.jobs, context="fork")
    except RayMissingError as exc:
        ap.error(str(exc))
    proc = None
    service = args.service
    if service is None and not args.in_process and any(det != "baseline" for det, _ in parsed):
        proc, service = start_service()
    hand = run_hand(args.object_set, args.hand)
    models = {spec: model_for(det, args.model, service) for spec, (det, _) in zip(args.settings, parsed, strict=True)}
    reported = {spec: reported_model(det, models[spec], service, hand)
                for spec, (det, _) in zip(args.settings, parsed, strict=True)}
    summaries: dict[str, Summary] = {}
    rounds: dict[str, list[dict[str, Any]]] = {}
    meta = {
        "command": "PYTHONPATH=service:client .venv/bin/python bench/clutter.py "
        + shlex.join(sys.argv[1:] if argv is None else argv),
        "commit": git_commit(),
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "cpus": os.cpu_count(),
        "jobs": args.jobs,
        "runner": runner.describe(),
        "service": service,
        "models": reported,
        "object_set": args.object_set,
        "hand": args.hand,
        "stop": args.stop or object_set_stop(args.object_set),
        "relook": args.relook, "flat_retry": args.flat_retry,
        "precision": {},
    }
    md = ""
    log = args.out / f"{args.tag}.rounds.jsonl"
    if args.fresh:
        log.unlink(missing_ok=True)
    if args.pictures:
        args.out.mkdir(parents=True, exist_ok=True)
        scene_pictures(args.out / f"{args.tag}-scenes.png", args.seed)
    try:
        for spec, (det, scene) in zip(args.settings, parsed, strict=True):
            setting = replace(SCENES[scene], objects=args.object_set, hand=hand, stop=args.stop, relook=args.relook,
                              flat_retry=args.flat_retry)
            if args.objects is not None:
                setting = replace(setting, num_objects=args.objects)
            seeds = [args.seed + i for i in range(args.rounds)]
            rows = {} if args.fresh else load_rows(log, spec, setting)
            if args.precision:
                rows = {s: r for s, r in rows.items() if r.get("precision") is not None}
            done = {s: RoundResult(**r["round"]) for s, r in rows.items()}
            checks = {s: r.get("precision") for s, r in rows.items()}
            jobs = [(det, models[spec], service, setting, s, args.precision) for s in seeds if s not in done]
            t0 = time.perf_counter()
            if done:
                print(f"{spec}: resuming, {len(seeds) - len(jobs)} of {len(seeds)} rounds recorded", flush=True)
            succeeded = attempted = 0
            # rounds come back as they finish (a pool or Ray tasks: graspd_lab.cluster), each logged at once
            with Progress(len(jobs), spec, "round") as bar:  # a bar on a terminal, a line a minute in a log
                for r, check in imap(_one_round, jobs, runner):
                    done[r.seed] = record_round(log, spec, setting, r, **({"precision": check} if check else {}))
                    checks[r.seed] = check
                    succeeded, attempted = succeeded + r.successes, attempted + r.attempts
                    bar.update(1, grasps=f"{succeeded}/{attempted} succeeded")
            results = [done[s] for s in seeds]
            summaries[spec] = summarize(results)
            rounds[spec] = [{**r.to_dict(), **({"precision": checks[r.seed]} if checks.get(r.seed) else {})}
                            for r in results]
            if args.precision:
                from containers import precision_summary  # noqa: PLC0415

                meta["precision"][spec] = precision_summary([c for c in (checks[s] for s in seeds) if c is not None])
            s = summaries[spec]
            print(f"{spec:28s} success {pct(s.success_rate)}{ci(s.success_ci)}  cleared {pct(s.cleared_rate)}"
                  f"{ci(s.cleared_ci)}  attempts {s.attempts}  failures {s.failures}  "
                  f"{s.seconds_per_round:.0f} s/round  ({time.perf_counter() - t0:.0f} s)", flush=True)
            md = write_results(args.out, args.tag, summaries, rounds, meta)  # after each setting: partial runs count
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(timeout=10)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
