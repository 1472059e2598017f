"""bench/clutter.py writes the Table 3 markdown, the PNG and the JSON (with the commit) for a tiny run."""

import importlib.util
import json
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[3] / "bench" / "clutter.py"


def _bench():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("bench_clutter", BENCH)
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_tiny_run_writes_table_chart_and_json(tmp_path: Path) -> None:
    bench = _bench()
    assert bench.main(["--rounds", "1", "--objects", "2", "--settings", "baseline@pile-side",
                       "--out", str(tmp_path), "--tag", "t"]) == 0
    md = (tmp_path / "t.md").read_text()
    assert "% grasps successful" in md and "baseline@pile-side" in md
    data = json.loads((tmp_path / "t.json").read_text())
    assert len(data["meta"]["commit"]) >= 7
    assert data["summaries"]["baseline@pile-side"]["rounds"] == 1
    assert (tmp_path / "t.png").read_bytes()[:4] == b"\x89PNG"


def test_unknown_setting_is_named() -> None:
    bench = _bench()
    with pytest.raises(SystemExit):
        bench.main(["--settings", "magic@pour-passive"])
    with pytest.raises(ValueError, match="scene"):
        bench.parse_setting("baseline@shelf")
