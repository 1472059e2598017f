"""How much of the oracle's gain could a ranking foresee?  bench/oracle.py records, for each detection, the service's
top feasible grasps each executed in physics, what the answer said of them (score, the segmented object's box:
its centre in the hand's frame and its extent) and what the true world knows (the object's mass and centre of
mass in the hand's frame).  A logistic hold estimate fitted on some rounds picks, in the others, the grasp with the
highest estimate among each detection's tried grasps: how often that grasp held, beside how often the service's
first did and how often any did (the oracle), says how much of the gap a ranking from such features can close.

Feature sets: "score" (the classifier's score alone); "seen" (the score, the box's log volume, the box centre's
offsets from the fingertips along the approach, the closing direction and the hand axis, and the offsets' products
with the log volume: what a service can compute); "truth" (the score, the log mass, the centre of mass's offsets
and their products with the log mass: what no detector may read, the ceiling of the seen proxies); both.
Evaluation: 5 folds by round (a round's detections stay together), and where --test records are given, a model
fitted on all --records picking in --test's rounds.  Training objects only: records of held-out objects are
refused (they judge the service, nothing is fitted on them).

  PYTHONPATH=service:client:lab .venv/bin/python bench/foresight.py \\
      --records bench/results/oracle-household-training-pile.json bench/results/oracle-household-training-packed.json \\
      --test bench/results/oracle-household-training-pile-s200.json \\
             bench/results/oracle-household-training-packed-s200.json
writes bench/results/foresight-<tag>.md and .json.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "lab", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import clutter  # noqa: E402

F64 = NDArray[np.float64]
FEATURE_SETS = ("score", "seen", "truth", "seen + truth")
FOLDS = 5


#: The object sets records may be fitted or tuned on (bench/oracle.py --object-set): training objects only.
TRAINING_OBJECT_SETS = ("household-training", "scaled-training")


def training_objects(meta: dict[str, Any]) -> bool:
    """Whether a bench/oracle.py run's records (its meta) are of training objects, the only ones fitted or tuned on:
    the household training models or the scaled random_urdfs 000-899 (the scaled random_urdfs 900-999 and the
    household held-out models never are)."""
    return any(f", {name}" in meta["scenes"] for name in TRAINING_OBJECT_SETS)
#: L2 penalty on the standardised weights (0.1-10 pick alike on the training records' folds).
L2 = 1.0


def fit_logistic(x: F64, y: F64, l2: float = L2, iterations: int = 50) -> tuple[F64, F64, F64]:
    """(mean, scale, weights with the bias last) of an L2-regularised logistic regression on standardised features
    (Newton's method; the bias unpenalised).  y: 1 held, 0 not."""
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    z = np.c_[(x - mean) / scale, np.ones(len(x))]
    w = np.zeros(z.shape[1])
    penalty = np.full(z.shape[1], l2)
    penalty[-1] = 0.0
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-(z @ w)))
        step = np.linalg.solve((z * (p * (1 - p))[:, None]).T @ z + np.diag(penalty) + 1e-9 * np.eye(len(w)),
                               z.T @ (p - y) + penalty * w)
        w -= step
        if np.abs(step).max() < 1e-10:
            break
    return mean, scale, w


def predict(model: tuple[F64, F64, F64], x: F64) -> F64:
    mean, scale, w = model
    return 1.0 / (1.0 + np.exp(-(np.c_[(x - mean) / scale, np.ones(len(x))] @ w)))


def _offsets_terms(size: F64, offsets: F64) -> list[F64]:
    """A size (log volume or log mass) and offsets (K,3) from the fingertips (approach, binormal, axis; m): the
    size, the approach offset, the two others' magnitudes, how far the fingertips stop short, and the products."""
    short = np.maximum(-offsets[:, 0], 0.0)
    side, along = np.abs(offsets[:, 1]), np.abs(offsets[:, 2])
    return [size, offsets[:, 0], side, along, short, size * short, size * side, size * along]


def features(detection: dict[str, Any], which: str) -> F64:
    """(K, n) features of one detection's K tried grasps (NaN rows where a grasp had no object)."""
    s = np.clip(np.asarray(detection["trial_scores"], np.float64), 1e-4, 1 - 1e-4)
    cols = [np.log(s / (1 - s))]
    if "seen" in which:
        seen = detection["trial_seen"]
        off = np.array([[t.get(f"centre_{k}", np.nan) for k in ("approach", "binormal", "axis")] for t in seen])
        vol = np.array([np.prod(t["extent"]) if "extent" in t else np.nan for t in seen])
        cols += _offsets_terms(np.log(np.maximum(vol, 1e-5)), off.reshape(-1, 3))
    if "truth" in which:
        truth = detection["trial_truth"]
        off = np.array([[t.get(f"com_{k}", np.nan) for k in ("approach", "binormal", "axis")] for t in truth])
        mass = np.array([t["mass"] if t.get("mass") is not None else np.nan for t in truth], np.float64)
        cols += _offsets_terms(np.log(np.maximum(mass, 1e-3)), off.reshape(-1, 3))
    return np.stack(cols, axis=1)


def held(detection: dict[str, Any]) -> F64:
    return np.array([o == "success" for o in detection["trial_outcomes"]], np.float64)


def choices(fit_on: list[dict[str, Any]], pick_in: list[dict[str, Any]], which: str) -> list[int]:
    """The index of the tried grasp with the highest estimate (a model fitted on fit_on's tried grasps) in each of
    pick_in's detections; a grasp without features is estimated by its score."""
    x = np.concatenate([features(d, which) for d in fit_on])
    y = np.concatenate([held(d) for d in fit_on])
    ok = np.isfinite(x).all(axis=1)
    model = fit_logistic(x[ok], y[ok])
    chosen = []
    for d in pick_in:
        p = predict(model, features(d, which))
        p = np.where(np.isfinite(p), p, np.asarray(d["trial_scores"], np.float64))
        chosen.append(int(np.argmax(p)))
    return chosen


def read(paths: list[Path]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(detections with at least one tried grasp and the per-grasp records, each tagged with its round, metas)."""
    detections: list[dict[str, Any]] = []
    metas: list[dict[str, Any]] = []
    for k, path in enumerate(paths):
        data = json.loads(path.read_text())
        meta = data["meta"]
        if not training_objects(meta):
            raise SystemExit(f"{path}: records of {meta['scenes']!r}: only training objects are fitted on")
        metas.append({"file": path.name, "command": meta["command"], "commit": meta["commit"],
                      "scenes": meta["scenes"]})
        for d in data["detections"]:
            if d.get("tried") and "trial_seen" in d and "trial_truth" in d:
                detections.append({**d, "round": (k, d["seed"])})
    return detections, metas


#: Two tried grasps are twins when they went for the same object (equal mass) with its centre of mass within this
#: (m, on each hand axis) of the same place in each hand's frame: nearly the same grasp on the same object.
TWIN_TOLERANCE = 0.005


def twins(detections: list[dict[str, Any]]) -> dict[str, int]:
    """Pairs of twin grasps within each detection: how many, how many of them both held, one held, neither."""
    counts = {"pairs": 0, "both_held": 0, "one_held": 0, "neither": 0}
    for d in detections:
        truth, ok = d["trial_truth"], held(d)
        for i in range(len(truth)):
            for j in range(i + 1, len(truth)):
                a, b = truth[i], truth[j]
                if a.get("mass") is None or a["mass"] != b.get("mass"):
                    continue
                if max(abs(a[f"com_{k}"] - b[f"com_{k}"]) for k in ("approach", "binormal", "axis")) > TWIN_TOLERANCE:
                    continue
                counts["pairs"] += 1
                counts[("neither", "one_held", "both_held")[int(ok[i] + ok[j])]] += 1
    return counts


def row(name: str, detections: list[dict[str, Any]], chosen: dict[str, list[int]]) -> dict[str, Any]:
    """Held counts of the first, each feature set's and any grasp; with every detection's perturbed copies
    (bench/oracle.py --perturb), also the mean share of copies that held for the first, each pick and the best."""
    out: dict[str, Any] = {
        "evaluation": name, "detections": len(detections), "first": sum(int(held(d)[0]) for d in detections),
        "picked": {k: sum(int(held(d)[i]) for d, i in zip(detections, v, strict=True)) for k, v in chosen.items()},
        "any": sum(int(held(d).any()) for d in detections)}
    if detections and all("trial_robust" in d for d in detections):
        out["robust"] = {"first": float(np.mean([d["trial_robust"][0] for d in detections])),
                         **{k: float(np.mean([d["trial_robust"][i] for d, i in zip(detections, v, strict=True)]))
                            for k, v in chosen.items()},
                         "best": float(np.mean([max(d["trial_robust"]) for d in detections]))}
    return out


def report(data: dict[str, Any]) -> str:
    meta = data["meta"]
    lines = ["# How much of the oracle's gain a ranking could foresee", "",
             f"- command: `{meta['command']}`", f"- commit: `{meta['commit']}`, date {meta['date']}",
             "- records: " + "; ".join(f"`{m['file']}` ({m['scenes']})" for m in meta["records"]),
             "- each detection's tried grasps (the service's first feasible ones, executed in physics): the share "
             "of detections whose pick held, picking the first (as ranked), the highest logistic hold estimate "
             "from each feature set (fitted on other rounds), or any that held (the oracle)", "",
             "| evaluation | detections | as ranked | " + " | ".join(FEATURE_SETS) + " | oracle |",
             "|---|---|---|" + "---|" * len(FEATURE_SETS) + "---|"]
    for r in data["rows"]:
        n = r["detections"]
        cells = [f"{100 * r['picked'][k] / n:.1f}%" for k in FEATURE_SETS]
        lines.append(f"| {r['evaluation']} | {n} | {100 * r['first'] / n:.1f}% | " + " | ".join(cells)
                     + f" | {100 * r['any'] / n:.1f}% |")
    robust = [r for r in data["rows"] if "robust" in r]
    if robust:
        lines += ["", "Each tried grasp also lifted in perturbed copies (`bench/oracle.py --perturb`): the mean share "
                  "of its copies that held, for the grasp each choice picks (a less noisy measure than one lift), and "
                  "for the most robust of the tried grasps:", "",
                  "| evaluation | as ranked | " + " | ".join(FEATURE_SETS) + " | most robust |",
                  "|---|---|" + "---|" * len(FEATURE_SETS) + "---|"]
        for r in robust:
            b = r["robust"]
            lines.append(f"| {r['evaluation']} | {100 * b['first']:.1f}% | "
                         + " | ".join(f"{100 * b[k]:.1f}%" for k in FEATURE_SETS) + f" | {100 * b['best']:.1f}% |")
    t = data["twins"]
    if t["pairs"]:
        failed = t["one_held"] + 2 * t["neither"]
        lines += ["", f"Twins (two tried grasps of one detection on the same object, its centre of mass within "
                  f"{1000 * TWIN_TOLERANCE:.0f} mm of the same place in both hands' frames): {t['pairs']} pairs, "
                  f"{t['both_held']} both held, {t['one_held']} one of the two, {t['neither']} neither; a twin of a "
                  f"grasp that failed held in {t['one_held']} of {failed} "
                  f"({100 * t['one_held'] / max(failed, 1):.0f}%)."
                  " What no feature of the grasp or its object can tell apart is physics the ranking cannot foresee."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--records", type=Path, nargs="+", required=True, help="bench/oracle.py .json records")
    ap.add_argument("--test", type=Path, nargs="*", default=[], help="records of other rounds to pick in")
    ap.add_argument("--tag", default="household-training")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = ap.parse_args(argv)
    detections, metas = read(args.records)
    rounds = sorted({d["round"] for d in detections})
    if len(rounds) < FOLDS:
        raise SystemExit(f"the records hold {len(rounds)} rounds with tried grasps; {FOLDS} folds need {FOLDS}")
    fold_of = {r: k % FOLDS for k, r in enumerate(rounds)}
    chosen: dict[str, list[int]] = {k: [0] * len(detections) for k in FEATURE_SETS}
    where = {id(d): n for n, d in enumerate(detections)}
    for f in range(FOLDS):
        fit_on = [d for d in detections if fold_of[d["round"]] != f]
        pick_in = [d for d in detections if fold_of[d["round"]] == f]
        for which in FEATURE_SETS:
            for d, i in zip(pick_in, choices(fit_on, pick_in, which), strict=True):
                chosen[which][where[id(d)]] = i
    rows = [row(f"{FOLDS} folds by round over the records", detections, chosen)]
    test_metas: list[dict[str, Any]] = []
    test: list[dict[str, Any]] = []
    if args.test:
        test, test_metas = read(args.test)
        rows.append(row("fitted on the records, picking in the test records", test,
                        {which: choices(detections, test, which) for which in FEATURE_SETS}))
    meta = {"command": "PYTHONPATH=service:client:lab .venv/bin/python bench/foresight.py "
            + shlex.join(sys.argv[1:] if argv is None else argv), "commit": clutter.git_commit(),
            "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "records": metas + test_metas}
    data = {"meta": meta, "rows": rows, "twins": twins(detections + (test if args.test else []))}
    args.out.mkdir(parents=True, exist_ok=True)
    md = report(data)
    (args.out / f"foresight-{args.tag}.md").write_text(md)
    (args.out / f"foresight-{args.tag}.json").write_text(json.dumps(data, indent=1))
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
