"""Zenoh guarded like HTTP: with GRASPD_TOKEN set every queryable and the stream need the token as the attachment
(401 error reply otherwise, nothing done, writers untouched, wildcards refused), payloads over the size cap get
413 before parsing, over-deep JSON gets an error reply, the Zenoh config file passes through (user/password auth
tested end to end), and a server exposed beyond loopback with no authentication refuses to start."""

from __future__ import annotations

import json
import logging
import shutil
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from fixtures import KRYLON_VIEWPOINT, box_top_grasp
from graspd.core.cloud import ViewpointCloud
from graspd.server.app import create_app
from graspd.server.requests import parse_request
from graspd.server.settings import Settings
from graspd.server.zenoh.node import (
    ZenohSetupError,
    check_exposure,
    exposure,
    in_fresh_context,
    is_local_endpoint,
    zenoh_config,
)
from graspd_client import RequestRejected, build_demonstration_request, build_feedback_request
from graspd_client.wire import zenoh_token_attachment
from graspd_client.zenoh_client import ZenohGraspClient
from graspd_client.zenoh_client import zenoh_config as client_config

from .conftest import free_port

TOKEN = "s3cret-zenoh-token-0123456789"
CAP = 4_000_000  # bytes: a demonstration (~1 MB of JSON lists) fits, the oversized payload does not
BOX = (0.05, 0.10, 0.08)
HEADERS = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture
def guarded(make_settings: Callable[..., Settings]) -> Iterator[tuple[TestClient, str]]:
    """A server with a token, a small size cap and the stream on; its HTTP test client and Zenoh endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = make_settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_instance="solo",
                             stream_num_samples=30, token=TOKEN, max_body_bytes=CAP)
    with TestClient(create_app(settings)) as c:
        yield c, endpoint


def _replies(session: Any, key: str, payload: bytes = b"", attachment: bytes | None = None) -> list[Any]:
    """Every reply (ok or error) to a query on key from every matching queryable."""
    import zenoh  # noqa: PLC0415

    return list(session.get(key, payload=payload, attachment=attachment, target=zenoh.QueryTarget.ALL,
                            consolidation=zenoh.ConsolidationMode.NONE, timeout=10))


def _error(reply: Any) -> dict[str, Any]:
    assert reply.err is not None, "expected an error reply"
    body: dict[str, Any] = json.loads(reply.err.payload.to_bytes())
    return body


def _counts(http: TestClient) -> tuple[int, int, int]:
    lib = http.get("/library", headers=HEADERS).json()
    return lib["num_entries"], lib["num_failures"], lib["num_outcomes"]


def _demo_body(render_box: Callable[..., ViewpointCloud], box_pose: Callable[..., np.ndarray]) -> bytes:
    pose = box_pose()
    cloud = render_box(pose)
    body = build_demonstration_request(cloud.points, box_top_grasp(pose, BOX), cloud.viewpoints, label="box")
    return json.dumps(body).encode()


KEYS = ["detect", "instances/solo", "instances/solo/detect", "demonstrations", "feedback", "library", "config"]


@pytest.mark.parametrize("attachment", [None, b"Bearer wrong-token", b"s3cret-zenoh-token-0123456789",
                                        zenoh_token_attachment(TOKEN) + b" "], ids=["none", "wrong", "bare", "padded"])
def test_anonymous_peer_refused_on_every_queryable(guarded: tuple[TestClient, str], body: dict[str, Any],
                                                   attachment: bytes | None) -> None:
    """Each queryable answers a query without the right attachment with HTTP's 401 body, and does nothing."""
    import zenoh  # noqa: PLC0415

    http, endpoint = guarded
    payloads = {"detect": json.dumps(body).encode(), "instances/solo/detect": json.dumps(body).encode(),
                "feedback": json.dumps(build_feedback_request("0123456789abcdef-0", False)).encode()}
    with zenoh.open(client_config(connect=[endpoint])) as session:
        for key in KEYS:
            replies = _replies(session, f"graspd/{key}", payloads.get(key, b""), attachment)
            assert len(replies) == 1, key
            err = _error(replies[0])
            assert err["status"] == 401 and err["field"] == "attachment", (key, err)
            assert set(err) >= {"error", "field", "detail"}
    metrics = http.get("/metrics", headers=HEADERS).text
    assert 'graspd_requests_total{outcome="unauthorized",transport="zenoh"} 2.0' in metrics
    assert 'graspd_requests_total{outcome="ok",transport="zenoh"}' not in metrics  # no detection ran


def test_writers_never_act_for_anonymous_peers(guarded: tuple[TestClient, str], render_box: Any,
                                               box_pose: Any) -> None:
    """Demonstrations and feedback without the token leave the library as it was; with it they write."""
    http, endpoint = guarded
    demo = _demo_body(render_box, box_pose)
    with ZenohGraspClient(connect=[endpoint], timeout=60, retries=0) as anon, \
            ZenohGraspClient(connect=[endpoint], timeout=60, retries=0, token=TOKEN) as robot:
        with pytest.raises(RequestRejected) as info:
            anon.query(demo, "graspd/demonstrations")
        assert info.value.status == 401
        assert _counts(http) == (0, 0, 0)
        entry = robot.query(demo, "graspd/demonstrations")["entry_id"]
        assert _counts(http) == (1, 0, 0)

        pose = box_pose()
        cloud = render_box(pose)
        grasps = robot.detect(cloud.points, cloud.viewpoints, method="templates", max_grasps=3)
        assert len(grasps) > 0 and entry == 1
        with pytest.raises(RequestRejected) as info:
            anon.feedback(grasps.ids[0], success=False)
        assert info.value.status == 401
        assert _counts(http) == (1, 0, 0)
        robot.feedback(grasps.ids[0], success=False)
        assert _counts(http) == (1, 1, 1)


def test_wildcard_query_reaches_no_writer_or_detector(guarded: tuple[TestClient, str]) -> None:
    """graspd/** without the token: every queryable answers 401; with the token, detectors and writers still
    refuse a query not addressed to their exact key (400 naming key_expr); the library is untouched."""
    import zenoh  # noqa: PLC0415

    http, endpoint = guarded
    with zenoh.open(client_config(connect=[endpoint])) as session:
        anon = _replies(session, "graspd/**", b"{}")
        assert len(anon) == len(KEYS)
        assert {_error(r)["status"] for r in anon} == {401}
        signed = _replies(session, "graspd/**", b"{}", zenoh_token_attachment(TOKEN))
    errors = [_error(r) for r in signed if r.err is not None]
    assert len(errors) == len(KEYS) - 1 and {e["status"] for e in errors} == {400}  # all but instance info
    assert {e["field"] for e in errors} == {"key_expr"}
    assert _counts(http) == (0, 0, 0)
    assert 'outcome="ok",transport="zenoh"' not in http.get("/metrics", headers=HEADERS).text


def test_token_accepted_via_the_client(guarded: tuple[TestClient, str], krylon: ViewpointCloud,
                                       caplog: pytest.LogCaptureFixture) -> None:
    """ZenohGraspClient(token=...) detects, lists instances and reads the library; the token is never logged."""
    http, endpoint = guarded
    caplog.set_level(logging.DEBUG)
    with ZenohGraspClient(connect=[endpoint], timeout=60, token=TOKEN) as zc:
        assert len(zc.detect(krylon.points, krylon.viewpoints, num_samples=20)) > 0
        assert [i["instance"] for i in zc.instances()] == ["solo"]
        assert zc.library()["num_entries"] == 0
    with ZenohGraspClient(connect=[endpoint], timeout=10) as anon:
        assert anon.instances() == []  # the info queryable refuses too; discovery just finds nothing
    assert TOKEN not in caplog.text
    assert 'graspd_requests_total{outcome="ok",transport="zenoh"} 1.0' in http.get("/metrics", headers=HEADERS).text


def test_stream_without_the_token_is_dropped(guarded: tuple[TestClient, str], krylon: ViewpointCloud,
                                             caplog: pytest.LogCaptureFixture) -> None:
    """Anonymous clouds on graspd/cloud are dropped (counted, one WARNING without the token); the client's
    published clouds carry the token and get grasps."""
    import zenoh  # noqa: PLC0415

    http, endpoint = guarded
    caplog.set_level(logging.INFO)
    got: list[dict[str, Any]] = []
    done = threading.Event()

    def on_grasps(sample: Any) -> None:
        got.append(json.loads(sample.payload.to_bytes()))
        done.set()

    payload = json.dumps({"cloud": {"points": krylon.points.tolist(), "viewpoints": [list(KRYLON_VIEWPOINT)]},
                          "num_samples": 20}).encode()
    with zenoh.open(client_config(connect=[endpoint])) as session, \
            ZenohGraspClient(connect=[endpoint], timeout=30, token=TOKEN) as robot:
        sub = session.declare_subscriber("graspd/grasps", on_grasps)
        pub = session.declare_publisher("graspd/cloud")
        deadline = time.monotonic() + 30
        while not pub.matching_status.matching and time.monotonic() < deadline:  # the server's subscription known
            time.sleep(0.05)
        for _ in range(50):
            pub.put(payload)
            pub.put(payload, attachment=b"Bearer nope")
            time.sleep(0.05)
        assert not done.wait(1.0) and got == []
        for _ in range(50):
            robot.publish(payload)
            if done.wait(0.3):
                break
        assert done.wait(30)
        sub.undeclare()
    assert "grasps" in got[0] and len(got[0]["grasps"]) > 0
    metrics = http.get("/metrics", headers=HEADERS).text
    assert 'graspd_requests_total{outcome="unauthorized",transport="zenoh-stream"} 100.0' in metrics
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING and "without the token" in r.getMessage()]
    assert len(warnings) == 1  # rate-limited, not one line per dropped cloud
    assert TOKEN not in caplog.text


def test_oversized_payload_gets_413_before_parsing(guarded: tuple[TestClient, str]) -> None:
    """A payload over max_body_bytes gets a 413 error body on the detect key and on a writer."""
    _, endpoint = guarded
    big = b"{" + b" " * CAP + b"}"  # valid JSON if parsed: the 413 comes from the size alone
    with ZenohGraspClient(connect=[endpoint], timeout=30, retries=0, token=TOKEN) as zc:
        for key in ("graspd/detect", "graspd/demonstrations"):
            with pytest.raises(RequestRejected) as info:
                zc.query(big, key)
            assert info.value.status == 413 and info.value.field == "payload"


@pytest.mark.parametrize("depth", [1_000, 100_000])
def test_deep_json_gets_an_error_reply(guarded: tuple[TestClient, str], depth: int) -> None:
    """JSON nested 1,000 and 100,000 deep gets a 4xx error reply on detect and on the writers, never silence."""
    _, endpoint = guarded
    deep = b'{"cloud": {"points": ' + b"[" * depth + b"]" * depth + b"}}"
    nested = b'{"grasp_id": ' + b'{"a": ' * depth + b"1" + b"}" * depth + b', "success": false}'
    with ZenohGraspClient(connect=[endpoint], timeout=30, retries=0, token=TOKEN) as zc:
        for payload, key in ((deep, "graspd/detect"), (deep, "graspd/demonstrations"), (nested, "graspd/feedback")):
            with pytest.raises(RequestRejected) as info:
                zc.query(payload, key)
            assert 400 <= info.value.status < 500, (key, info.value.body)


def test_a_500_names_only_the_request_id(guarded: tuple[TestClient, str], caplog: pytest.LogCaptureFixture) -> None:
    """A server fault behind a Zenoh queryable answers 500 with a generic message and the request id, never the
    exception text; the log lines for it (the traceback, the outcome) carry the same id."""
    import zenoh  # noqa: PLC0415

    http, endpoint = guarded
    node = http.app.state.service.zenoh  # type: ignore[attr-defined]

    def buggy(_payload: bytes) -> Any:
        raise RuntimeError("secret internal state 0xdeadbeef")

    on_query = in_fresh_context(node.queries.on_templates)  # a writer with a bug: the node's guard is tested
    boom = node.session.declare_queryable("graspd/boom", lambda q: on_query(q, "boom", "graspd/boom", buggy),
                                          complete=True)
    def outcome_lines() -> list[logging.LogRecord]:
        return [r for r in caplog.records if r.getMessage() == "boom"]

    try:
        with caplog.at_level(logging.INFO), zenoh.open(client_config(connect=[endpoint])) as session:
            replies = _replies(session, "graspd/boom", b"{}", zenoh_token_attachment(TOKEN))
            deadline = time.monotonic() + 5  # the outcome line is written just after the reply is sent
            while not outcome_lines() and time.monotonic() < deadline:
                time.sleep(0.01)
    finally:
        boom.undeclare()
    assert len(replies) == 1
    err = _error(replies[0])
    text = json.dumps(err)
    assert err["status"] == 500 and "deadbeef" not in text and "RuntimeError" not in text
    rid = err["request_id"]
    assert len(rid) == 16 and rid in err["error"]
    failed = [r for r in caplog.records if r.getMessage() == "zenoh boom failed"]
    assert len(failed) == 1 and failed[0].exc_info is not None  # the traceback is in the log, not the answer
    assert failed[0].request_id == rid  # type: ignore[attr-defined]
    outcome = outcome_lines()
    assert len(outcome) == 1 and outcome[0].request_id == rid and outcome[0].status == 500  # type: ignore[attr-defined]


def test_full_queue_answers_503_before_parsing(make_settings: Callable[..., Settings], krylon: ViewpointCloud,
                                               small_body: Callable[..., dict[str, Any]]) -> None:
    """With every worker busy and no queue, a query gets 503 with Retry-After before its payload is parsed
    (garbage gets 503, not 400); once free, the same garbage gets its 400, and the reply's request id."""
    import zenoh  # noqa: PLC0415

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = make_settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_stream=False, detect_workers=1,
                             queue_size=0)
    with TestClient(create_app(settings)) as http, zenoh.open(client_config(connect=[endpoint])) as session:
        engine = http.app.state.service.engine  # type: ignore[attr-defined]
        slow, _ = engine.submit(parse_request(small_body(krylon, num_samples=3000)), {})
        (busy,) = _replies(session, "graspd/detect", b"{not json")
        running = not slow.done()
        slow.result(timeout=120)
        (invalid,) = _replies(session, "graspd/detect", b"{not json")
    assert running, "the slow detection ended before the query: the test proves nothing"
    err = _error(busy)
    assert err["status"] == 503 and 1 <= err["retry_after"] <= settings.max_retry_after_s
    err = _error(invalid)
    assert err["status"] == 400 and err["field"] == "body" and len(err["request_id"]) == 16
    assert engine.pending == 0  # the refused and the parsed-and-refused queries gave their places back


# ---- configuration -----------------------------------------------------------------------------


def test_endpoints_judged_local_or_exposed() -> None:
    assert is_local_endpoint("tcp/127.0.0.1:7447") and is_local_endpoint("tls/[::1]:7447")
    assert is_local_endpoint("tcp/localhost:7447") and is_local_endpoint("unixsock-stream//run/graspd.sock")
    assert is_local_endpoint("udp/127.0.0.2:7447#iface=lo")
    for ep in ("tcp/0.0.0.0:7447", "tcp/[::]:7447", "tls/robot.local:7447", "tcp/192.168.1.10:7447"):
        assert not is_local_endpoint(ep), ep


def test_exposed_without_authentication_refuses_to_start(make_settings: Callable[..., Settings],
                                                         tmp_path: Path) -> None:
    """Listening on every interface needs a token, authentication in the config file, or an explicit opt-in."""
    settings = make_settings(zenoh_enabled=True, zenoh_listen=["tcp/0.0.0.0:7447"])
    conf = zenoh_config(settings)
    assert exposure(conf) == ["tcp/0.0.0.0:7447"]
    with pytest.raises(ZenohSetupError, match="GRASPD_TOKEN"):
        check_exposure(settings, conf)
    with pytest.raises(ZenohSetupError, match="reachable"), TestClient(create_app(settings)):
        pass  # the server does not come up
    check_exposure(make_settings(zenoh_listen=["tcp/0.0.0.0:7447"], token="t"), conf)
    check_exposure(make_settings(zenoh_listen=["tcp/0.0.0.0:7447"], zenoh_allow_anonymous=True), conf)
    assert exposure(zenoh_config(make_settings())) == []  # the default: loopback, multicast off
    auth = tmp_path / "auth.json5"
    auth.write_text('{ transport: { auth: { usrpwd: { user: "graspd", password: "pw", '
                    'dictionary_file: "users.txt" } } } }')
    exposed = make_settings(zenoh_listen=["tcp/0.0.0.0:7447"], zenoh_config=auth)
    check_exposure(exposed, zenoh_config(exposed))
    multicast = make_settings(zenoh_multicast=True)
    assert exposure(zenoh_config(multicast)) == ["multicast scouting"]


def test_config_file_keys_win_and_settings_fill_in(make_settings: Callable[..., Settings], tmp_path: Path) -> None:
    path = tmp_path / "zenoh.json5"
    path.write_text('// a robot cell\n{ mode: "client", connect: { endpoints: ["tcp/10.0.0.2:7447"] } }')
    conf = zenoh_config(make_settings(zenoh_config=path, zenoh_listen=["tcp/127.0.0.1:9999"]))
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/10.0.0.2:7447"]
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:9999"]  # not in the file
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    with pytest.raises(ZenohSetupError, match="GRASPD_ZENOH_CONFIG"):
        zenoh_config(make_settings(zenoh_config=tmp_path / "missing.json5"))
    (tmp_path / "bad.json5").write_text("{ mode: ")
    with pytest.raises(ZenohSetupError, match="not a valid Zenoh config"):
        zenoh_config(make_settings(zenoh_config=tmp_path / "bad.json5"))


def test_user_password_config_end_to_end(make_settings: Callable[..., Settings], tmp_path: Path,
                                         krylon: ViewpointCloud) -> None:
    """The README's setup minus TLS: the server's config file requires Zenoh user/password authentication;
    a client with the credentials and the token detects, a client without credentials gets no session."""
    import zenoh  # noqa: PLC0415

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    (tmp_path / "users.txt").write_text("robot:arm-password\n")
    server_conf = tmp_path / "server.json5"
    server_conf.write_text(json.dumps({"transport": {"auth": {"usrpwd": {
        "user": "graspd", "password": "server-password", "dictionary_file": str(tmp_path / "users.txt")}}}}))
    client_conf = tmp_path / "client.json5"
    client_conf.write_text(json.dumps({"transport": {"auth": {"usrpwd": {"user": "robot",
                                                                         "password": "arm-password"}}}}))
    settings = make_settings(zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_config=server_conf, token=TOKEN,
                             zenoh_stream=False)
    with TestClient(create_app(settings)):
        with ZenohGraspClient(connect=[endpoint], timeout=30, token=TOKEN, config=client_conf) as zc:
            assert len(zc.detect(krylon.points, krylon.viewpoints, num_samples=20)) > 0
        stranger = client_conf.with_name("stranger.json5")
        stranger.write_text(json.dumps({"transport": {"auth": {"usrpwd": {"user": "robot", "password": "guess"}}}}))
        for conf in (client_config(connect=[endpoint]), client_config(connect=[endpoint], config_file=stranger)):
            with zenoh.open(conf) as session:
                assert _replies(session, "graspd/library", attachment=zenoh_token_attachment(TOKEN)) == []


def _make_certs(folder: Path) -> None:
    """A CA and a server certificate for 127.0.0.1/localhost (P-256), with the openssl command."""

    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is not installed (needed to make test certificates)")
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]

    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=folder, check=True, capture_output=True, timeout=60)

    run("req", "-x509", *ec, "-keyout", "ca-key.pem", "-out", "ca.pem", "-days", "2", "-subj", "/CN=graspd test CA")
    run("req", *ec, "-keyout", "server-key.pem", "-out", "server.csr", "-subj", "/CN=localhost")
    (folder / "san.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    run("x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem", "-CAcreateserial",
        "-out", "server.pem", "-days", "2", "-extfile", "san.ext")


def _example(name: str, out: Path, **overrides: Any) -> Path:
    """examples/zenoh/<name> as Zenoh reads it, with some keys replaced (paths, endpoints), written to out."""
    import zenoh  # noqa: PLC0415

    conf = zenoh.Config.from_file(str(Path(__file__).resolve().parents[2] / "examples" / "zenoh" / name))
    for key, value in overrides.items():
        conf.insert_json5(key.replace("__", "/"), json.dumps(value))
    out.write_text(str(conf))
    return out


def test_example_secure_deployment_end_to_end(make_settings: Callable[..., Settings], tmp_path: Path,
                                              krylon: ViewpointCloud) -> None:
    """The README's secure deployment (examples/zenoh/*.json5: TLS, user/password, access control, and the
    token): the robot detects; no credentials, a user the access rules do not name, a plain-TCP peer and a
    robot without the token get nothing done."""
    import zenoh  # noqa: PLC0415

    _make_certs(tmp_path)
    port = free_port()
    (tmp_path / "users.txt").write_text("robot:robot-pw\nviewer:viewer-pw\n")
    tls = {"transport__link__tls__root_ca_certificate": str(tmp_path / "ca.pem")}
    server_conf = _example("graspd-server.json5", tmp_path / "server.json", **tls,
                           listen__endpoints=[f"tls/127.0.0.1:{port}"],
                           transport__link__tls__listen_certificate=str(tmp_path / "server.pem"),
                           transport__link__tls__listen_private_key=str(tmp_path / "server-key.pem"),
                           transport__auth__usrpwd__dictionary_file=str(tmp_path / "users.txt"))
    robot = _example("robot.json5", tmp_path / "robot.json", **tls, transport__auth__usrpwd__password="robot-pw")
    viewer = _example("robot.json5", tmp_path / "viewer.json", **tls, transport__auth__usrpwd__user="viewer",
                      transport__auth__usrpwd__password="viewer-pw")
    stranger = _example("robot.json5", tmp_path / "stranger.json", **tls, transport__auth__usrpwd__password="guess")
    endpoint = f"tls/127.0.0.1:{port}"
    settings = make_settings(zenoh_enabled=True, zenoh_config=server_conf, token=TOKEN, zenoh_stream=False,
                             zenoh_listen=["tcp/127.0.0.1:1"])  # ignored: the file sets listen
    with TestClient(create_app(settings)) as http:
        with ZenohGraspClient(connect=[endpoint], timeout=30, token=TOKEN, config=robot) as zc:
            assert len(zc.detect(krylon.points, krylon.viewpoints, num_samples=20)) > 0
            assert zc.library()["num_entries"] == 0
        with ZenohGraspClient(connect=[endpoint], timeout=30, retries=0, config=robot) as no_token:
            with pytest.raises(RequestRejected) as info:
                no_token.library()
            assert info.value.status == 401
        for conf in (viewer, stranger, None):
            config = client_config(connect=[endpoint], config_file=conf) if conf else \
                client_config(connect=[f"tcp/127.0.0.1:{port}"])
            with zenoh.open(config) as session:
                assert _replies(session, "graspd/library", attachment=zenoh_token_attachment(TOKEN)) == [], conf
        assert 'graspd_requests_total{outcome="ok",transport="zenoh"} 1.0' in http.get("/metrics", headers=HEADERS).text
