"""The lab's jobs as Ray tasks (graspd_lab.cluster, graspd-lab[cluster]): the same bytes as one process for the
same seed (scene data, the labelled mesh dataset, an instance model's views), the same rounds for the clutter
and container benchmarks, and a rerun after an interruption skips the work already on disk.

One local Ray of 2 CPUs serves the module (its start costs a few seconds); the jobs see it is up and use it."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

ray = pytest.importorskip("ray", reason="Ray is not installed: pip install -e './lab[cluster]' (scripts/setup.sh "
                          "does) to test the lab's jobs as Ray tasks")
pytest.importorskip("pybullet", reason="the lab's jobs need pybullet (graspd-lab)")

from fixtures import write_mesh  # noqa: E402
from graspd_lab.cluster import Runner, start_ray  # noqa: E402
from graspd_lab.training.dataset import GenerationParams, generate_dataset  # noqa: E402
from graspd_lab.training.instance import InstanceParams, MeshSource, make_instance_dataset  # noqa: E402
from graspd_lab.training.scene_data import SceneParams, generate_scene_dataset  # noqa: E402
from graspd_lab.world.mesh_file import read_mesh_object  # noqa: E402
from graspd_lab.world.meshes import box_mesh  # noqa: E402
from repo_module import load_bench  # noqa: E402

RAY2 = Runner(workers=2, ray=True)
SCENES = SceneParams(scenes=3, views_per_scene=2, objects=(2, 3), num_samples=20, per_view=40, scenes_per_chunk=1)


@pytest.fixture(scope="module", autouse=True)
def local_ray() -> Iterator[None]:
    started = start_ray(RAY2)
    yield
    if started:
        ray.shutdown()


def _files(folder: Path) -> dict[str, bytes]:
    """Every file of a job's output but timing.json (wall time and the runner), by relative path; the folder's
    own name (in the manifest's command) reads OUT."""
    return {str(p.relative_to(folder)): p.read_bytes().replace(str(folder).encode(), b"OUT")
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != "timing.json"}


def _bench(name: str) -> ModuleType:
    return load_bench(name, f"bench_{name}_ray")


def _rounds(log: Path) -> dict[tuple[str, int], dict[str, Any]]:
    """The rounds in a rounds.jsonl by (setting, seed), without their wall times."""
    out = {}
    for line in log.read_text().splitlines():
        row = json.loads(line)
        for key in ("seconds", "detect_seconds"):
            row["round"].pop(key)
        out[(row["setting"], row["round"]["seed"])] = row
    return out


@pytest.fixture(scope="module")
def serial_scenes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("serial")
    generate_scene_dataset(out, SCENES, runner=Runner())
    return out


def test_scene_data_on_ray_is_byte_identical_to_one_process(serial_scenes: Path, tmp_path: Path) -> None:
    manifest = generate_scene_dataset(tmp_path, SCENES, runner=RAY2)
    assert manifest["dataset_sha256"] == json.loads((serial_scenes / "manifest.json").read_text())["dataset_sha256"]
    assert _files(tmp_path) == _files(serial_scenes)  # chunks, records, splits, manifest: every byte
    assert json.loads((tmp_path / "timing.json").read_text())["runner"] == "ray (local, 2 CPUs)"


def test_scene_data_on_ray_resumes_from_the_chunks_written(serial_scenes: Path, tmp_path: Path) -> None:
    for name in ("params.json", "chunk_00001.npz", "chunk_00001.npz.json"):  # interrupted after one chunk
        (tmp_path / name).write_bytes((serial_scenes / name).read_bytes())
    before = (tmp_path / "chunk_00001.npz").stat().st_mtime_ns
    generate_scene_dataset(tmp_path, SCENES, runner=RAY2)
    assert (tmp_path / "chunk_00001.npz").stat().st_mtime_ns == before  # skipped, not made again
    assert _files(tmp_path) == _files(serial_scenes)


def test_the_labelled_mesh_dataset_on_ray_is_byte_identical(tmp_path: Path) -> None:
    params = GenerationParams(seed=11, exemplars=60, num_urdfs=1, procedural=(("box", 1), ("cylinder", 1)),
                              views_per_object=3, num_samples=30, per_view=10, objects_per_chunk=1)
    one = generate_dataset(tmp_path / "one", params, runner=Runner())
    two = generate_dataset(tmp_path / "ray", params, runner=RAY2)
    assert one["dataset_sha256"] == two["dataset_sha256"]
    assert _files(tmp_path / "one") == _files(tmp_path / "ray")


def test_an_instance_models_views_on_ray_are_byte_identical(tmp_path: Path) -> None:
    mesh = write_mesh(tmp_path / "box.ply", box_mesh(0.05, 0.08, 0.15))
    params = InstanceParams(views=4, per_view=32)
    obj = read_mesh_object(mesh, "box", "box", params.hand)
    events: list[dict[str, Any]] = []
    one = make_instance_dataset(obj, tmp_path / "one", params)
    two = make_instance_dataset(obj, tmp_path / "ray", params, events.append, runner=RAY2,
                                source=MeshSource(str(mesh), "box", "box", params.hand))
    assert one["dataset_sha256"] == two["dataset_sha256"] and one["counts"]["total"] > 0
    assert _files(tmp_path / "one") == _files(tmp_path / "ray")
    assert [e["view"] for e in events] == [1, 2, 3, 4]  # progress as each view finishes


def test_the_clutter_benchmark_on_ray_plays_the_same_rounds_and_resumes(tmp_path: Path) -> None:
    clutter = _bench("clutter")
    common = ["--objects", "2", "--settings", "baseline@pile-side", "--tag", "t"]
    assert clutter.main(["--rounds", "2", "--out", str(tmp_path / "one"), *common]) == 0
    assert clutter.main(["--rounds", "2", "--jobs", "2", "--ray", "--out", str(tmp_path / "ray"), *common]) == 0
    one, two = _rounds(tmp_path / "one" / "t.rounds.jsonl"), _rounds(tmp_path / "ray" / "t.rounds.jsonl")
    assert one == two and len(one) == 2
    # a third round: the two recorded are kept, one more is played
    assert clutter.main(["--rounds", "3", "--jobs", "2", "--ray", "--out", str(tmp_path / "ray"), *common]) == 0
    assert len((tmp_path / "ray" / "t.rounds.jsonl").read_text().splitlines()) == 3
    data = json.loads((tmp_path / "ray" / "t.json").read_text())
    assert data["meta"]["runner"] == "ray (local, 2 CPUs)" and data["summaries"]["baseline@pile-side"]["rounds"] == 3


def test_the_container_benchmark_on_ray_plays_the_same_rounds(tmp_path: Path) -> None:
    containers = _bench("containers")
    common = ["--rounds", "2", "--objects", "2", "--detectors", "baseline", "--styles", "corner", "--in-process",
              "--no-pictures", "--tag", "t"]
    assert containers.main([*common, "--out", str(tmp_path / "one")]) == 0
    assert containers.main([*common, "--jobs", "2", "--ray", "--out", str(tmp_path / "ray")]) == 0
    log = "containers-t.rounds.jsonl"
    assert _rounds(tmp_path / "one" / log) == _rounds(tmp_path / "ray" / log)


@pytest.mark.slow
@pytest.mark.parametrize("bench", ["clutter", "containers"])
def test_gpd_rounds_on_ray_are_those_of_one_process(bench: str, tmp_path: Path) -> None:
    """The detector in the loop (gpd-noclass in process, 3 objects): ~1 min per run on 2 cores."""
    mod = _bench(bench)
    if bench == "clutter":
        common = ["--rounds", "2", "--objects", "3", "--settings", "gpd-noclass@pile-side", "--in-process",
                  "--tag", "t"]
        log = "t.rounds.jsonl"
    else:
        common = ["--rounds", "2", "--objects", "2", "--detectors", "gpd-noclass", "--styles", "corner",
                  "--in-process", "--no-pictures", "--tag", "t"]
        log = "containers-t.rounds.jsonl"
    assert mod.main([*common, "--out", str(tmp_path / "one")]) == 0
    assert mod.main([*common, "--jobs", "2", "--ray", "--out", str(tmp_path / "ray")]) == 0
    assert _rounds(tmp_path / "one" / log) == _rounds(tmp_path / "ray" / log)
