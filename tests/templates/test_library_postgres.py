"""The template library on a real PostgreSQL server that the test starts itself (Debian's postgresql package,
installed by scripts/setup.sh; initdb/pg_ctl run as the postgres user when the tests run as root), with
password authentication over TCP: teach, detect, fail, reopen; a wrong password answers 503 without the
password in the body, the Zenoh reply or the log."""

from __future__ import annotations

import glob
import json
import logging
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import quote

import pytest
from fastapi.testclient import TestClient

from fixtures import box_top_grasp
from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd.templates import TemplateDetector, TemplateLibrary
from graspd_client.zenoh_client import zenoh_config

BOX = (0.05, 0.10, 0.08)
PASSWORD = "pg-S3cret/with@chars"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _server_bin() -> Path | None:
    """The folder of initdb/pg_ctl: on PATH, else Debian's /usr/lib/postgresql/<version>/bin (newest)."""
    found = shutil.which("initdb")
    if found and shutil.which("pg_ctl"):
        return Path(found).resolve().parent
    versions = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(Path(p).parts[-3]))
    return Path(versions[-1]).parent if versions else None


@pytest.fixture(scope="module")
def postgres() -> Iterator[tuple[str, int]]:
    """A throwaway PostgreSQL server on 127.0.0.1 with scram-sha-256 password auth and a database "graspd";
    yields (host, port).  The superuser "postgres" has PASSWORD."""
    pytest.importorskip("psycopg", reason="the postgres extra is not installed (pip install -e '.[postgres]')")
    bindir = _server_bin()
    if bindir is None:
        pytest.skip("no PostgreSQL server binaries (initdb, pg_ctl): apt-get install postgresql (scripts/setup.sh)")
    run_as: list[str] = []
    if os.geteuid() == 0:  # the server refuses to run as root
        try:
            pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no postgres user to run the server as")
        run_as = ["runuser", "-u", "postgres", "--"]
    base = Path(tempfile.mkdtemp(prefix="graspd-pg-"))  # outside pytest's 0700 folders: the server user reads it
    os.chmod(base, 0o777)
    pwfile = base / "pw"
    pwfile.write_text(PASSWORD + "\n")
    os.chmod(pwfile, 0o644)
    data, port = base / "data", _free_port()
    try:
        subprocess.run([*run_as, str(bindir / "initdb"), "-D", str(data), "-U", "postgres", "--pwfile", str(pwfile),
                        "--auth-local=trust", "--auth-host=scram-sha-256", "-E", "UTF8"],
                       check=True, capture_output=True, timeout=120)
        pwfile.unlink()
        subprocess.run([*run_as, str(bindir / "pg_ctl"), "-D", str(data), "-w", "-t", "60", "-l", str(base / "log"),
                        "-o", f"-p {port} -k {base} -c listen_addresses=127.0.0.1 -c fsync=off", "start"],
                       check=True, capture_output=True, timeout=120)
    except subprocess.CalledProcessError as exc:
        log = (base / "log").read_text() if (base / "log").exists() else ""
        shutil.rmtree(base, ignore_errors=True)
        raise AssertionError(f"PostgreSQL did not start: {exc.stderr!r} {log}") from None
    try:
        subprocess.run([*run_as, str(bindir / "createdb"), "-h", str(base), "-p", str(port), "-U", "postgres",
                        "graspd"], check=True, capture_output=True, timeout=60)
        yield "127.0.0.1", port
    finally:
        subprocess.run([*run_as, str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"],
                       capture_output=True, timeout=60)
        shutil.rmtree(base, ignore_errors=True)


def _url(host: str, port: int, password: str = PASSWORD) -> str:
    return f"postgresql+psycopg://postgres:{quote(password, safe='')}@{host}:{port}/graspd"


def test_library_on_a_real_postgresql_server(postgres: tuple[str, int], render_box, box_pose) -> None:
    """Teach a grasp, find it, report a failure, reopen: everything is in the PostgreSQL database."""
    url = _url(*postgres)
    pose = box_pose()
    cloud = render_box(pose)
    with TemplateLibrary(url) as lib:
        assert lib.engine.dialect.name == "postgresql"
        base = lib.summary()["num_entries"]
        entry = lib.add_demonstration(cloud, box_top_grasp(pose, BOX), label="box top")
        det = TemplateDetector(lib).detect(cloud, max_grasps=3)
        assert len(det.grasps) > 0 and det.detection_id is not None
        lib.add_feedback(f"{det.detection_id}.0", success=False)
    with TemplateLibrary(url) as again:  # a restart: a new engine on the same database
        summary = again.summary()
        assert summary["num_entries"] == base + 1 and summary["num_failures"] >= 1
        assert [e for e in summary["entries"] if e["id"] == entry][0]["label"] == "box top"


def test_wrong_password_answers_503_without_the_password(postgres: tuple[str, int],
                                                         caplog: pytest.LogCaptureFixture, tmp_path: Path) -> None:
    """The server rejects the password: GET /library and graspd/library answer 503 naming template_library,
    and neither they nor the log hold the wrong password (nor the right one)."""
    import zenoh  # noqa: PLC0415

    caplog.set_level(logging.DEBUG)
    wrong = "WrongPassw0rd/guess"
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    settings = Settings(template_library=_url(*postgres, password=wrong), models_dir=tmp_path / "no-models",
                        data_dir=tmp_path / "data", detect_workers=1, zenoh_listen=[endpoint], zenoh_stream=False)
    with TestClient(create_app(settings)) as http:
        r = http.get("/library")
        with zenoh.open(zenoh_config(connect=[endpoint])) as session:
            replies = list(session.get("graspd/library", timeout=30))
    assert r.status_code == 503 and r.json()["field"] == "template_library", r.text
    # the answer names the component and a request id, never the driver's text; the reason is in the log
    assert "template library" in r.json()["error"] and "request" in r.json()["error"]
    assert "password authentication failed" in "".join(repr(rec.__dict__) for rec in caplog.records)
    assert len(replies) == 1 and replies[0].err is not None
    reply = replies[0].err.payload.to_bytes().decode()
    assert json.loads(reply)["status"] == 503
    logged = caplog.text + "".join(repr(rec.__dict__) for rec in caplog.records)
    for text in (r.text, reply, logged):
        for secret in (wrong, quote(wrong, safe=""), PASSWORD, quote(PASSWORD, safe="")):
            assert secret not in text
