"""tests/sim drive the pybullet benchmark: skipped where the optional extra graspd[sim] is not installed."""

import importlib.util

collect_ignore_glob = [] if importlib.util.find_spec("pybullet") else ["test_*.py"]
