"""Whitespace-separated numbers in text (ASCII PCD and PLY data) read at C speed: numpy finds the tokens and the
lines they sit on with a few vectorised passes over the bytes, and np.fromstring parses every number in one call
(the C library's strtod, correctly rounded, the same parse PCL and open3d use).  No Python loop per line or value:
a 3 MB, 100k-point ASCII cloud takes tens of milliseconds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import DTypeLike, NDArray


@dataclass(frozen=True)
class TextNumbers:
    """The numbers of a text, in reading order, and how many sit on each non-blank line."""

    values: NDArray[np.floating]  # every number, row after row
    per_line: NDArray[np.intp]  # numbers on each line that holds any (blank lines skipped, as np.loadtxt does)

    def row_starts(self) -> NDArray[np.intp]:
        """Index in values of each non-blank line's first number."""
        return np.cumsum(self.per_line) - self.per_line


def line_starts(data: bytes | memoryview) -> NDArray[np.intp]:
    """Byte offset where each line of data begins (the first at 0; a line ends at a newline, b'\\n')."""
    newlines = np.flatnonzero(np.frombuffer(data, np.uint8) == 10)
    return np.concatenate(([0], newlines + 1))


def read_numbers(data: bytes | memoryview, dtype: DTypeLike = np.float64) -> TextNumbers:
    """Every whitespace-separated number of data and the count on each line; ValueError naming the problem when
    a token is not a number (a word, '1,2', '1-2', a NUL byte).  Numbers are what C's strtod reads: decimals,
    exponents, 'nan', 'inf'.  float32 values are parsed as float64 and rounded once more, exactly as
    strtod-then-cast readers (PCL, open3d) do."""
    text = bytes(data)
    raw = np.frombuffer(text, np.uint8)
    # Tokens split at bytes <= 32: C's isspace (tab to carriage return, space) and control bytes, which are no
    # separator to np.fromstring either: a token next to one fails to parse (ValueError), as it should.
    space = raw <= 32
    before = np.empty_like(space)  # is the byte before each one a space (the start of the text counts as one)?
    before[:1] = True
    before[1:] = space[:-1]
    starts = np.flatnonzero(~space & before)  # each token's first byte
    if starts.size == 0:  # np.fromstring reads whitespace alone as [-1.0]
        return TextNumbers(np.zeros(0, dtype), np.zeros(0, np.intp))
    line = np.searchsorted(np.flatnonzero(raw == 10), starts)  # the line of each token
    per_line = np.bincount(line)
    values = np.fromstring(text, dtype=dtype, sep=" ")  # raises ValueError at the first token that is no number
    if values.size != starts.size:
        raise ValueError(f"{starts.size} tokens but {values.size} numbers")
    return TextNumbers(values, per_line[per_line > 0].astype(np.intp, copy=False))
