"""Warm start: before the service says ready, one request on a small bundled cloud takes the path a real request
takes, so that the first real request pays no first-use costs: the JSON body parsed and validated
(server/requests.py, wire/), the cloud made into the detection frame, preprocessing (the KD-tree, normal
estimation), the environment model, the hand search, both stages of the model cascade (the prefilter on its own
images, then the full model) with full batches of both representations, onnxruntime's buffers sized for the
largest batch a request scores, the process's thread pool (graspd.core.parallel) and the response built and
serialised.  A capture file (binary PCD) and an organised cloud (with its shape), detected once, take the
readers' and the grid's compiled paths (tests/server/test_warm_kernels.py: after the warm-up a first upload
compiles nothing)."""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import Executor, wait
from typing import Any

import numpy as np

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.core.parallel import THREADS
from graspd.gpd.detector import Detection, score_parallel
from graspd.server.services.registry import ModelRegistry

log = logging.getLogger("graspd.server")

#: Samples of the warm-up detection: enough candidates that the cascade's first pass runs (more than
#: DetectionParams.cascade_min survive the filters on warmup_cloud) and scores a full batch.
WARMUP_SAMPLES = 400


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


def warmup_body(samples: int = WARMUP_SAMPLES) -> dict[str, Any]:
    """The warm-up request as a client sends it (graspd_client's wire format: binary arrays): warmup_cloud()
    with `samples` samples and the service's defaults for everything else."""
    from graspd_client import build_detect_request  # noqa: PLC0415 - the server's own wire codec

    cloud = warmup_cloud()
    return dict(build_detect_request(cloud.points, cloud.viewpoints, cloud.camera_source, num_samples=samples))


def warm_detection(registry: ModelRegistry, samples: int = WARMUP_SAMPLES) -> tuple[Detection, bytes]:
    """The warm-up request end to end, as the engine runs one (without its queue): parsed from JSON, detected
    with the default model (its cascade included) inside THREADS.request(), every scorer of the detector then
    scoring one full batch (DetectionParams.score_batch images), and the response serialised.  Returns the
    detection and the response bytes.  Raises what the request raises."""
    from graspd.server.requests import dumps, parse_request  # noqa: PLC0415 - keeps this module light
    from graspd.server.services.mapping import detection_inputs, result_body  # noqa: PLC0415
    from graspd.server.services.outcome import GpdResult  # noqa: PLC0415
    from graspd.server.wire.response import DetectResponse  # noqa: PLC0415

    req = parse_request(dumps(warmup_body(samples)))
    inputs = detection_inputs(req)
    given, params = inputs.given, inputs.params
    hand = req.hand_geometry()
    detector = registry.detector(registry.resolve(req.model, req.use_classifier and req.method == "gpd",
                                                  hand or HandGeometry()))
    with THREADS.request():
        det = detector.detect(given.cloud, params, hand)
        for scorer in (detector.prefilter, detector.classifier):
            if scorer is None:
                continue
            channels = int(getattr(scorer, "channels", 0)) or None
            size = int(getattr(scorer, "image_size", 60))
            if channels is not None:  # a full batch: onnxruntime sizes its buffers for the largest one
                score_parallel(scorer, np.zeros((params.score_batch, channels, size, size), np.uint8))
    body = DetectResponse.model_validate(result_body(GpdResult.of(det), request_id="warm-up", detection_id="warm-up",
                                                     timings=dict(det.timings), frame=given.frame)).to_json()
    return det, body


def warm_inputs(registry: ModelRegistry) -> None:
    """The other shapes of input a robot sends, detected once (their compiled code serves every worker thread): a
    capture file (binary PCD, parsed as an upload is) and an organised cloud (with its shape: the grid's mixed-pixel
    filter and normals)."""
    from graspd.server.requests import dumps, parse_body, parse_request  # noqa: PLC0415 - keeps this module light
    from graspd.server.services.mapping import detection_inputs  # noqa: PLC0415

    with THREADS.request():
        for req in (parse_body(warmup_pcd(), "application/octet-stream", {"num_samples": "60"}, []),
                    parse_request(dumps(warmup_organised_body()))):
            inputs = detection_inputs(req)
            hand = req.hand_geometry()
            detector = registry.detector(registry.resolve(req.model, req.use_classifier, hand or HandGeometry()))
            detector.detect(inputs.given.cloud, inputs.params, hand)


def warmup_pcd() -> bytes:
    """warmup_cloud() as a binary PCD file (float32 x y z, the camera as its VIEWPOINT), the way captures are
    uploaded: its points take the readers' and the voxel grid's float32 paths."""
    cloud = warmup_cloud()
    x, y, z = (float(v) for v in cloud.viewpoints[0])
    header = (f"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {len(cloud)}\nHEIGHT 1\n"
              f"VIEWPOINT {x} {y} {z} 1 0 0 0\nPOINTS {len(cloud)}\nDATA binary\n")
    return header.encode() + np.ascontiguousarray(cloud.points, "<f4").tobytes()


def warmup_organised_body(height: int = 96, width: int = 128) -> dict[str, Any]:
    """An organised cloud (an image grid with its shape, as a depth camera gives it): a table 0.7 m below a camera
    looking down, a 10 cm box on it, a row of pixels with no depth (NaN); it takes the grid's mixed-pixel filter and
    normals."""
    from graspd_client import build_detect_request  # noqa: PLC0415 - the server's own wire codec

    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    f = 0.9 * width
    ray = np.stack([(u - width / 2) / f, (v - height / 2) / f, np.ones_like(u)], axis=-1)
    depth = np.where((np.abs(ray[..., 0]) < 0.08) & (np.abs(ray[..., 1]) < 0.06), 0.6, 0.7)
    points = (ray * depth[..., None]).astype(np.float32)
    points[0] = np.nan
    return dict(build_detect_request(points, num_samples=40))


def warm_paths() -> None:
    """Run the paths the warm-up request does not take on tiny inputs, so that their first use (numba loading or,
    in a fresh install, compiling a kernel; a reader's first call) is not paid by a robot's request: ASCII PCD
    uploads (parsed as an upload is; binary ones: warm_inputs), the range window (clouds over a metre across), the
    admission's voxel count, and the hand search's pair coordinates for large obstacle sets."""
    from graspd.gpd.placement import slab_coordinates  # noqa: PLC0415 - keeps this module light
    from graspd.gpd.preprocess import DEFAULT_RANGE_WINDOW, region_mask  # noqa: PLC0415
    from graspd.server.requests import parse_body  # noqa: PLC0415
    from graspd.server.services.budget import occupied_voxels  # noqa: PLC0415

    ascii_pcd = (b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\n"
                 b"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n0 0 0.5\n0.1 0 0.5\n0 0.1 0.5\n")
    parse_body(ascii_pcd, "application/octet-stream", {}, [])  # binary PCD: warm_inputs

    rng = np.random.default_rng(0)
    wide = ViewpointCloud(points=rng.uniform(-1.5, 1.5, (64, 3)).astype(np.float32),
                          viewpoints=np.array([[0.0, 0.0, 2.0]], np.float32))
    region_mask(wide, None, DEFAULT_RANGE_WINDOW)
    occupied_voxels(wide, 0.003, None, DEFAULT_RANGE_WINDOW)
    pts = wide.points[:8]
    slab_coordinates(pts, pts[:2], np.tile(np.eye(3, dtype=np.float32), (2, 1, 1)), np.zeros(4, np.int64),
                     np.arange(4, dtype=np.int64), 0.01)


def warm_up(registry: ModelRegistry, executor: Executor | None = None, workers: int = 1,
            timeout: float = 120.0) -> float:
    """Run warm_detection(registry) here, or once on each of the `workers` threads of `executor` (the engine's
    detect workers, all at once: a worker thread's first detection otherwise pays for its own memory, a fresh
    allocator arena, and first uses); seconds taken.  Errors are logged, never raised: a failed warm-up leaves a
    working, merely cold, service."""
    t = time.perf_counter()
    try:
        warm_paths()
        warm_inputs(registry)
        if executor is None:
            dets = [warm_detection(registry)[0]]
        else:
            gate = threading.Barrier(workers)  # each worker thread takes one (none takes two)

            def on_worker() -> Detection:
                gate.wait(timeout)
                return warm_detection(registry)[0]

            futures = [executor.submit(on_worker) for _ in range(workers)]
            wait(futures, timeout)
            dets = [fut.result(0) for fut in futures]
    except Exception as exc:  # anything: the warm-up must not stop the service
        log.warning("warm-up detection failed", exc_info=True, extra={"error": type(exc).__name__})
        return time.perf_counter() - t
    seconds = time.perf_counter() - t
    det = dets[0]
    log.info("warm-up detection done", extra={"seconds": round(seconds, 3), "candidates": det.num_candidates,
                                               "model": det.model, "cascade": "prefilter" in det.timings,
                                               "workers": len(dets)})
    return seconds
