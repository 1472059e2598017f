"""ROS 2 over Zenoh against the JSON path: the round trip of a CDR gpd_ros CloudSources (query on
<prefix>/detect?type=cloud_sources, and the stream <prefix>/cloud_sources -> <prefix>/grasps) against the same
cloud as a JSON DetectRequest (query on <prefix>/detect, stream <prefix>/cloud), same options, one server
(in this process, loopback, unscored so that the detection is small and steady).  Client-side encoding is
included in both.  Per path: median round trip, median of (round trip - the server's own detection time), and
the CDR extra over JSON (target <= 15 ms at 66k points).

  PYTHONPATH=service:client .venv/bin/python bench/ros.py [--points 66000] [--repeat 15]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "service"), str(ROOT / "client"), str(ROOT / "bench")]

OPTIONS = {"num_samples": 30, "max_grasps": 100, "use_classifier": False}


def median_ms(values: list[float]) -> float:
    return 1e3 * float(np.median(values))


def main(argv: list[str] | None = None) -> int:
    from graspd.io.ros import Header, encode_cloud_sources
    from graspd.server.runner import free_port, serve_in_thread
    from graspd.server.settings import Settings
    from graspd_client import ZenohGraspClient, build_detect_request
    from graspd_client.zenoh_client import zenoh_config
    from load import make_cloud

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=66_000)
    ap.add_argument("--repeat", type=int, default=15)
    args = ap.parse_args(argv)
    cloud = None
    for seed in range(10):  # bench/load.py's tabletop; a seed whose 8 objects fit on the table
        try:
            cloud = make_cloud(args.points, seed)
            break
        except ValueError:
            continue
    assert cloud is not None
    pts, vps, src = cloud.points, cloud.viewpoints, cloud.camera_source
    header = Header("base_link", (1, 2))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    tmp = Path(tempfile.mkdtemp())
    settings = Settings(port=0, zenoh_listen=[endpoint], models_dir=tmp / "no-models", data_dir=tmp / "data",
                        allow_unscored=True, stream_options=OPTIONS, warmup=False,
                        stream_outputs={"marker_array": "", "moveit_grasps": "", "pose_array": "",
                                        "grasp_config_list": ""})
    (tmp / "no-models").mkdir()

    def json_body() -> bytes:
        return json.dumps(build_detect_request(pts, vps, src, **OPTIONS)).encode()

    def cdr_body() -> bytes:
        return encode_cloud_sources(pts, vps, src, header)

    rows: list[tuple[str, list[float], list[float]]] = []
    with serve_in_thread(settings), ZenohGraspClient(connect=[endpoint], timeout=120) as zc:
        import zenoh

        def timed_query(make: Callable[[], bytes], key: str) -> tuple[float, float]:
            t0 = time.perf_counter()
            reply = zc.query(make(), key)
            return time.perf_counter() - t0, float(reply["timings"]["detect"])

        got: list[dict[str, Any]] = []
        arrived = threading.Event()

        def on_grasps(sample: Any) -> None:
            got.append(json.loads(sample.payload.to_bytes()))
            arrived.set()

        session = zenoh.open(zenoh_config(connect=[endpoint]))
        sub = session.declare_subscriber("graspd/grasps", on_grasps)
        pubs = {k: session.declare_publisher(f"graspd/{k}") for k in ("cloud", "cloud_sources")}
        time.sleep(1.0)  # declarations propagate

        def timed_stream(make: Callable[[], bytes], key: str) -> tuple[float, float]:
            got.clear()
            arrived.clear()
            t0 = time.perf_counter()
            pubs[key].put(make())
            if not arrived.wait(120):
                raise RuntimeError(f"no answer on graspd/grasps for {key}")
            elapsed = time.perf_counter() - t0
            if "grasps" not in got[0]:
                raise RuntimeError(f"stream error: {got[0]}")
            return elapsed, float(got[0]["timings"]["detect"])

        paths: list[tuple[str, Callable[[], tuple[float, float]]]] = [
            ("query JSON", lambda: timed_query(json_body, "graspd/detect")),
            ("query CDR CloudSources", lambda: timed_query(cdr_body, "graspd/detect?type=cloud_sources")),
            ("stream JSON", lambda: timed_stream(json_body, "cloud")),
            ("stream CDR CloudSources", lambda: timed_stream(cdr_body, "cloud_sources")),
        ]
        for _, fn in paths:  # warm up every path once
            fn()
        samples: dict[str, tuple[list[float], list[float]]] = {name: ([], []) for name, _ in paths}
        for _ in range(args.repeat):  # interleaved: drifts in machine load hit every path alike
            for name, fn in paths:
                rt, det = fn()
                samples[name][0].append(rt)
                samples[name][1].append(rt - det)
        rows = [(name, *samples[name]) for name, _ in paths]
        sub.undeclare()
        session.close()

    print(f"{args.points} points, {len(cdr_body()) / 1e6:.2f} MB CDR, {len(json_body()) / 1e6:.2f} MB JSON; "
          f"median of {args.repeat} (ms)")
    print(f"{'path':<26}{'round trip':>12}{'minus detect':>14}")
    for name, rt, over in rows:
        print(f"{name:<26}{median_ms(rt):12.1f}{median_ms(over):14.1f}")
    for kind in ("query", "stream"):
        base = next(r for r in rows if r[0] == f"{kind} JSON")
        cdr = next(r for r in rows if r[0] == f"{kind} CDR CloudSources")
        print(f"{kind}: CDR CloudSources extra over JSON = {median_ms(cdr[2]) - median_ms(base[2]):+.1f} ms "
              "(target <= 15 ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
