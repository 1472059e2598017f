"""tests/lab/sim drive the pybullet benchmark: skipped where the lab distribution graspd-lab is not installed."""

import importlib.util

collect_ignore_glob = [] if importlib.util.find_spec("pybullet") else ["test_*.py"]
