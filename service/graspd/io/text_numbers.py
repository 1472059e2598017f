"""Whitespace-separated numbers in text (ASCII PCD and PLY data) read at C speed: numpy finds the tokens and the
lines they sit on with a few vectorised passes over the bytes, and np.fromstring parses every number in one call
(the C library's strtod, correctly rounded, the same parse PCL and open3d use).  No Python loop per line or value:
a 3 MB, 100k-point ASCII cloud takes tens of milliseconds.  The shape (tokens a line) comes first, from pieces of
CHUNK bytes cut at newlines, so that its temporary arrays stay a few times CHUNK whatever the size of the text, and
a reader can refuse a table of the wrong shape before parsing a number of it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import DTypeLike, NDArray

#: Bytes of text read at once (cut at the last newline before it).
CHUNK = 4 << 20


@dataclass(frozen=True)
class TextNumbers:
    """The numbers of a text, in reading order, and how many sit on each non-blank line."""

    values: NDArray[np.floating]  # every number, row after row
    per_line: NDArray[np.intp]  # numbers on each line that holds any (blank lines skipped, as np.loadtxt does)

    def row_starts(self) -> NDArray[np.intp]:
        """Index in values of each non-blank line's first number."""
        return np.cumsum(self.per_line) - self.per_line


def line_start(data: bytes, line: int) -> int:
    """Byte offset where line `line` (0-based; a line ends at b'\\n') begins; len(data) past the last newline.
    Counts newlines a CHUNK at a time (bytes.count, C) and indexes only the piece holding the one sought."""
    if line <= 0:
        return 0
    pos, left = 0, line
    while pos < len(data):
        stop = min(pos + CHUNK, len(data))
        found = data.count(b"\n", pos, stop)
        if found >= left:
            newlines = np.flatnonzero(np.frombuffer(data, np.uint8, stop - pos, pos) == 10)
            return pos + int(newlines[left - 1]) + 1
        left -= found
        pos = stop
    return len(data)


def _piece_counts(text: bytes) -> NDArray[np.intp]:
    """Tokens on each non-blank line of text (line_counts, on one piece)."""
    raw = np.frombuffer(text, np.uint8)
    # Tokens split at bytes <= 32: C's isspace (tab to carriage return, space) and control bytes, which are no
    # separator to np.fromstring either: a token next to one fails to parse (ValueError), as it should.
    space = raw <= 32
    before = np.empty_like(space)  # is the byte before each one a space (the start of the text counts as one)?
    before[:1] = True
    before[1:] = space[:-1]
    starts = np.flatnonzero(~space & before)  # each token's first byte
    per_line = np.bincount(np.searchsorted(np.flatnonzero(raw == 10), starts))  # tokens by line
    return per_line[per_line > 0].astype(np.intp, copy=False)


def line_counts(data: bytes) -> NDArray[np.intp]:
    """How many whitespace-separated tokens sit on each line of data that holds any (blank lines skipped, as
    np.loadtxt does): the shape of a table, known before any number is parsed."""
    counts: list[NDArray[np.intp]] = [np.zeros(0, np.intp)]
    pos = 0
    while pos < len(data):
        stop = len(data) if len(data) - pos <= CHUNK else data.rfind(b"\n", pos, pos + CHUNK) + 1
        if stop <= pos:  # no newline in a whole CHUNK: the line goes on to the next newline
            stop = data.find(b"\n", pos + CHUNK) + 1 or len(data)
        counts.append(_piece_counts(data[pos:stop]))
        pos = stop
    return counts[1] if len(counts) == 2 else np.concatenate(counts)


def parse_numbers(data: bytes, count: int, dtype: DTypeLike = np.float64) -> NDArray[np.floating]:
    """The count whitespace-separated numbers of data (line_counts found count tokens), in one np.fromstring
    call; ValueError naming the problem when a token is not a number (a word, '1,2', '1-2', a NUL byte).  Numbers
    are what C's strtod reads: decimals, exponents, 'nan', 'inf'.  float32 values are parsed as float64 and
    rounded once more, exactly as strtod-then-cast readers (PCL, open3d) do."""
    if count == 0:  # np.fromstring reads whitespace alone as [-1.0]
        return np.zeros(0, dtype)
    values = np.fromstring(data, dtype=dtype, sep=" ")  # raises ValueError at the first token that is no number
    if values.size != count:
        raise ValueError(f"{count} tokens but {values.size} numbers")
    return values


def read_numbers(data: bytes | memoryview, dtype: DTypeLike = np.float64) -> TextNumbers:
    """Every whitespace-separated number of data and the count on each non-blank line (line_counts, then
    parse_numbers)."""
    text = bytes(data)
    per_line = line_counts(text)
    return TextNumbers(parse_numbers(text, int(per_line.sum()), dtype), per_line)
