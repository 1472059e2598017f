"""Instance models: a classifier fine-tuned for one known object (the IROS 2016 GPD paper's instance prior,
Figure 7: a network fine-tuned on the object it will grasp beats the generic one on that object).

From a mesh file (graspd_lab.world.mesh_file: .obj/.stl/.ply in metres) this makes a small single-object dataset
with the dataset machinery (the same rendering, noise, candidates, labels, images and on-disk format as
graspd_lab.training.dataset; the object's views split into train, val and test), fine-tunes a base model on it
(generic15, or the category model box15 / cylinder15; weights from models_dir/BASE.pt, else read back from
BASE.onnx), exports models_dir/NAME.onnx with its card, and scores the generic, category and instance models
on the object's held-out test views: accuracy, RA99P and AP go to the card under "instance_comparison".

    graspd train --instance mug.ply --name mug --category cylinder --views 24 --max-minutes 2
    ... --workers 2 [--ray [--address ADDR]]   (the views rendered and labelled on a pool or as Ray tasks)

The views are rendered and labelled in this process by default; with a graspd_lab.cluster Runner of more than
one worker, or Ray, each view is a task that reads the mesh file itself (the same object, the same bytes).
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from graspd.core.hand import HandGeometry
from graspd.gpd.classifier import OnnxGraspClassifier, card_fits_hand, load_model, read_card
from graspd.gpd.images import channel_layout
from graspd.store.instances import BASE_MODELS, InstanceError, check_category, check_name
from graspd_lab.cluster import Runner, imap
from graspd_lab.training.config import TrainConfig
from graspd_lab.training.dataset import (
    CATEGORIES,
    CHUNK_KEYS,
    FORMAT,
    STORED_REPRESENTATION,
    GenerationParams,
    _empty_rows,
    _splits,
    _view_exemplars,
    derive_images,
    write_npz,
)
from graspd_lab.training.evaluate import classification_metrics
from graspd_lab.training.export import write_card
from graspd_lab.training.labels import normal_slack_deg
from graspd_lab.training.network import build_network
from graspd_lab.training.plans import train_and_export
from graspd_lab.training.rows import load_rows
from graspd_lab.world.mesh_file import MeshLimits, read_mesh_object
from graspd_lab.world.objects import GraspObject
from graspd_lab.world.render import MeshScene

#: The train loop's per-epoch log line (graspd_lab.training.loop.train): the epoch count for progress.
_EPOCH_LINE = re.compile(r"\bepoch (\d+):")

Progress = Callable[[dict[str, Any]], None]


@dataclass(frozen=True)
class InstanceParams:
    """Dataset and fine-tuning settings of an instance model: a few minutes on 2 CPU cores by default
    (24 views x 128 exemplars, ~10 s of rendering and labelling, then max_minutes of training)."""

    views: int = 24
    per_view: int = 128                    # exemplars kept per view (half positive)
    seed: int = 0
    max_minutes: float = 2.0
    epochs: int = 30
    batch_size: int = 64
    learning_rate: float = 5e-4            # fine-tuning: a quarter of generic15's
    patience: int = 6
    threads: int = 2
    num_samples: int = 50
    max_samples: int = 250
    split_fractions: tuple[float, float] = (0.25, 0.125)   # (test, val) views: 24 views -> 6 test, 3 val, 15 train
    hand: HandGeometry = field(default_factory=HandGeometry)

    def __post_init__(self) -> None:
        if not 3 <= self.views <= 1000:
            raise InstanceError("views", f"must lie in [3, 1000] (train, val and test views), got {self.views}")
        if not 2 <= self.per_view <= 4096:
            raise InstanceError("per_view", f"must lie in [2, 4096], got {self.per_view}")
        if not 0.0 < self.max_minutes <= 24 * 60:
            raise InstanceError("max_minutes", f"must lie in (0, 1440], got {self.max_minutes}")
        for key in ("epochs", "batch_size", "patience", "threads", "num_samples"):
            if getattr(self, key) < 1:
                raise InstanceError(key, f"must be >= 1, got {getattr(self, key)}")
        if not self.learning_rate > 0:
            raise InstanceError("learning_rate", f"must be > 0, got {self.learning_rate}")

    def generation(self) -> GenerationParams:
        return GenerationParams(seed=self.seed, exemplars=self.views * self.per_view, num_urdfs=0, procedural=(),
                                views_per_object=self.views, num_samples=self.num_samples,
                                max_samples=max(self.max_samples, self.num_samples), per_view=self.per_view,
                                objects_per_chunk=1, hand=self.hand, split_fractions=self.split_fractions)


# ---------------------------------------------------------------------------------------------------
# The single-object dataset
# ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MeshSource:
    """Where a task finds the object: the mesh file and what read_mesh_object made of it (open3d meshes do not
    pickle, so each worker reads the file; on a Ray cluster the path must be one every node sees)."""

    path: str
    name: str
    category: str
    hand: HandGeometry
    limits: MeshLimits | None = None


@lru_cache(maxsize=4)
def _source_scene(source: MeshSource) -> tuple[GraspObject, MeshScene]:
    """The object and its raycasting scene, read once per worker process."""
    obj = read_mesh_object(source.path, source.name, source.category, source.hand, source.limits)
    return obj, MeshScene([obj.mesh])


def _source_view(task: tuple[MeshSource, int, int, GenerationParams]
                 ) -> tuple[int, dict[str, NDArray[Any]], dict[str, Any]]:
    """Worker: the labelled rows and record of one view of the object in the mesh file."""
    source, view_id, quota, gen = task
    obj, scene = _source_scene(source)
    rows, record = _view_exemplars(obj, scene, 0, view_id, quota, gen)
    return view_id, rows, record


def make_instance_dataset(obj: GraspObject, out_dir: str | Path, params: InstanceParams,
                          progress: Progress | None = None, command: str | None = None,
                          runner: Runner | None = None, source: MeshSource | None = None) -> dict[str, Any]:
    """Write a one-object dataset of obj (graspd_lab.training.dataset's format: one chunk, splits/view.json over
    its views) to out_dir and return the manifest.  InstanceError naming "mesh" when a part of the view split
    lacks grasps or non-grasps (the hand finds nothing to learn on this object).  runner (with source, the
    mesh file obj was read from): the views as tasks on a pool or Ray (graspd_lab.cluster); the same bytes."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if (out / "manifest.json").exists() or any(out.glob("chunk_*.npz")):
        raise FileExistsError(f"{out} already holds a dataset; choose an empty folder")
    gen = params.generation()
    quota = gen.quota(1)
    scene = MeshScene([obj.mesh])
    t0 = time.perf_counter()
    parts: list[dict[str, NDArray[Any]]] = [_empty_rows()]
    views: list[dict[str, Any]] = []
    if runner is not None and source is not None and (runner.uses_ray or runner.workers > 1):
        tasks = [(source, view_id, quota, gen) for view_id in range(params.views)]
        by_view: dict[int, tuple[dict[str, NDArray[Any]], dict[str, Any]]] = {}
        exemplars = 0
        for view_id, rows, record in imap(_source_view, tasks, runner):  # as they finish; kept in view order
            by_view[view_id] = (rows, record)
            exemplars += len(rows["labels"])
            if progress is not None:
                progress({"stage": "dataset", "view": len(by_view), "views": params.views, "exemplars": exemplars})
        parts += [by_view[v][0] for v in range(params.views)]
        views = [by_view[v][1] for v in range(params.views)]
    else:
        for view_id in range(params.views):
            rows, record = _view_exemplars(obj, scene, 0, view_id, quota, gen)
            parts.append(rows)
            views.append(record)
            if progress is not None:
                progress({"stage": "dataset", "view": view_id + 1, "views": params.views,
                          "exemplars": int(sum(len(p["labels"]) for p in parts))})
    arrays = {k: np.concatenate([p[k] for p in parts]) for k in CHUNK_KEYS}
    digest = write_npz(out / "chunk_00000.npz", arrays)
    labels = arrays["labels"]
    chunk = {"file": "chunk_00000.npz", "rows": int(len(labels)), "positive": int(labels.sum()), "sha256": digest}
    objects = [{"id": 0, **obj.to_dict()}]
    view_split, object_split = _splits(objects, params.views, params.split_fractions, params.seed)
    (out / "splits").mkdir(exist_ok=True)
    (out / "splits" / "view.json").write_text(json.dumps(view_split))
    (out / "splits" / "object.json").write_text(json.dumps(object_split))
    for part in ("train", "val", "test"):
        members = {int(v) for _, v in view_split[part]}
        got = labels[np.isin(arrays["view_ids"], list(members))]
        if got.sum() == 0 or got.sum() == len(got):
            raise InstanceError("mesh", f"the {part} views of {obj.name!r} hold {int(got.sum())} grasps among "
                                f"{len(got)} candidates: the hand finds nothing to learn on this object (too large, "
                                "too thin, or an open surface?)")
    total, positive = int(len(labels)), int(labels.sum())
    manifest = {
        "format": FORMAT, "seed": params.seed, "representation": STORED_REPRESENTATION,
        "derivable": ["15", "12", "3", "herzog"], "image_size": 60, "channels": channel_layout(STORED_REPRESENTATION),
        "hand": params.hand.to_dict(), "label_normal_slack_deg": normal_slack_deg(params.hand, gen.labels),
        "parameters": gen.to_dict(), "per_view": quota, "objects": objects, "views": views, "chunks": [chunk],
        "counts": {"total": total, "positive": positive, "negative": total - positive,
                   "by_category": {c: (total if c == obj.category else 0) for c in CATEGORIES},
                   "target": gen.exemplars},
        "dataset_sha256": hashlib.sha256(digest.encode()).hexdigest(),
        "command": command or "graspd_lab.training.instance.make_instance_dataset",
        "instance": True,
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    elapsed = time.perf_counter() - t0
    how = runner if runner is not None and source is not None else Runner()
    (out / "timing.json").write_text(json.dumps({"seconds": elapsed, "workers": how.workers,
                                                 "runner": how.describe(), "exemplars": total,
                                                 "exemplars_per_minute": 60.0 * total / max(elapsed, 1e-9)}))
    return manifest


# ---------------------------------------------------------------------------------------------------
# Base weights: BASE.pt when export wrote one, else read back from BASE.onnx
# ---------------------------------------------------------------------------------------------------


def _onnx_arrays(onnx_path: Path) -> tuple[list[tuple[NDArray[Any], NDArray[Any] | None]],
                                           list[tuple[NDArray[Any], NDArray[Any] | None]]]:
    """(weight, bias) of every Conv and every Gemm/MatMul node of an exported graph, in graph order (Gemm
    weights as torch's (out, in))."""
    import onnx  # noqa: PLC0415
    from onnx import numpy_helper  # noqa: PLC0415

    model = onnx.load(str(onnx_path))
    init = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    convs: list[tuple[NDArray[Any], NDArray[Any] | None]] = []
    dense: list[tuple[NDArray[Any], NDArray[Any] | None]] = []
    for node in model.graph.node:
        if node.op_type not in ("Conv", "Gemm"):
            continue
        if node.input[1] not in init:
            raise ValueError(f"{onnx_path}: {node.op_type} weight {node.input[1]!r} is not a stored initializer")
        w = init[node.input[1]]
        b = init.get(node.input[2]) if len(node.input) > 2 else None
        if node.op_type == "Conv":
            convs.append((w, b))
        else:
            attrs = {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}
            if attrs.get("transA", 0) or attrs.get("alpha", 1.0) != 1.0 or attrs.get("beta", 1.0) != 1.0:
                raise ValueError(f"{onnx_path}: a Gemm with transA/alpha/beta is not an exported Linear")
            dense.append((w if attrs.get("transB", 0) else w.T, b))
    return convs, dense


def network_from_onnx(onnx_path: str | Path, card: dict[str, Any], calibration: NDArray[np.uint8]) -> nn.Module:
    """The torch network of an exported model (graspd_lab.training.export), rebuilt from its ONNX weights.

    The exporter folds each batch norm into the convolution before it, so the parts are not recoverable; the
    rebuilt network puts the folded convolution's output statistics over `calibration` images (uint8, the
    card's representation) into its batch norm (running mean/var = those statistics, scale = std, shift =
    mean + folded bias): in eval mode it computes exactly the exported function, and in training mode, where
    batch norm uses each batch's statistics, nearly so.  ValueError if it does not match the ONNX model."""
    onnx_path = Path(onnx_path)
    channels, size = int(card["channels"]), int(card["image_size"])
    network_args = dict(((card.get("training") or {}).get("config") or {}).get("network") or {})
    net = build_network(str(card.get("architecture", "fast")), channels, size, **network_args)
    convs, dense = _onnx_arrays(onnx_path)
    modules = list(net.modules())
    t_convs: list[tuple[nn.Conv2d, nn.BatchNorm2d | None]] = []
    for i, m in enumerate(modules):
        if isinstance(m, nn.Conv2d):
            after = modules[i + 1] if i + 1 < len(modules) else None
            t_convs.append((m, after if isinstance(after, nn.BatchNorm2d) else None))
    t_dense = [m for m in modules if isinstance(m, nn.Linear)]
    if len(t_convs) != len(convs) or len(t_dense) != len(dense):
        raise ValueError(f"{onnx_path}: {len(convs)} convolutions and {len(dense)} dense layers, the card's "
                         f"architecture has {len(t_convs)} and {len(t_dense)}")
    folded: list[tuple[nn.BatchNorm2d, torch.Tensor]] = []
    with torch.no_grad():
        for (conv, bn), (w, b) in zip(t_convs, convs, strict=True):
            conv.weight.copy_(torch.from_numpy(np.array(w, np.float32)))
            bias = torch.from_numpy(np.array(b, np.float32)) if b is not None else torch.zeros(conv.out_channels)
            if bn is None:
                if conv.bias is not None:
                    conv.bias.copy_(bias)
                continue
            # identity batch norm for now: (z - 0) / sqrt(1 - eps + eps) * 1 + bias
            assert bn.running_mean is not None and bn.running_var is not None
            bn.running_mean.zero_()
            bn.running_var.fill_(1.0 - bn.eps)
            bn.weight.fill_(1.0)
            bn.bias.copy_(bias)
            folded.append((bn, bias))
        for lin, (w, b) in zip(t_dense, dense, strict=True):
            lin.weight.copy_(torch.from_numpy(np.array(w, np.float32)))
            if lin.bias is not None and b is not None:
                lin.bias.copy_(torch.from_numpy(np.array(b, np.float32)))
    if folded:
        _calibrate_folded(net, folded, card, calibration)
    _check_parity(net, onnx_path, card, calibration[:256])
    return net.eval()


def _to_input(images: NDArray[np.uint8], card: dict[str, Any]) -> torch.Tensor:
    return torch.from_numpy(images.astype(np.float32) * np.float32(card["input"]["scale"])
                            + np.float32(card["input"]["offset"]))


def _calibrate_folded(net: nn.Module, folded: list[tuple[nn.BatchNorm2d, torch.Tensor]], card: dict[str, Any],
                      images: NDArray[np.uint8], batch_size: int = 256) -> None:
    """Move the folded convolutions' output statistics (over images) into their batch norms, keeping the
    eval-mode function (see network_from_onnx)."""
    sums = [torch.zeros(bn.num_features, dtype=torch.float64) for bn, _ in folded]
    squares = [torch.zeros(bn.num_features, dtype=torch.float64) for bn, _ in folded]
    counts = [0] * len(folded)
    handles = []
    for i, (bn, _) in enumerate(folded):
        def hook(module: nn.Module, inputs: tuple[torch.Tensor, ...], output: torch.Tensor, i: int = i) -> None:
            z = inputs[0].detach().double().transpose(0, 1).reshape(inputs[0].shape[1], -1)  # the conv's output
            sums[i] += z.sum(dim=1)
            squares[i] += (z * z).sum(dim=1)
            counts[i] += int(z.shape[1])
        handles.append(bn.register_forward_hook(hook))
    net.eval()
    with torch.no_grad():
        for a in range(0, len(images), batch_size):
            net(_to_input(images[a : a + batch_size], card))
    for h in handles:
        h.remove()
    with torch.no_grad():
        for (bn, bias), s1, s2, n in zip(folded, sums, squares, counts, strict=True):
            mean = s1 / max(n, 1)
            var = (s2 / max(n, 1) - mean * mean).clamp_min(0.0)
            assert bn.running_mean is not None and bn.running_var is not None
            bn.running_mean.copy_(mean.float())
            bn.running_var.copy_(var.float())
            bn.weight.copy_(torch.sqrt(var + bn.eps).float())
            bn.bias.copy_(bias + mean.float())


def _check_parity(net: nn.Module, onnx_path: Path, card: dict[str, Any], images: NDArray[np.uint8],
                  tolerance: float = 1e-4) -> None:
    net.eval()
    with torch.no_grad():
        torch_p = torch.softmax(net(_to_input(images, card)), dim=1)[:, 1].numpy()
    onnx_p = OnnxGraspClassifier(onnx_path, card, threads=1).score(images)
    diff = float(np.max(np.abs(torch_p - onnx_p), initial=0.0))
    if not diff <= tolerance:
        raise ValueError(f"{onnx_path}: the rebuilt torch network differs from the ONNX model by {diff:.2e}")


# ---------------------------------------------------------------------------------------------------
# The comparison on the instance's held-out views
# ---------------------------------------------------------------------------------------------------


def compare_models(dataset: str | Path, models: dict[str, tuple[str, OnnxGraspClassifier]],
                   hand: dict[str, float]) -> dict[str, Any]:
    """Accuracy, RA99P and AP of each model {name: (role, classifier)} on the test views of a dataset's view
    split (the object's held-out views)."""
    images15, labels, _ = load_rows(dataset, "view", "test", "15")
    out: dict[str, Any] = {}
    for name, (role, clf) in models.items():
        m = classification_metrics(clf.score(derive_images(images15, clf.representation)), labels)
        out[name] = {"role": role, "fits_hand": card_fits_hand(clf.card, hand),
                     **{k: m[k] for k in ("n", "positives", "accuracy", "precision", "recall", "ra99p",
                                          "threshold_99p", "average_precision")}}
    return out


# ---------------------------------------------------------------------------------------------------
# The whole pipeline
# ---------------------------------------------------------------------------------------------------


def resolve_base(models_dir: Path, category: str | None, base: str | None = "auto") -> str | None:
    """The base model's name: base itself, or with "auto" the category model (which must exist) or, without a
    category, generic15 when it is in models_dir (else None: training from scratch)."""
    if base != "auto":
        if base is not None and not (models_dir / f"{base}.onnx").is_file():
            raise InstanceError("base", f"no model {base!r} in {models_dir}")
        return base
    name = BASE_MODELS[category]
    if (models_dir / f"{name}.onnx").is_file():
        return name
    if category is not None:
        raise InstanceError("category", f"the category model {name!r} is not in {models_dir}")
    return None


def base_weights(base: str, models_dir: Path, work: Path, dataset: Path, representation: str) -> Path:
    """A .pt of the base model's weights for TrainConfig.init_from: models_dir/BASE.pt if export wrote one, else
    work/BASE-from-onnx.pt rebuilt from BASE.onnx (network_from_onnx, calibrated on the training views)."""
    pt = models_dir / f"{base}.pt"
    if pt.is_file():
        return pt
    card = read_card(models_dir / f"{base}.json")
    images, _, _ = load_rows(dataset, "view", "train", representation, limit=2048, seed=0)
    net = network_from_onnx(models_dir / f"{base}.onnx", card, images)
    out = work / f"{base}-from-onnx.pt"
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"state_dict": net.state_dict(), "architecture": card.get("architecture", "fast"),
                "channels": int(card["channels"]), "image_size": int(card["image_size"]),
                "config": (card.get("training") or {}).get("config"), "source": str(models_dir / f"{base}.onnx")},
               out)
    return out


def train_instance(mesh: str | Path, name: str, models_dir: str | Path, category: str | None = None,
                   params: InstanceParams | None = None, base: str | None = "auto",
                   work_dir: str | Path | None = None, overwrite: bool = False, command: str | None = None,
                   log: Callable[[str], None] = print, progress: Progress | None = None,
                   limits: MeshLimits | None = None, runner: Runner | None = None) -> Path:
    """Make the instance model NAME for the object in mesh; returns models_dir/NAME.onnx (its card holds
    "instance" and "instance_comparison").  InstanceError / MeshError name the option at fault.  runner: how
    the dataset's views run (graspd_lab.cluster; default: in this process)."""
    params = params or InstanceParams()
    models = Path(models_dir)
    check_name(name)
    check_category(category)
    if not overwrite and ((models / f"{name}.onnx").exists() or (models / f"{name}.json").exists()):
        raise InstanceError("name", f"model {name!r} already exists in {models}")
    work = Path(work_dir) if work_dir is not None else models / ".work" / name
    emit = progress or (lambda event: None)
    obj = read_mesh_object(mesh, name, category or "other", params.hand, limits)
    base_name = resolve_base(models, category, base)
    base_card = read_card(models / f"{base_name}.json") if base_name else None
    representation = str(base_card["representation"]) if base_card else "15"
    t0 = time.perf_counter()
    dataset = work / "dataset"
    if dataset.exists():  # a previous attempt's (the work folder is this model's own)
        shutil.rmtree(dataset)
    source = MeshSource(str(Path(mesh).resolve()), name, category or "other", params.hand, limits)
    manifest = make_instance_dataset(obj, dataset, params, emit, command, runner=runner, source=source)
    log(f"[{name}] dataset: {manifest['counts']['total']} exemplars ({manifest['counts']['positive']} positive) "
        f"from {params.views} views in {time.perf_counter() - t0:.1f} s")
    init_from = base_weights(base_name, models, work, dataset, representation) if base_name else None
    network = dict(((base_card or {}).get("training") or {}).get("config", {}).get("network") or {})
    config = TrainConfig(dataset=str(dataset), name=name, representation=representation,
                         architecture=str((base_card or {}).get("architecture", "fast")), split="view",
                         epochs=params.epochs, batch_size=params.batch_size, learning_rate=params.learning_rate,
                         patience=params.patience, seed=params.seed, threads=params.threads,
                         max_minutes=params.max_minutes, max_val=None, network=network,
                         init_from=None if init_from is None else str(init_from))
    emit({"stage": "training", "epoch": 0, "epochs": params.epochs})

    def train_log(line: str) -> None:
        log(line)
        match = _EPOCH_LINE.search(line)
        if match:
            emit({"stage": "training", "epoch": int(match.group(1)), "epochs": params.epochs})

    path = train_and_export(config, models, work / "train", command=command, log=train_log)
    emit({"stage": "evaluating"})
    card = json.loads(path.with_suffix(".json").read_text())
    hand = params.hand.to_dict()
    compared: dict[str, tuple[str, OnnxGraspClassifier]] = {}
    for cat, other in BASE_MODELS.items():
        if (models / f"{other}.onnx").is_file():
            role = "generic" if cat is None else "category" if cat == category else "other_category"
            compared[other] = (role, load_model(other, models, threads=params.threads))
    compared[name] = ("instance", OnnxGraspClassifier(path, card, threads=params.threads))
    comparison = compare_models(dataset, compared, hand)
    card["instance"] = {
        "object": obj.to_dict(), "category": category, "mesh": Path(mesh).name, "base_model": base_name,
        "base_weights": None if init_from is None else str(init_from),
        "base_fits_hand": None if base_card is None else card_fits_hand(base_card, hand),
        "params": {k: v for k, v in asdict(params).items() if k != "hand"},
        "dataset_counts": manifest["counts"], "seconds": round(time.perf_counter() - t0, 1),
    }
    card["instance_comparison"] = {
        "split": "view", "part": "test", "test_views": sorted(v for _, v in json.loads(
            (dataset / "splits" / "view.json").read_text())["test"]),
        "models": comparison,
        "paper": "IROS 2016 GPD (Gualtieri et al.), Figure 7: the instance prior",
    }
    write_card(path.with_suffix(".json"), card)
    for key, m in comparison.items():
        log(f"[{name}] {key} ({m['role']}) on the held-out views: accuracy {m['accuracy']:.4f}  "
            f"RA99P {m['ra99p']:.4f}  AP {m['average_precision']:.4f}  (n={m['n']})")
    emit({"stage": "done", "model": name, "path": str(path)})
    return path
