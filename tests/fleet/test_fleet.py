"""A fleet behind HAProxy, all real on loopback: graspd servers started with `graspd serve`,
Debian's haproxy running examples/fleet/haproxy.cfg (only its `bind` and `server` lines changed), clients sending
the real table_mug cloud.  A server SIGKILLed in the middle of a detection costs no request: HAProxy replays it on
another server; a slow client never reaches a server; servers share one PostgreSQL template library.  The slow
controls show that each piece of the config the replay needs is needed: without it the same kill fails a
request, so the main test can fail."""

from __future__ import annotations

import re
import signal
import subprocess
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import ModuleType
from typing import Any

import httpx
import numpy as np
import pytest

from fixtures import box_top_grasp, connect, read_response
from graspd_client import build_demonstration_request, build_detect_request, build_feedback_request

BOX = (0.05, 0.10, 0.08)


def _failures(run: Any) -> str:
    return "; ".join(f"{a.status} from {a.server or '?'}: {a.error}" for a in run.failed()[:5])


def test_the_shipped_config_is_valid(fleet: ModuleType, tmp_path: Path) -> None:
    """haproxy -c accepts examples/fleet/haproxy.cfg as shipped (compose's service names need not resolve here)
    and its loopback form, which keeps every line but the binds and the servers."""
    binary = fleet.haproxy_binary()
    shipped = subprocess.run([binary, "-c", "-f", str(fleet.CONFIG)], capture_output=True, text=True)
    assert shipped.returncode == 0, shipped.stdout + shipped.stderr
    text = fleet.CONFIG.read_text()
    loopback = fleet.loopback_config(text, 18000, 18404, [("graspd1", 18001), ("graspd2", 18002)])
    (tmp_path / "haproxy.cfg").write_text(loopback)
    check = subprocess.run([binary, "-c", "-f", str(tmp_path / "haproxy.cfg")], capture_output=True, text=True)
    assert check.returncode == 0, check.stdout + check.stderr
    assert "server graspd1 127.0.0.1:18001" in loopback and "graspd3" not in loopback
    kept = [line for line in text.splitlines() if line.split()[:1] not in (["bind"], ["server"])]
    assert all(line in loopback.splitlines() for line in kept)


def test_compose_runs_the_servers_the_config_names(fleet: ModuleType) -> None:
    """examples/fleet/compose.yaml and haproxy.cfg agree (CI has no Docker to run them): a compose service for
    each `server` line on port 8000, maxconn equal to the servers' detect workers, haproxy mounting this config
    and publishing 8000, and every server on the shared PostgreSQL library, started after the database is
    healthy."""
    yaml = pytest.importorskip("yaml")
    compose = yaml.safe_load((fleet.CONFIG.parent / "compose.yaml").read_text())
    services = compose["services"]
    text = fleet.CONFIG.read_text()
    servers = re.findall(r"(?m)^\s*server (\S+) (\S+):8000\b", text)
    assert servers and all(name == host for name, host in servers)
    maxconn = re.search(r"(?m)^\s*default-server .*\bmaxconn (\d+)", text)
    assert maxconn is not None
    for name, _ in servers:
        env = services[name]["environment"]
        assert services[name]["build"]["context"] == "../.." and "8000" in services[name]["expose"]
        assert env["GRASPD_DETECT_WORKERS"] == maxconn.group(1)
        assert env["GRASPD_TEMPLATE_LIBRARY"].startswith("postgresql+psycopg://") and "@postgres:5432/" in env[
            "GRASPD_TEMPLATE_LIBRARY"]
        assert services[name]["depends_on"]["postgres"]["condition"] == "service_healthy"
    proxy = services["haproxy"]
    assert "./haproxy.cfg:/usr/local/etc/haproxy/haproxy.cfg:ro" in proxy["volumes"]
    assert "8000:8000" in proxy["ports"] and re.search(r"(?m)^\s*bind :8000$", text)
    assert set(proxy["depends_on"]) == {name for name, _ in servers}
    assert (fleet.CONFIG.parent / "../../Dockerfile").resolve() == fleet.ROOT / "Dockerfile"


def test_three_servers_lose_no_request_when_one_is_killed_mid_request(fleet: ModuleType, mug_1mb: bytes,
                                                                       tmp_path: Path) -> None:
    """Three servers, four clients, 60 requests of a 1.06 MB cloud; graspd1 is SIGKILLed the moment HAProxy hands
    it a request, after it has answered three.  Every request is answered 200 with grasps, the lost one replayed
    (HAProxy counts the retry), and both other servers answer after the kill."""
    with fleet.Fleet(3, tmp_path) as f:
        run = fleet.kill_mid_run(f, mug_1mb, clients=4, requests=60, victim="graspd1", after=3)
    assert len(run.answers) == 60
    assert not run.failed(), f"{len(run.failed())} failed: {_failures(run)}"
    assert all(a.grasps > 0 for a in run.answers)
    assert run.killed == "graspd1" and run.killed_in_flight >= 1
    served = run.served()
    assert served["graspd1"] >= 3, served  # it really served before dying
    after = Counter(a.server for a in run.answers if a.done > run.killed_at + 0.05)
    assert after["graspd2"] > 0 and after["graspd3"] > 0, after
    assert int(run.stats["BACKEND"]["wretr"]) >= 1, run.stats["BACKEND"]  # the request it was computing, replayed
    assert run.stats["graspd1"]["status"].startswith("DOWN")


def test_a_slow_client_gets_408_from_haproxy_and_never_reaches_a_server(fleet: ModuleType, tmp_path: Path) -> None:
    """A client that sends its headers and then trickles its body is answered 408 by HAProxy when `timeout
    http-request` passes (1 s here; 10 s shipped), and no server ever sees the request."""
    config = re.sub(r"(?m)^(\s*timeout http-request) .*$", r"\1 1s", fleet.CONFIG.read_text())
    with fleet.Fleet(1, tmp_path, config=config) as f, connect(f.url) as s:
        s.sendall(b"POST /detect HTTP/1.1\r\nHost: fleet\r\nContent-Type: application/json\r\n"
                  b"Content-Length: 100000\r\n\r\n" + b'{"cloud": ' + b" " * 1000)
        t0 = time.monotonic()
        status, _, _ = read_response(s)
        waited = time.monotonic() - t0
        stats = f.stats()["graspd1"]
    assert status == 408 and 0.5 < waited < 5, (status, waited)
    assert int(stats["stot"] or 0) == 0, stats  # health checks are not requests: the server saw nothing


def test_a_hung_server_gets_detections_replayed_but_never_a_taught_grasp(fleet: ModuleType, render_box, box_pose,
                                                                         tmp_path: Path) -> None:
    """One server, SIGSTOPped (it accepts connections, never answers), `timeout server` 1 s: a POST
    /demonstrations gets 504 with no retry (the dead server may already have stored it: a replay could store
    it twice), while a POST /detect is retried (HAProxy's retry count grows) before it gives up."""
    config = re.sub(r"(?m)^(\s*timeout server) .*$", r"\1 1s", fleet.CONFIG.read_text())
    pose = box_pose()
    cloud = render_box(pose)
    with fleet.Fleet(1, tmp_path, config=config) as f, httpx.Client(base_url=f.url, timeout=60) as c:
        server = f.servers["graspd1"]
        server.send_signal(signal.SIGSTOP)
        try:
            before = int(f.stats()["BACKEND"]["wretr"] or 0)
            taught = c.post("/demonstrations", json=build_demonstration_request(
                cloud.points, box_top_grasp(pose, BOX), cloud.viewpoints))
            between = int(f.stats()["BACKEND"]["wretr"] or 0)
            detected = c.post("/detect", json=build_detect_request(cloud.points, cloud.viewpoints, num_samples=30))
            after = int(f.stats()["BACKEND"]["wretr"] or 0)
        finally:
            server.send_signal(signal.SIGCONT)
    assert taught.status_code == 504 and between == before, (taught.status_code, before, between)
    assert detected.status_code in (503, 504) and after > between, (detected.status_code, between, after)


def test_a_fleet_shares_one_postgresql_template_library(fleet: ModuleType, library_url: str, render_box,
                                                         box_pose, tmp_path: Path) -> None:
    """Two servers on one fresh PostgreSQL database, both opening it at the same moment (the first open creates
    the tables): a grasp taught through HAProxy is found by both, and a failure reported through HAProxy (on
    either server) reaches the library both read."""
    pose = box_pose()
    cloud = render_box(pose)
    with fleet.Fleet(2, tmp_path, env={"GRASPD_TEMPLATE_LIBRARY": library_url}) as f, \
            httpx.Client(base_url=f.url, timeout=60) as c:
        with ThreadPoolExecutor(2) as pool:  # the library opens on first use: both servers at once
            empty = list(pool.map(lambda n: httpx.get(f"{f.server_url(n)}/library", timeout=60), f.names))
        assert [r.status_code for r in empty] == [200, 200], [r.text for r in empty]
        assert [r.json()["num_entries"] for r in empty] == [0, 0]
        taught = c.post("/demonstrations", json=build_demonstration_request(
            cloud.points, box_top_grasp(pose, BOX), cloud.viewpoints, label="box top"))
        assert taught.status_code == 200, taught.text
        entry = taught.json()["entry_id"]
        answers: dict[str, dict[str, Any]] = {}
        for _ in range(10):  # leastconn takes turns between idle servers
            r = c.post("/detect", json=build_detect_request(cloud.points, cloud.viewpoints, method="templates",
                                                            max_grasps=3))
            assert r.status_code == 200, r.text
            answers.setdefault(r.headers[fleet.SERVER_HEADER], r.json())
            if len(answers) == 2:
                break
        assert set(answers) == {"graspd1", "graspd2"}
        for body in answers.values():
            assert body["num_entries"] == 1 and body["grasps"][0]["template_entry"] == entry
            assert np.linalg.norm(np.array(body["grasps"][0]["position"]) - box_top_grasp(pose, BOX)[:3, 3]) < 0.01
        for body in answers.values():  # each detection's failure, reported wherever HAProxy sends it
            r = c.post("/feedback", json=build_feedback_request(body["grasps"][0]["id"], success=False))
            assert r.status_code == 200, r.text
        libraries = [httpx.get(f"{f.server_url(n)}/library", timeout=30).json() for n in f.names]
    assert all(lib["num_entries"] == 1 and lib["num_failures"] >= 1 for lib in libraries), libraries
    assert libraries[0]["num_failures"] == libraries[1]["num_failures"]


CONTROLS = {
    "retry-on conn-failure only (HAProxy's default)": (r"(?m)^(\s*)retry-on .*$", r"\1retry-on conn-failure"),
    "tune.bufsize 16384 (HAProxy's default)": (r"(?m)^(\s*)tune\.bufsize .*$", r"\1tune.bufsize 16384"),
    "no option http-buffer-request": (r"(?m)^\s*option http-buffer-request\s*$", ""),
}


@pytest.mark.slow
@pytest.mark.parametrize("change", list(CONTROLS))
def test_without_each_piece_of_the_replay_config_the_same_kill_fails_a_request(
        fleet: ModuleType, mug_1mb: bytes, tmp_path: Path, change: str) -> None:
    """Controls (~10 s each): the shipped config with one piece the replay needs undone, the same kill as the
    main test (two servers here) fails at least one request: the client gets an error for the request the dead
    server was computing."""
    pattern, replacement = CONTROLS[change]
    config, n = re.subn(pattern, replacement, fleet.CONFIG.read_text())
    assert n == 1, f"{change}: the line to change is not in haproxy.cfg"
    with fleet.Fleet(2, tmp_path, config=config) as f:
        run = fleet.kill_mid_run(f, mug_1mb, clients=3, requests=30, victim="graspd1", after=2)
    assert run.killed_in_flight >= 1
    assert run.failed(), f"{change}: no request failed, so the main test could not tell it apart"
