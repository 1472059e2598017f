"""Command line: `graspd detect CLOUD ...` and the subcommands other modules register."""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path

import numpy as np

from .classifier import DEFAULT_CASCADE_MODEL, available_models, cascade_prefilter, default_model_name, load_model
from .cloud import CloudError
from .cloud_io import read_cloud
from .detector import DetectionParams, GraspDetector, Scorer
from .environment import EnvironmentParams
from .hand import HandGeometry, hand_preset
from .plot import plot_grasps
from .preprocess import PreprocessParams, preprocess
from .viewer import viewer_html

#: Modules exposing register(subparsers) for further subcommands (serve, train, ...).
SUBCOMMAND_MODULES: tuple[str, ...] = ("graspd.training.cli", "graspd.templates.cli")
#: Subcommands defined here: parsed without importing SUBCOMMAND_MODULES.
BUILTIN_COMMANDS: tuple[str, ...] = ("detect", "demo")
#: Registered only when importable (the server module needs the service extras).
OPTIONAL_SUBCOMMAND_MODULES: tuple[str, ...] = ("graspd.server.cli",)


def _detect(args: argparse.Namespace) -> int:
    try:
        viewpoints = np.array(args.viewpoint, np.float32).reshape(-1, 3) if args.viewpoint else None
        cloud = read_cloud(args.cloud, viewpoints=viewpoints)
        hand = hand_preset(args.hand) if args.hand else HandGeometry()
        params = DetectionParams(
            num_samples=args.samples,
            workspace=tuple(args.workspace) if args.workspace else None,
            max_grasps=args.max_grasps,
            gravity=tuple(args.gravity) if args.gravity else None,
            use_classifier=not args.no_classifier,
            exclude_support_plane=True if args.exclude_table else None,
            environment=EnvironmentParams(mode=args.environment),
            approach_distance=args.approach_distance,
            seed=args.seed,
        )
    except (CloudError, KeyError, ValueError, OSError) as exc:
        print(f"graspd detect: {exc}", file=sys.stderr)
        return 2
    classifier = None
    if not args.no_classifier:
        try:
            classifier = _load_classifier(args.model, args.models_dir)
        except ValueError as exc:
            print(f"graspd detect: {exc}", file=sys.stderr)
            return 2
    prefilter = None if classifier is None or args.no_cascade else _load_prefilter(classifier, args.models_dir)
    detection = GraspDetector(classifier, hand, prefilter).detect(cloud, params)
    out = detection.to_dict()
    if classifier is None:
        out["note"] = "no classifier: candidates are unscored (the paper's 'no classification' ablation)"
    text = json.dumps(out, indent=1)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text)
    if args.plot or args.view:
        # the cloud the environment labelled: the detector's preprocessing of the input
        shown = preprocess(cloud, PreprocessParams(voxel_size=params.voxel_size, workspace=params.workspace))
        title = f"{Path(args.cloud).name}: top {min(args.top, len(detection.grasps))} of " \
                f"{detection.num_candidates} candidates, model {detection.model or 'none (unscored)'}"
        if args.plot:
            plot_grasps(shown, detection.grasps, hand, args.plot, top=args.top, title=title,
                        gravity=params.gravity, environment=detection.environment)
        if args.view:
            Path(args.view).parent.mkdir(parents=True, exist_ok=True)
            Path(args.view).write_text(viewer_html(shown, detection, hand, top=args.view_top,
                                                   title=f"{Path(args.cloud).name}: {len(detection.grasps)} grasps, "
                                                         f"model {detection.model or 'none (unscored)'}"),
                                       encoding="utf-8")
    t = detection.timings
    print(f"{len(detection.grasps)} grasps from {detection.num_candidates} candidates on {detection.num_points} points "
          f"in {t['total']:.2f} s (" + ", ".join(f"{k} {v:.2f}" for k, v in t.items() if k != "total") + ")",
          file=sys.stderr)
    if not args.out:
        print(text)
    return 0


def _demo(args: argparse.Namespace) -> int:
    from .world.scenes import GRAVITY, cluttered_tabletop  # noqa: PLC0415

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cloud = cluttered_tabletop(num_objects=args.objects, seed=args.seed)
    classifier = None if args.no_classifier else _load_classifier(args.model, args.models_dir)
    params = DetectionParams(num_samples=args.samples, exclude_support_plane=True, gravity=GRAVITY,
                             approach_direction=GRAVITY, approach_max_angle_deg=80.0, max_grasps=20)
    detection = GraspDetector(classifier).detect(cloud, params)
    result = detection.to_dict()
    if classifier is None:
        result["note"] = "no classifier in models/: candidates are unscored (the paper's 'no classification' ablation)"
    (out / "grasps.json").write_text(json.dumps(result, indent=1))
    shown = preprocess(cloud, PreprocessParams(voxel_size=params.voxel_size))
    title = (f"demo tabletop ({args.objects} objects, {len(cloud)} points, 2 cameras): top {args.top} of "
             f"{detection.num_candidates} candidates, model {detection.model or 'none (unscored)'}")
    plot_grasps(shown, detection.grasps, detection.hand, out / "grasps.png", top=args.top, title=title,
                gravity=GRAVITY, environment=detection.environment)
    t = detection.timings
    print(f"{len(detection.grasps)} grasps from {detection.num_candidates} candidates in {t['total']:.2f} s "
          f"(model: {detection.model or 'none'}); wrote {out / 'grasps.png'} and {out / 'grasps.json'}")
    return 0


def _load_prefilter(model: Scorer, models_dir: str | None) -> Scorer | None:
    """The cascade's first pass for the model (the service's default, DEFAULT_CASCADE_MODEL), if shipped and made
    for the model's hand."""
    if DEFAULT_CASCADE_MODEL not in available_models(models_dir) or model.name == DEFAULT_CASCADE_MODEL:
        return None
    return cascade_prefilter(model, load_model(DEFAULT_CASCADE_MODEL, models_dir))  # type: ignore[no-any-return]


def _load_classifier(name: str | None, models_dir: str | None) -> Scorer | None:
    """The named ONNX classifier, or the default one if it is there (None: run unscored)."""

    if name is None:
        if default_model_name() not in available_models(models_dir):
            return None
        name = default_model_name()
    return load_model(name, models_dir)


def build_parser(subcommands: bool = True) -> argparse.ArgumentParser:
    """The parser; subcommands=False leaves out those of SUBCOMMAND_MODULES (their imports: SQLAlchemy,
    pydantic settings, the template library) for a run of a built-in command."""
    parser = argparse.ArgumentParser(prog="graspd", description="Grasp Pose Detection for two-finger hands")
    sub = parser.add_subparsers(dest="command", required=True)
    d = sub.add_parser("detect", help="detect grasps in a point cloud file (.pcd, .ply, .npz)")
    d.add_argument("cloud")
    d.add_argument("--viewpoint", type=float, nargs=3, action="extend", metavar=("X", "Y", "Z"),
                   help="camera position in the cloud frame (m); repeat for several cameras")
    d.add_argument("--workspace", type=float, nargs=6, metavar=("XMIN", "XMAX", "YMIN", "YMAX", "ZMIN", "ZMAX"))
    d.add_argument("--hand", help="hand preset: gpd (default), panda, robotiq_2f85")
    d.add_argument("--samples", type=int, default=1000, help="points to sample hands at")
    d.add_argument("--max-grasps", type=int, default=100)
    d.add_argument("--gravity", type=float, nargs=3, metavar=("GX", "GY", "GZ"),
                   help="gravity direction in the cloud frame; enables the top-grasp utility")
    d.add_argument("--model", help="classifier name in the models directory (default: scene15, trained on "
                   "cluttered scenes)")
    d.add_argument("--models-dir", help="directory of ONNX models and cards (default: the shipped models/)")
    d.add_argument("--no-classifier", action="store_true", help="skip scoring (the paper's ablation)")
    d.add_argument("--no-cascade", action="store_true", help="score every candidate with the full model (no first "
                   "pass: the service's request option cascade false)")
    d.add_argument("--exclude-table", action="store_true",
                   help="override: never sample on the dominant plane (the default samples on objects only)")
    d.add_argument("--environment", choices=("auto", "declared", "none"), default="auto",
                   help="environment model: auto (find the support and walls; default) or none (ablation)")
    d.add_argument("--approach-distance", type=float, default=0.05,
                   help="pre-grasp distance (m) whose path must be free of points and environment")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--out", help="write the grasps as JSON here (else print them)")
    d.add_argument("--plot", help="write a PNG of the cloud with the top grasps")
    d.add_argument("--top", type=int, default=10, help="grasps to draw in the --plot picture")
    d.add_argument("--view", help="write a self-contained interactive 3D view (HTML, works offline) here")
    d.add_argument("--view-top", type=int, default=50, help="grasps to draw in the --view page")
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
    if not subcommands:
        return parser
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(name).register(sub)
    for name in OPTIONAL_SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ImportError:
            continue
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else argv
    # `graspd detect` / `graspd demo` need none of the other subcommands' imports (~0.5 s of start-up)
    builtin = bool(words) and words[0] in BUILTIN_COMMANDS
    args = build_parser(subcommands=not builtin).parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())
