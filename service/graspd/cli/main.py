"""Command line: `graspd detect CLOUD ...` and the subcommands other modules register.

Start-up is kept short: this module imports the standard library only, so `graspd --help` and `graspd
--version` answer without numpy, open3d, onnxruntime, FastAPI or torch (bench/cli.py measures it).  A command
imports what it needs when it runs; a subcommand of another module (serve, train, templates) is imported
only when it is named.
"""

# ruff: noqa: PLC0415 -- the heavy imports live in the commands that need them (fast --help)

from __future__ import annotations

import argparse
import importlib
import json
import math
import sys
from collections.abc import Collection
from pathlib import Path
from typing import TYPE_CHECKING, Any

from graspd import __version__
from graspd.cli.targets import add_target_arguments

if TYPE_CHECKING:
    from graspd.core.cloud import ViewpointCloud
    from graspd.gpd.detector import Detection, DetectionParams, Scorer

#: Subcommands other modules define with register(subparsers): name -> (module, the help line `graspd --help`
#: shows without importing it; tests/cli/test_cli_startup.py keeps the two the same).
LAZY_SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "train": ("graspd_lab.training.cli", "train + evaluate + export a grasp classifier from a graspd dataset"),
    "templates": ("graspd.cli.templates", "grasp templates from demonstrations (Herzog et al.)"),
    "serve": ("graspd.server.cli", "run the grasp-detection service (HTTP + Zenoh)"),
}
#: Modules exposing register(subparsers) for further subcommands (serve, train, ...).
SUBCOMMAND_MODULES: tuple[str, ...] = tuple(module for module, _ in LAZY_SUBCOMMANDS.values())
#: Subcommands defined here.
BUILTIN_COMMANDS: tuple[str, ...] = ("detect", "demo")
#: Exit status of a command that cannot run as asked (bad arguments, no usable model).
EXIT_USAGE = 2
#: A demo detection slower than this (s) was a first call that compiled the kernels: a second one is timed too.
DEMO_COLD_S = 5.0


def missing_package_hint(exc: ImportError) -> str:
    """What to install when an import fails: the lab (graspd-lab: training, simulation, the demo's rendered scene)
    when a graspd_lab module is missing, otherwise graspd's own dependencies."""
    if (exc.name or "").startswith("graspd_lab") or "graspd_lab" in str(exc):
        return (f"needs the lab distribution graspd-lab, which is not installed ({exc}); install it with "
                f"`pip install -e ./lab` (make setup does)")
    return (f"cannot import what it needs ({type(exc).__name__}: {exc}); install graspd with its dependencies "
            f"(make setup, or pip install -e .)")


class CliError(Exception):
    """A command cannot run as asked: the message says what is wrong and what to do (printed, exit 2)."""


def _intrinsics(values: list[str] | None) -> Any:
    """--intrinsics: four numbers fx fy cx cy, or one calibration YAML file (graspd.io.calibration)."""
    if values is None:
        return None
    if len(values) == 1:
        from graspd.io.calibration import MAX_CALIBRATION_BYTES, parse_calibration

        path = Path(values[0])
        if path.stat().st_size > MAX_CALIBRATION_BYTES:
            raise ValueError(f"--intrinsics {path.name}: larger than {MAX_CALIBRATION_BYTES} bytes")
        return parse_calibration(path.read_bytes())
    if len(values) != 4:
        raise ValueError(f"--intrinsics takes FX FY CX CY (pixels) or one calibration YAML file, got {values}")
    return [float(v) for v in values]


def _inputs(args: argparse.Namespace) -> Any:
    """(label, CloudInput, message description or None) of each cloud to detect on: the file's one, or one per
    selected message of a bag."""
    import numpy as np

    from graspd.io.bag import BagQuery, is_bag_path, read_bag
    from graspd.io.cloud_files import read_input

    if is_bag_path(args.cloud):
        query = BagQuery(topic=args.topic, info_topic=args.info_topic, index=args.index, every=args.every,
                         frame=args.frame, depth_scale=args.depth_scale)
        for message in read_bag(args.cloud, query):
            yield f"{Path(args.cloud).name} {message.topic} #{message.index}", message.cloud_input(), \
                message.describe()
        return
    viewpoints = np.array(args.viewpoint, np.float32).reshape(-1, 3) if args.viewpoint else None
    # the service's way with the same file (graspd.io.inputs): NaN rows dropped and counted, camera poses applied
    yield Path(args.cloud).name, read_input(args.cloud, viewpoints=viewpoints, camera_poses=args.camera_pose,
                                            points_frame=args.points_frame,
                                            intrinsics=_intrinsics(args.intrinsics),
                                            depth_scale=args.depth_scale), None


def _numbered(path: str | None, index: int | None) -> str | None:
    """A per-message output path: NAME-INDEX.EXT (None: path itself)."""
    if path is None or index is None:
        return path
    p = Path(path)
    return str(p.with_name(f"{p.stem}-{index}{p.suffix}"))


def _detect(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from graspd.cli.targets import target_spec
    from graspd.core.errors import FieldError
    from graspd.core.hand import HandGeometry, hand_preset
    from graspd.gpd.detector import DetectionParams
    from graspd.gpd.environment import EnvironmentParams

    try:
        hand = hand_preset(args.hand) if args.hand else HandGeometry()
        params = DetectionParams(
            num_samples=args.samples,
            workspace=tuple(args.workspace) if args.workspace else None,
            max_grasps=args.max_grasps,
            gravity=tuple(args.gravity) if args.gravity else None,
            use_classifier=not args.no_classifier,
            exclude_support_plane=True if args.exclude_table else None,
            environment=EnvironmentParams(mode=args.environment),
            unknown_space=args.unknown_space,
            flat_objects=args.flat_objects,
            robust_copies=args.robust_copies,
            approach_distance=args.approach_distance,
            seed=args.seed,
        )
        if args.max_per_object is not None:
            params = replace(params, max_per_object=args.max_per_object)
        target = target_spec(args)  # what to grasp, checked against each input's rows as it is detected
        inputs = _inputs(args)
        first = next(inputs)  # the file read (or the bag's first selected message) before any model loads
    except (FieldError, KeyError, ValueError, OSError) as exc:  # FieldError: CloudError, a bad camera pose
        print(f"graspd detect: {exc}", file=sys.stderr)
        return 2
    try:
        classifier = None if args.no_classifier else _load_classifier(args.model, args.models_dir)
        prefilter = None if classifier is None or args.no_cascade else _load_prefilter(classifier, args.models_dir)
    except CliError as exc:
        print(f"graspd detect: {exc}", file=sys.stderr)
        return EXIT_USAGE
    results = []
    current = first
    while True:
        label, given, message = current
        index = None if message is None or args.every is None else message["index"]
        try:  # a target that does not fit this input (TargetError, a mask of another size): named, exit 2
            results.append(_detect_one(args, label, given, message, hand, params, classifier, prefilter, index,
                                       target))
        except (FieldError, ValueError) as exc:
            print(f"graspd detect: {label}: {exc}", file=sys.stderr)
            return 2
        if message is None or args.every is None:
            break
        try:
            current = next(inputs)
        except StopIteration:
            break
        except (FieldError, KeyError, ValueError, OSError) as exc:
            print(f"graspd detect: {exc}", file=sys.stderr)
            return 2
    out: Any = results if args.every is not None and message is not None else results[0]
    text = json.dumps(out, indent=1)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text)
    else:
        print(text)
    return 0


def _detect_one(args: argparse.Namespace, label: str, given: Any, message: dict[str, Any] | None, hand: Any,
                params: Any, classifier: Any, prefilter: Any, index: int | None,
                target: dict[str, Any] | None = None) -> dict[str, Any]:
    """One detection on one input, as the service runs it (target: the request's, cli.targets.target_spec); the
    answer (with the bag message it came from).  ValueError or TargetError when the target does not fit."""
    from dataclasses import replace

    from graspd.cli.targets import cli_target
    from graspd.gpd.detector import GraspDetector
    from graspd.gpd.preprocess import PreprocessParams, preprocess
    from graspd.io.inputs import point_counts

    cloud = given.cloud
    params = replace(params, target=cli_target(target, given))
    detection = GraspDetector(classifier, hand, prefilter).detect(cloud, params)
    detection = replace(detection, warnings=(*given.warnings, *detection.warnings))  # the input's first, as served
    detection, out_of_range = _checked(detection, cloud, params, classifier)  # the request-level checks, as served
    out = {"frame": given.frame, **({"message": message} if message is not None else {}), **_with_ranking(detection),
           **point_counts(given.received, given.dropped, out_of_range)}  # as the service answers
    if classifier is None:
        out["note"] = "no classifier: candidates are unscored (the paper's 'no classification' ablation)"
    plot, view = _numbered(args.plot, index), _numbered(args.view, index)
    if plot or view:
        from graspd.viz.plot import plot_grasps  # matplotlib: only when a picture is asked for
        from graspd.viz.viewer import object_box, targeted_object, viewer_html

        # the cloud the environment labelled: the detector's preprocessing of the input
        shown = preprocess(cloud, PreprocessParams(voxel_size=params.voxel_size, workspace=params.workspace))
        title = f"{label}: {_drawn(args.top, detection)}"
        picked = targeted_object(detection, args.target_object, target is not None)  # marked in both
        marked = object_box(detection.objects[picked]) if picked is not None and picked < len(
            detection.objects) else None
        if plot:
            plot_grasps(shown, detection.grasps, hand, plot, top=args.top, title=title,
                        gravity=params.gravity, environment=detection.environment, warnings=detection.warnings,
                        marked=marked, marked_label=f"target: object {picked}")
        if view:
            Path(view).parent.mkdir(parents=True, exist_ok=True)
            Path(view).write_text(viewer_html(shown, detection, hand, top=args.view_top,
                                              title=f"{label}: {len(detection.grasps)} grasps, "
                                                    f"model {detection.model or 'none (unscored)'}",
                                              picked=picked),
                                  encoding="utf-8")
    t = detection.timings
    print(f"{label}: {len(detection.grasps)} grasps from {detection.num_candidates} candidates on "
          f"{detection.num_points} points in {t['total']:.2f} s ("
          + ", ".join(f"{k} {v:.2f}" for k, v in t.items() if k != "total") + ")", file=sys.stderr)
    return out


def _demo(args: argparse.Namespace) -> int:
    from graspd.gpd.detector import DetectionParams, GraspDetector
    from graspd.gpd.preprocess import PreprocessParams, preprocess
    from graspd.viz.plot import plot_grasps
    try:
        from graspd_lab.world.scenes import GRAVITY, cluttered_tabletop
    except ImportError as exc:  # the demo renders its scene with the lab's world
        print(f"graspd demo: {missing_package_hint(exc)}", file=sys.stderr)
        return EXIT_USAGE

    try:
        classifier = None if args.no_classifier else _load_classifier(args.model, args.models_dir)
    except CliError as exc:
        print(f"graspd demo: {exc}", file=sys.stderr)
        return EXIT_USAGE
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cloud = cluttered_tabletop(num_objects=args.objects, seed=args.seed)
    params = DetectionParams(num_samples=args.samples, exclude_support_plane=True, gravity=GRAVITY,
                             approach_direction=GRAVITY, approach_max_angle_deg=80.0, max_grasps=20)
    detector = GraspDetector(classifier)
    first = detector.detect(cloud, params)
    # a fresh install compiles its kernels on the first call (cached on disk): time a warm call too, as served
    again = detector.detect(cloud, params) if first.timings["total"] > DEMO_COLD_S else None
    detection, _ = _checked(first, cloud, params, classifier)
    result = _with_ranking(detection)
    if classifier is None:
        result["note"] = "no classifier in models/: candidates are unscored (the paper's 'no classification' ablation)"
    (out / "grasps.json").write_text(json.dumps(result, indent=1))
    shown = preprocess(cloud, PreprocessParams(voxel_size=params.voxel_size))
    title = f"demo tabletop ({args.objects} objects, {len(cloud)} points, 2 cameras): {_drawn(args.top, detection)}"
    plot_grasps(shown, detection.grasps, detection.hand, out / "grasps.png", top=args.top, title=title,
                gravity=GRAVITY, environment=detection.environment, warnings=detection.warnings)
    took = f"{first.timings['total']:.2f} s"
    if again is not None:
        took = (f"{again.timings['total']:.2f} s ({first.timings['total']:.1f} s the first time: the kernels "
                "compiled, cached on disk for later runs)")
    print(f"{len(detection.grasps)} grasps from {detection.num_candidates} candidates in {took} "
          f"(model: {detection.model or 'none'}); wrote {out / 'grasps.json'} (all {len(detection.grasps)}) and "
          f"{out / 'grasps.png'} (the best {min(args.top, len(detection.grasps))})")
    return 0


def _drawn(top: int, detection: Detection) -> str:
    """What a picture's title says it draws: 'the best 8 of the 20 grasps returned (1077 candidates, model
    scene15)'."""
    n = len(detection.grasps)
    return (f"the best {min(top, n)} of the {n} grasps returned ({detection.num_candidates} candidates, model "
            f"{detection.model or 'none: unscored'})")


def _with_ranking(detection: Detection) -> dict[str, Any]:
    """detection.to_dict() with each grasp's ranking terms and the rule combining them, as the service answers
    (non-finite terms as null)."""
    from graspd.core.grasp import RANKING_RULE

    out = detection.to_dict()
    ranking = detection.grasps.ranking
    if ranking is not None:
        for grasp, terms in zip(out["grasps"], ranking.to_dicts(), strict=True):
            grasp["ranking"] = {k: v if math.isfinite(v) else None for k, v in terms.items()}
        out["ranking_rule"] = RANKING_RULE
    return out


def _checked(detection: Detection, cloud: ViewpointCloud, params: DetectionParams,
             classifier: Scorer | None) -> tuple[Detection, int]:
    """The detection with the service's request-level warnings (graspd.gpd.sanity.check_detection, the same as on
    every transport), each also printed on stderr, and the points the range window left out (as answers count
    them)."""
    from graspd.gpd.classifier import card_serves_hand
    from graspd.gpd.sanity import check_detection, region_check

    card = getattr(classifier, "card", None)
    fits = None if card is None else card_serves_hand(dict(card), detection.hand.to_dict())
    region = region_check(cloud, params.workspace, params.range_window)
    detection = detection.warned(*check_detection(detection, cloud, params.workspace, params.range_window, fits,
                                                  region))
    for w in detection.warnings:
        print(f"warning {w.code}: {w.message}", file=sys.stderr)
    return detection, region.left_out


_UNSCORED_HINT = "or run unscored with --no-classifier (the paper's 'no classification' ablation)"


def _load_prefilter(model: Scorer, models_dir: str | None) -> Scorer | None:
    """The cascade's first pass for the model (the service's default, DEFAULT_CASCADE_MODEL), if shipped and made
    for the model's hand.  CliError when it is there but does not load."""
    from graspd.gpd.classifier import DEFAULT_CASCADE_MODEL, available_models, cascade_prefilter

    if DEFAULT_CASCADE_MODEL not in available_models(models_dir) or model.name == DEFAULT_CASCADE_MODEL:
        return None
    first = _checked_model(DEFAULT_CASCADE_MODEL, models_dir, "--no-cascade (score every candidate with the "
                                                                 "full model)")
    return cascade_prefilter(model, first)  # type: ignore[no-any-return]


def _load_classifier(name: str | None, models_dir: str | None) -> Scorer:
    """The named ONNX classifier, else the default one (classifier.DEFAULT_MODEL_NAME).  CliError, with what to
    do, when the models folder is missing or holds no model, when the model is not there, or when it does not
    load or score: a detection never runs unscored unless --no-classifier asks for it."""
    from graspd.gpd.classifier import available_models, default_model_name, default_models_dir

    folder = Path(models_dir) if models_dir is not None else default_models_dir()
    where = "--models-dir" if models_dir is not None else "the default models folder (GRASPD_MODELS_DIR, else " \
        "models/ of the repository)"
    if name is None or not name.endswith(".onnx"):  # by name: it must be in the folder
        if not folder.is_dir():
            raise CliError(f"models folder {folder} ({where}) does not exist: point --models-dir at a folder of "
                           f"NAME.onnx files with their NAME.json cards (the repository ships them in models/), "
                           f"{_UNSCORED_HINT}")
        names = available_models(folder)
        if not names:
            raise CliError(f"models folder {folder} ({where}) holds no model (a NAME.onnx with its NAME.json "
                           f"card): copy the shipped models/ there or train one (graspd train), {_UNSCORED_HINT}")
        if name is None and default_model_name() not in names:
            raise CliError(f"the default model {default_model_name()!r} is not in {folder}; it has {names}: choose "
                           f"one with --model NAME, {_UNSCORED_HINT}")
    return _checked_model(name or default_model_name(), models_dir, _UNSCORED_HINT)


def _checked_model(name: str, models_dir: str | None, instead: str) -> Scorer:
    """A model loaded and probed on one blank image (it must give one finite probability); CliError naming the
    model, why it failed and what to do (`instead`: the option that does without it)."""
    import numpy as np

    from graspd.gpd.classifier import ModelError, load_model

    try:
        model = load_model(name, models_dir)
        probe = model.score(np.zeros((1, model.channels, model.image_size, model.image_size), np.uint8))
    except ModelError as exc:
        raise CliError(f"{exc}: restore the model's .onnx and .json (for example git checkout models/), choose "
                       f"another with --model NAME, {instead}") from None
    except Exception as exc:  # onnxruntime raises its own types when a network loads but cannot run
        raise CliError(f"model {name!r} does not run ({type(exc).__name__}: {exc}): restore its .onnx and "
                       f".json, choose another with --model NAME, {instead}") from None
    if probe.shape != (1,) or not np.isfinite(probe).all():
        raise CliError(f"model {name!r} gives {probe!r} for one blank image, not one probability: restore or "
                       f"retrain it, choose another with --model NAME, {instead}")
    return model


def build_parser(load: Collection[str] | bool = ()) -> argparse.ArgumentParser:
    """The parser.  load: the LAZY_SUBCOMMANDS whose modules are imported and registered (True: all of them);
    the others are listed by name and help line only, so that `graspd --help` and the built-in commands do
    without their imports (SQLAlchemy, FastAPI, pydantic settings, torch)."""
    parser = argparse.ArgumentParser(prog="graspd", description="Grasp Pose Detection for two-finger hands")
    parser.add_argument("--version", action="version", version=f"graspd {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    d = sub.add_parser("detect", help="detect grasps in a point cloud file (.pcd, .ply, .npz, .npy), a depth "
                       "image (.png, .npy with --intrinsics) or a ROS bag (.mcap, .db3, .bag, a rosbag2 folder)")
    d.add_argument("cloud", help=".pcd, .ply; .npz (points, optional viewpoints, camera_source, normals, "
                   "camera_poses); .npy ((N,3) points, (H,W,3) organised, or with --intrinsics an (H,W) depth image in "
                   "metres); .png (16-bit depth, --depth-scale m a unit) with --intrinsics; a ROS bag (rosbag2 .mcap, "
                   ".db3 or folder, ROS 1 .bag) with --topic.  Rows with NaN are dropped "
                   "and counted (warning non_finite_dropped)")
    d.add_argument("--viewpoint", type=float, nargs=3, action="extend", metavar=("X", "Y", "Z"),
                   help="camera position in the cloud frame (m); repeat for several cameras")
    d.add_argument("--camera-pose", type=float, nargs="+", action="append", metavar="V",
                   help="camera-to-robot transform of a camera: X Y Z QX QY QZ QW (m, quaternion as ROS TF gives "
                   "it) or 16 numbers (4x4, row-major); repeat per camera; instead of --viewpoint.  Grasps, and "
                   "--workspace/--gravity, are then in the robot frame")
    d.add_argument("--points-frame", choices=("camera", "robot"),
                   help="with --camera-pose: the points are in the camera's frame (moved into the robot frame) or "
                   "already in the robot frame; a depth image is always 'camera'")
    d.add_argument("--intrinsics", nargs="+", metavar="V",
                   help="depth images: pinhole intrinsics FX FY CX CY in pixels (ROS CameraInfo K), or the camera's "
                   "calibration YAML file as ROS camera drivers write it (camera_calibration_parsers; its projection "
                   "matrix is used, as depth_image_proc does)")
    d.add_argument("--depth-scale", type=float, default=0.001,
                   help="depth PNG: metres per unit (default 0.001: millimetres)")
    d.add_argument("--topic", help="bags: the PointCloud2 or depth Image topic (default: the bag's only "
                   "PointCloud2 topic, else its only Image topic)")
    d.add_argument("--info-topic", help="bags: the CameraInfo topic of a depth Image topic (default: the sibling "
                   "camera_info, e.g. /camera/depth/camera_info for /camera/depth/image_rect_raw)")
    d.add_argument("--index", type=int, default=0, help="bags: the message of the topic to detect on (0-based)")
    d.add_argument("--every", type=int, help="bags: detect on every Nth message from --index on (one answer per "
                   "message: a JSON list; --plot/--view files get -INDEX before their suffix)")
    d.add_argument("--frame", help="bags: the frame the grasps are given in, through the bag's /tf_static chain "
                   "from the cloud's frame (default: the root of that chain; the cloud's own frame when it has no "
                   "/tf_static)")
    d.add_argument("--workspace", type=float, nargs=6, metavar=("XMIN", "XMAX", "YMIN", "YMAX", "ZMIN", "ZMAX"))
    d.add_argument("--hand", help="hand preset: gpd (default), panda, robotiq_2f85")
    d.add_argument("--samples", type=int, default=1000, help="points to sample hands at")
    d.add_argument("--max-grasps", type=int, default=100)
    d.add_argument("--gravity", type=float, nargs=3, metavar=("GX", "GY", "GZ"),
                   help="gravity direction in the cloud frame; enables the top-grasp utility")
    d.add_argument("--model", help="classifier name in the models directory (default: household15, trained on "
                   "cluttered scenes, containers and household objects at their true size)")
    d.add_argument("--models-dir", help="directory of ONNX models and cards (default: the shipped models/)")
    d.add_argument("--no-classifier", action="store_true", help="skip scoring (the paper's ablation)")
    d.add_argument("--no-cascade", action="store_true", help="score every candidate with the full model (no first "
                   "pass: the service's request option cascade false)")
    d.add_argument("--exclude-table", action="store_true",
                   help="override: never sample on the dominant plane (the default samples on objects only)")
    d.add_argument("--environment", choices=("auto", "declared", "none"), default="auto",
                   help="environment model: auto (find the support levels, walls and rims; default) or none "
                   "(ablation)")
    d.add_argument("--unknown-space", choices=("avoid", "fallback", "allow"), default="avoid",
                   help="space no camera saw: avoid (default: a hand reaching into it collides), fallback (the same; "
                   "when no hand is left, those reaching least into it come back with a warning) or allow (check "
                   "the seen points only, as GPD does; the answer warns when the best grasps reach into it)")
    d.add_argument("--flat-objects", action="store_true", help="also grasp objects lying flat (a packet 1 cm thick) "
                   "by their edges, the fingertips stopping above the table (such grasps hold less often)")
    d.add_argument("--robust-copies", type=int, default=0, help="rank the first 16 grasps by their score averaged "
                   "over this many copies moved 2 mm and turned 3 degrees (0: off, the default)")
    d.add_argument("--approach-distance", type=float, default=0.05,
                   help="pre-grasp distance (m) whose path must be free of points and environment")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--out", help="write the grasps as JSON here (else print them)")
    d.add_argument("--plot", help="write a PNG of the cloud with the top grasps")
    d.add_argument("--top", type=int, default=10, help="grasps to draw in the --plot picture")
    d.add_argument("--view", help="write a self-contained interactive 3D view (HTML, works offline) here")
    d.add_argument("--view-top", type=int, default=50, help="grasps to draw in the --view page")
    add_target_arguments(d)
    d.set_defaults(func=_detect)
    demo = sub.add_parser("demo", help="detect grasps on a bundled rendered tabletop scene and draw them")
    demo.add_argument("--out", default="out/demo", help="folder for grasps.png and grasps.json")
    demo.add_argument("--objects", type=int, default=6)
    demo.add_argument("--samples", type=int, default=800)
    demo.add_argument("--seed", type=int, default=7)
    demo.add_argument("--top", type=int, default=8)
    demo.add_argument("--model")
    demo.add_argument("--models-dir")
    demo.add_argument("--no-classifier", action="store_true")
    demo.set_defaults(func=_demo)
    for name, (module, help_line) in LAZY_SUBCOMMANDS.items():
        if load is True or (load is not False and name in load):
            importlib.import_module(module).register(sub)
        else:
            sub.add_parser(name, help=help_line, add_help=False)  # never parsed: main() loads a named one
    return parser


def main(argv: list[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else argv
    command = words[0] if words else None
    load = [command] if command in LAZY_SUBCOMMANDS else []
    try:
        parser = build_parser(load)
    except ImportError as exc:  # e.g. `graspd train` without the lab, `graspd serve` without the service's deps
        print(f"graspd {command}: {missing_package_hint(exc)}", file=sys.stderr)
        return EXIT_USAGE
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())
