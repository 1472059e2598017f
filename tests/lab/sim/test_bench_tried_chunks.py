"""bench/tried_chunks.py collects the oracle's tried grasps in chunks of round seeds, and resumes after a stop."""

from __future__ import annotations

from pathlib import Path

import pytest

from repo_module import load_bench


def test_a_chunk_is_one_oracle_run_on_training_objects_with_perturbed_lifts_and_images(tmp_path: Path) -> None:
    bench = load_bench("tried_chunks")
    cmd = bench.chunk_command("tray", 310, 10, tmp_path, None)
    assert cmd[1].endswith("bench/oracle.py")
    args = " ".join(cmd[2:])
    assert "--container tray --split training --object-set household-training --seed 310 --rounds 10" in args
    images = tmp_path / "tried-household-training-tray-s310.npz"
    assert f"--perturb 4 --images {images} --out {tmp_path} --tag household-training-tray-s310" in args
    assert "--scene pile-side" in " ".join(bench.chunk_command("pile-side", 0, 5, tmp_path, "household15"))


def test_finished_chunks_are_skipped_so_a_stopped_job_resumes(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    bench = load_bench("tried_chunks")
    for first in (300, 310):
        (tmp_path / f"oracle-household-training-packed-side-s{first}.json").write_text("{}")
    assert bench.main(["--kinds", "packed-side", "--first-seed", "300", "--chunks", "2", "--dir", str(tmp_path)]) == 0
    done = ["packed-side seeds 300-309: done", "packed-side seeds 310-319: done"]
    assert capsys.readouterr().out.splitlines() == done


def test_chunks_of_scaled_training_objects_are_named_after_their_set(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    bench = load_bench("tried_chunks")
    cmd = " ".join(bench.chunk_command("tote", 300, 10, tmp_path, None, "scaled-training"))
    assert "--container tote --split training --object-set scaled-training --seed 300" in cmd
    assert "--tag scaled-training-tote-s300" in cmd
    (tmp_path / "oracle-scaled-training-tote-s300.json").write_text("{}")
    args = ["--object-set", "scaled-training", "--kinds", "tote", "--chunks", "1", "--dir", str(tmp_path)]
    assert bench.main(args) == 0
    assert capsys.readouterr().out.splitlines() == ["tote seeds 300-309: done"]
    with pytest.raises(SystemExit):
        bench.main(["--object-set", "household", "--kinds", "tote", "--dir", str(tmp_path)])  # held out: refused
