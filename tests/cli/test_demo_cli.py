"""`graspd demo` detects on its rendered tabletop, writes grasps.json and grasps.png, and reports a warm time: when
the first call was slow (a fresh install compiling its kernels), it times a second call and says so."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import graspd.cli.main as cli


@pytest.mark.parametrize("cold_s", [0.0, 1e6])
def test_the_demo_reports_a_warm_time_and_says_when_the_first_call_was_cold(
        cold_s: float, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cli, "DEMO_COLD_S", cold_s)  # 0: every first call counts as cold; 1e6: none does
    assert cli.main(["demo", "--out", str(tmp_path), "--objects", "3", "--samples", "150"]) == 0
    said = capsys.readouterr().out
    answer = json.loads((tmp_path / "grasps.json").read_text())
    assert answer["grasps"] and (tmp_path / "grasps.png").stat().st_size > 10_000
    assert f"{len(answer['grasps'])} grasps from {answer['num_candidates']} candidates in " in said
    assert ("the first time: the kernels compiled, cached on disk" in said) == (cold_s == 0.0)
