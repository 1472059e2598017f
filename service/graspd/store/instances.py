"""What instance models share between training (graspd_lab.training.instance, `graspd train --instance`) and the
server (POST /models), without torch: the names a model may take, the categories with a category model, the
base model of each, and the progress lines a training job prints (JSON, one event per line)."""

from __future__ import annotations

import json
import re
from typing import Any

from graspd.core.errors import FieldError

#: The base model of an instance: the generic model, or the category model of its category.
BASE_MODELS: dict[str | None, str] = {None: "generic15", "box": "box15", "cylinder": "cylinder15"}
#: Categories an instance may name (those with a category model).
INSTANCE_CATEGORIES = ("box", "cylinder")
#: Model names an instance may take: a file stem, no path.
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
#: Prefix of a progress line on a job's stdout (`graspd train --instance ... --progress-json`).
PROGRESS_PREFIX = "graspd-progress "


class InstanceError(FieldError):
    """An instance request that cannot be made; .field names the option (name, category, views, mesh, ...)."""


def check_name(name: Any) -> str:
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
        raise InstanceError("name", f"must be 1-64 letters, digits, '_' or '-' starting with a letter or digit "
                            f"(a file stem), got {name!r}")
    return name


def check_category(category: Any) -> str | None:
    if category is not None and category not in INSTANCE_CATEGORIES:
        raise InstanceError("category", f"must be one of {list(INSTANCE_CATEGORIES)} or none, got {category!r}")
    return category


def progress_line(event: dict[str, Any]) -> str:
    """One progress event as the line a job prints."""
    return PROGRESS_PREFIX + json.dumps(event, separators=(",", ":"))


def parse_progress(line: str) -> dict[str, Any] | None:
    """The event of a progress line, None for any other line."""
    if not line.startswith(PROGRESS_PREFIX):
        return None
    try:
        event = json.loads(line[len(PROGRESS_PREFIX):])
    except ValueError:
        return None
    return event if isinstance(event, dict) else None
