"""The models endpoints' answers on the wire (GET /models, POST /models): the classifiers and the instance-model
jobs."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field


class ModelInfo(BaseModel):
    name: str
    representation: str
    default: bool
    card: dict[str, Any]
    measured_hands: list[dict[str, float]] = Field(
        default_factory=list, description="hands the model also serves though its card's hand (its grasp images) "
        "is another: the benchmarks chose it for them over the model made for each (HandGeometry fields, m); a "
        "request carrying one gets no model_hand_mismatch warning")


class InstanceJobOut(BaseModel):
    """An instance model being made (POST /models): a classifier fine-tuned for one uploaded mesh."""

    id: str = Field(description="the job's id")
    name: str = Field(description="the model's name: POST /detect selects it with model=name once state is done")
    category: Literal["box", "cylinder"] | None = Field(description="the object's category: the category model "
                                                         "was fine-tuned; none: the generic one")
    hand: str = Field(description="hand preset the grasp images are made for")
    base_model: str | None = Field(description="the model fine-tuned (None: trained from scratch)")
    state: Literal["queued", "running", "done", "failed"]
    stage: Literal["dataset", "training", "evaluating", "loading", "done"] | None = Field(
        description="while running: rendering and labelling views, fine-tuning, comparing, loading the model")
    view: int | None = Field(description="views rendered and labelled so far")
    views: int | None = Field(description="views to render")
    epoch: int | None = Field(description="fine-tuning epochs finished")
    epochs: int | None = Field(description="most epochs (training stops earlier at its time budget)")
    created_at: float = Field(description="UNIX time the job was queued (s)")
    elapsed_s: float = Field(description="running time so far, or until it finished (s)")
    error: str | None = Field(description="why it failed")
    field: str | None = Field(description="the request field at fault when it failed (e.g. mesh)")


class ModelsResponse(BaseModel):
    default: str | None
    cascade: str | None = Field(None, description="the cascade's first-pass model (GRASPD_CASCADE_MODEL), used "
                                "with the models made for its hand; null: no cascade")
    models: list[ModelInfo]
    jobs: list[InstanceJobOut] = Field(default_factory=list, description="instance models queued, being made "
                                       "or made by this server process (POST /models), oldest first")
