"""graspd.core.progress: a bar on a terminal; in logs, plain lines at most every so often and never a carriage
return; GRASPD_PROGRESS overrides."""

from __future__ import annotations

import io

import pytest

from graspd.core.progress import Progress, progress_mode, track


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_modes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("GRASPD_PROGRESS", raising=False)
    monkeypatch.setenv("TERM", "xterm")
    assert progress_mode(io.StringIO()) == "lines" and progress_mode(Terminal()) == "bar"
    monkeypatch.setenv("TERM", "dumb")
    assert progress_mode(Terminal()) == "lines"
    monkeypatch.setenv("GRASPD_PROGRESS", "off")
    assert progress_mode(Terminal()) == "off"


def test_a_log_gets_lines_and_no_carriage_return(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("GRASPD_PROGRESS", raising=False)
    out = io.StringIO()
    with Progress(4, "rounds", "round", stream=out, every_s=0.0) as bar:
        for k in range(4):
            bar.update(1, success=0.5 + 0.1 * k)
    text = out.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[0].startswith("rounds: 1/4 round (25%)") and "about" in lines[0] and "success 0.5" in lines[0]
    assert lines[-1].startswith("rounds: 4/4 round (100%)") and lines[-1].endswith("(done)")


def test_a_short_job_in_a_log_says_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("GRASPD_PROGRESS", raising=False)
    out = io.StringIO()
    assert list(track(range(50), "chunks", stream=out)) == list(range(50))
    assert out.getvalue() == ""


def test_a_terminal_gets_a_bar(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("GRASPD_PROGRESS", raising=False)
    monkeypatch.setenv("TERM", "xterm")
    out = Terminal()
    with Progress(3, "epochs", "epoch", stream=out) as bar:
        bar.write("epoch 1: loss 0.5")
        bar.update(3, loss=0.25)
    text = out.getvalue()
    assert "\r" in text and "3/3" in text and "loss 0.25" in text and "epoch 1: loss 0.5\n" in text


def test_off_is_silent(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("GRASPD_PROGRESS", "off")
    out = Terminal()
    with Progress(2, "x", stream=out, every_s=0.0) as bar:
        bar.update(2)
        bar.write("hidden")
    assert out.getvalue() == ""
