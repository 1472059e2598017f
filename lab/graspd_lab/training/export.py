"""Export a trained network to ONNX (dynamic batch axis) with its JSON model card, and check parity.

The ONNX graph maps float32 images (batch, C, S, S), already scaled by the card's input.scale and
input.offset, to "score" (batch,) = P(grasp) in [0, 1]; graspd.gpd.classifier loads the pair.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from graspd.gpd.classifier import OnnxGraspClassifier, card_without_paths
from graspd_lab.training.network import GraspProbability

INPUT_NAME = "images"
OUTPUT_NAME = "score"
#: uint8 pixel -> network input: x = pixel * INPUT_SCALE + INPUT_OFFSET, in [0, 1].
INPUT_SCALE = 1.0 / 255.0
INPUT_OFFSET = 0.0
#: Largest |onnxruntime - torch| allowed on P(grasp) by check_parity.
PARITY_TOLERANCE = 1e-4


def export_onnx(net: nn.Module, path: str | Path, channels: int, image_size: int = 60) -> Path:
    """Write the network (in eval mode, with a softmax head) to path as ONNX with a dynamic batch axis."""
    import onnx  # noqa: PLC0415

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    model = GraspProbability(net).eval()
    dummy = torch.zeros(2, channels, image_size, image_size)
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the TorchScript exporter: stable output, no onnxscript
        torch.onnx.export(model, (dummy,), str(path), input_names=[INPUT_NAME], output_names=[OUTPUT_NAME],
                          dynamic_axes={INPUT_NAME: {0: "batch"}, OUTPUT_NAME: {0: "batch"}},
                          opset_version=17, do_constant_folding=True, dynamo=False)
    onnx.checker.check_model(onnx.load(str(path)))
    return path


def torch_scores(net: nn.Module, images: NDArray[np.uint8], batch_size: int = 512) -> NDArray[np.float32]:
    """P(grasp) (M,) from the torch network on uint8 images scaled as the card says."""
    model = GraspProbability(net).eval()
    out = []
    with torch.no_grad():
        for a in range(0, len(images), batch_size):
            x = torch.from_numpy(images[a : a + batch_size].astype(np.float32) * np.float32(INPUT_SCALE)
                                 + np.float32(INPUT_OFFSET))
            out.append(model(x).numpy())
    return np.concatenate(out).astype(np.float32) if out else np.zeros(0, np.float32)


def check_parity(net: nn.Module, onnx_path: str | Path, card: dict[str, Any], images: NDArray[np.uint8],
                 tolerance: float = PARITY_TOLERANCE) -> float:
    """Largest |onnxruntime - torch| P(grasp) over images; ValueError if above tolerance."""

    clf = OnnxGraspClassifier(onnx_path, card, threads=1)
    diff = float(np.max(np.abs(clf.score(images) - torch_scores(net, images)), initial=0.0))
    if not diff <= tolerance:
        raise ValueError(f"ONNX parity failed for {onnx_path}: max |ort - torch| = {diff:.2e} > {tolerance:.0e}")
    return diff


def save_weights(net: nn.Module, path: str | Path, architecture: str, channels: int, image_size: int,
                 network: dict[str, Any]) -> Path:
    """Write the torch weights beside the ONNX file (models/NAME.pt), so that a shipped model can be fine-tuned
    (TrainConfig.init_from) or reloaded (loop.load_weights)."""
    path = Path(path)
    torch.save({"state_dict": net.state_dict(), "architecture": architecture, "channels": channels,
                "image_size": image_size, "network": dict(network)}, path)
    return path


def paths_relative_to(value: Any, root: Path) -> Any:
    """value (a model card, or any part of one) with every absolute path under root written relative to it (root
    itself as "."): a dataset given as /checkout/data/generated/gpd15 is recorded as data/generated/gpd15."""
    if isinstance(value, str):
        prefix = re.escape(str(root).rstrip("/"))
        inside = rf"(?<![\w.~/:]){prefix}/(?=[\w.+\-@%])"  # a path below root: drop root and its slash
        itself = rf"(?<![\w.~/:]){prefix}/?(?![\w.+\-@%/])"  # root itself
        return re.sub(itself, ".", re.sub(inside, "", value))
    if isinstance(value, dict):
        return {k: paths_relative_to(v, root) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [paths_relative_to(v, root) for v in value]
    return value


def write_card(path: str | Path, card: dict[str, Any], root: str | Path | None = None) -> Path:
    """Write a model card as indented JSON with no directory of this machine in it: paths under root (default:
    the working directory, where `graspd train` runs, the repository's root) relative to it, any other absolute
    path cut to its last part (card_without_paths).  The card ships with the model and is shown by GET /models."""
    path = Path(path)
    relative = paths_relative_to(card, Path(root if root is not None else Path.cwd()).resolve())
    path.write_text(json.dumps(card_without_paths(relative), indent=2, sort_keys=False) + "\n")
    return path


def base_card(name: str, representation: str, channels: int, image_size: int, architecture: str,
              hand: dict[str, float], channel_names: list[str]) -> dict[str, Any]:
    """The card fields fixed by the export: what goes in, what comes out, what geometry it assumes."""
    return {
        "name": name,
        "format": "graspd-model-card/1",
        "representation": representation,
        "channels": channels,
        "channel_layout": channel_names,
        "image_size": image_size,
        "architecture": architecture,
        "hand": hand,
        "input": {
            "name": INPUT_NAME, "dtype": "float32", "layout": "NCHW", "shape": ["batch", channels, image_size,
                                                                                image_size],
            "source": "graspd.gpd.images.encode_images uint8 images",
            "scale": INPUT_SCALE, "offset": INPUT_OFFSET,
            "formula": "x = uint8_pixel * scale + offset",
        },
        "output": {
            "name": OUTPUT_NAME, "dtype": "float32", "shape": ["batch"],
            "meaning": "probability that the candidate is an antipodal grasp (softmax of class 1)",
            "range": [0.0, 1.0],
        },
    }
