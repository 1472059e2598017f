"""Train a grasp-image classifier on a graspd dataset: reproducible from a config and a seed, on the CPU.

Class-balanced (class-weighted cross-entropy), Adam, early stopping on the validation part of the
chosen split; writes checkpoint.pt (best validation state, config, architecture) and
train_metrics.json (per-epoch history) to the output folder.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from graspd.images import REPRESENTATIONS

from .network import ARCHITECTURES, build_network


@dataclass
class TrainConfig:
    """Everything that determines a training run (with the dataset's own manifest)."""

    dataset: str
    name: str = "generic15"
    representation: str = "15"
    architecture: str = "fast"
    split: str = "view"                       # "view" (the paper's) or "object"
    categories: list[str] | None = None       # None = all; e.g. ["box"] for a category model
    epochs: int = 20
    batch_size: int = 128
    learning_rate: float = 1e-3
    weight_decay: float = 1e-4
    patience: int = 4                         # epochs without validation-loss improvement before stopping
    seed: int = 0
    threads: int = 2
    max_train: int | None = None              # use at most this many training exemplars (random, seeded)
    max_val: int | None = 20000
    max_minutes: float | None = None          # training time budget (after loading); the LR decays over it
    augment: bool = True                      # random mirror images across hand y and z (label-preserving)
    feedback: str | None = None               # SQLAlchemy URL of a feedback store: executed grasps join training
    feedback_repeat: int = 4                  # each stored outcome is drawn this many times per epoch
    network: dict[str, Any] = field(default_factory=dict)  # extra FastNet arguments (width, hidden)

    def __post_init__(self) -> None:
        if self.representation not in REPRESENTATIONS:
            raise ValueError(f"representation must be one of {sorted(REPRESENTATIONS)}, got {self.representation!r}")
        if self.architecture not in ARCHITECTURES:
            raise ValueError(f"architecture must be one of {list(ARCHITECTURES)}, got {self.architecture!r}")
        if self.split not in ("view", "object"):
            raise ValueError(f"split must be 'view' or 'object', got {self.split!r}")
        for key in ("epochs", "batch_size", "threads", "feedback_repeat"):
            if getattr(self, key) < 1:
                raise ValueError(f"{key} must be >= 1, got {getattr(self, key)}")
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate must be > 0, got {self.learning_rate}")
        if self.categories is not None:
            from .dataset import CATEGORIES

            bad = [c for c in self.categories if c not in CATEGORIES]
            if bad:
                raise ValueError(f"categories must be among {list(CATEGORIES)}, got {bad}")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown training config fields {unknown}; known: {sorted(known)}")
        return cls(**data)

    @classmethod
    def from_json(cls, path: str | Path) -> TrainConfig:
        return cls.from_dict(json.loads(Path(path).read_text()))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def load_rows(directory: str | Path, kind: str, part: str, representation: str,
              categories: list[str] | None = None, limit: int | None = None,
              seed: int = 0) -> tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.uint8]]:
    """(images (M,C,S,S) uint8 of a representation, labels (M,), categories (M,)) of one split part.

    Reads the small per-row arrays first, then the images chunk by chunk into one preallocated
    array, so the peak memory is the result plus one chunk; limit keeps a seeded random subset.
    """
    from .dataset import CATEGORIES, derive_images, read_manifest, read_split, split_mask

    directory = Path(directory)
    manifest = read_manifest(directory)
    split = read_split(directory, kind)
    codes = None if categories is None else np.array([CATEGORIES[c] for c in categories], np.uint8)
    masks: list[NDArray[np.bool_]] = []
    for entry in manifest["chunks"]:
        with np.load(directory / entry["file"]) as z:
            mask = split_mask(z["object_ids"], z["view_ids"], split, part)
            if codes is not None:
                mask &= np.isin(z["categories"], codes)
            masks.append(mask)
    total = int(sum(m.sum() for m in masks))
    if total == 0:
        raise ValueError(f"split {kind!r} part {part!r} (categories {categories}) has no rows in {directory}")
    if limit is not None and limit < total:
        keep = np.zeros(total, bool)
        keep[np.random.default_rng(seed).choice(total, limit, replace=False)] = True
        start = 0
        for i, m in enumerate(masks):
            idx = np.flatnonzero(m)
            m = np.zeros_like(m)
            m[idx[keep[start : start + len(idx)]]] = True
            start += len(idx)
            masks[i] = m
        total = limit
    channels = REPRESENTATIONS[representation]
    size = int(manifest["image_size"])
    images = np.empty((total, channels, size, size), np.uint8)
    labels = np.empty(total, np.uint8)
    cats = np.empty(total, np.uint8)
    row = 0
    for entry, mask in zip(manifest["chunks"], masks, strict=True):
        n = int(mask.sum())
        if n == 0:
            continue
        with np.load(directory / entry["file"]) as z:
            images[row : row + n] = derive_images(z["images"][mask], representation)
            labels[row : row + n] = z["labels"][mask]
            cats[row : row + n] = z["categories"][mask]
        row += n
    return images, labels, cats


_RowKey = tuple[str, str, str, tuple[str, ...] | None, int | None, int]
_Rows = tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.uint8]]
_ROW_CACHE: dict[_RowKey, _Rows] | None = None


@contextmanager
def row_cache() -> Iterator[None]:
    """Within this block, training keeps the train and val rows it loaded last (15 channels) in memory, so
    consecutive models of a plan that differ only in representation or network read the dataset once."""
    global _ROW_CACHE
    _ROW_CACHE = {}
    try:
        yield
    finally:
        _ROW_CACHE = None


def training_rows(dataset: str, kind: str, part: str, categories: list[str] | None, limit: int | None,
                  seed: int) -> _Rows:
    """(15-channel images, labels, categories) of a split part, restricted to categories and to a seeded
    random subset of at most limit rows; served from the row cache when one is active (one entry per part)."""
    key: _RowKey = (str(Path(dataset).resolve()), kind, part, None if categories is None else tuple(categories),
                    limit, seed)
    if _ROW_CACHE is not None and key in _ROW_CACHE:
        return _ROW_CACHE[key]
    if _ROW_CACHE is not None:  # free the previous rows of this part before loading new ones
        for old in [k for k in _ROW_CACHE if k[2] == part]:
            del _ROW_CACHE[old]
    rows = load_rows(dataset, kind, part, "15", categories, limit, seed)
    if _ROW_CACHE is not None:
        _ROW_CACHE[key] = rows
    return rows


def feedback_rows(url: str, representation: str, image_size: int
                  ) -> tuple[NDArray[np.uint8], NDArray[np.uint8], dict[str, Any]]:
    """(images (M,C,S,S) uint8 of a representation, labels (M,): 1 = the grasp held, summary) of the executed
    grasps stored with their grasp image in a feedback store (graspd.templates.store, any SQLAlchemy URL).

    These are the robot's own outcomes (POST /feedback): real labels from the real sensor, added to the
    training rows.  15-channel images are derived to any representation; an image stored in another
    representation must match the one trained, and one of another size is skipped (counted in summary).
    """
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError, SQLAlchemyError

    from graspd.templates.store import TemplateError

    from .dataset import derive_images

    try:
        shown = make_url(url).render_as_string(hide_password=True)
    except ArgumentError as exc:
        raise ValueError(f"feedback: not a SQLAlchemy URL: {url!r} ({exc})") from exc
    channels = REPRESENTATIONS[representation]
    images: list[NDArray[np.uint8]] = []
    labels: list[int] = []
    skipped = 0
    try:
        rows = list(_stored_outcomes(url))
    except (SQLAlchemyError, TemplateError) as exc:
        raise ValueError(f"feedback: cannot read the store {shown}: {exc}") from exc
    for row in rows:
        img, rep = row["image"], row["representation"]
        if img.ndim != 3 or img.shape[1:] != (image_size, image_size):
            skipped += 1
        elif rep == representation and img.shape[0] == channels:
            images.append(img)
            labels.append(int(row["success"]))
        elif rep == "15" and img.shape[0] == 15:
            images.append(derive_images(img[None], representation)[0])
            labels.append(int(row["success"]))
        else:
            skipped += 1
    x = np.stack(images) if images else np.zeros((0, channels, image_size, image_size), np.uint8)
    y = np.asarray(labels, np.uint8)
    summary = {"store": shown, "outcomes": int(len(y)),
               "successes": int(y.sum()), "skipped": skipped}
    return x, y, summary


def _stored_outcomes(url: str) -> Iterator[dict[str, Any]]:
    """The outcomes with images of a feedback store (oldest first); the store must exist (no new file)."""
    from sqlalchemy.engine import make_url

    from graspd.templates.store import TemplateLibrary

    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite" and parsed.database not in (None, "", ":memory:") \
            and not Path(parsed.database).exists():
        raise ValueError(f"feedback: no such store {parsed.database}")
    with TemplateLibrary(url) as store:
        yield from store.iter_outcomes(with_images_only=True)


_AXES = {"x": 0, "y": 1, "z": 2}
_IMAGE_AXES = {0: (1, 2), 1: (0, 2), 2: (0, 1)}  # projection along hand axis p -> hand axes of (rows, cols)


def mirror_images(images: NDArray[np.uint8], representation: str, axis: int) -> NDArray[np.uint8]:
    """Grasp images (B,C,S,S) of the same grasps reflected through the hand plane normal to hand axis 1 (y, the
    closing direction) or 2 (z, the hand axis).  The hand is symmetric under both reflections and antipodal
    grasps stay antipodal, so the label is unchanged: a free, exact augmentation."""
    from graspd.images import channel_layout

    if axis not in (1, 2):
        raise ValueError(f"axis must be 1 (hand y) or 2 (hand z), got {axis}")
    layout = channel_layout(representation)
    out = images.copy()
    occupied: dict[str, NDArray[np.bool_]] = {}
    for proj in "xyz":
        normals = [layout.index(f"{proj}:{c}") for c in ("nx", "ny", "nz") if f"{proj}:{c}" in layout]
        if normals:
            occupied[proj] = np.any(images[:, normals] > 0, axis=1)
    for c, name in enumerate(layout):
        proj, kind = name.split(":")
        p = _AXES[proj]
        rows, cols = _IMAGE_AXES[p]
        value = images[:, c]
        if kind in ("nx", "ny", "nz") and _AXES[kind[1]] == axis:
            value = np.where(occupied[proj], 255 - value, 0).astype(np.uint8)
        elif kind in ("occ", "unobs") and p == axis:
            hit = occupied[proj] if kind == "occ" and proj in occupied else value > 0
            value = np.where(hit, 255 - value, 0).astype(np.uint8)
        if rows == axis:
            value = value[:, ::-1, :]
        elif cols == axis:
            value = value[:, :, ::-1]
        out[:, c] = value
    return out


def augment(images: NDArray[np.uint8], representation: str, rng: np.random.Generator) -> NDArray[np.uint8]:
    """Each image mirrored across hand y and/or hand z with probability 1/2 each (see mirror_images)."""
    out = images.copy()
    for axis in (1, 2):
        sel = rng.random(len(out)) < 0.5
        if sel.any():
            out[sel] = mirror_images(out[sel], representation, axis)
    return out


def _batches(n: int, batch_size: int, rng: np.random.Generator | None) -> list[NDArray[np.int64]]:
    order = rng.permutation(n) if rng is not None else np.arange(n)
    return [order[a : a + batch_size] for a in range(0, n, batch_size)]


def _to_tensor(images: NDArray[np.uint8], idx: NDArray[np.int64] | None = None) -> torch.Tensor:
    from .export import INPUT_OFFSET, INPUT_SCALE

    x = torch.from_numpy(images if idx is None else images[idx]).float()
    return x.mul_(INPUT_SCALE).add_(INPUT_OFFSET)


def predict_logits(net: nn.Module, images: NDArray[np.uint8], batch_size: int = 512) -> NDArray[np.float32]:
    """Logits (M, 2) of a network in eval mode."""
    net.eval()
    out = []
    with torch.no_grad():
        for idx in _batches(len(images), batch_size, None):
            out.append(net(_to_tensor(images, idx)).numpy())
    return np.concatenate(out) if out else np.zeros((0, 2), np.float32)


def recalibrate_batchnorm(net: nn.Module, images: NDArray[np.uint8], batch_size: int = 256) -> None:
    """Recompute batch-norm running statistics from (a random sample of) training images with the current
    weights (exact averages instead of the lagging momentum estimate: matters on small datasets)."""
    bns = [m for m in net.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    if not bns:
        return
    momenta = [bn.momentum for bn in bns]
    for bn in bns:
        bn.reset_running_stats()
        bn.momentum = None
    net.train()
    with torch.no_grad():
        for a in range(0, len(images), batch_size):
            net(_to_tensor(images[a : a + batch_size]))
    for bn, m in zip(bns, momenta, strict=True):
        bn.momentum = m


def grasp_probability(logits: NDArray[np.float32]) -> NDArray[np.float32]:
    """Softmax of class 1 from logits (M, 2)."""
    z = logits - logits.max(axis=1, keepdims=True)
    e = np.exp(z)
    return (e[:, 1] / e.sum(axis=1)).astype(np.float32)


def train(config: TrainConfig, out_dir: str | Path, log: Any = print) -> dict[str, Any]:
    """Train one network; returns the metrics dict also written to out_dir/train_metrics.json."""
    from .dataset import derive_images, read_manifest

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    t0 = time.perf_counter()
    manifest = read_manifest(config.dataset)
    x_tr, y_tr, _ = training_rows(config.dataset, config.split, "train", config.categories, config.max_train,
                                  config.seed)
    tr_index = np.arange(len(y_tr))
    x_va15, y_va, _ = training_rows(config.dataset, config.split, "val", config.categories, config.max_val,
                                    config.seed + 1)
    x_va = derive_images(x_va15, config.representation)
    rep = config.representation
    size = int(manifest["image_size"])
    feedback: dict[str, Any] | None = None
    x_fb = np.zeros((0, REPRESENTATIONS[rep], size, size), np.uint8)
    y_fb = np.zeros(0, np.uint8)
    if config.feedback is not None:
        x_fb, y_fb, feedback = feedback_rows(config.feedback, rep, size)
        feedback["repeat"] = config.feedback_repeat
        log(f"[{config.name}] feedback: {feedback['outcomes']} executed grasps ({feedback['successes']} held, "
            f"{feedback['skipped']} skipped) from {feedback['store']}, each drawn {config.feedback_repeat}x per epoch")
    # training rows: the dataset's rows 0..n_ds-1, then every feedback outcome feedback_repeat times
    n_ds = len(y_tr)
    fb_index = np.repeat(np.arange(len(y_fb)), config.feedback_repeat)
    y_all = np.concatenate([y_tr, y_fb[fb_index]])

    def batch_images(rows: NDArray[np.int64]) -> NDArray[np.uint8]:
        ds = rows[rows < n_ds]
        images = x_tr[ds] if rep == "15" else derive_images(x_tr[ds], rep)
        if len(ds) < len(rows):
            images = np.concatenate([images, x_fb[fb_index[rows[rows >= n_ds] - n_ds]]])
        return augment(images, rep, rng) if config.augment else images

    def batch_labels(rows: NDArray[np.int64]) -> NDArray[np.uint8]:
        return np.concatenate([y_all[rows[rows < n_ds]], y_all[rows[rows >= n_ds]]])

    load_s = time.perf_counter() - t0
    log(f"[{config.name}] loaded {len(y_tr)} train / {len(y_va)} val exemplars in {load_s:.1f} s "
        f"(train positives {y_tr.mean():.3f})")
    counts = np.bincount(y_all, minlength=2).astype(np.float64)
    if counts.min() == 0:
        raise ValueError(f"training part has only one class (counts {counts.tolist()}); cannot train")
    class_weight = torch.tensor(counts.sum() / (2.0 * counts), dtype=torch.float32)
    channels = REPRESENTATIONS[config.representation]
    net = build_network(config.architecture, channels, size, **config.network)
    loss_fn = nn.CrossEntropyLoss(weight=class_weight)
    opt = torch.optim.Adam(net.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
    steps_per_epoch = -(-len(y_all) // config.batch_size)
    total_steps = config.epochs * steps_per_epoch
    limit_s = None if config.max_minutes is None else 60.0 * config.max_minutes
    t_train = time.perf_counter()
    step = 0
    out_of_time = False
    y_va_t = torch.from_numpy(y_va.astype(np.int64))
    best: dict[str, Any] = {"val_loss": float("inf")}
    best_state: dict[str, torch.Tensor] = {}
    history: list[dict[str, float]] = []
    stale = 0
    stopped = "epochs"
    for epoch in range(config.epochs):
        te = time.perf_counter()
        net.train()
        total, seen = 0.0, 0
        for idx in _batches(len(y_all), config.batch_size, rng):
            # cosine learning-rate decay over the run: over the steps, or over the time budget if that ends first
            progress = step / total_steps
            if limit_s is not None:
                progress = max(progress, (time.perf_counter() - t_train) / limit_s)
            if progress >= 1.0:
                out_of_time = True
                break
            for group in opt.param_groups:
                group["lr"] = config.learning_rate * 0.5 * (1.0 + np.cos(np.pi * progress))
            step += 1
            x = _to_tensor(batch_images(idx))
            y = torch.from_numpy(batch_labels(idx).astype(np.int64))
            opt.zero_grad(set_to_none=True)
            loss = loss_fn(net(x), y)
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
            seen += len(idx)
        if seen == 0:  # the time budget ran out at the end of the previous epoch
            stopped = "time_limit"
            break
        recalibrate_batchnorm(net, batch_images(rng.choice(tr_index, min(4096, len(tr_index)), replace=False)))
        logits = predict_logits(net, x_va)
        val_loss = float(loss_fn(torch.from_numpy(logits), y_va_t))
        val_acc = float(np.mean((logits[:, 1] > logits[:, 0]) == (y_va == 1)))
        row = {"epoch": epoch + 1, "train_loss": total / seen, "exemplars_seen": seen, "val_loss": val_loss,
               "val_accuracy": val_acc, "seconds": time.perf_counter() - te}
        history.append(row)
        log(f"[{config.name}] epoch {epoch + 1}: train loss {row['train_loss']:.4f}  val loss {val_loss:.4f}  "
            f"val acc {val_acc:.4f}  ({row['seconds']:.1f} s)")
        if val_loss < best["val_loss"]:
            best = dict(row)
            best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
            stale = 0
        else:
            stale += 1
            if stale >= config.patience:
                stopped = "early_stopping"
                break
        if out_of_time:
            stopped = "time_limit"
            break
    net.load_state_dict(best_state)
    checkpoint = out / "checkpoint.pt"
    torch.save({"state_dict": net.state_dict(), "config": config.to_dict(), "architecture": config.architecture,
                "channels": channels, "image_size": size}, checkpoint)
    metrics = {
        "config": config.to_dict(),
        "dataset_sha256": manifest.get("dataset_sha256"),
        "num_train": int(len(y_tr)), "num_val": int(len(y_va)), "feedback": feedback,
        "train_class_counts": counts.astype(int).tolist(),
        "best_epoch": int(best["epoch"]), "best_val_loss": best["val_loss"], "best_val_accuracy": best["val_accuracy"],
        "stopped": stopped, "history": history,
        "seconds_total": time.perf_counter() - t0, "seconds_load": load_s,
        "torch_threads": config.threads, "torch_version": torch.__version__,
    }
    (out / "train_metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    return metrics


def load_checkpoint(path: str | Path) -> tuple[nn.Module, TrainConfig]:
    """The network (eval mode) and config stored by train()."""
    ckpt = torch.load(Path(path), map_location="cpu", weights_only=True)
    config = TrainConfig.from_dict(ckpt["config"])
    net = build_network(ckpt["architecture"], int(ckpt["channels"]), int(ckpt["image_size"]), **config.network)
    net.load_state_dict(ckpt["state_dict"])
    return net.eval(), config


def export_trained(net: nn.Module, config: TrainConfig, train_metrics: dict[str, Any], models_dir: str | Path,
                   command: str, evaluate_on: list[tuple[str, list[str] | None]] | None = None,
                   parity_rows: int = 256) -> Path:
    """Export a trained network to models_dir/<name>.onnx, check ONNX/torch parity, evaluate the exported
    model on the test parts listed (default: the training split, all categories, and each category
    trained on), and write the model card models_dir/<name>.json.  Returns the .onnx path."""
    from graspd.classifier import OnnxGraspClassifier
    from graspd.images import channel_layout

    from .dataset import CATEGORIES, derive_images, read_manifest
    from .evaluate import classification_metrics
    from .export import base_card, check_parity, export_onnx, write_card
    from .network import count_parameters, multiply_adds

    manifest = read_manifest(config.dataset)
    channels = REPRESENTATIONS[config.representation]
    size = int(manifest["image_size"])
    models = Path(models_dir)
    onnx_path = export_onnx(net, models / f"{config.name}.onnx", channels, size)
    card = base_card(config.name, config.representation, channels, size, config.architecture, manifest["hand"],
                     channel_layout(config.representation))
    clf = OnnxGraspClassifier(onnx_path, card, threads=config.threads)
    if evaluate_on is None:
        evaluate_on = [(config.split, None)] + [(config.split, [c]) for c in (config.categories or [])]
    metrics: dict[str, Any] = {}
    for kind, cats in evaluate_on:
        images15, labels, row_cats = training_rows(config.dataset, kind, "test", None, None, 0)
        rows = np.arange(len(labels)) if cats is None else np.flatnonzero(
            np.isin(row_cats, [CATEGORIES[c] for c in cats]))
        images = derive_images(images15[rows], config.representation)
        if "parity_max_abs_diff" not in card:
            card["parity_max_abs_diff"] = check_parity(net, onnx_path, card, images[:parity_rows])
        key = f"{kind}_test" + ("" if cats is None else "_" + "+".join(cats))
        metrics[key] = {"split": kind, "part": "test", "categories": cats or "all",
                        **classification_metrics(clf.score(images), labels[rows])}
    card.update({
        "categories": config.categories or "all",
        "metrics": metrics,
        "network": {"parameters": count_parameters(net), "multiply_adds_per_image": multiply_adds(net, channels, size)},
        "training": {
            "config": config.to_dict(),
            "dataset_manifest_sha256": manifest.get("dataset_sha256"),
            "dataset_seed": manifest.get("seed"),
            "dataset_counts": manifest.get("counts"),
            "num_train": train_metrics["num_train"], "num_val": train_metrics["num_val"],
            "feedback": train_metrics.get("feedback"),
            "best_epoch": train_metrics["best_epoch"], "epochs_run": len(train_metrics["history"]),
            "stopped": train_metrics["stopped"], "best_val_accuracy": train_metrics["best_val_accuracy"],
            "seconds": round(train_metrics["seconds_total"], 1), "torch_version": train_metrics["torch_version"],
        },
        "command": command,
    })
    write_card(onnx_path.with_suffix(".json"), card)
    return onnx_path


def config_command(config: TrainConfig, models_dir: str | Path) -> str:
    """The graspd command line that reproduces a config (used for the model card)."""
    parts = ["graspd", "train", "--dataset", config.dataset, "--name", config.name, "--representation",
             config.representation, "--architecture", config.architecture, "--split", config.split,
             "--epochs", str(config.epochs), "--batch-size", str(config.batch_size), "--learning-rate",
             str(config.learning_rate), "--patience", str(config.patience), "--seed", str(config.seed),
             "--threads", str(config.threads), "--models-dir", str(models_dir)]
    if config.categories:
        parts += ["--categories", ",".join(config.categories)]
    if config.max_train is not None:
        parts += ["--max-train", str(config.max_train)]
    if config.max_minutes is not None:
        parts += ["--max-minutes", str(config.max_minutes)]
    if config.feedback is not None:
        from sqlalchemy.engine import make_url

        parts += ["--feedback", make_url(config.feedback).render_as_string(hide_password=True),
                  "--feedback-repeat", str(config.feedback_repeat)]
    return " ".join(parts)


def train_and_export(config: TrainConfig, models_dir: str | Path, work_dir: str | Path | None = None,
                     command: str | None = None, log: Any = print) -> Path:
    """The whole pipeline for one model: train, export to ONNX with parity check, evaluate, write the card."""
    work = Path(work_dir) if work_dir is not None else Path(models_dir) / ".work" / config.name
    metrics = train(config, work, log=log)
    net, _ = load_checkpoint(work / "checkpoint.pt")
    path = export_trained(net, config, metrics, models_dir, command or config_command(config, models_dir))
    log(f"[{config.name}] exported {path}")
    return path


def train_plan(plan: dict[str, Any], models_dir: str | Path, dataset: str | None = None,
               only: list[str] | None = None, command: str | None = None, log: Any = print) -> list[Path]:
    """Train, evaluate and export every model of a plan, reading the dataset once (row_cache).

    plan: {"defaults": {TrainConfig fields}, "models": [{TrainConfig fields, optional "subdir"}]}; dataset
    overrides the plan's; only: names to make (default all).  Models go to models_dir/<subdir>/<name>.onnx.
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
    paths = []
    with row_cache():
        for entry in entries:
            if only and entry.get("name") not in only:
                continue
            fields_ = {**defaults, **{k: v for k, v in entry.items() if k != "subdir"}}
            config = TrainConfig.from_dict(fields_)
            folder = Path(models_dir) / entry.get("subdir", "")
            cmd = (command or "graspd train --plan PLAN") + f"  # model {config.name}"
            paths.append(train_and_export(config, folder, Path(models_dir) / ".work" / config.name, cmd, log))
    return paths


#: A tiny dataset for tests and demos: a few procedural and pybullet_data objects, 4 views each.
TINY_DATASET = {"exemplars": 600, "num_urdfs": 6, "procedural": (("box", 6), ("cylinder", 6), ("sphere", 2)),
                "views_per_object": 4, "num_samples": 60}


def train_tiny_model(out_dir: str | Path, seed: int = 0, name: str = "tiny15") -> Path:
    """A small real classifier for tests: generates a tiny dataset (~700 exemplars from 20 objects) under
    out_dir/dataset, trains the fast 15-channel network for a few epochs and exports out_dir/models/<name>.onnx
    with its card; about a minute or less on 2 cores.  Returns the .onnx path (load it with
    graspd.classifier.load_model)."""
    from .dataset import GenerationParams, generate_dataset

    out = Path(out_dir)
    data = out / "dataset"
    if not (data / "manifest.json").exists():
        generate_dataset(data, GenerationParams(seed=seed, **TINY_DATASET), workers=1)  # type: ignore[arg-type]
    config = TrainConfig(dataset=str(data), name=name, epochs=8, batch_size=32, patience=8, seed=seed,
                         max_val=None)
    command = f"graspd.training.train.train_tiny_model({str(out)!r}, seed={seed})"
    return train_and_export(config, out / "models", out / "work", command=command, log=lambda *a: None)


def prefix_dataset(source: str | Path, target: str | Path, num_chunks: int) -> dict[str, Any]:
    """A dataset made of the first num_chunks chunk files of source (a finished or an interrupted
    generation: chunks are deterministic, so any run of the same command has the same first chunks),
    with its own manifest and splits; the chunk files are linked, not copied.  Returns the manifest.

    The view split of an object is the generator's (seeded per object); the object split is drawn by the
    generator's rule over the objects present."""
    import hashlib
    import os

    from .dataset import CATEGORIES, FORMAT, _splits, sha256_file

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
