"""Fleet benchmark: graspd servers behind HAProxy with the shipped examples/fleet/haproxy.cfg.

Measures POST /detect requests per second with 1, 2 and 3 servers behind HAProxy (and one server without it, the
proxy's cost), all on this machine, in rounds that take the setups in turn (the same server processes serve
them all: one HAProxy per fleet size); then the kill run: all servers under load, one SIGKILLed while it computes
a request, and every request must still be answered 200 with grasps (HAProxy replays the lost one on another
server).  Prints a table and writes <results>/fleet.md, fleet.json and fleet.png (default bench/results/), with
the command and the machine load (`uptime`) before and after.

The cloud is the real table_mug.pcd (../shared/data/real), camera at the origin, thinned by --points.
Servers, HAProxy and clients share this machine's cores: on a small box more servers cannot add cores (they
divide the same ones), and the figures say so; a real fleet has one server per machine.

  PYTHONPATH=service:client .venv/bin/python bench/fleet.py
  PYTHONPATH=service:client .venv/bin/python bench/fleet.py --rounds 5 --duration 20 --clients 8

The fleet machinery (Fleet, drive, kill_mid_run) is also what tests/fleet/ runs.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from collections import Counter
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import Any

import httpx
import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "examples" / "fleet" / "haproxy.cfg"
MUG = ROOT.parent / "shared" / "data" / "real" / "table_mug.pcd"
SERVER_HEADER = "x-graspd-server"  # set by haproxy.cfg: the name of the server that answered


# --- set-up ---------------------------------------------------------------------------------------------------
def haproxy_binary() -> str | None:
    """The haproxy executable: on PATH, else Debian's /usr/sbin/haproxy (not on a normal user's PATH)."""
    found = shutil.which("haproxy")
    if found:
        return found
    return "/usr/sbin/haproxy" if os.access("/usr/sbin/haproxy", os.X_OK) else None


def free_port() -> int:
    """A TCP port on 127.0.0.1 nobody listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def loopback_config(text: str, port: int, stats_port: int, servers: list[tuple[str, int]]) -> str:
    """The shipped haproxy.cfg for a fleet on 127.0.0.1: the `graspd` frontend on port, the stats frontend on
    stats_port, and the backend's `server` lines replaced by one per (name, port).  Every other line (timeouts,
    buffers, retries, health checks, default-server) is kept as shipped."""
    out: list[str] = []
    section = ""
    servers_written = False
    for line in text.splitlines():
        words = line.split()
        if line[:1].strip() and words:  # a section header starts in column 0
            section = " ".join(words[:2])
        elif words and words[0] == "bind" and section == "frontend graspd":
            line = f"    bind 127.0.0.1:{port}"
        elif words and words[0] == "bind" and section == "frontend stats":
            line = f"    bind 127.0.0.1:{stats_port}"
        elif words and words[0] == "server" and section == "backend graspd":
            if servers_written:
                continue
            servers_written = True
            out.extend(f"    server {name} 127.0.0.1:{p}" for name, p in servers)
            continue
        out.append(line)
    if not servers_written:
        raise ValueError("no `server` line in the graspd backend of the HAProxy config")
    return "\n".join(out) + "\n"


def mug_request(num_points: int | None = None, num_samples: int = 30, seed: int = 1) -> tuple[bytes, int]:
    """The JSON body of POST /detect for table_mug.pcd (104,444 points, camera at the origin), evenly thinned to
    num_points (None: all), and its number of points."""
    import open3d as o3d  # noqa: PLC0415  (heavy; only the client side of the benchmark needs it)

    from graspd_client import build_detect_request  # noqa: PLC0415

    if not MUG.exists():
        raise FileNotFoundError(f"{MUG} (../shared/data/real beside the repository)")
    points = np.asarray(o3d.io.read_point_cloud(str(MUG)).points, np.float32)
    if num_points is not None and num_points < len(points):
        points = points[np.linspace(0, len(points) - 1, num_points).round().astype(int)]
    return json.dumps(build_detect_request(points, num_samples=num_samples, seed=seed)).encode(), len(points)


def graspd_command() -> list[str]:
    """How to start this checkout's `graspd` CLI: its [project.scripts] entry point from pyproject.toml, run by
    this Python (a venv's console script may belong to another checkout with another module layout)."""
    entry = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]["graspd"]
    module, _, func = entry.partition(":")
    code = (f"import sys; sys.argv[0] = 'graspd'; from {module} import {func}; sys.exit({func}())")
    return [sys.executable, "-c", code]


def uptime() -> str:
    """`uptime`'s line (the machine load the figures were taken under)."""
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "load average: " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


# --- the fleet ------------------------------------------------------------------------------------------------
class Fleet:
    """n graspd servers on free loopback ports behind HAProxy running the shipped config; a context manager
    that stops every process it started, also on failure.  Logs in workdir (server-<name>.log, haproxy.log)."""

    def __init__(self, n: int, workdir: Path, *, workers: int = 0, config: str | None = None,
                 env: dict[str, str] | None = None) -> None:
        self.names = [f"graspd{i + 1}" for i in range(n)]
        self.workdir = workdir
        self.workers = workers
        self.config_text = config if config is not None else CONFIG.read_text()
        self.env = env or {}
        self.ports = {name: free_port() for name in self.names}
        self.port, self.stats_port = free_port(), free_port()
        self.servers: dict[str, subprocess.Popen[bytes]] = {}
        self.haproxy: subprocess.Popen[bytes] | None = None
        self.extra: list[subprocess.Popen[bytes]] = []  # proxy(): HAProxies over some of the servers

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def server_url(self, name: str) -> str:
        return f"http://127.0.0.1:{self.ports[name]}"

    def __enter__(self) -> Fleet:
        try:
            self.start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    def start(self, timeout: float = 180.0) -> None:
        """Start the servers (all at once), wait until each answers /readyz 200, then HAProxy over all of them,
        and wait until it reports every server UP."""
        if haproxy_binary() is None:
            raise FileNotFoundError("haproxy is not installed (apt-get install haproxy; scripts/setup.sh)")
        self.workdir.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, "PYTHONPATH": f"{ROOT / 'service'}:{ROOT / 'client'}", "GRASPD_LOG_LEVEL": "WARNING",
               "GRASPD_ZENOH_ENABLED": "false", **self.env}
        for name in self.names:
            server_env = {**env, "GRASPD_DATA_DIR": str(self.workdir / f"data-{name}")}
            cmd = [*graspd_command(), "serve", "--host", "127.0.0.1", "--port", str(self.ports[name]), "--no-zenoh"]
            if self.workers:
                cmd += ["--workers", str(self.workers)]
            with (self.workdir / f"server-{name}.log").open("wb") as log:
                self.servers[name] = subprocess.Popen(cmd, env=server_env, stdout=log, stderr=subprocess.STDOUT,
                                                      start_new_session=True)
        end = time.monotonic() + timeout
        for name in self.names:
            self._wait_ready(name, end)
        self.haproxy = self._proxy(self.names, self.port, self.stats_port, "haproxy", end)

    def proxy(self, names: list[str], timeout: float = 60.0) -> str:
        """One more HAProxy, with the same config, over some of the servers (the benchmark's 1- and 2-server
        setups on the same server processes); its URL.  Stopped by close()."""
        port, stats_port = free_port(), free_port()
        self.extra.append(self._proxy(names, port, stats_port, f"haproxy-{port}", time.monotonic() + timeout))
        return f"http://127.0.0.1:{port}"

    def _proxy(self, names: list[str], port: int, stats_port: int, stem: str, end: float
               ) -> subprocess.Popen[bytes]:
        """Start HAProxy on port over the named servers (config workdir/<stem>.cfg, log <stem>.log) and wait
        until its statistics show them all UP."""
        binary = haproxy_binary() or "haproxy"
        cfg = self.workdir / f"{stem}.cfg"
        cfg.write_text(loopback_config(self.config_text, port, stats_port, [(n, self.ports[n]) for n in names]))
        check = subprocess.run([binary, "-c", "-q", "-f", str(cfg)], capture_output=True, text=True)
        if check.returncode != 0:
            raise RuntimeError(f"haproxy -c rejects {cfg}: {check.stdout}{check.stderr}")
        with (self.workdir / f"{stem}.log").open("wb") as log:  # -db: foreground, logs on stdout
            proc = subprocess.Popen([binary, "-db", "-f", str(cfg)], stdout=log, stderr=subprocess.STDOUT,
                                    start_new_session=True)
        while time.monotonic() < end:
            if proc.poll() is not None:
                raise RuntimeError(f"haproxy exited: {(self.workdir / f'{stem}.log').read_text()[-2000:]}")
            try:
                if all(self.stats(stats_port)[name]["status"] == "UP" for name in names):
                    return proc
            except (httpx.HTTPError, KeyError):
                pass
            time.sleep(0.2)
        proc.kill()
        raise RuntimeError(f"haproxy did not report {names} UP in time (log: {self.workdir / f'{stem}.log'})")

    def _wait_ready(self, name: str, end: float) -> None:
        proc = self.servers[name]
        while time.monotonic() < end:
            if proc.poll() is not None:
                log = (self.workdir / f"server-{name}.log").read_text()[-2000:]
                raise RuntimeError(f"{name} exited with {proc.returncode}: {log}")
            try:
                if httpx.get(f"{self.server_url(name)}/readyz", timeout=2).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        raise RuntimeError(f"{name} not ready in time")

    def stats(self, stats_port: int | None = None) -> dict[str, dict[str, str]]:
        """HAProxy's statistics of the graspd backend (its CSV), by server name, plus "BACKEND": status, scur
        (requests on the server now), stot (requests sent to it), hrsp_2xx, wretr (retries), wredis
        (redispatches).  Of the main HAProxy unless another one's stats_port is given."""
        r = httpx.get(f"http://127.0.0.1:{stats_port or self.stats_port}/stats;csv", timeout=5)
        r.raise_for_status()
        rows = csv.DictReader(io.StringIO(r.text.lstrip("# ")))
        return {row["svname"]: row for row in rows if row["pxname"] == "graspd" and row["svname"] != "FRONTEND"}

    def cpu_seconds(self) -> float:
        """CPU time (user + system, s) used so far by the live servers, the HAProxies and this process (the
        clients): what the fleet costs, whatever share of a busy machine it got."""
        total = 0.0
        for p in [*self.servers.values(), *([self.haproxy] if self.haproxy else []), *self.extra, None]:
            if p is not None and p.poll() is not None:
                continue
            try:
                t = psutil.Process(p.pid if p is not None else os.getpid()).cpu_times()
            except psutil.NoSuchProcess:
                continue
            total += t.user + t.system
        return total

    def kill(self, name: str) -> None:
        """SIGKILL a server: no drain, no answer to what it was computing (a crash, an OOM kill)."""
        self.servers[name].send_signal(signal.SIGKILL)
        self.servers[name].wait(timeout=30)

    def close(self) -> None:
        """Stop HAProxy and the servers (SIGTERM, then SIGKILL after 10 s), each by its own process id."""
        procs = ([self.haproxy] if self.haproxy is not None else []) + self.extra + list(self.servers.values())
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)


# --- load -----------------------------------------------------------------------------------------------------
@dataclass
class Answer:
    """One request as a client saw it."""

    status: int  # 0: no HTTP answer (transport error)
    server: str  # X-Graspd-Server: the server that answered ("" if none)
    grasps: int
    seconds: float
    done: float  # time.monotonic() when the answer arrived
    error: str = ""


@dataclass
class Run:
    """A load run: every answer, its wall time, and what happened to the fleet during it."""

    answers: list[Answer] = field(default_factory=list)
    wall: float = 0.0
    killed: str = ""
    killed_at: float = 0.0  # time.monotonic()
    killed_in_flight: int = 0  # requests HAProxy had on the killed server at the kill (its scur)
    cpu_s: float = 0.0  # CPU time (user + system) the fleet and the clients used during the run
    stats: dict[str, dict[str, str]] = field(default_factory=dict)

    def failed(self) -> list[Answer]:
        return [a for a in self.answers if a.status != 200 or a.grasps == 0]

    def rps(self) -> float:
        return sum(a.status == 200 for a in self.answers) / self.wall if self.wall else 0.0

    def served(self) -> Counter[str]:
        return Counter(a.server for a in self.answers if a.status == 200)

    def latency_ms(self, q: float) -> float:
        ok = [a.seconds for a in self.answers if a.status == 200]
        return float(np.percentile(ok, q)) * 1000 if ok else float("nan")


def _client(url: str, payload: bytes, run: Run, lock: threading.Lock, budget: list[int], stop_at: float) -> None:
    """One robot: POST /detect back to back until the shared budget is spent or stop_at passes."""
    with httpx.Client(base_url=url, timeout=120) as client:
        while time.monotonic() < stop_at:
            with lock:
                if budget[0] <= 0:
                    return
                budget[0] -= 1
            t0 = time.monotonic()
            try:
                r = client.post("/detect", content=payload, headers={"Content-Type": "application/json"})
                grasps = len(r.json().get("grasps", [])) if r.status_code == 200 else 0
                answer = Answer(r.status_code, r.headers.get(SERVER_HEADER, ""), grasps, time.monotonic() - t0,
                                time.monotonic(), "" if r.status_code == 200 else r.text[:200])
            except (httpx.HTTPError, ValueError) as exc:
                answer = Answer(0, "", 0, time.monotonic() - t0, time.monotonic(), repr(exc)[:200])
            with lock:
                run.answers.append(answer)


def drive(url: str, payload: bytes, clients: int, requests: int | None = None, duration: float | None = None,
          during: Any = None) -> Run:
    """clients concurrent clients sending payload until `requests` are sent or `duration` s pass; during(run),
    if given, runs in this thread meanwhile (the kill)."""
    run = Run()
    lock = threading.Lock()
    budget = [requests if requests is not None else 1 << 62]
    stop_at = time.monotonic() + (duration if duration is not None else 1e9)
    threads = [threading.Thread(target=_client, args=(url, payload, run, lock, budget, stop_at), daemon=True)
               for _ in range(clients)]
    t0 = time.monotonic()
    for t in threads:
        t.start()
    if during is not None:
        during(run)
    for t in threads:
        t.join()
    run.wall = time.monotonic() - t0
    return run


def kill_when_busy(fleet: Fleet, victim: str, after: int, timeout: float = 120.0) -> Any:
    """A `during` for drive(): once the victim has answered `after` requests, SIGKILL it the moment HAProxy
    hands it a new one (its stot grows and scur >= 1: a detection just started, ~0.1 s or more of work), so
    that it dies mid-request; records the kill in the run."""

    def during(run: Run) -> None:
        end = time.monotonic() + timeout
        seen = -1
        while time.monotonic() < end:
            row = fleet.stats()[victim]
            stot, scur = int(row["stot"] or 0), int(row["scur"] or 0)
            served = sum(a.server == victim and a.status == 200 for a in list(run.answers))
            if served >= after and seen >= 0 and stot > seen and scur >= 1:
                fleet.kill(victim)
                run.killed, run.killed_at, run.killed_in_flight = victim, time.monotonic(), scur
                return
            seen = stot
            time.sleep(0.002)
        raise RuntimeError(f"{victim} was never handed a request after answering {after}")

    return during


def kill_mid_run(fleet: Fleet, payload: bytes, clients: int, requests: int, victim: str = "graspd1",
                 after: int = 3) -> Run:
    """The kill run: clients send `requests` requests through HAProxy; the victim is SIGKILLed while it computes
    one, after it has answered `after`.  HAProxy's statistics at the end are kept in run.stats."""
    run = drive(fleet.url, payload, clients, requests=requests, during=kill_when_busy(fleet, victim, after))
    run.stats = fleet.stats()
    return run


# --- the benchmark --------------------------------------------------------------------------------------------
def plot(rows: list[dict[str, Any]], kill: dict[str, Any], path: Path, cores: int) -> None:
    """Bars per setup: median requests per second (whiskers: the slowest and fastest round) and the CPU time a
    request cost; the kill run's failed-request count in the title."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, (ax, cpu) = plt.subplots(1, 2, figsize=(10, 4.2), gridspec_kw={"width_ratios": [3, 2]})
    labels = [r["setup"].replace(", ", "\n") for r in rows]
    colors = ["#999999" if not r["haproxy"] else "#3b75af" for r in rows]
    values = [r["rps"] for r in rows]
    spread = np.array([[r["rps"] - min(r["rps_rounds"]) for r in rows],
                       [max(r["rps_rounds"]) - r["rps"] for r in rows]])
    bars = ax.bar(labels, values, yerr=spread, capsize=4, color=colors)
    for b, v in zip(bars, values, strict=True):
        ax.annotate(f"{v:.2f}", (b.get_x() + b.get_width() / 2, v), xytext=(12, 2), textcoords="offset points",
                    ha="left", va="bottom", fontsize=9)
    ax.set_ylabel("requests per second (200 with grasps)")
    ax.set_title("throughput (median round; whiskers: min-max)", fontsize=10)
    ms = [r["cpu_ms_per_request"] for r in rows]
    cpu.bar(labels, ms, color=colors)
    for i, v in enumerate(ms):
        cpu.annotate(f"{v}", (i, v), ha="center", va="bottom", fontsize=9)
    cpu.set_ylabel("CPU ms per request (servers + HAProxy + clients)")
    cpu.set_title("what a request costs", fontsize=10)
    for a in (ax, cpu):
        a.grid(True, axis="y", alpha=0.3)
        a.tick_params(axis="x", labelsize=8)
    fig.suptitle(f"graspd behind HAProxy, all on one shared {cores}-core machine; kill run: {kill['requests']} "
                 f"requests, one server SIGKILLed mid-request, {kill['failed']} failed", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--servers", type=int, default=3, help="largest fleet (setups: 1 server direct, then 1..N "
                    "servers behind HAProxy)")
    ap.add_argument("--clients", type=int, default=6, help="concurrent clients (robots)")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds per setup and round")
    ap.add_argument("--rounds", type=int, default=3, help="rounds over all setups (in turn: load drifts)")
    ap.add_argument("--points", type=int, default=None, help="thin table_mug to this many points (default: all "
                    "104,444, a 1.67 MB request)")
    ap.add_argument("--num-samples", type=int, default=100, help="samples per request")
    ap.add_argument("--workers", type=int, default=0, help="detect workers per server (0: its cores)")
    ap.add_argument("--kill-requests", type=int, default=120, help="requests of the kill run (all servers)")
    ap.add_argument("--results", type=Path, default=ROOT / "bench" / "results")
    ap.add_argument("--tag", default="fleet", help="output files <tag>.md/.json/.png")
    args = ap.parse_args(argv)
    cores = len(os.sched_getaffinity(0))
    command = "PYTHONPATH=service:client .venv/bin/python bench/fleet.py " + shlex.join(
        sys.argv[1:] if argv is None else argv)
    load_before = uptime()
    print(f"{command}\nbefore: {load_before}  ({cores} cores)")
    payload, points = mug_request(args.points, args.num_samples)
    print(f"cloud: table_mug.pcd, {points} points, request {len(payload) / 1e6:.2f} MB JSON, "
          f"num_samples {args.num_samples}; {args.clients} clients")
    runs: dict[str, list[Run]] = {}
    kill: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="graspd-fleet-") as tmp, \
            Fleet(args.servers, Path(tmp), workers=args.workers) as fleet:
        # one set of server processes; an HAProxy per fleet size over the first n of them
        setups = {"1 server, direct": fleet.server_url("graspd1")}
        for n in range(1, args.servers + 1):
            setups[f"{n} server{'s' if n > 1 else ''}, HAProxy"] = (
                fleet.url if n == args.servers else fleet.proxy(fleet.names[:n]))
        drive(fleet.url, payload, args.clients, requests=2 * args.clients)  # warm every server
        for r in range(args.rounds):
            order = list(setups)[r % len(setups):] + list(setups)[:r % len(setups)]  # a different start each round
            for setup in order:
                cpu0 = fleet.cpu_seconds()
                run = drive(setups[setup], payload, args.clients, duration=args.duration)
                run.cpu_s = fleet.cpu_seconds() - cpu0
                runs.setdefault(setup, []).append(run)
                print(f"round {r + 1} {setup:20s} {run.rps():6.2f} req/s  {run.cpu_s / run.wall:4.2f} cores  "
                      f"failed {len(run.failed())}  served {dict(run.served())}  "
                      f"(load {uptime().split('load average: ')[-1]})", flush=True)
        before = fleet.stats()["BACKEND"]
        run = kill_mid_run(fleet, payload, args.clients, args.kill_requests)
        backend = run.stats["BACKEND"]
        after = Counter(a.server for a in run.answers if a.status == 200 and a.done > run.killed_at)
        kill = {"requests": len(run.answers), "failed": len(run.failed()), "killed": run.killed,
                "in_flight_at_kill": run.killed_in_flight, "served": dict(run.served()),
                "served_after_kill": dict(after), "retries": int(backend["wretr"] or 0) - int(before["wretr"] or 0),
                "redispatches": int(backend["wredis"] or 0) - int(before["wredis"] or 0),
                "killed_status": run.stats[run.killed]["status"], "p50_ms": round(run.latency_ms(50), 1),
                "max_ms": round(run.latency_ms(100), 1), "failures": [asdict(a) for a in run.failed()[:5]]}
        print(f"kill run: {kill['requests']} requests, {kill['failed']} failed; {run.killed} SIGKILLed with "
              f"{run.killed_in_flight} request(s) on it; served {kill['served']} (after the kill "
              f"{kill['served_after_kill']}); HAProxy retries {kill['retries']}, redispatches "
              f"{kill['redispatches']}; slowest answer {kill['max_ms']:.0f} ms")
    rows = []
    for setup, rs in runs.items():
        merged = Run(answers=[a for r in rs for a in r.answers], wall=sum(r.wall for r in rs))
        rows.append({"setup": setup, "servers": int(setup.split()[0]), "haproxy": "HAProxy" in setup,
                     "requests": len(merged.answers), "failed": len(merged.failed()),
                     "rps": round(float(np.median([r.rps() for r in rs])), 3),
                     "rps_rounds": [round(r.rps(), 3) for r in rs],
                     "cores_used": round(sum(r.cpu_s for r in rs) / merged.wall, 2),
                     "cpu_ms_per_request": round(1000 * sum(r.cpu_s for r in rs)
                                                 / max(sum(a.status == 200 for a in merged.answers), 1)),
                     "p50_ms": round(merged.latency_ms(50), 1),
                     "p95_ms": round(merged.latency_ms(95), 1), "served": dict(merged.served())})
    load_after = uptime()
    print(f"after: {load_after}")
    print(f"\n{'setup':20s} {'req/s':>6s} {'rounds':>22s} {'cores':>6s} {'CPU ms/req':>10s} {'p50 ms':>7s} "
          f"{'p95 ms':>7s} {'failed':>6s}")
    for row in rows:
        print(f"{row['setup']:20s} {row['rps']:6.2f} {' '.join(f'{x:.2f}' for x in row['rps_rounds']):>22s} "
              f"{row['cores_used']:6.2f} {row['cpu_ms_per_request']:10d} {row['p50_ms']:7.0f} {row['p95_ms']:7.0f} "
              f"{row['failed']:6d}")
    args.results.mkdir(parents=True, exist_ok=True)
    meta = {"command": command, "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "cores": cores,
            "uptime_before": load_before, "uptime_after": load_after, "points": points,
            "request_mb": round(len(payload) / 1e6, 2), "num_samples": args.num_samples, "clients": args.clients,
            "duration_s": args.duration, "rounds": args.rounds, "workers_per_server": args.workers or cores,
            "haproxy": subprocess.run([haproxy_binary() or "haproxy", "-v"], capture_output=True,
                                      text=True).stdout.splitlines()[0].split(" - ")[0]}
    (args.results / f"{args.tag}.json").write_text(json.dumps({"meta": meta, "throughput": rows, "kill": kill},
                                                              indent=1))
    plot(rows, kill, args.results / f"{args.tag}.png", cores)
    (args.results / f"{args.tag}.md").write_text(markdown(meta, rows, kill, args.tag))
    print(f"wrote {args.results / args.tag}.md/.json/.png")
    return 0 if kill.get("failed", 1) == 0 and all(r["failed"] == 0 for r in rows) else 1


def markdown(meta: dict[str, Any], rows: list[dict[str, Any]], kill: dict[str, Any], tag: str) -> str:
    """The results page: the throughput table, the kill run, the command and the machine load."""
    lines = [
        "# bench/fleet.py: graspd behind HAProxy", "",
        f"`{meta['command']}`, {meta['date']}, {meta['haproxy']}.", "",
        f"Machine: {meta['cores']} cores, shared by the servers, HAProxy, the clients and other jobs on the box.  "
        f"`uptime` before: `{meta['uptime_before']}`; after: `{meta['uptime_after']}`.", "",
        f"Cloud: table_mug.pcd, {meta['points']} points ({meta['request_mb']} MB JSON), num_samples "
        f"{meta['num_samples']}; {meta['clients']} concurrent clients; {meta['workers_per_server']} detect "
        f"workers per server.  The same server processes serve every setup (one HAProxy per fleet size over "
        f"the first n servers); {meta['rounds']} rounds of {meta['duration_s']:g} s per setup, taken in turn so "
        "that a change in the machine's load hits every setup alike; req/s is the median round.", "",
        "| setup | requests | failed | req/s (median) | req/s per round | cores used | CPU ms per request | "
        "p50 ms | p95 ms | answered by |",
        "|---|---:|---:|---:|---|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        served = ", ".join(f"{k or '-'} {v}" for k, v in sorted(r["served"].items()))
        rounds = " / ".join(f"{x:.2f}" for x in r["rps_rounds"])
        lines.append(f"| {r['setup']} | {r['requests']} | {r['failed']} | {r['rps']:.2f} | {rounds} | "
                     f"{r['cores_used']:.2f} | {r['cpu_ms_per_request']} | {r['p50_ms']:.0f} | {r['p95_ms']:.0f} | "
                     f"{served} |")
    lines += [
        "", f"![requests per second]({tag}.png)", "",
        f"All servers share the same {meta['cores']} cores, which other jobs on this machine use too: "
        "\"cores used\" is the CPU time the servers, HAProxy and the clients used per second of the row, and "
        "\"CPU ms per request\" what a request cost them.  Where more servers answer more requests per second "
        "here, look at the cores used: more processes take a bigger share of a machine other jobs are loading, "
        "they do not add cores.  The rows show HAProxy's cost and how the fleet behaves, not how it scales; a "
        "real fleet puts each server on its own machine, where each adds its own throughput (one server's own "
        "figures: bench/load.py).", "",
        "## A server killed mid-request", "",
        f"All servers behind HAProxy; {kill['requests']} requests from {meta['clients']} clients; "
        f"{kill['killed']} SIGKILLed the moment HAProxy handed it a request, after it had answered a few "
        f"({kill['in_flight_at_kill']} request(s) on it at the kill).", "",
        f"- failed requests: **{kill['failed']}** of {kill['requests']} (every other answer 200 with grasps)",
        f"- answered by: {kill['served']}; after the kill: {kill['served_after_kill']}",
        f"- HAProxy: {kill['retries']} retries (the requests lost with the server, replayed on another), "
        f"{kill['redispatches']} redispatches; {kill['killed']} now {kill['killed_status']}",
        f"- latency p50 {kill['p50_ms']:.0f} ms, slowest {kill['max_ms']:.0f} ms (a replayed request pays for its "
        "first attempt too)", "",
    ]
    if kill.get("failures"):
        lines += ["Failures:", "", "```", *(json.dumps(f) for f in kill["failures"]), "```", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
