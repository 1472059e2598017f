"""The library store: survives a restart, loses nothing under 8 concurrent writers, migrates old schemas,
and rejects bad input with errors that name the field."""

from __future__ import annotations

import multiprocessing as mp
import os
import pwd
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import sqlalchemy as sa

from fixtures import box_top_grasp
from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.store.database import SCHEMA_VERSION, make_engine, migrate
from graspd.templates import TemplateDetector, TemplateError, TemplateLibrary

REPO = Path(__file__).resolve().parents[2]
BOX = (0.05, 0.10, 0.08)
T = 900

WRITER = """
import sys, numpy as np
from graspd.templates import TemplateLibrary
url, who, count = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
lib = TemplateLibrary(url)
rng = np.random.default_rng(who)
for k in range(count):
    h = rng.uniform(0, 0.09, 900).astype(np.float32)
    t = rng.integers(0, 4, 900).astype(np.uint8)
    e = lib.insert_entry(h, t, np.eye(4), np.eye(4), 0.05, label=f"w{who}-{k}")
    det = lib.record_detection(h[None], t[None], np.array([e]), np.eye(4)[None], np.array([0.05]), np.array([0.1]))
    lib.add_feedback(det + ".0", success=False)
"""


def _random_entry(lib: TemplateLibrary, rng: np.random.Generator, label: str) -> int:
    h = rng.uniform(0, 0.09, T).astype(np.float32)
    t = rng.integers(0, 4, T).astype(np.uint8)
    return lib.insert_entry(h, t, np.eye(4), np.eye(4), 0.05, label=label)


def test_library_survives_a_restart(render_box, box_pose, library_url) -> None:
    url = library_url()
    pose = box_pose()
    cloud = render_box(pose)
    lib = TemplateLibrary(url)
    entry = lib.add_demonstration(cloud, box_top_grasp(pose, BOX), label="top")
    det = TemplateDetector(lib).detect(cloud, max_grasps=3)
    lib.add_feedback(det.grasp_ids[0], success=False)
    before = lib.snapshot()
    lib.close()
    again = TemplateLibrary(url)  # a new process would do the same: nothing is cached across opens
    after = again.snapshot()
    assert after.entry_ids.tolist() == [entry]
    assert np.array_equal(after.heights, before.heights) and np.array_equal(after.types, before.types)
    assert np.array_equal(after.grasps, before.grasps) and len(after.f_heights) == 1
    assert again.entry(entry)["label"] == "top" and again.entry(entry)["num_failures"] == 1
    assert again.hand == HandGeometry()
    # feedback on a grasp from before the restart still resolves
    assert again.add_feedback(det.grasp_ids[1], success=True).entry_id == entry


def _eight_writers(url: str, count: int) -> dict:
    """Eight processes open the (new) library at once, then each adds count entries, detections and failures."""
    env = {"PYTHONPATH": f"{REPO / 'service'}:{REPO / 'client'}", "PATH": "/usr/bin:/bin"}
    procs = [subprocess.Popen([sys.executable, "-c", WRITER, url, str(w), str(count)], env=env,
                              stderr=subprocess.PIPE) for w in range(8)]
    errors = [p.communicate(timeout=240)[1].decode() for p in procs]
    assert all(p.returncode == 0 for p in procs), errors
    return TemplateLibrary(url).summary()


def test_eight_concurrent_processes_lose_nothing(library_url) -> None:
    count = 6
    summary = _eight_writers(library_url("procs"), count)
    assert summary["num_entries"] == 8 * count
    assert summary["num_failures"] == 8 * count and summary["num_outcomes"] == 8 * count
    assert summary["num_detections"] == 8 * count
    labels = {e["label"] for e in summary["entries"]}
    assert labels == {f"w{w}-{k}" for w in range(8) for k in range(count)}
    assert all(e["failures"] == 1 for e in summary["entries"])


def _open_at(url: str, start: float, errors: Any) -> None:
    """At the wall-clock time start, connect to the (new) store at url and write a row; report any error."""
    engine = make_engine(url)
    while time.time() < start:  # spin, not sleep: the openers must collide
        pass
    try:
        with engine.begin() as conn:
            conn.execute(sa.text("CREATE TABLE IF NOT EXISTS opened (pid INTEGER)"))
            conn.execute(sa.text("INSERT INTO opened VALUES (:pid)"), {"pid": os.getpid()})
    except BaseException as exc:  # noqa: BLE001 - reported to the parent
        errors.put(repr(exc))


def test_processes_creating_one_store_at_once_all_open(tmp_path) -> None:
    # a fresh file's switch to WAL takes an exclusive lock without the busy handler: openers must wait for it
    fork = mp.get_context("fork")
    errors = fork.Queue()
    for trial in range(30):
        start = time.time() + 0.1
        procs = [fork.Process(target=_open_at, args=(f"sqlite:///{tmp_path}/at-once-{trial}.db", start, errors))
                 for _ in range(8)]
        for p in procs:
            p.start()
        for p in procs:
            p.join(60)
        assert all(p.exitcode == 0 for p in procs)
        reported = []
        while not errors.empty():
            reported.append(errors.get())
        assert reported == [], f"trial {trial}"
        with make_engine(f"sqlite:///{tmp_path}/at-once-{trial}.db").connect() as conn:
            assert conn.execute(sa.text("SELECT COUNT(DISTINCT pid) FROM opened")).scalar() == 8


@pytest.mark.parametrize("where", ["file", "memory"])
def test_eight_concurrent_threads_lose_nothing(library_url, where) -> None:
    lib = TemplateLibrary(library_url("threads") if where == "file" else "sqlite://")
    errors: list[BaseException] = []

    def write(who: int) -> None:
        try:
            rng = np.random.default_rng(who)
            for k in range(10):
                _random_entry(lib, rng, f"t{who}-{k}")
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(w,)) for w in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(lib.snapshot()) == 80 and lib.summary()["num_entries"] == 80


def test_old_schema_is_migrated_with_its_data(library_url) -> None:
    url = library_url("old")
    engine = make_engine(url)
    assert migrate(engine, target=1) == 1
    with engine.begin() as conn:  # a v1 library: outcomes had no image columns yet
        cols = {c["name"] for c in sa.inspect(conn).get_columns("outcomes")}
        assert "image" not in cols
        conn.execute(sa.text("INSERT INTO meta (key, value) VALUES ('hand', :h), ('geometry', :g)"),
                     {"h": '{"finger_width": 0.01, "hand_outer_diameter": 0.12, "hand_depth": 0.06, '
                           '"hand_height": 0.02, "init_bite": 0.01}', "g": '{"n": 30, "size": 0.15, "depth": 0.09}'})
        conn.execute(sa.text("INSERT INTO outcomes (grasp_id, success, entry_id, created_at, heights, types, pose, "
                             "width) VALUES ('a.0', 1, NULL, 0, :h, :t, :p, 0.05)"),
                     {"h": np.zeros(T, np.float32).tobytes(), "t": np.zeros(T, np.uint8).tobytes(),
                      "p": np.eye(4).tobytes()})
    engine.dispose()
    lib = TemplateLibrary(url)
    with lib.engine.connect() as conn:
        assert conn.execute(sa.text("SELECT version FROM schema_version")).scalar_one() == SCHEMA_VERSION
    old = list(lib.iter_outcomes())
    assert len(old) == 1 and old[0]["success"] and old[0]["image"] is None
    assert migrate(lib.engine) == SCHEMA_VERSION  # idempotent


def test_bad_input_names_the_field(render_box, box_pose, library_url) -> None:
    url = library_url()
    pose = box_pose()
    cloud = render_box(pose)
    lib = TemplateLibrary(url)
    with pytest.raises(TemplateError, match="hand_pose"):
        lib.add_demonstration(cloud, np.eye(3))
    with pytest.raises(TemplateError, match="hand_pose"):
        lib.add_demonstration(cloud, np.full((4, 4), np.nan))
    bad = box_top_grasp(pose, BOX)
    bad[:3, 0] *= 2.0
    with pytest.raises(TemplateError, match="hand_pose"):
        lib.add_demonstration(cloud, bad)
    away = box_top_grasp(pose, BOX)
    away[:3, 3] += np.array([0.5, 0.0, 0.0])  # nowhere near the object
    with pytest.raises(TemplateError, match="hand_pose"):
        lib.add_demonstration(cloud, away)
    with pytest.raises(TemplateError, match="cloud"):
        lib.add_demonstration({"points": []}, box_top_grasp(pose, BOX))
    few = ViewpointCloud(points=np.zeros((3, 3), np.float32), viewpoints=np.zeros((1, 3), np.float32))
    with pytest.raises((TemplateError, CloudError), match="cloud.points"):
        lib.add_demonstration(few, box_top_grasp(pose, BOX))
    with pytest.raises(TemplateError, match="grasp_id"):
        lib.add_feedback("no-such-grasp", success=False)
    with pytest.raises(TemplateError, match="grasp_id"):
        lib.add_feedback("0123456789abcdef.0", success=False)
    with pytest.raises(TemplateError, match="success"):
        lib.add_feedback("0123456789abcdef.0", success="yes")  # type: ignore[arg-type]
    with pytest.raises(TemplateError, match="max_grasps"):
        TemplateDetector(lib).detect(cloud, max_grasps=0)
    with pytest.raises(TemplateError, match="workspace"):
        TemplateDetector(lib).detect(cloud, workspace=(0.0, 1.0))  # type: ignore[arg-type]
    with pytest.raises(TemplateError, match="workspace"):
        TemplateDetector(lib).detect(cloud, workspace=(1.0, 0.0, -1.0, 1.0, -1.0, 1.0))
    with pytest.raises(TemplateError, match="hand"):
        TemplateLibrary(url, hand=HandGeometry(hand_depth=0.05))
    with pytest.raises(TemplateError, match="library_url"):
        TemplateLibrary("not a url")


@pytest.fixture(scope="module")
def postgres_url():
    """A throwaway PostgreSQL server (the system's initdb/pg_ctl, run as the postgres user when root)."""
    pytest.importorskip("psycopg")
    if not (shutil.which("initdb") and shutil.which("pg_ctl")):
        pytest.skip("PostgreSQL server binaries (initdb, pg_ctl) not installed")
    run_as: list[str] = []
    if os.geteuid() == 0:
        try:
            pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root without a postgres user to run the server")
        run_as = ["runuser", "-u", "postgres", "--"]
    base = Path(tempfile.mkdtemp(prefix="graspd-pg-"))  # outside pytest's 0700 folders: the server user reads it
    os.chmod(base, 0o777)
    data, port = base / "data", 54000 + os.getpid() % 1000
    subprocess.run([*run_as, "initdb", "-D", str(data), "-A", "trust", "-U", "postgres"], check=True,
                   capture_output=True)
    subprocess.run([*run_as, "pg_ctl", "-D", str(data), "-w", "-l", str(base / "log"), "-o",
                    f"-p {port} -k {base} -c listen_addresses=''", "start"], check=True, capture_output=True)
    try:
        subprocess.run([*run_as, "createdb", "-h", str(base), "-p", str(port), "-U", "postgres", "graspd"],
                       check=True, capture_output=True)
        yield f"postgresql+psycopg://postgres@/graspd?host={base}&port={port}"
    finally:
        subprocess.run([*run_as, "pg_ctl", "-D", str(data), "-m", "immediate", "stop"], capture_output=True)
        shutil.rmtree(base, ignore_errors=True)


@pytest.mark.slow
def test_eight_concurrent_processes_on_postgresql(postgres_url) -> None:
    count = 5
    summary = _eight_writers(postgres_url, count)
    assert summary["num_entries"] == summary["num_failures"] == summary["num_outcomes"] == 8 * count
    assert summary["schema_version"] == SCHEMA_VERSION
