"""graspd_lab.cluster without Ray: the serial and pool paths give the same results, asking for Ray where it is
not installed names what to install, and the labelled mesh dataset resumes from its chunk records."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from graspd_lab.cluster import RAY_MISSING, RayMissingError, Runner, imap, ray_available, runner_from_args
from graspd_lab.training import dataset, scene_data
from graspd_lab.training.dataset import GenerationParams, generate_dataset
from repo_module import load_bench


def _cube(x: int) -> tuple[int, int]:
    return x, x**3


def test_serial_and_pool_map_every_item_once() -> None:
    serial = list(imap(_cube, range(7), Runner()))
    assert serial == [(x, x**3) for x in range(7)]  # serial: in item order
    pooled = list(imap(_cube, range(7), Runner(workers=2, context="fork")))
    assert sorted(pooled) == serial  # a pool: as they finish
    assert list(imap(_cube, [], Runner(workers=2))) == []


def test_runner_says_how_the_job_ran() -> None:
    assert Runner().describe() == "serial"
    assert Runner(workers=3).describe() == "pool of 3"
    assert Runner(workers=2, ray=True).describe() == "ray (local, 2 CPUs)"
    assert Runner(address="auto").uses_ray and Runner(address="auto").describe() == "ray (auto)"
    with pytest.raises(ValueError, match="workers"):
        Runner(workers=0)


def test_asking_for_ray_without_it_names_the_cluster_extra(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # how Python marks a module that cannot be imported
    assert not ray_available()
    with pytest.raises(RayMissingError, match=r"lab\[cluster\]"):
        runner_from_args(type("Args", (), {"ray": True, "address": None})(), 2)
    for main in (scene_data.main, dataset.main):
        with pytest.raises(SystemExit) as exc:
            main(["--out", str(tmp_path / "x"), "--ray"])
        assert exc.value.code == 2
        assert "lab[cluster]" in capsys.readouterr().err
    clutter = load_bench("clutter", "bench_clutter_noray")
    with pytest.raises(SystemExit):
        clutter.main(["--settings", "baseline@pile-side", "--address", "auto", "--out", str(tmp_path)])
    assert RAY_MISSING in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # refused before any work


def test_the_labelled_dataset_resumes_from_its_chunk_records(tmp_path: Path) -> None:
    pytest.importorskip("pybullet")  # pybullet_data's random_urdfs
    params = GenerationParams(seed=11, exemplars=60, num_urdfs=1, procedural=(("box", 1), ("cylinder", 1)),
                              views_per_object=3, num_samples=30, per_view=10, objects_per_chunk=1)
    whole = generate_dataset(tmp_path / "whole", params, runner=Runner())
    assert len(whole["chunks"]) == 3
    cut = tmp_path / "cut"
    cut.mkdir()
    for name in ("params.json", "chunk_00001.npz", "chunk_00001.npz.json"):  # interrupted after one chunk
        (cut / name).write_bytes((tmp_path / "whole" / name).read_bytes())
    before = (cut / "chunk_00001.npz").stat().st_mtime_ns
    resumed = generate_dataset(cut, params, runner=Runner(workers=2, context="fork"))
    assert resumed["dataset_sha256"] == whole["dataset_sha256"]
    assert (cut / "chunk_00001.npz").stat().st_mtime_ns == before  # kept, not made again
    assert json.loads((cut / "timing.json").read_text())["runner"] == "pool of 2"
    other = tmp_path / "other"  # chunks of a run with another seed: refused, never mixed
    other.mkdir()
    (other / "params.json").write_text((cut / "params.json").read_text().replace('"seed": 11', '"seed": 12'))
    with pytest.raises(FileExistsError, match="other parameters"):
        generate_dataset(other, params, runner=Runner())
