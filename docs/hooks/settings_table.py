"""MkDocs hook: the table of every service setting, made at build time from graspd.server.settings.Settings (its
fields, defaults and descriptions), so the configuration page lists each GRASPD_* variable the server reads.

A page asks for it with the line ``<!-- graspd-settings -->``."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
MARKER = "<!-- graspd-settings -->"


def load_settings() -> Any:
    """graspd's Settings class, from this checkout."""
    for folder in ("client", "service"):
        if str(ROOT / folder) not in sys.path:
            sys.path.insert(0, str(ROOT / folder))
    from graspd.server.settings import Settings  # noqa: PLC0415 (the checkout's service, found at build time)

    return Settings


def cell(text: object) -> str:
    """Text made safe for one Markdown table cell: one line, pipes escaped, and angle brackets outside code spans
    shown as text (a description's `<name>.onnx` is not an HTML tag, its `{"preset": string}` no attribute list)."""
    parts = re.sub(r"\s*\n\s*", " ", str(text)).replace("|", "\\|").strip().split("`")
    return "`".join(part if i % 2 else part.replace("<", "&lt;").replace(">", "&gt;").replace("{", "&#123;")
                    for i, part in enumerate(parts))


def type_name(annotation: Any) -> str:
    """A short name of a field's type: int, float, str, bool, Path, a union, a literal's values."""
    text = getattr(annotation, "__name__", None) if not getattr(annotation, "__args__", None) else None
    text = text or str(annotation)
    text = re.sub(r"\b(typing|pathlib|collections\.abc)\.", "", text)
    return text.replace("NoneType", "None")


def default_text(field: Any) -> str:
    """The default as JSON, or a note for a default computed when the server starts."""
    if field.default_factory is not None:
        try:
            value = field.default_factory()
        except TypeError:
            return "computed at start"
        if value in ({}, [], ()):
            return f"`{json.dumps(value)}`"
        return "computed at start"
    if field.default is None:
        return "none"
    value = field.default
    if isinstance(value, Path):
        value = str(value)
    try:
        return f"`{json.dumps(value)}`"
    except TypeError:
        return f"`{value}`"


def settings_table(settings: Any) -> str:
    """Every field of Settings as a row: the variable, its type, its default, its description."""
    prefix = settings.model_config.get("env_prefix", "")
    rows = ["| variable | type | default | meaning |", "|---|---|---|---|"]
    for name, field in settings.model_fields.items():
        rows.append(f"| `{prefix}{name.upper()}` | {cell(type_name(field.annotation))} | {cell(default_text(field))} "
                    f"| {cell(field.description or '')} |")
    return "\n".join(rows) + "\n"


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, settings_table(load_settings()))
