"""Step 5 of Algorithm 1: score grasp images with a trained CNN, run through onnxruntime: on a CUDA GPU when
onnxruntime offers the CUDA execution provider (the onnxruntime-gpu package), else on the CPU.

A shipped model is two files in the models folder: ``<name>.onnx`` (float32 input "images" of shape
(batch, C, S, S), output "score" of shape (batch,), the probability that the candidate is a grasp)
and ``<name>.json``, its model card (representation, image size, hand geometry, input scaling,
metrics, how it was made).  The images (uint8, graspd.gpd.images.encode_images) are scaled as the card
says, ``x = images * input.scale + input.offset``, before they enter the network.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from graspd.core.hand import HandGeometry, hand_preset

#: The model the service uses when none is named: container15 fine-tuned on scenes half of household objects at their
#: true size, with Kinect, stereo and time-of-flight noise (models/plan-household.json); 15-channel images, GPD hand.
DEFAULT_MODEL_NAME = "household15"

#: Hands a model serves though its grasp images were made for another hand, because the benchmarks chose it over
#: the model made for that hand (model name -> hands).  household15 (GPD-hand images) against panda15 and robotiq15
#: (each made for its preset's images), with that preset, on the training household objects at true size
#: (bench/results/*-household-training-*-{panda,robotiq}-*.md; success / cleared): Panda piles 91/90 against 86/89,
#: packed 91/92 against 87/90, trays 80/78 against 71/71, deep bins 82/78 against 76/71; Robotiq 2F-85 piles 90/90
#: against 89/87, packed 95/94 against 88/88, trays 79/82 against 74/65, deep bins 80/67 against 82/77.  The
#: Panda-like hand (the Panda preset opening 75 mm) is the one the held-out household figures are measured with.
MEASURED_HANDS: dict[str, tuple[HandGeometry, ...]] = {
    "household15": (hand_preset("panda"), hand_preset("panda").with_opening(0.075), hand_preset("robotiq_2f85")),
}

#: Environment variable that overrides the models folder.
MODELS_DIR_ENV = "GRASPD_MODELS_DIR"
_REQUIRED_CARD_KEYS = ("name", "representation", "channels", "image_size", "input", "output")


class ModelError(ValueError):
    """A model or model card that is missing, unknown or malformed."""


@runtime_checkable
class GraspClassifier(Protocol):
    """Anything that maps grasp images (M, C, S, S) uint8 to grasp probabilities (M,) float32 in [0, 1]."""

    name: str
    representation: str
    card: dict[str, Any]

    def score(self, images: NDArray[np.uint8]) -> NDArray[np.float32]: ...


#: The hand fields a grasp image depends on (its closing region): a model scores images of one hand.
IMAGE_HAND_FIELDS = ("finger_width", "hand_outer_diameter", "hand_depth", "hand_height")


#: An absolute POSIX path in text: a card written on a build machine may name where it was trained.
_ABSOLUTE_PATH = re.compile(r"(?<![\w.~/:])/(?:[\w.+\-@%]+/)+(?P<name>[\w.+\-@%]*)")


def card_without_paths(value: Any) -> Any:
    """value (a model card, or any part of one) with every absolute path cut to its last part, so that an
    answer never names a directory of the machine that trained or serves the model."""
    if isinstance(value, str):
        return _ABSOLUTE_PATH.sub(lambda m: m["name"] or ".", value)
    if isinstance(value, dict):
        return {k: card_without_paths(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [card_without_paths(v) for v in value]
    return value


def card_fits_hand(card: dict[str, Any], hand: dict[str, float]) -> bool:
    """Whether a model card's hand makes the same grasp images as `hand` (a HandGeometry.to_dict()): equal on
    every IMAGE_HAND_FIELDS field to 0.1 mm.  A card without a hand fits nothing."""
    made_for = card.get("hand")
    return isinstance(made_for, dict) and _same_images(made_for, hand)


def _same_images(a: dict[str, Any], b: dict[str, float]) -> bool:
    """Whether two hands (HandGeometry.to_dict()) make the same grasp images: equal on IMAGE_HAND_FIELDS to 0.1 mm."""
    return all(abs(float(a.get(k, float("nan"))) - float(b[k])) <= 1e-4 for k in IMAGE_HAND_FIELDS)


def card_serves_hand(card: dict[str, Any], hand: dict[str, float]) -> bool:
    """Whether a model serves `hand` (a HandGeometry.to_dict()): its grasp images were made for it
    (card_fits_hand), or the benchmarks chose it for that hand (MEASURED_HANDS, by the card's name)."""
    measured = MEASURED_HANDS.get(str(card.get("name", "")), ())
    return card_fits_hand(card, hand) or any(_same_images(h.to_dict(), hand) for h in measured)


#: The cascade's cheap first pass: scores every candidate so the full model scores only the best.
DEFAULT_CASCADE_MODEL = "scene3"


def cascade_prefilter(model: Any, first: Any | None) -> Any | None:
    """The first pass to use with `model`: `first` when it is another classifier made for the same hand
    (card_fits_hand on the images' hand fields), else None (no cascade)."""
    if first is None or model is None or first is model:
        return None
    made_for = dict(getattr(model, "card", {})).get("hand")
    if not isinstance(made_for, dict) or not card_fits_hand(dict(getattr(first, "card", {})), made_for):
        return None
    return first


def default_model_name() -> str:
    """Name of the default model (the generic 15-channel classifier)."""
    return DEFAULT_MODEL_NAME


def default_models_dir() -> Path:
    """The models folder: $GRASPD_MODELS_DIR if set, else models/ at the repository root (3 folders up)."""
    env = os.environ.get(MODELS_DIR_ENV)
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "models"


def available_models(models_dir: str | Path | None = None) -> list[str]:
    """Names of the models in a folder (each an .onnx file with a .json card beside it), sorted."""
    folder = Path(models_dir) if models_dir is not None else default_models_dir()
    if not folder.is_dir():
        return []
    return sorted(p.stem for p in folder.glob("*.onnx") if p.with_suffix(".json").is_file())


def read_card(path: str | Path) -> dict[str, Any]:
    """A model card (JSON) checked for the keys the classifier needs; ModelError names what is wrong."""
    path = Path(path)
    try:
        card = json.loads(path.read_text())
    except FileNotFoundError:
        raise ModelError(f"model card {path} does not exist") from None
    except json.JSONDecodeError as exc:
        raise ModelError(f"model card {path} is not valid JSON: {exc}") from None
    if not isinstance(card, dict):
        raise ModelError(f"model card {path} must be a JSON object")
    missing = [k for k in _REQUIRED_CARD_KEYS if k not in card]
    if missing:
        raise ModelError(f"model card {path} lacks {missing}")
    for key in ("scale", "offset"):
        if not isinstance(card["input"].get(key), int | float):
            raise ModelError(f"model card {path}: input.{key} must be a number")
    return card


#: Images per onnxruntime run by default: small batches keep a network's activations in the CPU's caches (32
#: images cost ~28% less CPU per image than 600 for the shipped networks), and scores do not depend on it.
RUN_BATCH = 32
#: Environment variable naming the execution provider to use ("cpu" forces the CPU where a GPU is offered).
PROVIDER_ENV = "GRASPD_ORT_PROVIDER"
#: The GPU execution providers used when onnxruntime offers them, in order of preference.
GPU_PROVIDERS = ("CUDAExecutionProvider",)
CPU_PROVIDER = "CPUExecutionProvider"


def choose_providers(available: list[str] | None = None) -> list[str]:
    """The execution providers a session gets: the first of GPU_PROVIDERS onnxruntime offers, then the CPU (the
    fallback for operators the GPU lacks), or the CPU alone; $GRASPD_ORT_PROVIDER=cpu forces the CPU."""
    if available is None:
        import onnxruntime as ort  # noqa: PLC0415

        available = list(ort.get_available_providers())
    if os.environ.get(PROVIDER_ENV, "").strip().lower() == "cpu":
        return [CPU_PROVIDER]
    gpu = [p for p in GPU_PROVIDERS if p in available]
    return [gpu[0], CPU_PROVIDER] if gpu else [CPU_PROVIDER]


class OnnxGraspClassifier:
    """A grasp classifier backed by an ONNX network run by onnxruntime (choose_providers: a CUDA GPU when
    offered, else the CPU); `provider` names the one the session uses, also given in the card as
    card["runtime"]["provider"].

    threads: onnxruntime intra-op threads (0 = onnxruntime's choice); batch_size: images per run,
    bounding the float32 buffer to batch_size * C * S * S * 4 bytes.
    """

    def __init__(self, onnx_path: str | Path, card: dict[str, Any] | None = None, threads: int = 2,
                 batch_size: int = RUN_BATCH) -> None:
        import onnxruntime as ort  # noqa: PLC0415

        self.path = Path(onnx_path)
        if not self.path.is_file():
            raise ModelError(f"model file {self.path} does not exist")
        if threads < 0:
            raise ModelError(f"threads must be >= 0, got {threads}")
        if batch_size < 1:
            raise ModelError(f"batch_size must be >= 1, got {batch_size}")
        card = card if card is not None else read_card(self.path.with_suffix(".json"))
        self.name: str = str(card["name"])
        self.representation: str = str(card["representation"])
        self.channels = int(card["channels"])
        self.image_size = int(card["image_size"])
        self.scale = np.float32(card["input"]["scale"])
        self.offset = np.float32(card["input"]["offset"])
        self.batch_size = batch_size
        self.threads = threads  # intra-op threads of one run (0: onnxruntime's choice, every core)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        # intra-op threads (threads > 1) wait on a lock, not spinning: the process's other detections need the cores
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(self.path), opts, providers=choose_providers())
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ModelError(f"model file {self.path} could not be loaded by onnxruntime: {exc}") from None
        self.provider: str = str(self.session.get_providers()[0])
        self.card: dict[str, Any] = {**card, "runtime": {"provider": self.provider, "threads": threads}}
        self.input_name = self.session.get_inputs()[0].name
        self.output_name = self.session.get_outputs()[0].name

    def __repr__(self) -> str:
        return f"OnnxGraspClassifier(name={self.name!r}, representation={self.representation!r}, path={self.path})"

    def check_images(self, images: NDArray[Any]) -> None:
        """ValueError naming 'images' unless they are uint8 (M, C, S, S) matching this model's card."""
        if not isinstance(images, np.ndarray) or images.dtype != np.uint8:
            raise ValueError(f"images must be a uint8 numpy array, got {getattr(images, 'dtype', type(images))}")
        want = (self.channels, self.image_size, self.image_size)
        if images.ndim != 4 or images.shape[1:] != want:
            raise ValueError(
                f"images must have shape (M, {want[0]}, {want[1]}, {want[2]}) for model {self.name!r} "
                f"(representation {self.representation!r}), got {images.shape}"
            )

    def score(self, images: NDArray[np.uint8]) -> NDArray[np.float32]:
        """Probability (M,) float32 in [0, 1] that each grasp image shows a grasp."""
        self.check_images(images)
        out = np.empty(len(images), np.float32)
        for a in range(0, len(images), self.batch_size):
            # images * scale + offset in float32, in two passes (the cast happens inside the multiplication)
            batch = np.multiply(images[a : a + self.batch_size], self.scale, dtype=np.float32)
            batch += self.offset
            res = self.session.run([self.output_name], {self.input_name: batch})[0]
            out[a : a + len(batch)] = np.asarray(res, np.float32).reshape(-1)
        return np.clip(out, 0.0, 1.0, out=out)


def load_model(path_or_name: str | Path, models_dir: str | Path | None = None, threads: int = 2,
               batch_size: int = RUN_BATCH) -> OnnxGraspClassifier:
    """A model by name (models_dir/<name>.onnx + .json) or by the path of its .onnx file.

    ModelError names the unknown model and lists the known ones.
    """
    candidate = Path(path_or_name)
    if candidate.suffix == ".onnx" or candidate.is_file():
        onnx_path = candidate
    else:
        folder = Path(models_dir) if models_dir is not None else default_models_dir()
        onnx_path = folder / f"{path_or_name}.onnx"
        if not onnx_path.is_file() or not onnx_path.with_suffix(".json").is_file():
            known = available_models(folder)
            raise ModelError(f"unknown model {str(path_or_name)!r} in {folder}; known models: {known}")
    if not onnx_path.is_file():
        raise ModelError(f"model file {onnx_path} does not exist")
    return OnnxGraspClassifier(onnx_path, read_card(onnx_path.with_suffix(".json")), threads=threads,
                               batch_size=batch_size)


def load_models(models_dir: str | Path | None = None, threads: int = 2,
                batch_size: int = RUN_BATCH) -> dict[str, OnnxGraspClassifier]:
    """Every model in a folder, by name."""
    folder = Path(models_dir) if models_dir is not None else default_models_dir()
    return {name: load_model(name, folder, threads=threads, batch_size=batch_size)
            for name in available_models(folder)}


def model_candidates(models_dir: str | Path | None = None) -> list[str]:
    """Names a folder means to ship: every .onnx file, and every model card (a JSON object with a
    "representation" key) even without its .onnx, so that a deleted network is reported, not ignored."""
    folder = Path(models_dir) if models_dir is not None else default_models_dir()
    if not folder.is_dir():
        return []
    names = {p.stem for p in folder.glob("*.onnx")}
    for card in folder.glob("*.json"):
        if card.stem in names:
            continue
        try:
            text = json.loads(card.read_text())
        except (OSError, ValueError):
            continue  # a file that is not a card at all (plan.json and the like)
        if isinstance(text, dict) and "representation" in text:
            names.add(card.stem)
    return sorted(names)


def load_models_checked(models_dir: str | Path | None = None, threads: int = 2, batch_size: int = RUN_BATCH
                        ) -> tuple[dict[str, OnnxGraspClassifier], dict[str, str]]:
    """Every model in a folder, each loaded on its own: (the models that load, {name: why} for the rest).

    A truncated, empty or corrupt .onnx, a broken card or a card without its .onnx fails only that model.
    """
    folder = Path(models_dir) if models_dir is not None else default_models_dir()
    models: dict[str, OnnxGraspClassifier] = {}
    errors: dict[str, str] = {}
    for name in model_candidates(folder):
        onnx_path, card_path = folder / f"{name}.onnx", folder / f"{name}.json"
        try:
            if not onnx_path.is_file():
                raise ModelError(f"model file {onnx_path} does not exist (its card {card_path.name} does)")
            if not card_path.is_file():
                raise ModelError(f"model card {card_path} does not exist (its network {onnx_path.name} does)")
            model = OnnxGraspClassifier(onnx_path, read_card(card_path), threads=threads, batch_size=batch_size)
            probe = model.score(np.zeros((1, model.channels, model.image_size, model.image_size), np.uint8))
            if probe.shape != (1,) or not np.isfinite(probe).all():  # loads, but does not score as its card says
                raise ModelError(f"model {name!r} gave {probe!r} for one blank image, not one probability")
            models[name] = model
        except Exception as exc:  # onnxruntime and a malformed card raise many types; each model fails alone
            errors[name] = str(exc) if isinstance(exc, ModelError) else f"{type(exc).__name__}: {exc}"
    return models, errors
