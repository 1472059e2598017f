"""The model registry: whatever graspd.classifier loads from the models folder, by name, plus the
detector for each (and the unscored detector when there is no model)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from graspd.detector import GraspDetector

from .problems import Problem

log = logging.getLogger("graspd.server")


@dataclass
class ModelRegistry:
    """Classifiers by name and the default name (None: no model, detections come back unscored)."""

    classifiers: dict[str, Any] = field(default_factory=dict)
    default: str | None = None
    load_error: str | None = None
    _detectors: dict[str | None, GraspDetector] = field(default_factory=dict)

    @classmethod
    def load(cls, models_dir: Path, default: str | None = None, threads: int = 1) -> ModelRegistry:
        """Load every model in models_dir through graspd.classifier.load_models; a folder without models
        gives an empty registry (the service then runs unscored and says so)."""
        from graspd import classifier

        try:
            models = dict(classifier.load_models(models_dir, threads=threads))
        except Exception as exc:  # a broken model must not stop the service; /readyz reports it
            log.error("model loading failed", extra={"models_dir": str(models_dir), "error": str(exc)})
            return cls(load_error=f"{type(exc).__name__}: {exc}")
        if default is not None and default not in models:
            return cls(models, None, load_error=f"default model {default!r} not in {sorted(models)}")
        if default is None and models:
            preferred = classifier.default_model_name()
            default = preferred if preferred in models else sorted(models)[0]
        return cls(models, default)

    def names(self) -> list[str]:
        return sorted(self.classifiers)

    def resolve(self, name: str | None) -> str | None:
        """The model a request gets: its own (422 naming 'model' if unknown) or the default."""
        if name is None:
            return self.default
        if name not in self.classifiers:
            raise Problem(422, f"unknown model {name!r}; known: {self.names()}", "model")
        return name

    def detector(self, name: str | None) -> GraspDetector:
        if name not in self._detectors:
            self._detectors[name] = GraspDetector(None if name is None else self.classifiers[name])
        return self._detectors[name]

    def describe(self) -> dict[str, Any]:
        return {
            "default": self.default,
            "models": [
                {"name": n, "representation": str(getattr(c, "representation", "")), "default": n == self.default,
                 "card": dict(getattr(c, "card", {}))}
                for n, c in sorted(self.classifiers.items())
            ],
        }
