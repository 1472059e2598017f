"""The training configuration (TrainConfig) and the graspd command line that reproduces one."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from sqlalchemy.engine import make_url

from graspd.gpd.images import REPRESENTATIONS
from graspd_lab.training.dataset import CATEGORIES
from graspd_lab.training.network import ARCHITECTURES


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
    resume: bool = False                      # continue from out_dir/last.pt when its config matches
    init_from: str | None = None              # fine-tune: a .pt path (checkpoint or models/NAME.pt) or a model name
    hard_negatives: float = 0.0               # > 0: oversample this top fraction of negatives by score from epoch 2
    calibrate: bool = True                    # fit Platt scaling on the val rows and fold it into the last layer

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
        if not 0.0 <= self.hard_negatives < 1.0:
            raise ValueError(f"hard_negatives must be in [0, 1), got {self.hard_negatives}")
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate must be > 0, got {self.learning_rate}")
        if self.categories is not None:
            bad = [c for c in self.categories if c not in CATEGORIES]
            if bad:
                raise ValueError(f"categories must be among {list(CATEGORIES)}, got {bad}")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        """A config from a dict (plans, checkpoints, cards); fields added later take their defaults."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown training config fields {unknown}; known: {sorted(known)}")
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def resumable_with(self, other: dict[str, Any]) -> list[str]:
        """The fields (other than resume and max_minutes) in which a stored config differs from this one."""
        mine, theirs = self.to_dict(), TrainConfig.from_dict(other).to_dict()
        return sorted(k for k in mine if k not in RESUME_FREE and mine[k] != theirs[k])


#: Config fields an interrupted run may change when it is resumed.
RESUME_FREE = ("resume", "max_minutes")


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
        parts += ["--feedback", make_url(config.feedback).render_as_string(hide_password=True),
                  "--feedback-repeat", str(config.feedback_repeat)]
    if config.init_from is not None:
        parts += ["--init-from", config.init_from]
    if config.hard_negatives > 0:
        parts += ["--hard-negatives", str(config.hard_negatives)]
    if not config.calibrate:
        parts += ["--no-calibrate"]
    return " ".join(parts)
