"""Classifier benchmark: the IJRR paper's evaluation of the shipped models, and their CPU inference speed.

Writes OUT/classifier.md (tables) and PNG precision-recall curves:
  Figure 8  - representations 15 / 12 / 3 / Herzog (models/comparison/rep*-view, rep*-object: identical configs)
  Figure 10 - category models (box15, cylinder15) vs the generic model on their category, view split
  LeNet (paper's network) vs the fast network: accuracy, RA99P, and seconds to classify 1k candidates with
  onnxruntime on 2 threads (median of repeats, images from the dataset's test part).

  PYTHONPATH=service .venv/bin/python bench/classifier.py --dataset DATA --models-dir models --out models/evaluation
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

from graspd.classifier import OnnxGraspClassifier, available_models, load_model  # noqa: E402
from graspd.training.dataset import CATEGORIES, derive_images  # noqa: E402
from graspd.training.evaluate import classification_metrics, pr_curve  # noqa: E402
from graspd.training.rows import load_rows  # noqa: E402

REPRESENTATIONS = ("15", "12", "3", "herzog")
CATEGORY_MODELS = {"box": "box15", "cylinder": "cylinder15"}
SPEED_MODELS = ("lenet15", "generic15")


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


def _row(name: str, m: dict[str, Any], extra: str = "") -> str:
    return (f"| {name} | {m['n']} | {m['accuracy']:.3f} | {m['ra99p']:.3f} | {m['average_precision']:.3f} |"
            f"{extra}")


HEADER = "| model | test exemplars | accuracy | RA99P | AP |"
RULE = "|---|---:|---:|---:|---:|"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", required=True, type=Path)
    ap.add_argument("--models-dir", default=Path("models"), type=Path)
    ap.add_argument("--out", default=Path("models/evaluation"), type=Path)
    ap.add_argument("--limit", type=int, default=None, help="at most this many test exemplars per table row")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads for the timing")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    ev = Evaluator(args.dataset, args.limit)
    comparison = args.models_dir / "comparison"
    shipped = set(available_models(args.models_dir))
    found: dict[str, float] = {}
    held = set(available_models(comparison))
    lines = [f"# Grasp classifier evaluation\n\nDataset: `{args.dataset}`; test parts of its splits. "
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
    lines += ["## Targets (issue 3)\n", "| target | measured | goal | met |", "|---|---:|---:|---|"]
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
