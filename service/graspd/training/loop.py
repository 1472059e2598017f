"""Train a grasp-image classifier on a graspd dataset: reproducible from a config and a seed, on the CPU.

Class-balanced (class-weighted cross-entropy), Adam, early stopping on the validation part of the
chosen split; writes checkpoint.pt (best validation state, config, architecture) and
train_metrics.json (per-epoch history) to the output folder.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from ..images import REPRESENTATIONS
from .augment import augment
from .config import TrainConfig
from .dataset import derive_images, read_manifest
from .export import INPUT_OFFSET, INPUT_SCALE
from .network import build_network
from .rows import feedback_rows, training_rows


def _batches(n: int, batch_size: int, rng: np.random.Generator | None) -> list[NDArray[np.int64]]:
    order = rng.permutation(n) if rng is not None else np.arange(n)
    return [order[a : a + batch_size] for a in range(0, n, batch_size)]


def _to_tensor(images: NDArray[np.uint8], idx: NDArray[np.int64] | None = None) -> torch.Tensor:
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
