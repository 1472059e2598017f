"""Warm start: one detection on a small bundled cloud before the service says ready, so that the first real
request pays no first-use costs (open3d's import and normal estimation, the KD-tree and numpy code paths,
onnxruntime's first runs and buffer allocation, BLAS thread start-up)."""

from __future__ import annotations

import logging
import time

import numpy as np

from graspd.core.cloud import ViewpointCloud
from graspd.gpd.detector import DetectionParams
from graspd.server.services.registry import ModelRegistry

log = logging.getLogger("graspd.server")

#: Samples of the warm-up detection: enough candidates for a full scoring batch path, little time.
WARMUP_SAMPLES = 40


def warmup_cloud(seed: int = 0) -> ViewpointCloud:
    """A tabletop seen from above at an angle, procedural (no file, no rendering, ~28k points): a 40 x 40 cm
    table with a box (6 x 4 x 8 cm) and an upright cylinder (r 3.5 cm, 10 cm) on it, 1 mm noise, z up."""
    rng = np.random.default_rng(seed)
    table = np.column_stack([rng.uniform(-0.2, 0.2, 14_000), rng.uniform(-0.2, 0.2, 14_000), np.zeros(14_000)])
    # box: its top and two sides facing the camera (which stands at -x, -y, above)
    n = 2_500
    top = np.column_stack([rng.uniform(-0.13, -0.07, n), rng.uniform(-0.02, 0.02, n), np.full(n, 0.08)])
    side_x = np.column_stack([np.full(n, -0.13), rng.uniform(-0.02, 0.02, n), rng.uniform(0.0, 0.08, n)])
    side_y = np.column_stack([rng.uniform(-0.13, -0.07, n), np.full(n, -0.02), rng.uniform(0.0, 0.08, n)])
    # cylinder: the half facing the camera and its top disc
    ang = rng.uniform(np.pi / 2, 2 * np.pi, 5_000)
    wall = np.column_stack([0.08 + 0.035 * np.cos(ang), 0.03 + 0.035 * np.sin(ang), rng.uniform(0.0, 0.1, 5_000)])
    r = 0.035 * np.sqrt(rng.uniform(0.0, 1.0, 2_000))
    a = rng.uniform(0.0, 2 * np.pi, 2_000)
    disc = np.column_stack([0.08 + r * np.cos(a), 0.03 + r * np.sin(a), np.full(2_000, 0.1)])
    pts = np.concatenate([table, top, side_x, side_y, wall, disc])
    pts += rng.normal(0.0, 0.001, pts.shape)
    return ViewpointCloud(points=pts.astype(np.float32), viewpoints=np.array([[-0.5, -0.5, 0.6]], np.float32))


def warm_up(registry: ModelRegistry) -> float:
    """Run one detection with the default model (unscored when there is none) on warmup_cloud(); seconds taken.
    Errors are logged, never raised: a failed warm-up leaves a working, merely cold, service."""
    t = time.perf_counter()
    try:
        det = registry.detector(registry.default).detect(warmup_cloud(), DetectionParams(num_samples=WARMUP_SAMPLES))
    except Exception as exc:  # anything: the warm-up must not stop the service
        log.warning("warm-up detection failed", exc_info=True, extra={"error": type(exc).__name__})
        return time.perf_counter() - t
    seconds = time.perf_counter() - t
    log.info("warm-up detection done", extra={"seconds": round(seconds, 3), "candidates": det.num_candidates,
                                               "model": det.model})
    return seconds
