"""Time the ROS message layer (prints only): CloudSources encode/decode at 66k points and the four outputs at 100
grasps.  Run: python -m graspd.io.ros.bench [--points N] [--grasps M] [--repeat R]."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.io.ros.decode import decode_cloud_sources
from graspd.io.ros.encode import (
    encode_cloud_sources,
    encode_grasp_config_list,
    encode_marker_array,
    encode_moveit_grasps,
    encode_pose_array,
)
from graspd.io.ros.types import CLOUD_SOURCES, Header, typestore


def _best_ms(fn: Callable[[], Any], repeat: int) -> float:
    """Fastest of repeat runs, in milliseconds (after one warm-up run)."""
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * min(times)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--points", type=int, default=66_000)
    ap.add_argument("--grasps", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    n, m = args.points, args.grasps
    points = rng.random((n, 3)).astype(np.float32)
    views = np.array([[0.6, 0.0, 0.5], [-0.6, 0.0, 0.5]])
    src = rng.integers(0, 2, n)
    header = Header("base_link", (1, 2))
    payload = encode_cloud_sources(points, views, src, header)
    grasps = GraspSet(positions=rng.random((m, 3)), rotations=Rotation.random(m, random_state=1).as_matrix(),
                      widths=rng.random(m) * 0.08, scores=rng.random(m), samples=rng.random((m, 3)))
    hand = HandGeometry()
    rows = [
        (f"CloudSources encode ({n} points, {len(payload) / 1e6:.2f} MB)",
         lambda: encode_cloud_sources(points, views, src, header)),
        (f"CloudSources decode ({n} points)", lambda: decode_cloud_sources(payload)),
        (f"GraspConfigList encode ({m} grasps)", lambda: encode_grasp_config_list(grasps, header)),
        (f"PoseArray encode ({m} grasps)", lambda: encode_pose_array(grasps, header)),
        (f"MarkerArray encode ({m} grasps, {3 * m + 1} markers)", lambda: encode_marker_array(grasps, header, hand)),
        (f"moveit_msgs/Grasp encode ({m} messages)", lambda: encode_moveit_grasps(grasps, header)),
    ]
    if n <= 100_000:  # rosbags' deserializer builds one object per camera_source entry: the reference, not the path
        rows.append((f"rosbags deserialize_cdr CloudSources ({n} points, reference)",
                     lambda: typestore().deserialize_cdr(payload, CLOUD_SOURCES)))
    width = max(len(name) for name, _ in rows)
    print(f"{'step':<{width}}  best of {args.repeat} (ms)")
    for name, fn in rows:
        print(f"{name:<{width}}  {_best_ms(fn, args.repeat):8.2f}")


if __name__ == "__main__":
    main()
