"""The CLI starts fast and fails loud: --help and --version import nothing heavy, and `graspd detect` without
a usable model exits non-zero with a sentence that says what to do (never a run with scores 0.00)."""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from graspd.cli.main import LAZY_SUBCOMMANDS, build_parser, main
from graspd.gpd.classifier import default_model_name, default_models_dir

#: Modules whose import costs most of a second; `graspd --help` must not load any of them.
HEAVY = ("numpy", "scipy", "open3d", "onnxruntime", "fastapi", "pydantic", "torch", "matplotlib", "sqlalchemy",
         "zenoh")

_PROBE = """
import sys
from graspd.cli.main import main
try:
    main([{arg!r}])
except SystemExit:
    pass
print("heavy:" + ",".join(m for m in {heavy!r} if m in sys.modules))
"""


@pytest.mark.parametrize("arg", ["--help", "--version"])
def test_help_and_version_import_nothing_heavy(arg: str) -> None:
    proc = subprocess.run([sys.executable, "-c", _PROBE.format(arg=arg, heavy=HEAVY)], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    last = proc.stdout.strip().splitlines()[-1]
    assert last == "heavy:", f"{arg} imported {last}"


def test_version_is_the_installed_one() -> None:
    proc = subprocess.run([sys.executable, "-m", "graspd.cli", "--version"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0
    assert proc.stdout.strip() == f"graspd {importlib.metadata.version('graspd')}"


def _help_lines(parser: argparse.ArgumentParser) -> dict[str, str | None]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest: a.help for a in sub._get_subactions()}


def test_the_listed_help_lines_are_the_modules_own() -> None:
    """`graspd --help` lists the lazy subcommands with a copy of their help line: the copy must not drift."""
    listed, loaded = _help_lines(build_parser(())), _help_lines(build_parser(True))
    assert set(LAZY_SUBCOMMANDS) <= set(listed)
    assert listed == loaded


def test_help_of_a_lazy_subcommand_is_its_full_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["templates", "--help"])
    assert exit_.value.code == 0
    assert "demonstrate" in capsys.readouterr().out


def _detect(cloud: Path, models: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[int, str]:
    rc = main(["detect", str(cloud), "--samples", "20", "--models-dir", str(models), *extra])
    return rc, capsys.readouterr().err


def test_empty_or_missing_models_dir_exits_nonzero(real_data: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    rc, err = _detect(real_data / "krylon.pcd", tmp_path, capsys)
    assert rc != 0 and "holds no model" in err and "--no-classifier" in err
    rc, err = _detect(real_data / "krylon.pcd", tmp_path / "nonesuch", capsys)
    assert rc != 0 and "does not exist" in err and "--models-dir" in err


def test_a_model_that_cannot_load_exits_nonzero(real_data: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    shipped, name = default_models_dir(), default_model_name()
    shutil.copy(shipped / f"{name}.json", tmp_path / f"{name}.json")
    (tmp_path / f"{name}.onnx").write_bytes((shipped / f"{name}.onnx").read_bytes()[:200])  # truncated
    rc, err = _detect(real_data / "krylon.pcd", tmp_path, capsys)
    assert rc != 0 and name in err and "restore" in err
    # the default model absent, another one there: say which are there instead of running unscored
    (tmp_path / f"{name}.onnx").unlink()
    (tmp_path / f"{name}.json").unlink()
    for suffix in (".onnx", ".json"):
        shutil.copy(shipped / f"generic15{suffix}", tmp_path / f"generic15{suffix}")
    rc, err = _detect(real_data / "krylon.pcd", tmp_path, capsys)
    assert rc != 0 and f"'{name}' is not in" in err and "generic15" in err and "--model" in err


def test_empty_models_dir_through_the_entry_point(real_data: Path, tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "graspd.cli", "detect", str(real_data / "krylon.pcd"),
                           "--models-dir", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert proc.stdout == ""  # no grasps printed
    assert "holds no model" in proc.stderr


def test_detect_answers_the_ranking_terms_as_the_service_does(real_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "g.json"
    assert main(["detect", str(real_data / "table_mug.pcd"), "--samples", "100", "--no-classifier",
                 "--out", str(out)]) == 0
    answer = json.loads(out.read_text())
    assert answer["ranking_rule"].startswith("key = classifier x utility x width x unknown")
    terms = [g["ranking"] for g in answer["grasps"]]
    assert terms and all(set(t) == {"classifier", "utility", "width", "unknown", "key"} for t in terms)
    keys = [t["key"] for t in terms]
    assert keys == sorted(keys, reverse=True)
