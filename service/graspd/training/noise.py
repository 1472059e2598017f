"""Shim: moved to graspd.world.noise (issue 12); kept for an importer not yet updated
(tests/core/test_environment.py)."""

from ..world.noise import DepthNoise

__all__ = ["DepthNoise"]
