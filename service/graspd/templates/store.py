"""Where the grasp library's names lived before the split: graspd.database (schema, migrations, engines,
redaction), graspd.outcomes (the outcome store) and graspd.templates.library (the library).

Kept only for importers not yet moved (graspd.server.templates_service, graspd.training.train,
tests/server, tests/training); delete it once they import from those modules.
"""

from __future__ import annotations

from ..database import MIGRATIONS, SCHEMA_VERSION, make_engine, migrate, redact_text, redact_url
from ..outcomes import Feedback
from .geometry import TemplateError
from .library import DEFAULT_URL, LibrarySnapshot, TemplateLibrary, UnknownGrasp, parse_grasp_id

__all__ = [
    "DEFAULT_URL",
    "MIGRATIONS",
    "SCHEMA_VERSION",
    "Feedback",
    "LibrarySnapshot",
    "TemplateError",
    "TemplateLibrary",
    "UnknownGrasp",
    "make_engine",
    "migrate",
    "parse_grasp_id",
    "redact_text",
    "redact_url",
]
