"""Classifier benchmark: the IJRR paper's evaluation of the shipped models, and their CPU inference speed.

Writes OUT/classifier.md (tables) and PNG precision-recall curves:
  Figure 8  - representations 15 / 12 / 3 / Herzog (models/comparison/rep*-view, rep*-object: identical configs)
  Figure 10 - category models (box15, cylinder15) vs the generic model on their category, view split
  LeNet (paper's network) vs the fast network: accuracy, RA99P, and seconds to classify 1k candidates with
  onnxruntime on 2 threads (median of repeats, images from the dataset's test part).

  PYTHONPATH=service .venv/bin/python bench/classifier.py --dataset DATA --models-dir models --out models/evaluation

With --scenes it adds the top of the ranking on cluttered scenes (graspd_lab.training.scene_eval), measured against the
true meshes: precision@1/5/10 per scene of the service's answer (defaults, the model under test) and of the
classifier's own score ranking, on scenes of objects no training scene holds, and a reliability diagram with
the expected calibration error of the scores on those scenes' candidates:

  PYTHONPATH=service .venv/bin/python bench/classifier.py --scenes 30 --scene-models generic15 scene15 \
      --out models/evaluation [--dataset SCENE_DATA]   # --scene-objects held-out: random_urdfs 900-999
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from graspd.gpd.classifier import OnnxGraspClassifier, available_models, load_model  # noqa: E402
from graspd_lab.training.dataset import CATEGORIES, derive_images, read_manifest  # noqa: E402
from graspd_lab.training.evaluate import (  # noqa: E402
    classification_metrics,
    expected_calibration_error,
    pr_curve,
    reliability_bins,
)
from graspd_lab.training.rows import load_rows  # noqa: E402

REPRESENTATIONS = ("15", "12", "3", "herzog")
CATEGORY_MODELS = {"box": "box15", "cylinder": "cylinder15"}
SPEED_MODELS = ("lenet15", "generic15")
ROOT = Path(__file__).resolve().parents[1]


def shown_path(path: Path) -> str:
    """A dataset path as the results file records it: relative to the repository when it lies inside it, else its
    last two parts (never a machine's absolute path in a committed file)."""
    resolved = path.resolve()
    if resolved.is_relative_to(ROOT):
        return resolved.relative_to(ROOT).as_posix()
    return Path(*resolved.parts[-2:]).as_posix() if len(resolved.parts) > 2 else resolved.name


class Evaluator:
    """Scores models on the test part of a split; each split's 15-channel rows are read once, and every
    representation and category subset is derived from them in memory."""

    def __init__(self, dataset: Path, limit: int | None) -> None:
        self.dataset = dataset
        self.limit = limit
        self._rows: dict[str, tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.uint8]]] = {}

    def rows(self, kind: str, representation: str, categories: list[str] | None
             ) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        if kind not in self._rows:
            self._rows[kind] = load_rows(self.dataset, kind, "test", "15", None, self.limit)
        images, labels, cats = self._rows[kind]
        keep = np.ones(len(labels), bool) if categories is None else np.isin(
            cats, [CATEGORIES[c] for c in categories])
        return derive_images(images[keep], representation), labels[keep]

    def run(self, clf: OnnxGraspClassifier, kind: str, categories: list[str] | None = None
            ) -> tuple[dict[str, Any], NDArray[np.float32], NDArray[np.uint8]]:
        images, labels = self.rows(kind, clf.representation, categories)
        scores = clf.score(images)
        return classification_metrics(scores, labels), scores, labels


def time_1k(clf: OnnxGraspClassifier, images: NDArray[np.uint8], repeats: int = 7) -> float:
    """Median seconds to score 1000 candidates (images tiled to 1000 rows), after one warm-up run."""
    reps = int(np.ceil(1000 / len(images)))
    batch = np.ascontiguousarray(np.concatenate([images] * reps)[:1000])
    clf.score(batch)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        clf.score(batch)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def plot_curves(curves: list[tuple[str, NDArray[np.float32], NDArray[np.uint8]]], title: str, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    for label, scores, truth in curves:
        prec, rec, _ = pr_curve(scores, truth)
        ax.plot(rec, prec, label=label)
    ax.axhline(0.99, color="grey", lw=0.8, ls="--")
    ax.set(xlabel="recall", ylabel="precision", title=title, xlim=(0, 1), ylim=(0.5, 1.005))
    ax.legend(loc="lower left", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_reliability(curves: list[tuple[str, NDArray[np.float64], NDArray[np.bool_]]], title: str, path: Path) -> None:
    """Reliability diagram: fraction of grasps against mean score per score bin (the diagonal is calibrated)."""
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    ax.plot([0, 1], [0, 1], color="grey", lw=0.8, ls="--", label="calibrated")
    for label, scores, truth in curves:
        bins = [b for b in reliability_bins(scores, truth) if b["count"] > 0]
        ece = expected_calibration_error(scores, truth)
        ax.plot([b["mean_score"] for b in bins], [b["positive_fraction"] for b in bins], marker="o",
                label=f"{label} (ECE {ece:.3f})")
    ax.set(xlabel="mean score in bin", ylabel="fraction that are grasps", title=title, xlim=(0, 1), ylim=(0, 1))
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def scene_section(models: list[str], models_dir: Path, scenes: int, objects: str, out: Path, threads: int
                  ) -> tuple[list[str], dict[str, float]]:
    """The scene tables: precision@k on evaluation scenes for each model, and their reliability diagram.
    A name FIRST+FULL is the two-model cascade: FIRST scores every candidate, FULL the kept ones."""
    from graspd_lab.training.scene_eval import SceneEvalParams, evaluate_scenes, evaluation_views  # noqa: PLC0415

    t0 = time.perf_counter()
    views = evaluation_views(SceneEvalParams(scenes=scenes, objects=objects))
    what = "the object split's test objects (no training scene holds them)" if objects == "unseen" else \
        "the held-out test objects random_urdfs 900-999"
    lines = [f"## Precision at the top on cluttered scenes ({objects} objects)\n",
             f"{len(views)} scenes (trays, piles, packed rows) of {what}, one view each with the clutter "
             "benchmark's cameras and noise; built in "
             f"{time.perf_counter() - t0:.0f} s.  `service` = what POST /detect answers: the detector run in this "
             "process with the service's default DetectionParams and the workspace box a robot sends (selection "
             "included); FIRST+FULL is the service's default cascade, a name without + is the full model alone "
             "(cascade off); `score` = every candidate by classifier score.  Labels: the true meshes (contacts on one "
             "object within friction cones of mu 0.5, nothing hit on the way in).\n",
             "| model | service p@1 | service p@5 | service p@10 | score p@1 | score p@5 | score p@10 | "
             "candidate ECE | s (detect + label, all scenes) |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    found: dict[str, float] = {}
    curves = []
    notes: list[str] = []
    for name in models:
        first, _, full = name.rpartition("+")
        clf = load_model(full, models_dir, threads=threads)
        pre = load_model(first, models_dir, threads=threads) if first else None
        t_model = time.perf_counter()
        r = evaluate_scenes(clf, views, prefilter=pre)
        found[f"{name} {objects} seconds"] = time.perf_counter() - t_model
        m = r["mean"]
        ece = expected_calibration_error(r["scores"], r["labels"])
        curves.append((name, r["scores"], r["labels"]))
        found.update({f"{name} {objects} {k}": v for k, v in m.items()})
        found[f"{name} {objects} ece"] = ece
        lines.append(f"| {name} | {m['service p@1']:.3f} | {m['service p@5']:.3f} | {m['service p@10']:.3f} | "
                     f"{m['score p@1']:.3f} | {m['score p@5']:.3f} | {m['score p@10']:.3f} | {ece:.3f} | "
                     f"{found[f'{name} {objects} seconds']:.0f} |")
        worst = sorted(r["scenes"], key=lambda s: s.get("service p@1", 1.0))[:3]
        notes.append(f"{name}: lowest service p@1 scenes: " + "; ".join(
            f"scene {s['scene']} ({s['kind']}, {s['sensing']}, {s['objects']} objects): {s.get('service p@1', 0):.0f}"
            for s in worst) + "\n")
    lines += ["", *notes]
    plot_reliability(curves, f"Scores on candidates of {objects}-object scenes", out / f"reliability_{objects}.png")
    lines.append(f"Reliability diagram: `reliability_{objects}.png`.\n")
    return lines, found


def scene_data_main(args: argparse.Namespace, ev: Evaluator) -> int:
    """Tables for a scene dataset: every --scene-models model on the view and object splits' test parts
    (accuracy, RA99P, AP, ECE, precision-recall curves), then the scene precision@k section if --scenes."""
    lines = [f"# Grasp classifier evaluation on scene data\n\nDataset: `{shown_path(args.dataset)}` "
             "(graspd_lab.training.scene_data); "
             "test parts of its splits: view = new scenes and views of training objects, object = scenes of objects "
             "no training scene holds.  RA99P = recall at 99% precision; ECE = expected calibration error "
             f"(10 bins); s per 1k = onnxruntime on {args.threads} threads, median of 7, load average "
             f"{os.getloadavg()[0]:.2f} before the tables.\n",
             "| model | split | test exemplars | positives | accuracy | RA99P | AP | ECE | s per 1k candidates |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    found: dict[str, float] = {}
    for kind in ("view", "object"):
        curves = []
        for name in args.scene_models:
            if "+" in name:  # a cascade: its models have rows of their own; the cascade shows in the scene section
                continue
            clf = load_model(name, args.models_dir, threads=args.threads)
            m, s, y = ev.run(clf, kind)
            curves.append((name, s, y))
            found[f"{name} {kind} ra99p"] = m["ra99p"]
            seconds = time_1k(clf, ev.rows(kind, clf.representation, None)[0][:1000])
            lines.append(f"| {name} | {kind} | {m['n']} | {m['positives']} | {m['accuracy']:.3f} | {m['ra99p']:.3f} | "
                         f"{m['average_precision']:.3f} | {expected_calibration_error(s, y):.3f} | {seconds:.3f} |")
        plot_curves(curves, f"Scene data, {kind} split", args.out / f"scenes_{kind}_split.png")
    lines.append("")
    if args.scenes:
        more, f2 = scene_section(args.scene_models, args.models_dir, args.scenes, args.scene_objects, args.out,
                                 args.threads)
        lines += more
        found.update(f2)
    text = "\n".join(lines)
    (args.out / "scene_data.md").write_text(text + "\n")
    print(text)
    return 0


def _row(name: str, m: dict[str, Any], extra: str = "") -> str:
    return (f"| {name} | {m['n']} | {m['accuracy']:.3f} | {m['ra99p']:.3f} | {m['average_precision']:.3f} |"
            f"{extra}")


HEADER = "| model | test exemplars | accuracy | RA99P | AP |"
RULE = "|---|---:|---:|---:|---:|"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", type=Path, help="dataset (single-object or scene) for the test-part tables")
    ap.add_argument("--models-dir", default=Path("models"), type=Path)
    ap.add_argument("--out", default=Path("models/evaluation"), type=Path)
    ap.add_argument("--limit", type=int, default=None, help="at most this many test exemplars per table row")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads for the timing")
    ap.add_argument("--scenes", type=int, default=0, help="evaluation scenes for precision@k (0 = skip)")
    ap.add_argument("--scene-objects", choices=["unseen", "held-out"], default="unseen")
    ap.add_argument("--scene-models", nargs="+", default=["generic15"],
                    help="models for the scene tables; FIRST+FULL names a cascade (FIRST prefilters for FULL)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.dataset is None:
        if not args.scenes:
            ap.error("give --dataset, --scenes N, or both")
        lines, found = scene_section(args.scene_models, args.models_dir, args.scenes, args.scene_objects, args.out,
                                     args.threads)
        text = "\n".join(["# Grasp classifier evaluation on scenes\n", *lines])
        (args.out / f"scenes_{args.scene_objects}.md").write_text(text + "\n")
        print(text)
        return 0
    ev = Evaluator(args.dataset, args.limit)
    if read_manifest(args.dataset).get("kind") == "scenes":
        return scene_data_main(args, ev)
    comparison = args.models_dir / "comparison"
    shipped = set(available_models(args.models_dir))
    found: dict[str, float] = {}
    held = set(available_models(comparison))
    lines = [f"# Grasp classifier evaluation\n\nDataset: `{shown_path(args.dataset)}`; test parts of its splits. "
             "RA99P = recall at 99% precision.\n"]

    lines += ["## Figure 8: representations\n", "| representation | split | model | test exemplars | accuracy | "
              "RA99P | AP |", "|---|---|---|---:|---:|---:|---:|"]
    for kind in ("view", "object"):
        curves = []
        for rep in REPRESENTATIONS:
            name = f"rep{rep}-{kind}"
            if name not in held:
                continue
            m, s, y = ev.run(load_model(name, comparison, threads=args.threads), kind)
            curves.append((f"{rep} channels" if rep != "herzog" else "Herzog/Kappler", s, y))
            found[f"{name} ra99p"] = m["ra99p"]
            lines.append(f"| {rep} | {kind} | {name} | {m['n']} | {m['accuracy']:.3f} | {m['ra99p']:.3f} | "
                         f"{m['average_precision']:.3f} |")
        if curves:
            plot_curves(curves, f"Representations, {kind} split", args.out / f"fig8_{kind}_split.png")
    lines.append("")

    lines += ["## Figure 10: category models vs the generic model (view split)\n",
              "| category | model | test exemplars | accuracy | RA99P | AP |", "|---|---|---:|---:|---:|---:|"]
    for cat, name in CATEGORY_MODELS.items():
        if name not in shipped or "generic15" not in shipped:
            continue
        curves = []
        for model in (name, "generic15"):
            m, s, y = ev.run(load_model(model, args.models_dir, threads=args.threads), "view", [cat])
            curves.append((model, s, y))
            lines.append(f"| {cat} | {model} | {m['n']} | {m['accuracy']:.3f} | {m['ra99p']:.3f} | "
                         f"{m['average_precision']:.3f} |")
        plot_curves(curves, f"{cat}-like objects, view split", args.out / f"fig10_{cat}.png")
    lines.append("")

    lines += ["## LeNet (paper) vs fast network: accuracy and CPU speed\n",
              f"onnxruntime CPU, {args.threads} intra-op threads, 1000 candidates (real test images), median of 7; "
              f"machine load average before timing: {os.getloadavg()[0]:.2f} (the machine is shared).\n",
              "| model | architecture | multiply-adds/image | view accuracy | view RA99P | s per 1k candidates |",
              "|---|---|---:|---:|---:|---:|"]
    curves = []
    for name in SPEED_MODELS:
        if name not in shipped:
            continue
        clf = load_model(name, args.models_dir, threads=args.threads)
        m, s, y = ev.run(clf, "view")
        curves.append((f"{name} ({clf.card.get('architecture')})", s, y))
        images, _ = ev.rows("view", clf.representation, None)
        seconds = time_1k(clf, images[:1000])
        found[f"{name} accuracy"], found[f"{name} ra99p"], found[f"{name} s"] = m["accuracy"], m["ra99p"], seconds
        macs = clf.card.get("network", {}).get("multiply_adds_per_image", 0)
        lines.append(f"| {name} | {clf.card.get('architecture')} | {macs / 1e6:.1f} M | {m['accuracy']:.3f} | "
                     f"{m['ra99p']:.3f} | {seconds:.3f} |")
    if curves:
        plot_curves(curves, "LeNet vs fast network, view split", args.out / "lenet_vs_fast.png")
    lines.append("")

    targets = [("generic15 view-split accuracy", "generic15 accuracy", ">=", 0.93),
               ("generic15 view-split RA99P", "generic15 ra99p", ">=", 0.89),
               ("15-channel object-split RA99P (rep15-object)", "rep15-object ra99p", ">=", 0.60),
               ("generic15: s per 1k candidates, 2 threads", "generic15 s", "<=", 0.30)]
    lines += ["## Targets\n", "| target | measured | goal | met |", "|---|---:|---:|---|"]
    for label, key, op, goal in targets:
        if key in found:
            v = found[key]
            ok = v >= goal if op == ">=" else v <= goal
            lines.append(f"| {label} | {v:.3f} | {op} {goal} | {'yes' if ok else 'no'} |")
    lines.append("")
    text = "\n".join(lines)
    (args.out / "classifier.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
