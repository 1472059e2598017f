"""Shim: moved to graspd.world.render and graspd.world.cameras (issue 12); kept for an importer not yet
updated (tests/core/test_environment.py)."""

from ..world.cameras import tabletop_cameras
from ..world.render import render_scene

__all__ = ["render_scene", "tabletop_cameras"]
