"""Plans: train, export to ONNX and evaluate one model (train_and_export) or every model of a plan,
the tiny real model the tests use, and datasets made of the first chunks of another."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from torch import nn

from graspd.gpd.classifier import OnnxGraspClassifier
from graspd.gpd.images import REPRESENTATIONS, channel_layout
from graspd_lab.training.config import TrainConfig, config_command
from graspd_lab.training.dataset import (
    CATEGORIES,
    FORMAT,
    GenerationParams,
    _splits,
    derive_images,
    generate_dataset,
    read_manifest,
    sha256_file,
)
from graspd_lab.training.evaluate import classification_metrics
from graspd_lab.training.export import base_card, check_parity, export_onnx, save_weights, write_card
from graspd_lab.training.loop import load_checkpoint, train
from graspd_lab.training.network import count_parameters, multiply_adds
from graspd_lab.training.rows import row_cache, training_rows


def export_trained(net: nn.Module, config: TrainConfig, train_metrics: dict[str, Any], models_dir: str | Path,
                   command: str, evaluate_on: list[tuple[str, list[str] | None]] | None = None,
                   parity_rows: int = 256) -> Path:
    """Export a trained network to models_dir/<name>.onnx (and its torch weights to <name>.pt, for fine-tuning),
    check ONNX/torch parity, evaluate the exported model on the test parts listed (default: the training split,
    all categories, and each category trained on), and write the model card models_dir/<name>.json.  Returns
    the .onnx path."""
    manifest = read_manifest(config.dataset)
    channels = REPRESENTATIONS[config.representation]
    size = int(manifest["image_size"])
    models = Path(models_dir)
    onnx_path = export_onnx(net, models / f"{config.name}.onnx", channels, size)
    save_weights(net, models / f"{config.name}.pt", config.architecture, channels, size, config.network)
    card = base_card(config.name, config.representation, channels, size, config.architecture, manifest["hand"],
                     channel_layout(config.representation))
    calibration = train_metrics.get("calibration")
    if calibration is not None:
        card["output"]["meaning"] += ("; calibrated on the validation rows: Platt scaling sigmoid(a z + b) of the "
                                      "logit difference z, folded into the last layer")
    clf = OnnxGraspClassifier(onnx_path, card, threads=config.threads)
    if evaluate_on is None:
        evaluate_on = [(config.split, None)] + [(config.split, [c]) for c in (config.categories or [])]
    metrics: dict[str, Any] = {}
    for kind, cats in evaluate_on:
        images15, labels, row_cats = training_rows(config.dataset, kind, "test", None, None, 0)
        if cats is not None:
            keep = np.flatnonzero(np.isin(row_cats, [CATEGORIES[c] for c in cats]))
            images15, labels = images15[keep], labels[keep]
        # the stored 15-channel images are scored as they are, not copied: two more copies of the test part of a
        # 1,200-scene dataset (2.5 GB each, beside 13 GB of cached training rows) ran a 24 GiB machine out of memory
        images = images15 if config.representation == "15" else derive_images(images15, config.representation)
        if "parity_max_abs_diff" not in card:
            card["parity_max_abs_diff"] = check_parity(net, onnx_path, card, images[:parity_rows])
        key = f"{kind}_test" + ("" if cats is None else "_" + "+".join(cats))
        metrics[key] = {"split": kind, "part": "test", "categories": cats or "all",
                        **classification_metrics(clf.score(images), labels)}
    card.update({
        "categories": config.categories or "all",
        "metrics": metrics,
        "calibration": calibration,
        "network": {"parameters": count_parameters(net), "multiply_adds_per_image": multiply_adds(net, channels, size)},
        "training": {
            "config": config.to_dict(),
            "dataset_manifest_sha256": manifest.get("dataset_sha256"),
            "dataset_seed": manifest.get("seed"),
            "dataset_counts": manifest.get("counts"),
            "num_train": train_metrics["num_train"], "num_val": train_metrics["num_val"],
            "feedback": train_metrics.get("feedback"),
            "init_from": train_metrics.get("init_from"),
            "resumed_from_epoch": train_metrics.get("resumed_from_epoch"),
            "best_epoch": train_metrics["best_epoch"], "epochs_run": len(train_metrics["history"]),
            "stopped": train_metrics["stopped"], "best_val_accuracy": train_metrics["best_val_accuracy"],
            "seconds": round(train_metrics["seconds_total"], 1), "torch_version": train_metrics["torch_version"],
        },
        "command": command,
    })
    write_card(onnx_path.with_suffix(".json"), card)
    return onnx_path


def train_and_export(config: TrainConfig, models_dir: str | Path, work_dir: str | Path | None = None,
                     command: str | None = None, log: Any = print) -> Path:
    """The whole pipeline for one model: train, export to ONNX with parity check, evaluate, write the card."""
    work = Path(work_dir) if work_dir is not None else Path(models_dir) / ".work" / config.name
    metrics = train(config, work, log=log, models_dir=models_dir)
    net, _ = load_checkpoint(work / "checkpoint.pt")
    path = export_trained(net, config, metrics, models_dir, command or config_command(config, models_dir))
    log(f"[{config.name}] exported {path}")
    return path


def train_plan(plan: dict[str, Any], models_dir: str | Path, dataset: str | None = None,
               only: list[str] | None = None, command: str | None = None, log: Any = print,
               resume: bool = False) -> list[Path]:
    """Train, evaluate and export every model of a plan, reading the dataset once (row_cache).

    plan: {"defaults": {TrainConfig fields}, "models": [{TrainConfig fields, optional "subdir"}]}; dataset
    overrides the plan's; only: names to make (default all); resume: each model continues from its work dir's
    last.pt.  Models go to models_dir/<subdir>/<name>.onnx.  Logs the plan's time budget first.
    """
    defaults = dict(plan.get("defaults", {}))
    if dataset is not None:
        defaults["dataset"] = dataset
    entries = plan.get("models")
    if not isinstance(entries, list) or not entries:
        raise ValueError("plan.models must be a non-empty list of model configs")
    names = [e.get("name") for e in entries]
    if only:
        unknown = sorted(set(only) - set(names))
        if unknown:
            raise ValueError(f"unknown plan models {unknown}; the plan has {names}")
    chosen = []
    for entry in entries:
        if only and entry.get("name") not in only:
            continue
        fields_ = {**defaults, **{k: v for k, v in entry.items() if k != "subdir"}}
        if resume:
            fields_["resume"] = True
        chosen.append((TrainConfig.from_dict(fields_), Path(models_dir) / entry.get("subdir", "")))
    log(plan_budget([config for config, _ in chosen]))
    paths = []
    with row_cache():
        for config, folder in chosen:
            cmd = (command or "graspd train --plan PLAN") + f"  # model {config.name}"
            paths.append(train_and_export(config, folder, Path(models_dir) / ".work" / config.name, cmd, log))
    return paths


def plan_budget(configs: list[TrainConfig]) -> str:
    """One line stating a plan's training time budget: the sum of the models' max_minutes (training only; loading
    and evaluation come on top), and which models have none."""
    total = sum(c.max_minutes for c in configs if c.max_minutes is not None)
    unbounded = [c.name for c in configs if c.max_minutes is None]
    line = f"plan: {len(configs)} models, training budget {total:.1f} min (sum of max_minutes)"
    if unbounded:
        line += f"; no time limit (epochs only) on {', '.join(unbounded)}"
    return line


#: A tiny dataset for tests and demos: a few procedural and pybullet_data objects, 4 views each.
TINY_DATASET = {"exemplars": 600, "num_urdfs": 6, "procedural": (("box", 6), ("cylinder", 6), ("sphere", 2)),
                "views_per_object": 4, "num_samples": 60}


def train_tiny_model(out_dir: str | Path, seed: int = 0, name: str = "tiny15") -> Path:
    """A small real classifier for tests: generates a tiny dataset (~700 exemplars from 20 objects) under
    out_dir/dataset, trains the fast 15-channel network for a few epochs and exports out_dir/models/<name>.onnx
    with its card; about a minute or less on 2 cores.  Returns the .onnx path (load it with
    graspd.gpd.classifier.load_model)."""
    out = Path(out_dir)
    data = out / "dataset"
    if not (data / "manifest.json").exists():
        generate_dataset(data, GenerationParams(seed=seed, **TINY_DATASET), workers=1)  # type: ignore[arg-type]
    config = TrainConfig(dataset=str(data), name=name, epochs=8, batch_size=32, patience=8, seed=seed,
                         max_val=None)
    command = f"graspd_lab.training.plans.train_tiny_model({str(out)!r}, seed={seed})"
    return train_and_export(config, out / "models", out / "work", command=command, log=lambda *a: None)


def prefix_dataset(source: str | Path, target: str | Path, num_chunks: int) -> dict[str, Any]:
    """A dataset made of the first num_chunks chunk files of source (a finished or an interrupted
    generation: chunks are deterministic, so any run of the same command has the same first chunks),
    with its own manifest and splits; the chunk files are linked, not copied.  Returns the manifest.

    The view split of an object is the generator's (seeded per object); the object split is drawn by the
    generator's rule over the objects present."""
    src, dst = Path(source), Path(target)
    files = sorted(src.glob("chunk_*.npz"))[:num_chunks]
    expected = [f"chunk_{i:05d}.npz" for i in range(num_chunks)]
    if [f.name for f in files] != expected:
        raise ValueError(f"{src} must hold chunk_00000.npz .. chunk_{num_chunks - 1:05d}.npz; found "
                         f"{[f.name for f in files][:3]}...")
    (dst / "splits").mkdir(parents=True, exist_ok=True)
    names = {code: name for name, code in CATEGORIES.items()}
    chunks: list[dict[str, Any]] = []
    objects: dict[int, str] = {}
    by_category = dict.fromkeys(CATEGORIES, 0)
    for f in files:
        with np.load(f) as z:
            ids, cats, labels = z["object_ids"], z["categories"], z["labels"]
        objects.update({int(o): names[int(c)] for o, c in zip(ids, cats, strict=True)})
        for code, count in enumerate(np.bincount(cats, minlength=len(CATEGORIES))):
            by_category[names[code]] += int(count)
        link = dst / f.name
        if not link.exists():
            os.symlink(f.resolve(), link)
        chunks.append({"file": f.name, "rows": int(len(labels)), "positive": int(labels.sum()),
                       "sha256": sha256_file(f)})
    source_manifest = src / "manifest.json"
    params = json.loads(source_manifest.read_text()).get("parameters", {}) if source_manifest.exists() else {}
    views_per_object = int(params.get("views_per_object", 8))
    fractions = tuple(params.get("split_fractions", (0.15, 0.10)))
    seed = int(params.get("seed", 0))
    records = [{"id": o, "category": c} for o, c in sorted(objects.items())]
    view, obj = _splits(records, views_per_object, (float(fractions[0]), float(fractions[1])), seed)
    (dst / "splits" / "view.json").write_text(json.dumps(view))
    (dst / "splits" / "object.json").write_text(json.dumps(obj))
    total = sum(int(c["rows"]) for c in chunks)
    positive = sum(int(c["positive"]) for c in chunks)
    manifest = {
        "format": FORMAT, "seed": seed, "representation": "15", "image_size": 60,
        "hand": params.get("hand", {"finger_width": 0.01, "hand_outer_diameter": 0.12, "hand_depth": 0.06,
                                    "hand_height": 0.02, "init_bite": 0.01}),
        "prefix_of": str(src), "num_chunks": num_chunks, "objects": records, "chunks": chunks,
        "counts": {"total": total, "positive": positive, "negative": total - positive,
                   "by_category": by_category},
        "dataset_sha256": hashlib.sha256("".join(str(c["sha256"]) for c in chunks).encode()).hexdigest(),
    }
    (dst / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return manifest
