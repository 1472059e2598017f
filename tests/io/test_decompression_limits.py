"""Every compressed input is inflated under a bound decided before the data is read: .npz members (bzip2 and
LZMA refused, deflate read in chunks up to the size the zip directory and the npy header both declare, the total
capped), PCD binary_compressed (LZF never writes past the declared size) and depth PNGs (decoded to the declared
image, whatever the IDAT stream would inflate to).  Each hostile input is built here, small, and refused (or read
at its declared size) naming the field, with the memory it took measured."""

from __future__ import annotations

import io
import os
import struct
import subprocess
import sys
import tracemalloc
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from graspd.core.cloud import CloudError
from graspd.io.cloud_files import parse_npy, parse_npz, parse_pcd
from graspd.io.lzf import LzfError, lzf_decompress
from graspd.io.npz import MAX_NPZ_ENTRIES

REPO = Path(__file__).resolve().parents[2]
MB = 1 << 20


def npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def zeros_stream(compress: Callable[[bytes], bytes], flush: Callable[[], bytes], head: bytes, mib: int) -> bytes:
    """head then mib MiB of zeros through a compressor, a MiB at a time (never all in memory)."""
    zero = bytes(MB)
    return compress(head) + b"".join(compress(zero) for _ in range(mib)) + flush()


def npz_with(name: str, content: bytes, compression: int, declared: int | None = None,
             extra: dict[str, bytes] | None = None) -> bytes:
    """An .npz (zip) whose member name.npy holds content; with declared, its zip entry (local header and central
    directory) claims that many bytes uncompressed instead."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as z:
        z.writestr(f"{name}.npy", content)
        for other, data in (extra or {}).items():
            z.writestr(f"{other}.npy", data)
    data = bytearray(buf.getvalue())
    if declared is not None:
        assert data[:4] == b"PK\x03\x04"
        struct.pack_into("<I", data, 22, declared)
        central = data.index(b"PK\x01\x02")
        struct.pack_into("<I", data, central + 24, declared)
    return bytes(data)


def raw_member(name: str, stream: bytes, method: int, declared: int, crc: int = 0) -> bytes:
    """A one-member zip of an already compressed stream (method 8 deflate, 12 bzip2), claiming declared bytes
    uncompressed (with that crc): how a bomb is made without ever holding what it inflates to."""
    fname = f"{name}.npy".encode()
    local = struct.pack("<4sHHHHHIIIHH", b"PK\x03\x04", 20, 0, method, 0, 0, crc, len(stream), declared,
                        len(fname), 0) + fname
    central = struct.pack("<4sHHHHHHIIIHHHHHII", b"PK\x01\x02", 20, 20, 0, method, 0, 0, crc, len(stream),
                          declared, len(fname), 0, 0, 0, 0, 0, 0) + fname
    offset = len(local) + len(stream)
    end = struct.pack("<4sHHHHIIH", b"PK\x05\x06", 0, 0, 1, 1, len(central), offset, 0)
    return local + stream + central + end


def refused(call: Callable[[], Any]) -> tuple[CloudError, int]:
    """The CloudError call raises and the peak of Python/numpy memory (bytes) it took on the way."""
    tracemalloc.start()
    try:
        with pytest.raises(CloudError) as err:
            call()
        return err.value, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


HEAD = npy(np.zeros((1, 3), np.float32))  # 128 bytes of header, 12 of data


# ---- .npz --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("compression", "word"), [(zipfile.ZIP_BZIP2, "bzip2"), (zipfile.ZIP_LZMA, "LZMA")])
def test_bzip2_and_lzma_members_are_refused_before_anything_is_inflated(compression: int, word: str) -> None:
    """zipfile inflates a whole bzip2/LZMA chunk at once (no output bound): such a member is refused from its
    directory entry; the 16 MiB it holds are never inflated."""
    content = HEAD + bytes(16 * MB)
    bomb = npz_with("points", content, compression, declared=4096)
    assert len(bomb) < 200_000
    error, peak = refused(lambda: parse_npz(bomb))
    assert error.field == "cloud.points" and word in error.message and "deflate" in error.message
    assert peak < 1 * MB


def test_a_kilobyte_bzip2_bomb_is_refused_from_its_directory_entry() -> None:
    """A ~1 kB .npz whose points.npy is bzip2, declares 4 KiB in the zip directory and unpacks to 64 MiB (the
    audit's unpacked to 1 GiB; bzip2 takes seconds to make that): refused from the directory entry."""
    import bz2  # noqa: PLC0415

    comp = bz2.BZ2Compressor(9)
    stream = zeros_stream(comp.compress, comp.flush, HEAD, 64)
    bomb = raw_member("points", stream, zipfile.ZIP_BZIP2, 4096)
    assert len(bomb) < 2_000
    error, peak = refused(lambda: parse_npz(bomb))
    assert error.field == "cloud.points" and "bzip2" in error.message
    assert peak < 1 * MB


def test_a_deflate_member_whose_header_declares_more_than_its_entry_is_refused_before_its_data() -> None:
    """The npy header declares 5M float64 points (120 MB), the zip entry 4 KiB: refused after the header, the
    120 MB never allocated (the entry's checksum is right for its 4 KiB: only the sizes give it away)."""
    head = npy(np.zeros((1, 3), np.float64)).replace(b"(1, 3)", b"(5000000, 3)")
    comp = zlib.compressobj(9, zlib.DEFLATED, -15)
    bomb = raw_member("points", zeros_stream(comp.compress, comp.flush, head, 128), zipfile.ZIP_DEFLATED, 4096,
                      zlib.crc32(head + bytes(4096 - len(head))))
    assert len(bomb) < 200_000
    error, peak = refused(lambda: parse_npz(bomb))
    assert error.field == "cloud.points" and "4096" in error.message and "npy header declares" in error.message
    assert peak < 1 * MB


def test_a_deflate_member_inflating_past_its_declared_size_is_read_only_up_to_it() -> None:
    """Header and entry agree on a (1, 3) array (140 bytes) but the deflate stream goes on for 256 MiB of
    zeros: nothing past the 140 bytes is inflated (zipfile's read() of the whole member inflated it all).  With
    the entry's checksum wrong the member is corrupt (a 422 naming it); right, the declared array is read."""
    comp = zlib.compressobj(9, zlib.DEFLATED, -15)
    stream = zeros_stream(comp.compress, comp.flush, HEAD, 256)
    assert len(stream) < 400_000
    error, peak = refused(lambda: parse_npz(raw_member("points", stream, zipfile.ZIP_DEFLATED, len(HEAD))))
    assert error.field == "cloud.points" and "corrupt" in error.message
    assert peak < 2 * MB
    honest_crc = raw_member("points", stream, zipfile.ZIP_DEFLATED, len(HEAD), zlib.crc32(HEAD))
    tracemalloc.start()
    try:
        points = parse_npz(honest_crc)["points"]
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert points.shape == (1, 3) and peak < 2 * MB


def test_the_members_together_are_capped() -> None:
    """Each member fits, the two together exceed the request's cap: the second is refused from its header,
    naming it."""
    pts = np.ones((1000, 3))
    data = npz_with("points", npy(pts), zipfile.ZIP_DEFLATED, extra={"normals": npy(pts)})
    assert len(parse_npz(data, max_bytes=60_000)["normals"]) == 1000
    with pytest.raises(CloudError) as err:
        parse_npz(data, max_bytes=30_000)
    assert err.value.field == "cloud.normals" and "30000" in err.value.message


@pytest.mark.parametrize(("name", "shape", "words"), [
    ("viewpoints", (1000, 3), "at most 64 camera positions"),
    ("viewpoints", (64, 4), "(K, 3)"),
    ("camera_poses", (65, 4, 4), "at most 64 camera poses"),
    ("points", (5_000_001, 3), "exceeds the limit"),
])
def test_camera_counts_and_shapes_are_checked_from_the_member_header(name: str, shape: tuple[int, ...],
                                                                      words: str) -> None:
    """A viewpoints member of 1,000 cameras (or 65 poses, or too many points) is refused from its header: no
    array of it is built (the header is edited; its data is absent)."""
    small = tuple(1 for _ in shape[:-1]) + shape[-1:]
    head = npy(np.zeros(small, np.float32)).replace(str(small).encode(), str(shape).encode())
    data = npz_with(name, head, zipfile.ZIP_DEFLATED,
                    extra={} if name == "points" else {"points": npy(np.zeros((2, 3), np.float32))})
    error, peak = refused(lambda: parse_npz(data))
    assert error.field == f"cloud.{name}" and words in error.message, error.message
    assert peak < 1 * MB


def test_an_archive_listing_more_entries_than_the_cap_is_refused() -> None:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for i in range(MAX_NPZ_ENTRIES + 1):
            z.writestr(f"a{i}.npy", b"")
    with pytest.raises(CloudError, match="entries") as err:
        parse_npz(buf.getvalue())
    assert err.value.field == "body"


def test_npz_as_numpy_writes_it_still_reads_every_layout() -> None:
    """savez and savez_compressed, float32/float64, big-endian and Fortran-ordered arrays: the same arrays back."""
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(500, 3))
    arrays = {"points": np.asfortranarray(pts.astype(">f8")), "normals": pts.astype(np.float32),
              "viewpoints": np.array([[0.5, 0.0, 1.0], [0.0, 0.5, 1.0]]), "camera_source": np.arange(500) % 2,
              "camera_poses": np.stack([np.eye(4)] * 2)}
    for save in (np.savez, np.savez_compressed):
        buf = io.BytesIO()
        save(buf, colours=np.zeros((500, 3)), **arrays)  # type: ignore[operator]
        back = parse_npz(buf.getvalue())
        assert set(back) == set(arrays)
        for name, array in arrays.items():
            assert back[name].shape == array.shape and np.array_equal(back[name], array), name


# ---- .npy error text ----------------------------------------------------------------------------------------

def _npy_v3(header: str) -> bytes:
    text = header.encode() + b"\n"
    return b"\x93NUMPY\x03\x00" + struct.pack("<I", len(text)) + text + bytes(12)


@pytest.mark.parametrize("data", [
    _npy_v3("{'descr': garbage, 'fortran_order': False, 'shape': (1, 3), }"),
    _npy_v3("{'descr': '<f4', 'fortran_order': False, 'shape': (1, 3), 'x': os.system}"),
    _npy_v3("[1, 2, 3]"),
    _npy_v3("{'descr': '<f4', 'fortran_order': 0, 'shape': (1, 3), }"),
    _npy_v3("{'descr': '<f4', 'fortran_order': False, 'shape': (1, -3), }"),
    _npy_v3("{'descr': 'not a type', 'fortran_order': False, 'shape': (1, 3), }"),
    _npy_v3("{'descr': '<f4', 'fortran_order': False, 'shape': (1, 3" + ")" * 300 + "}"),
    b"\x93NUMPY\x09\x00\x10\x00{}",
    b"\x93NUMPY\x01\x00\xff\xff{}",
    b"\x93NUMPY\x01",
])
def test_a_garbage_npy_header_is_named_in_plain_words(data: bytes) -> None:
    """No Python object repr (ast nodes, 'object at 0x...') in the text: the field and what is wrong."""
    with pytest.raises(CloudError) as err:
        parse_npy(data)
    assert err.value.field == "body" and err.value.message.startswith("npy: ")
    for leak in ("object at", "0x", "<ast", "Error:"):
        assert leak not in str(err.value), str(err.value)


def test_npy_in_every_version_and_order_reads_as_numpy_wrote_it() -> None:
    pts = np.arange(12, dtype=">i4").reshape(4, 3)
    for array in (pts, np.asfortranarray(pts), pts.astype(np.float16)):
        for version in ((1, 0), (2, 0), (3, 0)):
            buf = io.BytesIO()
            np.lib.format.write_array(buf, array, version=version)
            back = parse_npy(buf.getvalue())
            assert back.dtype == array.dtype and np.array_equal(back, array)


# ---- PCD binary_compressed (LZF) -----------------------------------------------------------------------------

def lzf_zeros(n_refs: int) -> bytes:
    """An LZF stream: one zero byte, then n_refs back references of 264 bytes to it (3 bytes each)."""
    return b"\x00\x00" + bytes([0xE0, 255, 0]) * n_refs


def test_lzf_never_writes_past_the_declared_size() -> None:
    """A stream that encodes 26 MB declared as 1,000 bytes stops at the first reference that would pass them:
    only the declared 1,000 bytes were ever allocated."""
    stream = lzf_zeros(100_000)
    tracemalloc.start()
    try:
        with pytest.raises(LzfError, match="past the declared size"):
            lzf_decompress(stream, 1000)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64_000
    assert lzf_decompress(lzf_zeros(3), 1 + 3 * 264) == bytes(1 + 3 * 264)


def _compressed_pcd(points: int, stream: bytes, uncompressed: int) -> bytes:
    head = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {points}\n"
            f"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA binary_compressed\n").encode()
    return head + struct.pack("<II", len(stream), uncompressed) + stream


def test_pcd_binary_compressed_is_bounded_by_its_declared_points() -> None:
    """A stream inflating past POINTS x 12 bytes is refused while decoding, at that size; one declaring more
    than 32x its compressed size is refused before decoding; an honest one reads."""
    error, peak = refused(lambda: parse_pcd(_compressed_pcd(100, lzf_zeros(100_000), 1200)))
    assert error.field == "cloud.points" and "declared size" in error.message
    assert peak < 1 * MB  # the 300 kB stream (and a copy), the 1,200-byte output: not the 26 MB it encodes
    error, _ = refused(lambda: parse_pcd(_compressed_pcd(1_000_000, lzf_zeros(50), 12_000_000)))
    assert error.field == "cloud.points" and "more than 32x" in error.message
    pts = np.random.default_rng(1).normal(size=(10, 3)).astype("<f4")
    raw = pts.T.tobytes()  # one block per field: every x, then every y, then every z
    literals = b"".join(bytes([len(raw[i:i + 32]) - 1]) + raw[i:i + 32] for i in range(0, len(raw), 32))
    assert np.array_equal(parse_pcd(_compressed_pcd(10, literals, len(raw)))[0], pts)


# ---- depth PNG -------------------------------------------------------------------------------------------------

PNG_PROBE = """
import resource, struct, sys, zlib
import numpy as np
from graspd.io.depth import read_depth_png

def chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

rows = b"".join(b"\\x00" + np.full(100, 700, ">u2").tobytes() for _ in range(100))
comp = zlib.compressobj(9)
zero = bytes(1 << 20)
idat = comp.compress(rows) + b"".join(comp.compress(zero) for _ in range(512)) + comp.flush()
png = (b"\\x89PNG\\r\\n\\x1a\\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 100, 100, 16, 0, 0, 0, 0))
       + chunk(b"IDAT", idat) + chunk(b"IEND", b""))
read_depth_png(b"\\x89PNG\\r\\n\\x1a\\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 2, 2, 16, 0, 0, 0, 0))
               + chunk(b"IDAT", zlib.compress(bytes(10))) + chunk(b"IEND", b""))  # Pillow's imports, first
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
depth = read_depth_png(png)
grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
print(len(png), depth.shape, round(float(depth[0, 0]), 4), grown)
"""


def test_a_depth_png_whose_idat_inflates_to_half_a_gigabyte_decodes_its_declared_pixels_only() -> None:
    """A 100 x 100 16-bit PNG whose IDAT goes on for 512 MiB of zeros (~0.5 MB sent): Pillow inflates the
    declared 100 rows and stops; the process's peak memory grows by less than 50 MB (a fresh interpreter:
    ru_maxrss is its own)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "service"), str(REPO / "client"), env.get("PYTHONPATH", "")])
    out = subprocess.run([sys.executable, "-c", PNG_PROBE], capture_output=True, text=True, env=env, timeout=120,
                         check=True)
    size, rows, cols, first, grown_kib = out.stdout.split()
    assert int(size) < 1_000_000
    assert (rows, cols, first) == ("(100,", "100)", "0.7"), out.stdout
    assert int(grown_kib) < 50 * 1024, out.stdout
