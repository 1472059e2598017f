"""Every chunk of a bag decompressed under a bound.  rosbags inflates a whole MCAP chunk (zstd, lz4) or ROS 1
chunk (bz2, lz4) in one call, trusting the data: a small chunk may unpack to gigabytes.  graspd puts bounded
decompressors in rosbags' two decompressor tables (rosbags.rosbag2.storage_mcap.DECOMPRESSORS,
rosbags.rosbag1.reader.decompressors; rosbags 0.11): a chunk whose declared uncompressed size exceeds the limit
is refused before anything is inflated, and the data is inflated, frame by frame, never past the declared size
(MCAP) or the limit (ROS 1, which declares no size to the decompressor).  Within `decompression_budget(total)`
the chunks of one read together may inflate at most `total` bytes."""

from __future__ import annotations

import bz2
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any, Protocol

import lz4.frame
import rosbags.rosbag1.reader as rosbag1_reader
import rosbags.rosbag2.storage_mcap as mcap_storage

try:
    from compression import zstd  # type: ignore[import-not-found]  # Python 3.14
except ImportError:
    from backports import zstd

from graspd.core.cloud import CloudError

#: Most bytes one chunk of a bag may inflate to: a chunk holds at least one whole message, and a PointCloud2 at
#: the point cap (5M points of up to 48 bytes) takes up to 240 MB.
MAX_CHUNK_BYTES = 256 << 20


class _Decompressor(Protocol):
    eof: bool
    needs_input: bool
    unused_data: bytes

    def decompress(self, data: bytes, max_length: int = -1) -> bytes: ...


class _Budget:
    """Bytes the chunks of one read may still inflate to (None: no total, each chunk under MAX_CHUNK_BYTES)."""

    def __init__(self, total: int | None) -> None:
        self.left = total

    def limit(self) -> int:
        return MAX_CHUNK_BYTES if self.left is None else min(MAX_CHUNK_BYTES, self.left)

    def spend(self, size: int) -> None:
        if self.left is not None:
            self.left -= size


_BUDGET: ContextVar[_Budget | None] = ContextVar("graspd_bag_budget", default=None)


@contextmanager
def decompression_budget(total: int | None) -> Iterator[None]:
    """Within this block, the bag chunks decompressed (in this thread or task) inflate to at most total bytes
    together; None: no total (each chunk still at most MAX_CHUNK_BYTES)."""
    token = _BUDGET.set(_Budget(total))
    try:
        yield
    finally:
        _BUDGET.reset(token)


def bounded_decompress(make: Callable[[], _Decompressor], data: bytes | memoryview, declared: int | None,
                       what: str) -> bytes:
    """data inflated by a stream of frames (make() decodes one), refused with a CloudError naming body when the
    declared size (None: unknown) or the output passes the limit, or when the data ends inside a frame."""
    budget = _BUDGET.get() or _Budget(None)
    limit = budget.limit()
    if declared is not None:
        if declared > limit:
            raise CloudError("body", f"a {what} chunk declares {declared} bytes uncompressed, more than the limit of "
                             f"{limit} bytes")
        limit = declared
    pieces: list[bytes] = []
    total = 0
    rest = bytes(data)
    while rest:
        decoder = make()
        piece = decoder.decompress(rest, max_length=limit + 1 - total)
        total += len(piece)
        pieces.append(piece)
        if total > limit:
            raise CloudError("body", f"a {what} chunk inflates past "
                             + (f"its declared {declared} bytes" if declared is not None else f"{limit} bytes"))
        if not decoder.eof:
            raise CloudError("body", f"a {what} chunk's compressed data is truncated")
        rest = decoder.unused_data
    budget.spend(total)
    return b"".join(pieces)


def _mcap(make: Callable[[], Any], name: str) -> Callable[[bytes, int], bytes]:
    return lambda data, size: bounded_decompress(make, data, size, f"MCAP {name}")


def _ros1(make: Callable[[], Any], name: str) -> Callable[[bytes], bytes]:
    return lambda data: bounded_decompress(make, data, None, f"ROS 1 {name}")


def install() -> None:
    """Put the bounded decompressors in rosbags' tables (idempotent).  CloudError naming body when this rosbags
    has no such tables: then no compressed chunk could be read under a bound."""
    if not isinstance(getattr(mcap_storage, "DECOMPRESSORS", None), dict) or not isinstance(
            getattr(rosbag1_reader, "decompressors", None), dict):
        raise CloudError("body", "this rosbags version has no decompressor tables to bound; install rosbags 0.11")
    mcap_storage.DECOMPRESSORS["zstd"] = _mcap(zstd.ZstdDecompressor, "zstd")
    mcap_storage.DECOMPRESSORS["lz4"] = _mcap(lz4.frame.LZ4FrameDecompressor, "lz4")
    rosbag1_reader.decompressors["bz2"] = _ros1(bz2.BZ2Decompressor, "bz2")
    rosbag1_reader.decompressors["lz4"] = _ros1(lz4.frame.LZ4FrameDecompressor, "lz4")
