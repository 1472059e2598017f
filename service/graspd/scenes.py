"""Shim: moved to graspd.world.scenes (issue 12); kept for importers not yet updated (cli.py,
bench/perf.py, bench/load.py, tests/server/test_detect_options.py)."""

from .world.scenes import GRAVITY, cluttered_tabletop, subsample

__all__ = ["GRAVITY", "cluttered_tabletop", "subsample"]
