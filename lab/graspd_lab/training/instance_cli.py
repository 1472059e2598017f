"""`graspd train --instance MESH --name NAME [--category box|cylinder] [--views N] [--max-minutes M]`: an instance
model (graspd_lab.training.instance) from the command line.  add_arguments/run hang it on `graspd train`; the same
command runs standalone as `python -m graspd_lab.training.instance_cli --instance MESH --name NAME ...` (the
server's POST /models jobs run it so, with --progress-json).  --workers N [--ray [--address ADDR]]: the dataset's
views rendered and labelled on a pool of N processes or as Ray tasks (graspd_lab.cluster)."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any

from graspd.core.errors import FieldError
from graspd.core.hand import HAND_PRESETS, hand_preset
from graspd.core.progress import Progress
from graspd.gpd.classifier import default_models_dir
from graspd.store.instances import INSTANCE_CATEGORIES, progress_line
from graspd_lab.cluster import RayMissingError, runner_from_args
from graspd_lab.cluster import add_arguments as add_cluster_arguments


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The instance options of `graspd train` (besides its --name, --max-minutes, --seed, --threads, --epochs,
    --batch-size, --learning-rate, --patience, --models-dir and --work-dir, which they share)."""
    g = p.add_argument_group("instance models", "fine-tune a model for one object (IROS 2016 GPD, Figure 7): "
                                                "--instance MESH --name NAME [--category box|cylinder]")
    g.add_argument("--instance", metavar="MESH", help="mesh of the object (.obj, .stl or .ply, metres): make an "
                   "instance model of it instead of training on --dataset")
    g.add_argument("--category", choices=INSTANCE_CATEGORIES,
                   help="the object's category: fine-tune the category model (box15, cylinder15), not generic15")
    g.add_argument("--views", type=int, help="rendered views of the object (default 24; a quarter are held out "
                                             "for the comparison, an eighth for validation)")
    g.add_argument("--per-view", type=int, dest="per_view", help="exemplars kept per view (default 128)")
    g.add_argument("--hand", default="gpd", help=f"hand preset the images are made for: {sorted(HAND_PRESETS)}")
    g.add_argument("--base", help="base model to fine-tune (default: the category model or generic15); 'none' "
                                  "trains from scratch")
    g.add_argument("--overwrite", action="store_true", help="replace an existing model called NAME")
    g.add_argument("--progress-json", action="store_true", dest="progress_json",
                   help="progress events as 'graspd-progress {json}' lines on stdout (the log goes to stderr)")
    g.add_argument("--workers", type=int, default=1, help="render and label the views on N processes (or N Ray "
                   "CPUs with --ray; default 1: in this process)")
    add_cluster_arguments(g)


#: argparse destinations that become InstanceParams fields when given.
_PARAM_FLAGS = ("views", "per_view", "max_minutes", "seed", "threads", "epochs", "batch_size", "learning_rate",
                "patience")


def command_line(argv: list[str]) -> str:
    return "graspd train " + " ".join(shlex.quote(a) for a in argv)


def run(args: argparse.Namespace, argv: list[str] | None = None) -> int:
    """Make the instance model the parsed arguments ask for; 0, or 2 with the reason on stderr."""
    from graspd_lab.training.instance import InstanceParams, train_instance  # noqa: PLC0415 - torch: loaded only when training

    out = sys.stderr if args.progress_json else sys.stdout

    views: list[Progress] = []  # the rendering stage's display (graspd.core.progress), once it starts

    def emit(event: dict[str, Any]) -> None:
        if args.progress_json:
            print(progress_line(event), flush=True)
        elif event.get("stage") == "dataset":
            if not views:
                views.append(Progress(int(event["views"]), f"[{args.name}] rendering and labelling views", "view"))
            views[0].update(1, exemplars=event["exemplars"])
            if event["view"] >= event["views"]:
                views[0].close()

    def log(line: str) -> None:
        print(line, file=sys.stderr if args.progress_json else sys.stdout, flush=True)

    try:
        if not getattr(args, "name", None):
            raise FieldError("name", "--instance needs --name NAME (the new model's name)")
        fields = {k: getattr(args, k) for k in _PARAM_FLAGS if getattr(args, k, None) is not None}
        try:
            hand = hand_preset(args.hand)
        except KeyError as exc:
            raise FieldError("hand", str(exc.args[0])) from None
        params = InstanceParams(hand=hand, **fields)
        try:
            runner = runner_from_args(args, getattr(args, "workers", 1) or 1, context="spawn")
        except (RayMissingError, ValueError) as exc:
            raise FieldError("workers", str(exc)) from None
        models_dir = Path(args.models_dir) if getattr(args, "models_dir", None) else default_models_dir()
        base = "auto" if args.base is None else (None if args.base == "none" else args.base)
        path = train_instance(args.instance, args.name, models_dir, args.category, params, base=base,
                              work_dir=getattr(args, "work_dir", None), overwrite=args.overwrite,
                              command=command_line(argv if argv is not None else sys.argv[2:]), log=log,
                              progress=emit, runner=runner)
    except (FieldError, ValueError, OSError) as exc:
        field = exc.field if isinstance(exc, FieldError) else None
        emit({"stage": "failed", "error": str(exc), "field": field})
        print(f"graspd train: {exc}", file=sys.stderr, flush=True)
        return 2
    card = json.loads(path.with_suffix(".json").read_text())
    print(f"{card['name']} (instance of {args.instance}, base {card['instance']['base_model']}):", file=out)
    for key, m in card["instance_comparison"]["models"].items():
        print(f"  {key:>12} ({m['role']}): accuracy {m['accuracy']:.4f}  RA99P {m['ra99p']:.4f}  "
              f"AP {m['average_precision']:.4f}  (n={m['n']} held-out)", file=out)
    print(f"wrote {path} and {path.with_suffix('.json')}", file=out, flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    p = argparse.ArgumentParser(prog="python -m graspd_lab.training.instance_cli",
                                description="Make an instance model: a classifier fine-tuned for one object.")
    p.add_argument("--name", help="the new model's name (file stem in models-dir)")
    p.add_argument("--max-minutes", type=float, dest="max_minutes", help="training time budget (default 2)")
    p.add_argument("--seed", type=int)
    p.add_argument("--threads", type=int, help="torch and onnxruntime threads (default 2)")
    p.add_argument("--epochs", type=int)
    p.add_argument("--batch-size", type=int, dest="batch_size")
    p.add_argument("--learning-rate", type=float, dest="learning_rate")
    p.add_argument("--patience", type=int)
    p.add_argument("--models-dir", help="where the base models are and NAME.onnx goes (default models/)")
    p.add_argument("--work-dir", help="dataset, checkpoint and metrics (default models-dir/.work/NAME)")
    add_arguments(p)
    args = p.parse_args(argv)
    if not args.instance:
        p.error("--instance MESH is required")
    return run(args, argv)


if __name__ == "__main__":
    raise SystemExit(main())
