"""`graspd train ...`: train, evaluate and export one grasp classifier (ONNX + model card) in one command."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any

from graspd.gpd.classifier import default_models_dir
from graspd_lab.training import instance_cli


def _categories(text: str) -> list[str]:
    return [c.strip() for c in text.split(",") if c.strip()]


def register(subparsers: Any) -> None:
    """Add the `train` subcommand to graspd's argparse subparsers."""
    p = subparsers.add_parser(
        "train", help="train + evaluate + export a grasp classifier from a graspd dataset",
        description="Train a CNN on a graspd dataset (graspd_lab.training.dataset format), evaluate the exported "
                    "ONNX model on the test part of the split, and write models-dir/NAME.onnx with its card.")
    p.add_argument("--config", help="JSON training config (graspd_lab.training.config.TrainConfig); flags override it")
    p.add_argument("--plan", help="JSON plan of several models ({defaults, models: [...]}, e.g. models/plan.json); "
                                  "trains them all in one process, reading the dataset once")
    p.add_argument("--only", type=_categories, help="with --plan: comma-separated model names to make")
    p.add_argument("--dataset", help="dataset folder (manifest.json, chunk_*.npz, splits/)")
    p.add_argument("--name", help="model name (file stem in models-dir); default generic15")
    p.add_argument("--representation", choices=["15", "12", "3", "herzog"])
    p.add_argument("--architecture", choices=["fast", "lenet"])
    p.add_argument("--split", choices=["view", "object"], help="split to train/validate/test on")
    p.add_argument("--categories", type=_categories, help="comma-separated: box,cylinder,other (default all)")
    p.add_argument("--epochs", type=int)
    p.add_argument("--batch-size", type=int, dest="batch_size")
    p.add_argument("--learning-rate", type=float, dest="learning_rate")
    p.add_argument("--patience", type=int)
    p.add_argument("--seed", type=int)
    p.add_argument("--threads", type=int, help="torch and onnxruntime threads (default 2)")
    p.add_argument("--max-train", type=int, dest="max_train", help="use at most this many training exemplars")
    p.add_argument("--max-minutes", type=float, dest="max_minutes", help="stop training after this wall time")
    p.add_argument("--feedback", help="SQLAlchemy URL of a feedback store (the service's GRASPD_TEMPLATE_LIBRARY): "
                   "the executed grasps stored with their images (POST /feedback) join the training rows")
    p.add_argument("--feedback-repeat", type=int, dest="feedback_repeat",
                   help="draw each stored outcome this many times per epoch (default 4)")
    p.add_argument("--resume", action="store_true", default=None,
                   help="continue an interrupted run from work-dir/last.pt (its config must match, except "
                        "--max-minutes; the time budget counts the time already spent); with --plan, every model")
    p.add_argument("--init-from", dest="init_from",
                   help="fine-tune: start from these weights (a checkpoint.pt, a models/NAME.pt, or a model NAME "
                        "found as models-dir/NAME.pt); same architecture and representation")
    p.add_argument("--hard-negatives", type=float, dest="hard_negatives",
                   help="from epoch 2, oversample this top fraction of the negatives by current score (e.g. 0.1: "
                        "they make up half the negatives drawn); default 0 = off")
    p.add_argument("--no-calibrate", action="store_false", dest="calibrate", default=None,
                   help="skip the Platt calibration of the scores on the validation rows")
    p.add_argument("--models-dir", default=None, help="where to write NAME.onnx and NAME.json (default models/)")
    p.add_argument("--work-dir", default=None, help="checkpoint and training metrics (default models-dir/.work/NAME)")
    instance_cli.add_arguments(p)  # --instance MESH [--category ...]: an instance model (training/instance.py)
    p.set_defaults(func=_run)


_CONFIG_FLAGS = ("dataset", "name", "representation", "architecture", "split", "categories", "epochs",
                 "batch_size", "learning_rate", "patience", "seed", "threads", "max_train", "max_minutes",
                 "feedback", "feedback_repeat", "resume", "init_from", "hard_negatives", "calibrate")


def _run(args: argparse.Namespace) -> int:
    if args.instance:
        return instance_cli.run(args)
    from graspd_lab.training.config import TrainConfig  # noqa: PLC0415 - training pulls in torch: loaded only when `graspd train` runs
    from graspd_lab.training.plans import train_and_export, train_plan  # noqa: PLC0415

    models_dir = Path(args.models_dir) if args.models_dir else default_models_dir()
    command = "graspd " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:2] == ["train"] else None
    if args.plan:
        try:
            paths = train_plan(json.loads(Path(args.plan).read_text()), models_dir, args.dataset, args.only,
                               command=command, resume=bool(args.resume))
        except (TypeError, ValueError) as exc:
            print(f"graspd train: {exc}", file=sys.stderr)
            return 2
        for path in paths:
            _print_card(path)
        return 0
    data: dict[str, Any] = json.loads(Path(args.config).read_text()) if args.config else {}
    data.update({k: getattr(args, k) for k in _CONFIG_FLAGS if getattr(args, k) is not None})
    if "dataset" not in data:
        print("graspd train: --dataset (or a config with 'dataset') is required", file=sys.stderr)
        return 2
    try:
        config = TrainConfig.from_dict(data)
    except (TypeError, ValueError) as exc:
        print(f"graspd train: {exc}", file=sys.stderr)
        return 2
    try:
        path = train_and_export(config, models_dir, args.work_dir, command=command)
    except ValueError as exc:  # e.g. a training part with one class, an unreadable feedback store
        print(f"graspd train: {exc}", file=sys.stderr)
        return 2
    _print_card(path)
    return 0


def _print_card(path: Any) -> None:
    card = json.loads(path.with_suffix(".json").read_text())
    print(f"{card['name']}:")
    for key, m in card["metrics"].items():
        print(f"  {key}: accuracy {m['accuracy']:.4f}  RA99P {m['ra99p']:.4f}  AP {m['average_precision']:.4f}  "
              f"(n={m['n']})")
    print(f"wrote {path} and {path.with_suffix('.json')}")
