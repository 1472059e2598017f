"""The model registry: the classifiers of the models folder, each loaded on its own, by name, plus the detector
for each.  A model that fails to load is reported by name (and why) in /readyz and the log while the others
serve; the default model missing or broken makes the service not ready, and requests that would use it get
a 503 naming `model` instead of silently unscored grasps."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from graspd.core.hand import HandGeometry
from graspd.gpd import classifier
from graspd.gpd.detector import GraspDetector
from graspd.server.problems import Problem
from graspd.store.database import scrub

log = logging.getLogger("graspd.server")


@dataclass
class ModelRegistry:
    """Classifiers by name; `default` is the loaded default model's name (None when it did not load, or, with
    allow_unscored, when there is none: then requests naming no model come back unscored)."""

    classifiers: dict[str, Any] = field(default_factory=dict)
    default: str | None = None
    load_error: str | None = None  # the default model's problem, when the service cannot be ready
    errors: dict[str, str] = field(default_factory=dict)  # models that failed to load: name -> why
    wanted_default: str | None = None  # the configured (or built-in) default name
    allow_unscored: bool = False
    cascade: str | None = None  # the cascade's first-pass model (a loaded model's name), or None
    _detectors: dict[str | None, GraspDetector] = field(default_factory=dict)

    @classmethod
    def load(cls, models_dir: Path, default: str | None = None, threads: int = 1,
             allow_unscored: bool = False, cascade: str | None = None) -> ModelRegistry:
        """Load every model in models_dir, each on its own (graspd.gpd.classifier.load_models_checked); failures
        are logged at ERROR by name.  default: the configured default name, else classifier's default.
        cascade: the first-pass model's name (used only if it loaded; else logged and off)."""

        models, errors = classifier.load_models_checked(models_dir, threads=threads)
        errors = {name: scrub(why) for name, why in errors.items()}  # answers and logs hold no path
        for name, why in sorted(errors.items()):
            log.error("model failed to load", extra={"model": name, "error": why})
        wanted = default or classifier.default_model_name()
        load_error = None
        if wanted in errors:
            load_error = f"default model {wanted!r} failed to load: {errors[wanted]}"
        elif wanted not in models and not (allow_unscored and default is None):
            load_error = (f"default model {wanted!r} is not in the models folder (GRASPD_MODELS_DIR; models there: "
                          f"{sorted(models)})")
        if load_error is not None:
            log.error("default model unavailable: not ready", extra={"model": wanted, "error": load_error})
        if cascade is not None and cascade not in models:
            log.warning("cascade model not loaded: no cascade", extra={"model": cascade})
            cascade = None
        return cls(models, wanted if wanted in models else None, load_error, errors, wanted, allow_unscored, cascade)

    def names(self) -> list[str]:
        return sorted(self.classifiers)

    def fits(self, name: str | None, hand: HandGeometry) -> bool | None:
        """Whether model `name` serves this hand: trained on its grasp images, or chosen for it by the benchmarks
        (graspd.gpd.classifier.card_serves_hand; None: no model, unscored)."""
        if name is None or name not in self.classifiers:
            return None
        return classifier.card_serves_hand(dict(getattr(self.classifiers[name], "card", {})), hand.to_dict())

    def is_instance(self, name: str) -> bool:
        """Whether a model was made for one object (an instance model: its card has "instance"); such a model
        serves only requests that name it."""
        return "instance" in dict(getattr(self.classifiers.get(name), "card", {}) or {})

    def resolve(self, name: str | None, scoring: bool = True, hand: HandGeometry | None = None) -> str | None:
        """The model a request gets: its own, else the default, unless the default does not serve the request's
        hand (fits) and a loaded model does (then that one, by name; never an instance model).  A
        name that is not in the folder is a 422 naming 'model'; one that failed to load, or a missing default while
        scoring was asked for, is a 503 naming 'model'.  With scoring False (use_classifier false) a missing default is
        no error."""
        if name is None and scoring and hand is not None and self.fits(self.default, hand) is False:
            fitting = [n for n in self.names() if self.fits(n, hand) and not self.is_instance(n)]
            if fitting:
                return fitting[0]
        if name is not None:
            if name in self.classifiers:
                return name
            if name in self.errors:
                raise Problem(503, f"model {name!r} is unavailable: it failed to load ({self.errors[name]})",
                              "model")
            raise Problem(422, f"unknown model {name!r}; known: {self.names()}", "model")
        if self.default is not None or not scoring:
            return self.default
        if self.load_error is None:  # allow_unscored and no default model: unscored by configuration
            return None
        raise Problem(503, f"{self.load_error}; name another model (GET /models) or set use_classifier false",
                      "model")

    def add(self, name: str, model: Any) -> None:
        """Serve a model loaded after start-up (an instance model POST /models made) under its name.  The
        classifier dict is replaced, not changed in place: requests reading it meanwhile see the old or the new."""
        self.classifiers = {**self.classifiers, name: model}
        self.errors = {k: v for k, v in self.errors.items() if k != name}
        self._detectors.pop(name, None)
        log.info("model added", extra={"model": name})

    def prefilter(self, name: str | None) -> Any:
        """The cascade's first pass for model `name` (graspd.gpd.classifier.cascade_prefilter), or None."""
        if name is None or self.cascade is None or name == self.cascade:
            return None
        return classifier.cascade_prefilter(self.classifiers.get(name), self.classifiers.get(self.cascade))

    def detector(self, name: str | None) -> GraspDetector:
        if name not in self._detectors:
            self._detectors[name] = GraspDetector(None if name is None else self.classifiers[name],
                                                  prefilter=self.prefilter(name))
        return self._detectors[name]

    def describe(self) -> dict[str, Any]:
        return {
            "default": self.default,
            "cascade": self.cascade,
            "models": [
                {"name": n, "representation": str(getattr(c, "representation", "")), "default": n == self.default,
                 "card": classifier.card_without_paths(dict(getattr(c, "card", {}))),
                 "measured_hands": [h.to_dict() for h in classifier.MEASURED_HANDS.get(n, ())]}
                for n, c in sorted(self.classifiers.items())
            ],
        }
