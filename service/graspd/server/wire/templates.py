"""The grasp-template endpoints on the wire (POST /demonstrations, POST /feedback, GET /library): requests and
answers."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, field_validator

from .arrays import Matrix4
from .detect import Cloud, DetectRequest, Hand


class DemonstrationRequest(BaseModel):
    """POST /demonstrations: a cloud of the table and one object, and the grasp demonstrated on it."""

    model_config = ConfigDict(extra="forbid")
    cloud: Cloud
    hand_pose: Matrix4 = Field(description="demonstrated hand pose (4x4, cloud frame, the grasp convention: "  # type: ignore[valid-type]
                               "rotation columns [approach, binormal, axis], translation the hand-base centre)")
    # (orthonormal and right-handed: the templates check it, services.templates)
    hand: Hand | None = Field(None, description="the demonstrating hand; must be the library's (GET /library)")
    label: str | None = Field(None, max_length=200, description="what was grasped, for people")
    workspace: list[Annotated[float, Field(allow_inf_nan=False)]] | None = Field(
        None, min_length=6, max_length=6, description="[xmin, xmax, ymin, ymax, zmin, zmax] (m, cloud frame): crop")

    _workspace = field_validator("workspace")(DetectRequest._workspace.__func__)  # type: ignore[attr-defined]
    _hand = field_validator("hand", mode="before")(DetectRequest._hand.__func__)  # type: ignore[attr-defined]


class FeedbackRequest(BaseModel):
    """POST /feedback: the outcome of executing a grasp this service returned."""

    model_config = ConfigDict(extra="forbid")
    grasp_id: str = Field(min_length=1, max_length=100, description="the grasp's id from a detect response")
    success: StrictBool = Field(description="whether the robot held the object")


class LibraryEntryOut(BaseModel):
    id: int
    label: str | None
    created_at: float = Field(description="UNIX time (s)")
    failures: int = Field(description="size of the entry's failure set F_l")
    outcomes: int = Field(description="outcomes reported for grasps from this entry")
    successes: int


class LibraryCounts(BaseModel):
    num_entries: int
    num_failures: int = Field(description="templates in all failure sets")
    num_outcomes: int = Field(description="outcomes stored (template and GPD grasps)")
    num_successes: int
    num_images: int = Field(description="outcomes stored with their GPD grasp image (for fine-tuning)")
    num_detections: int = Field(description="template detections whose grasps feedback can name")


class LibraryResponse(LibraryCounts):
    schema_version: int
    hand: dict[str, float] = Field(description="the hand the library is made for (m)")
    template: dict[str, Any] = Field(description="template geometry: n tiles a side, size (m), ...")
    entries: list[LibraryEntryOut]


class DemonstrationResponse(BaseModel):
    entry_id: int = Field(description="the new library entry")
    library: LibraryCounts


class FeedbackResponse(BaseModel):
    grasp_id: str
    method: Literal["gpd", "templates"] = Field(description="the detector that returned the grasp")
    success: bool
    outcome_id: int = Field(description="the stored outcome")
    entry_id: int | None = Field(description="templates: the library entry the grasp came from")
    failure_added: bool = Field(description="templates: the candidate's template joined F_l of that entry")
    image_stored: bool = Field(description="the outcome was stored with the grasp's 15-channel GPD image")
