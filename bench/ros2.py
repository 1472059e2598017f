"""ROS 2 natively over DDS: a sensor_msgs/PointCloud2 published on /graspd/cloud -> the gpd_ros GraspConfigList on
/graspd/grasp_config_list, against the server's own detection time.  The server runs `graspd serve --ros2` in a
child process (so that the samples really cross the loopback, not Cyclone's in-process path), unscored and with
few samples so that the detection is small and steady; this process is the ROS 2 peer (cyclonedds, ROS 2 names,
sensor-data QoS as a camera driver publishes).  The cloud is bench/load.py's rendered tabletop (~217k points),
filled up to --points with jittered copies.

Per cloud: round trip (write -> GraspConfigList received), the server's detection time (timings.detect of the
JSON answer on /graspd/detections), and their difference: the time beyond the detection (DDS both ways, CDR
decoding, request checks, queueing, encoding of the answer; target <= 20 ms at 300k points).  The peer's own
PointCloud2 encoding is timed apart (a camera driver has its bytes already).

Where the time beyond the detection goes: a second pass (skip it with --no-trace) runs the same server with
timestamps (CLOCK_MONOTONIC, the clock both processes share) at each hand-off of the cloud -> grasps path
(TRACE_POINTS: the listener's wake-up, the take, the stream thread, decoding, the worker, the detector, the
GraspConfigList's encoding and write) and the minor page faults of the thread at each, patched in from this
file (the server's code is unchanged; a mark costs a few microseconds).  The headline figures come from the
first, untraced pass.

  PYTHONPATH=service:client .venv/bin/python bench/ros2.py [--points 300000] [--repeat 10] [--no-trace]
Writes bench/results/ros2.md and ros2.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "service"), str(ROOT / "client"), str(ROOT / "bench")]

OPTIONS = {"num_samples": 30, "max_grasps": 100, "use_classifier": False}
TARGET_MS = 20.0
#: The stages of one cloud in the traced pass, between consecutive marks: (from, to, what happens).  "write0",
#: "write1" and "got" are the peer's (its write call, the GraspConfigList's arrival in its listener); the others
#: the server's.
STAGES: tuple[tuple[str, str, str], ...] = (
    ("write0", "write1", "peer: DDS write of the cloud (a copy, then 1344 B fragments in UDP datagrams)"),
    ("write1", "avail", "server: DDS receive of the last datagrams, reassembly into one buffer, listener woken"),
    ("avail", "on_cloud", "server: take on the listener thread (cyclonedds copies the sample twice into bytes)"),
    ("on_cloud", "frame", "server: hand-off to the stream thread (condition variable)"),
    ("frame", "decoded", "server: CDR decoding and checks (node.decode: io.ros + ros_stream.decode_input)"),
    ("decoded", "job", "server: request built, hand-off to the engine's worker (queue)"),
    ("job", "detect0", "server: engine's request checks, memory budget"),
    ("detect1", "gcl0", "server: after the detector: checks, the Outcome to the node, GraspConfigList encoding"),
    ("gcl0", "gcl1", "server: DDS write of the GraspConfigList"),
    ("gcl1", "got", "peer: DDS delivery, listener woken"),
)


def median_ms(values: list[float]) -> float:
    return 1e3 * float(np.median(values))


def p90_ms(values: list[float]) -> float:
    return 1e3 * float(np.percentile(values, 90))


class Sink:
    """Samples of one topic with their arrival time (perf_counter)."""

    def __init__(self) -> None:
        self.got: list[tuple[float, bytes]] = []
        self.cond = threading.Condition()

    def __call__(self, data: bytes) -> None:
        now = time.perf_counter()
        with self.cond:
            self.got.append((now, data))
            self.cond.notify_all()

    def take(self, timeout: float) -> tuple[float, bytes] | None:
        with self.cond:
            if not self.cond.wait_for(lambda: bool(self.got), timeout):
                return None
            return self.got.pop(0)


def main(argv: list[str] | None = None) -> int:

    from graspd.io.ros import encode_pointcloud2
    from load import make_cloud

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=300_000)
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--results", default=str(ROOT / "bench" / "results"))
    ap.add_argument("--socket-buffer", type=int, default=min(rmem_max(), 8 << 20),
                    help="GRASPD_ROS2_SOCKET_BUFFER_BYTES of the server (default: net.core.rmem_max, at most 8 MiB)")
    ap.add_argument("--no-trace", dest="trace", action="store_false",
                    help="skip the second, traced pass (where the time beyond the detection goes)")
    args = ap.parse_args(argv)
    load_start = os.getloadavg()[0]
    cloud = None
    for seed in range(10):  # bench/load.py's tabletop; a seed whose 8 objects fit on the table
        try:
            cloud = make_cloud(args.points, seed)
            break
        except ValueError:
            continue
    assert cloud is not None
    points, viewpoint = cloud.points, cloud.viewpoints[0]
    if len(points) < args.points:  # the rendered tabletop has ~217k points: jittered copies (1 mm) fill it up
        rng = np.random.default_rng(0)
        extra = points[rng.integers(0, len(points), args.points - len(points))]
        points = np.concatenate([points, extra + rng.normal(0.0, 0.001, extra.shape).astype(points.dtype)])
    headline = run_pass(args, points, viewpoint, None)
    traced: dict[str, Any] | None = None
    if args.trace:
        with tempfile.TemporaryDirectory() as tmp:
            traced = run_pass(args, points, viewpoint, Path(tmp) / "marks.txt")
    rows, encode_s, lost = headline["rows"], headline["encode_s"], headline["lost"]
    mb = len(encode_pointcloud2(points)) / 1e6
    beyond = [r["beyond"] for r in rows]
    decode_s = [float(r["server_timings"]["decode"]) for r in rows]
    queue_s = [float(r["server_timings"]["queue"]) for r in rows]
    write_s = [r["peer_write"] for r in rows]
    rest_s = [b - d - q - w for b, d, q, w in zip(beyond, decode_s, queue_s, write_s, strict=True)]
    summary: dict[str, Any] = {
        "points": len(points), "megabytes": round(mb, 2), "repeat": len(rows), "lost": lost,
        "round_trip_ms": round(median_ms([r["round_trip"] for r in rows]), 1),
        "detect_ms": round(median_ms([r["detect"] for r in rows]), 1),
        "beyond_detect_ms": round(median_ms(beyond), 1), "beyond_detect_p90_ms": round(p90_ms(beyond), 1),
        "decode_ms": round(median_ms(decode_s), 1), "queue_ms": round(median_ms(queue_s), 2),
        "peer_write_ms": round(median_ms(write_s), 1), "rest_ms": round(median_ms(rest_s), 1),
        "peer_encode_ms": round(median_ms(encode_s), 1), "target_ms": TARGET_MS,
        "machine": f"{platform.node()} {platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "load_start": round(load_start, 2), "load_end": round(os.getloadavg()[0], 2),
        "socket_buffer": args.socket_buffer}

    def row(name: str, values: list[float], bold: bool = False) -> str:
        med = f"{median_ms(values):.1f}"
        return f"| {name} | {f'**{med}**' if bold else med} | {p90_ms(values):.1f} |"

    lines = [f"PointCloud2 in -> GraspConfigList out over DDS (loopback, server in a child process), "
             f"{len(points)} points ({mb:.2f} MB), median of {len(rows)} (ms); {lost} clouds lost (best effort)",
             "", "| step | median (ms) | p90 (ms) |", "|---|---:|---:|",
             row("round trip (write -> GraspConfigList)", [r["round_trip"] for r in rows]),
             row("server detection (timings.detect)", [r["detect"] for r in rows]),
             row("**beyond the detection**", beyond, bold=True),
             row("- the peer's DDS write of the cloud (its write call)", write_s),
             row("- the server's CDR decoding and checks (timings.decode)", decode_s),
             row("- the hand-off to the engine's worker (timings.queue)", queue_s),
             row("- the rest: DDS receive and take, stream thread, encoding, DDS back", rest_s),
             row("peer's PointCloud2 encoding (not in the round trip)", encode_s), "",
             f"target: beyond the detection <= {TARGET_MS:g} ms: "
             f"{'met' if summary['beyond_detect_ms'] <= TARGET_MS else 'NOT met'}",
             f"server's UDP receive buffer: {args.socket_buffer or 'Cyclone default'} B "
             f"(net.core.rmem_max {rmem_max()})",
             f"machine: {summary['machine']}; 1-min load average at the start {load_start:.2f}, "
             f"at the end {os.getloadavg()[0]:.2f}"]
    if traced is not None and traced["stages"]:
        stages = traced["stages"]
        summary["traced"] = {"beyond_detect_ms": round(median_ms([r["beyond"] for r in traced["rows"]]), 1),
                             "stages_ms": {k: round(v["median_ms"], 2) for k, v in stages.items()},
                             "faults": {k: v["faults"] for k, v in stages.items() if v["faults"] is not None}}
        lines += ["", f"Where it goes (a second, traced server; median of {len(traced['rows'])}, beyond the "
                      f"detection there {summary['traced']['beyond_detect_ms']} ms; medians do not add up exactly)",
                  "", "| stage | median (ms) | p90 (ms) | minor page faults (median) |", "|---|---:|---:|---:|"]
        for (start, stop, what) in STAGES:
            st = stages.get(f"{start}->{stop}")
            if st is not None:
                faults = "" if st["faults"] is None else f"{st['faults']:.0f}"
                lines.append(f"| {what} | {st['median_ms']:.2f} | {st['p90_ms']:.2f} | {faults} |")
    print("\n".join(lines))
    results = Path(args.results)
    results.mkdir(parents=True, exist_ok=True)
    flags = "" if args.trace else " --no-trace"
    (results / "ros2.md").write_text("# bench/ros2.py\n\n" + "\n".join(lines) + "\n\n`PYTHONPATH=service:client "
                                     f".venv/bin/python bench/ros2.py --points {args.points} --repeat "
                                     f"{args.repeat}{flags}`\n")
    runs = [{k: v for k, v in r.items() if k not in ("t0", "t1", "t_got")} for r in rows]
    (results / "ros2.json").write_text(json.dumps({**summary, "runs": runs}, indent=1) + "\n")
    return 0


def stage_times(rows: list[dict[str, Any]], marks_file: Path) -> dict[str, dict[str, Any]]:
    """Per STAGES entry: median and p90 (ms) over the clouds of rows, and the median of the minor page faults taken
    between its marks when both are on one server thread (else None).  The marks of a cloud are the first of each
    name between its write and its GraspConfigList's arrival."""
    marks: list[tuple[str, float, int, int]] = []
    for line in marks_file.read_text().splitlines():
        fields = line.split()
        marks.append((fields[0], float(fields[1]), int(fields[2]), int(fields[3])))
    spans: dict[str, list[float]] = {}
    faults: dict[str, list[int]] = {}
    for r in rows:
        seen: dict[str, tuple[float, int, int]] = {"write0": (r["t0"], 0, 0), "write1": (r["t1"], 0, 0),
                                                   "got": (r["t_got"], 0, 0)}
        for label, at, thread, flt in marks:
            if r["t0"] <= at <= r["t_got"] and label not in seen:
                seen[label] = (at, thread, flt)
        for start, stop, _ in STAGES:
            if start in seen and stop in seen:
                key = f"{start}->{stop}"
                spans.setdefault(key, []).append(seen[stop][0] - seen[start][0])
                (_, t_a, f_a), (_, t_b, f_b) = seen[start], seen[stop]
                if t_a and t_a == t_b:
                    faults.setdefault(key, []).append(f_b - f_a)
    return {k: {"median_ms": median_ms(v), "p90_ms": p90_ms(v),
                "faults": float(np.median(faults[k])) if k in faults else None} for k, v in spans.items()}


def traced_server(marks_file: str, argv: list[str]) -> int:
    """`graspd serve` with a mark (name, CLOCK_MONOTONIC time, thread id, the thread's minor page faults so far)
    written to marks_file at each hand-off of a cloud (STAGES), by wrapping the node's, the engine's and the DDS
    layer's methods; nothing else changes."""
    import resource

    from graspd.server.cli import main as serve
    from graspd.server.ros2 import dds, node
    from graspd.server.services import engine

    out = open(marks_file, "a", buffering=1)  # noqa: SIM115 - open for the server's whole life

    def mark(name: str) -> None:
        faults = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
        out.write(f"{name} {time.monotonic():.7f} {threading.get_native_id()} {faults}\n")

    def around(cls: Any, method: str, before: str | None, after: str | None = None,
               when: Any = lambda self, *a: True) -> None:
        inner = getattr(cls, method)

        def wrapper(self: Any, *a: Any, **k: Any) -> Any:
            hit = when(self, *a)
            if hit and before:
                mark(before)
            result = inner(self, *a, **k)
            if hit and after:
                mark(after)
            return result

        setattr(cls, method, wrapper)

    around(dds.RawReader, "_available", "avail", when=lambda self, *a: self.name.endswith("graspd/cloud"))
    around(node.Ros2Node, "_on_cloud", "on_cloud")
    around(node.Ros2Node, "_stream_frame", "frame")
    around(node.Ros2Node, "decode", None, "decoded")
    around(engine.DetectionEngine, "_job", "job")
    around(engine.DetectionEngine, "_detect", "detect0", "detect1")
    around(dds.RawWriter, "write", "gcl0", "gcl1", when=lambda self, *a: self.name.endswith("grasp_config_list"))
    return serve(argv)


def run_pass(args: argparse.Namespace, points: np.ndarray, viewpoint: np.ndarray, trace: Path | None
             ) -> dict[str, Any]:
    """One server (traced when trace names the marks file), args.repeat + 1 clouds (the first warms up):
    {"rows": per cloud, "encode_s": the peer's encodings, "lost": clouds lost, "stages": per stage (ms, traced)}."""
    from cyclonedds.domain import Domain, DomainParticipant
    from cyclonedds.topic import Topic

    from graspd.io.ros import Header, encode_pointcloud2
    from graspd.server.ros2.dds import RawReader, RawWriter, discovery_xml, reliable_qos, sensor_qos
    from graspd.server.ros2.interfaces import idl_type
    from graspd.server.runner import free_port

    domain = random.randrange(1, 230)
    tmp = Path(tempfile.mkdtemp())
    (tmp / "no-models").mkdir()
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'service'}:{ROOT / 'client'}", "GRASPD_ROS2_DOMAIN_ID": str(domain),
           "GRASPD_MODELS_DIR": str(tmp / "no-models"), "GRASPD_DATA_DIR": str(tmp / "data"),
           "GRASPD_ALLOW_UNSCORED": "true", "GRASPD_WARMUP": "false", "GRASPD_LOG_LEVEL": "WARNING",
           "GRASPD_STREAM_OPTIONS": json.dumps(OPTIONS), "GRASPD_STREAM_VIEWPOINT": json.dumps(viewpoint.tolist())}
    if args.socket_buffer:
        env["GRASPD_ROS2_SOCKET_BUFFER_BYTES"] = str(args.socket_buffer)
    serve = ["serve", "--ros2", "--no-zenoh", "--port", str(free_port())]
    command = [sys.executable, "-m", "graspd.server.cli", *serve] if trace is None else \
        [sys.executable, str(Path(__file__).resolve()), "--traced-server", str(trace), *serve]
    server = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL)
    domain_entity = Domain(domain, discovery_xml("localhost", [], [], 128 << 20))

    class Peer:
        def __init__(self) -> None:
            self.dp = DomainParticipant(domain)
            self.topics: dict[str, Any] = {}

        def topic(self, name: str, ros_type: str, distro: str) -> Any:
            if name not in self.topics:
                self.topics[name] = Topic(self.dp, name, idl_type(ros_type, distro))
            return self.topics[name]

    rows: list[dict[str, float]] = []
    encode_s: list[float] = []
    lost = 0
    try:
        peer: Any = Peer()  # the participant RawReader and RawWriter need: .dp and .topic()
        gcl, answers = Sink(), Sink()
        keep = [RawReader(peer, "rt/graspd/grasp_config_list", "gpd_ros/msg/GraspConfigList", "jazzy",
                          reliable_qos(10), gcl),
                RawReader(peer, "rt/graspd/detections", "std_msgs/msg/String", "jazzy", reliable_qos(10), answers)]
        writer = RawWriter(peer, "rt/graspd/cloud", "sensor_msgs/msg/PointCloud2", "jazzy", sensor_qos())
        end = time.monotonic() + 120
        while (writer.matched() == 0 or not all(r.matched() for r in keep)) and time.monotonic() < end:
            if server.poll() is not None:
                raise RuntimeError("the server exited")
            time.sleep(0.1)
        if writer.matched() == 0:
            raise RuntimeError("the server's node did not match within 120 s")
        time.sleep(0.5)
        runs = 0
        while len(rows) < args.repeat + 1 and runs < 3 * (args.repeat + 1):  # the first one warms up
            runs += 1
            t_enc = time.perf_counter()
            payload = encode_pointcloud2(points, Header("base_link", (runs, 0)))
            t0 = time.perf_counter()
            encode_s.append(t0 - t_enc)
            writer.write(payload)
            t1 = time.perf_counter()
            got = gcl.take(30)
            answer = answers.take(30) if got is not None else None
            if got is None or answer is None:  # best effort: a lost sample is not retried by DDS
                lost += 1
                continue
            timings = json.loads(_string(answer[1]))["timings"]
            detect = float(timings["detect"])
            rows.append({"round_trip": got[0] - t0, "detect": detect, "beyond": got[0] - t0 - detect,
                         "peer_write": t1 - t0, "server_total": float(timings["total"]), "server_timings": timings,
                         "t0": t0, "t1": t1, "t_got": got[0]})
            time.sleep(0.2)
        del keep, writer, peer
    finally:
        server.terminate()
        server.wait(60)
        del domain_entity
    rows = rows[1:]
    return {"rows": rows, "encode_s": encode_s[1:], "lost": lost,
            "stages": None if trace is None else stage_times(rows, trace)}


def rmem_max() -> int:
    """net.core.rmem_max (bytes): the largest UDP receive buffer a process may ask for."""
    try:
        return int(Path("/proc/sys/net/core/rmem_max").read_text())
    except OSError:
        return 0


def _string(cdr: bytes) -> str:
    """The text of a CDR std_msgs/String (u32 length with the NUL, then the bytes)."""
    n = int.from_bytes(cdr[4:8], "little")
    return cdr[8:8 + n - 1].decode()


if __name__ == "__main__":
    if sys.argv[1:2] == ["--traced-server"]:  # the server of the traced pass (run_pass starts it)
        raise SystemExit(traced_server(sys.argv[2], sys.argv[3:]))
    raise SystemExit(main())
