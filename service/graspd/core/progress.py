"""One progress display for every long job: dataset generation, training, instance jobs, benchmarks.

On a terminal it is a tqdm bar on stderr (count, rate, elapsed, time left).  Anywhere else (a CI log, a file,
a pipe, a job whose output is captured) there is no bar and no carriage return: one plain line at most every
`every_s` seconds (default 60) while the job runs, and one when it ends, if it ran that long.  The environment
variable GRASPD_PROGRESS=bar|lines|off overrides the choice (off: nothing at all).

    for chunk in track(chunks, desc="dataset chunks", unit="chunk"):
        ...
    with Progress(total=epochs * steps, desc="train scene15", unit="batch") as bar:
        bar.update(1, loss=0.41)
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterable, Iterator
from typing import IO, Any, Literal, TypeVar

T = TypeVar("T")
Mode = Literal["bar", "lines", "off"]
#: Environment variable that forces a mode: bar, lines or off.
ENV = "GRASPD_PROGRESS"
#: Seconds between two plain lines (the non-terminal mode).
EVERY_S = 60.0


def progress_mode(stream: IO[str]) -> Mode:
    """bar when stream is a terminal (and TERM is not dumb), else lines; GRASPD_PROGRESS overrides."""
    forced = os.environ.get(ENV, "").strip().lower()
    if forced in ("bar", "lines", "off"):
        return forced  # type: ignore[return-value]
    try:
        tty = bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        tty = False
    return "bar" if tty and os.environ.get("TERM") != "dumb" else "lines"


def _duration(seconds: float) -> str:
    """1h02m, 3m05s or 12s."""
    s = int(round(seconds))
    if s >= 3600:
        return f"{s // 3600}h{s % 3600 // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


def _value(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


class Progress:
    """Progress of one job of `total` steps (None: unknown).  update(n, **figures) after each step; figures
    (a loss, a success rate) are shown beside the count.  A context manager: close() on exit."""

    def __init__(self, total: int | None, desc: str, unit: str = "it", *, stream: IO[str] | None = None,
                 mode: Mode | None = None, every_s: float = EVERY_S) -> None:
        self.stream: IO[str] = stream if stream is not None else sys.stderr
        self.mode: Mode = mode if mode is not None else progress_mode(self.stream)
        self.total, self.desc, self.unit, self.every_s = total, desc, unit, every_s
        self.n = 0
        self.figures = ""
        self.t0 = self._last = time.monotonic()
        self._lines = 0
        self._bar: Any = None
        if self.mode == "bar":
            from tqdm import tqdm  # noqa: PLC0415 -- only when a bar is drawn

            self._bar = tqdm(total=total, desc=desc, unit=unit, file=self.stream, dynamic_ncols=True,
                             mininterval=0.5, leave=True)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def update(self, n: int = 1, **figures: Any) -> None:
        """n more steps done; figures replace those shown."""
        self.n += n
        if figures:
            self.figures = ", ".join(f"{k} {_value(v)}" for k, v in figures.items())
        if self._bar is not None:
            if figures:
                self._bar.set_postfix_str(self.figures, refresh=False)
            self._bar.update(n)
        elif self.mode == "lines" and time.monotonic() - self._last >= self.every_s:
            self._write(self.line())

    def write(self, text: str) -> None:
        """A line of the job's own (an epoch's summary) that does not break the bar."""
        if self._bar is not None:
            self._bar.write(text, file=self.stream)
        elif self.mode != "off":
            self._write(text)

    def line(self) -> str:
        """The plain progress line: 'desc: 12/30 rounds (40%), 5m10s, about 7m45s left, figures'."""
        elapsed = time.monotonic() - self.t0
        out = f"{self.desc}: {self.n}"
        if self.total:
            out += f"/{self.total} {self.unit} ({100 * self.n / self.total:.0f}%), {_duration(elapsed)}"
            if 0 < self.n < self.total:
                out += f", about {_duration(elapsed * (self.total - self.n) / self.n)} left"
        else:
            out += f" {self.unit}, {_duration(elapsed)}"
        return out + (f", {self.figures}" if self.figures else "")

    def close(self) -> None:
        """End the display: the bar's last state stays; in lines mode a last line if the job ran every_s."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        elif self.mode == "lines" and (self._lines or time.monotonic() - self.t0 >= self.every_s):
            finished = self.total is None or self.n >= self.total
            self._write(self.line() + (" (done)" if finished else " (stopped)"))
            self.mode = "off"

    def _write(self, text: str) -> None:
        print(text, file=self.stream, flush=True)
        self._last = time.monotonic()
        self._lines += 1


def track(items: Iterable[T], desc: str, unit: str = "it", total: int | None = None, **kwargs: Any) -> Iterator[T]:
    """items, one at a time, with a Progress over them (total: len(items) when it has one)."""
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    with Progress(total, desc, unit, **kwargs) as bar:
        for item in items:
            yield item
            bar.update(1)
