"""`graspd serve` flags become settings: --zenoh-config names the Zenoh JSON5 file, as GRASPD_ZENOH_CONFIG does."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from graspd.server import cli
from graspd.server.zenoh.node import ZenohSetupError, zenoh_config


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="graspd")
    cli.register(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(argv)


def test_zenoh_config_flag_sets_the_setting(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    conf = tmp_path / "zenoh.json5"
    conf.write_text('{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:0"] } }')
    monkeypatch.setenv("GRASPD_ZENOH_CONFIG", str(tmp_path / "from-env.json5"))  # the flag overrides the env
    settings = cli.settings_from_args(_parse(["serve", "--zenoh-config", str(conf), "--zenoh-instance", "a"]))
    assert settings.zenoh_config == conf and settings.zenoh_instance == "a"
    assert zenoh_config(settings).get_json("listen/endpoints") == '["tcp/127.0.0.1:0"]'  # the file is read


def test_without_the_flag_the_environment_decides(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    missing = tmp_path / "missing.json5"
    monkeypatch.setenv("GRASPD_ZENOH_CONFIG", str(missing))
    settings = cli.settings_from_args(_parse(["serve"]))
    assert settings.zenoh_config == missing
    with pytest.raises(ZenohSetupError, match="GRASPD_ZENOH_CONFIG"):  # refused at start, naming the setting
        zenoh_config(settings)
