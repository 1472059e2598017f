"""Train a grasp-image classifier on a graspd dataset: reproducible from a config and a seed, on the CPU.

Class-balanced (class-weighted cross-entropy), Adam, early stopping on the validation part of the
chosen split, optional fine-tuning from earlier weights and hard-negative mining; writes last.pt (the
resumable state, every epoch), checkpoint.pt (best validation state, Platt-calibrated on the validation
rows, config, architecture) and train_metrics.json (per-epoch history) to the output folder.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from graspd.core.progress import Progress
from graspd.gpd.classifier import default_models_dir
from graspd.gpd.images import REPRESENTATIONS
from graspd_lab.training.augment import augment
from graspd_lab.training.config import TrainConfig
from graspd_lab.training.dataset import derive_images, read_manifest, sha256_file
from graspd_lab.training.evaluate import expected_calibration_error, fit_platt
from graspd_lab.training.export import INPUT_OFFSET, INPUT_SCALE
from graspd_lab.training.network import build_network, fold_logit_affine
from graspd_lab.training.rows import feedback_rows, training_rows

#: The resumable training state train() rewrites at the end of every epoch.
LAST = "last.pt"
#: At most this many training negatives are scored per epoch for hard-negative mining (a random subset).
MAX_SCORED_NEGATIVES = 100_000
#: The share of an epoch's negatives drawn from the hard ones when mining.
HARD_SHARE = 0.5


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


def sample_negatives(negatives: NDArray[np.int64], scores: NDArray[np.floating[Any]], fraction: float,
                     rng: np.random.Generator, share: float = HARD_SHARE
                     ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """One epoch's negatives, as many as given: share of them drawn from the top fraction by score (NaN = not
    scored), the rest uniformly without replacement; returns (rows drawn, positions of the hard ones)."""
    n = len(negatives)
    scored = np.flatnonzero(~np.isnan(scores))
    k = min(len(scored), max(1, int(np.ceil(fraction * len(scored)))))
    if n == 0 or k == 0:
        return rng.permutation(negatives), np.zeros(0, np.int64)
    hard = scored[np.argsort(-scores[scored], kind="stable")[:k]]
    n_hard = int(round(share * n))
    drawn = np.concatenate([negatives[rng.choice(hard, n_hard, replace=n_hard > k)],
                            rng.choice(negatives, n - n_hard, replace=False)])
    return drawn.astype(np.int64), hard.astype(np.int64)


def resolve_weights(init_from: str, models_dir: str | Path | None = None) -> Path:
    """The .pt file init_from names: a path (ends in .pt or has a folder), else models_dir/NAME.pt or the
    default models folder's; ValueError naming init_from and the places tried."""
    path = Path(init_from)
    if path.suffix == ".pt" or len(path.parts) > 1:
        candidates = [path]
    else:
        folders = [Path(models_dir)] if models_dir is not None else []
        candidates = [d / f"{init_from}.pt" for d in [*folders, default_models_dir()]]
    for c in candidates:
        if c.is_file():
            return c
    raise ValueError(f"init_from {init_from!r}: no weights file (tried {', '.join(map(str, candidates))})")


def _read_weights(path: Path, what: str) -> dict[str, Any]:
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the same error to the user
        raise ValueError(f"{what}: cannot read {path} as torch weights ({exc})") from exc
    missing = [k for k in ("state_dict", "architecture", "channels") if not isinstance(ckpt, dict) or k not in ckpt]
    if missing:
        raise ValueError(f"{what}: {path} lacks {missing} (not a graspd checkpoint or models/NAME.pt)")
    return ckpt


def load_weights(path: str | Path) -> nn.Module:
    """The network (eval mode) in a .pt file: a train() checkpoint.pt or last.pt, or an exported models/NAME.pt."""
    ckpt = _read_weights(Path(path), str(path))
    kwargs = ckpt.get("network", ckpt.get("config", {}).get("network", {}))
    net = build_network(str(ckpt["architecture"]), int(ckpt["channels"]), int(ckpt.get("image_size", 60)), **kwargs)
    net.load_state_dict(ckpt["state_dict"])
    return net.eval()


def _init_weights(net: nn.Module, config: TrainConfig, channels: int, size: int,
                  models_dir: str | Path | None) -> dict[str, Any]:
    """Load config.init_from into a fresh network; ValueError naming init_from when it does not fit."""
    assert config.init_from is not None
    what = f"init_from {config.init_from!r}"
    path = resolve_weights(config.init_from, models_dir)
    ckpt = _read_weights(path, what)
    got = (str(ckpt["architecture"]), int(ckpt["channels"]), int(ckpt.get("image_size", size)))
    if got != (config.architecture, channels, size):
        raise ValueError(f"{what} ({path}) is a {got[0]} network on {got[1]} channels of {got[2]} px; this run "
                         f"trains a {config.architecture} network on {channels} channels of {size} px")
    try:
        net.load_state_dict(ckpt["state_dict"])
    except RuntimeError as exc:
        raise ValueError(f"{what} ({path}): the weights do not fit the network ({exc})") from exc
    return {"init_from": config.init_from, "path": str(path), "sha256": sha256_file(path)}


def _save_atomic(obj: dict[str, Any], path: Path) -> None:
    """torch.save to a temporary file, then rename: an interruption leaves the previous file whole."""
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def calibrate(net: nn.Module, images: NDArray[np.uint8], labels: NDArray[np.uint8]) -> dict[str, float] | None:
    """Fit Platt scaling on (validation) rows and fold it into the network's last layer; returns a, b and the
    ECE before and after, or None when the rows hold one class (nothing to fit)."""
    if len(np.unique(labels)) < 2:
        return None
    logits = predict_logits(net, images)
    a, b = fit_platt(logits[:, 1] - logits[:, 0], labels)
    before = expected_calibration_error(grasp_probability(logits), labels)
    fold_logit_affine(net, a, b)
    after = expected_calibration_error(grasp_probability(predict_logits(net, images)), labels)
    return {"a": a, "b": b, "val_ece_before": before, "val_ece_after": after}


def train(config: TrainConfig, out_dir: str | Path, log: Any = print,
          models_dir: str | Path | None = None) -> dict[str, Any]:
    """Train one network; returns the metrics dict also written to out_dir/train_metrics.json.

    models_dir is where a model name in config.init_from is looked up (then the default models folder)."""
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

    def row_images(rows: NDArray[np.int64]) -> NDArray[np.uint8]:
        ds = rows[rows < n_ds]
        images = x_tr[ds] if rep == "15" else derive_images(x_tr[ds], rep)
        if len(ds) < len(rows):
            images = np.concatenate([images, x_fb[fb_index[rows[rows >= n_ds] - n_ds]]])
        return images

    def batch_images(rows: NDArray[np.int64]) -> NDArray[np.uint8]:
        images = row_images(rows)
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
    y_va_t = torch.from_numpy(y_va.astype(np.int64))
    # the loop's state: what last.pt holds, so that an interrupted run continues where its last epoch ended
    step, first_epoch, elapsed_before = 0, 0, 0.0
    best: dict[str, Any] = {"val_loss": float("inf")}
    best_state: dict[str, torch.Tensor] = {}
    history: list[dict[str, Any]] = []
    stale = 0
    saved_stop: str | None = None
    resumed_from: int | None = None
    init: dict[str, Any] | None = None
    last_path = out / LAST
    if config.resume and last_path.exists():
        last = torch.load(last_path, map_location="cpu", weights_only=True)
        differ = config.resumable_with(last["config"])
        if last.get("dataset_sha256") != manifest.get("dataset_sha256"):
            differ.append("dataset contents (dataset_sha256)")
        if differ:
            raise ValueError(f"cannot resume from {last_path}: its run differs in {differ} (resume and max_minutes "
                             "may change; start a fresh run without --resume or in another work dir)")
        net.load_state_dict(last["state_dict"])
        opt.load_state_dict(last["optimizer"])
        rng.bit_generator.state = last["numpy_rng"]
        torch.set_rng_state(last["torch_rng"])
        step, first_epoch, elapsed_before = int(last["step"]), int(last["epoch"]), float(last["elapsed_s"])
        best, best_state, history, stale = last["best"], last["best_state"], last["history"], int(last["stale"])
        saved_stop, init = last["stopped"], last["init"]
        resumed_from = first_epoch
        log(f"[{config.name}] resuming from {last_path}: {first_epoch} epochs done, {elapsed_before / 60:.1f} min "
            f"of training spent" + (f", stopped by {saved_stop}" if saved_stop else ""))
    else:
        if config.resume:
            log(f"[{config.name}] resume: no {last_path} yet, starting a fresh run")
        last_path.unlink(missing_ok=True)  # a stale state of another run must not be resumed later
        if config.init_from is not None:
            init = _init_weights(net, config, channels, size, models_dir)
            log(f"[{config.name}] fine-tuning from {init['path']}")
    negatives = np.flatnonzero(y_tr == 0)
    others = np.concatenate([np.flatnonzero(y_tr == 1), n_ds + np.arange(len(fb_index))])

    def epoch_order(epoch: int) -> tuple[NDArray[np.int64], dict[str, Any]]:
        """The epoch's rows in training order; from the second epoch on, with hard negatives oversampled."""
        if config.hard_negatives <= 0 or epoch == 0 or len(negatives) == 0:
            return rng.permutation(len(y_all)), {}
        scores = np.full(len(negatives), np.nan)
        pick = np.arange(len(negatives))
        if len(pick) > MAX_SCORED_NEGATIVES:
            pick = np.sort(rng.choice(len(negatives), MAX_SCORED_NEGATIVES, replace=False))
        scores[pick] = np.concatenate([grasp_probability(predict_logits(net, row_images(negatives[pick[a : a + 2048]])))
                                       for a in range(0, len(pick), 2048)])
        drawn, hard = sample_negatives(negatives, scores, config.hard_negatives, rng)
        rows = np.concatenate([others, drawn])
        info = {"hard_negatives": int(len(hard)), "hard_negatives_drawn": int(round(HARD_SHARE * len(negatives))),
                "hard_negative_mean_score": float(scores[hard].mean()), "scored_negatives": int(len(pick))}
        return rows[rng.permutation(len(rows))], info

    t_train = time.perf_counter()

    def elapsed() -> float:
        return elapsed_before + time.perf_counter() - t_train

    stopped: str | None = saved_stop if saved_stop in ("epochs", "early_stopping") else None
    for epoch in range(first_epoch, config.epochs if stopped is None else first_epoch):
        te = time.perf_counter()
        order, mining = epoch_order(epoch)
        net.train()
        total, seen = 0.0, 0
        out_of_time = False
        # the epoch's batches: a bar on a terminal, a line a minute in a log (graspd.core.progress)
        with Progress(-(-len(order) // config.batch_size), f"[{config.name}] epoch {epoch + 1}/{config.epochs}",
                      "batch") as bar:
            for a in range(0, len(order), config.batch_size):
                idx = order[a : a + config.batch_size]
                # cosine learning-rate decay over the run: over the steps, or over the time budget if that ends first
                progress = step / total_steps
                if limit_s is not None:
                    progress = max(progress, elapsed() / limit_s)
                if progress >= 1.0:
                    out_of_time = True
                    break
                for group in opt.param_groups:
                    group["lr"] = float(config.learning_rate * 0.5 * (1.0 + np.cos(np.pi * progress)))
                step += 1
                x = _to_tensor(batch_images(idx))
                y = torch.from_numpy(batch_labels(idx).astype(np.int64))
                opt.zero_grad(set_to_none=True)
                loss = loss_fn(net(x), y)
                loss.backward()
                opt.step()
                total += loss.item() * len(idx)
                seen += len(idx)
                bar.update(1, loss=round(total / seen, 4))
        if seen == 0:  # the time budget ran out at the end of the previous epoch
            stopped = "time_limit"
            break
        recalibrate_batchnorm(net, batch_images(rng.choice(tr_index, min(4096, len(tr_index)), replace=False)))
        logits = predict_logits(net, x_va)
        val_loss = float(loss_fn(torch.from_numpy(logits), y_va_t))
        val_acc = float(np.mean((logits[:, 1] > logits[:, 0]) == (y_va == 1)))
        row = {"epoch": epoch + 1, "train_loss": total / seen, "exemplars_seen": seen, "val_loss": val_loss,
               "val_accuracy": val_acc, "seconds": time.perf_counter() - te, "resumed": resumed_from is not None,
               **mining}
        history.append(row)
        if val_loss < best["val_loss"]:
            best = dict(row)
            best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
            stale = 0
        else:
            stale += 1
            if stale >= config.patience:
                stopped = "early_stopping"
        if stopped is None and out_of_time:
            stopped = "time_limit"
        if stopped is None and epoch + 1 == config.epochs:
            stopped = "epochs"
        _save_atomic({"state_dict": net.state_dict(), "optimizer": opt.state_dict(), "epoch": epoch + 1, "step": step,
                      "numpy_rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state(), "best": best,
                      "best_state": best_state, "history": history, "stale": stale, "elapsed_s": elapsed(),
                      "stopped": stopped, "init": init, "config": config.to_dict(),
                      "dataset_sha256": manifest.get("dataset_sha256"), "architecture": config.architecture,
                      "channels": channels, "image_size": size}, last_path)
        hard = (f"  hard negatives {mining['hard_negatives']} (mean score {mining['hard_negative_mean_score']:.3f})"
                if mining else "")
        log(f"[{config.name}] epoch {epoch + 1}: train loss {row['train_loss']:.4f}  val loss {val_loss:.4f}  "
            f"val acc {val_acc:.4f}  ({row['seconds']:.1f} s){hard}")
        if stopped is not None:
            break
    stopped = stopped or saved_stop or "epochs"
    train_s = elapsed()
    if not best_state:
        raise ValueError(f"[{config.name}] no epoch finished within the time budget ({config.max_minutes} min)")
    net.load_state_dict(best_state)
    calibration = calibrate(net, x_va, y_va) if config.calibrate else None
    if calibration is not None:
        log(f"[{config.name}] calibrated on {len(y_va)} val rows: p = sigmoid({calibration['a']:.3f} z "
            f"{calibration['b']:+.3f}), ECE {calibration['val_ece_before']:.4f} -> {calibration['val_ece_after']:.4f}")
    elif config.calibrate:
        log(f"[{config.name}] not calibrated: the validation rows hold one class")
    _save_atomic({"state_dict": net.state_dict(), "config": config.to_dict(), "architecture": config.architecture,
                  "channels": channels, "image_size": size, "calibration": calibration}, out / "checkpoint.pt")
    metrics = {
        "config": config.to_dict(),
        "dataset_sha256": manifest.get("dataset_sha256"),
        "num_train": int(len(y_tr)), "num_val": int(len(y_va)), "feedback": feedback,
        "train_class_counts": counts.astype(int).tolist(),
        "init_from": init, "resumed_from_epoch": resumed_from,
        "best_epoch": int(best["epoch"]), "best_val_loss": best["val_loss"], "best_val_accuracy": best["val_accuracy"],
        "stopped": stopped, "history": history, "calibration": calibration,
        "seconds_total": time.perf_counter() - t0, "seconds_load": load_s, "seconds_training": train_s,
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
