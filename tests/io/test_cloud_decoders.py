"""graspd's own PCD and PLY decoders (numpy, no open3d): every layout PCL and the PLY writers produce, x y z found
by name among other fields and types, lists skipped, NaN pixels kept in order, and what is not a table of
numbers refused naming cloud.points.  Where open3d is importable the decoders are held equal to it, value for
value, on the real clouds and on files open3d writes; the other tests need no open3d."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest

from graspd.core.cloud import CloudError
from graspd.io import text_numbers
from graspd.io.cloud_files import parse_pcd, parse_ply, read_input
from graspd.io.lzf import LzfError, lzf_decompress
from graspd.io.text_numbers import line_start, read_numbers

RNG = np.random.default_rng(7)
PTS = (RNG.normal(size=(300, 3)) * 10.0 ** RNG.integers(-3, 2, (300, 1))).astype(np.float32)


# ---- the text reader ---------------------------------------------------------------------------------------------
def test_read_numbers_counts_each_line_and_skips_blank_ones() -> None:
    table = read_numbers(b"  \n1\t2\r\n\n3 4 5 \n-inf nan 1e5", np.float64)
    assert table.per_line.tolist() == [2, 3, 3] and table.row_starts().tolist() == [0, 2, 5]
    assert np.array_equal(table.values, [1, 2, 3, 4, 5, -np.inf, np.nan, 1e5], equal_nan=True)
    for empty in (b"", b" ", b"\n \n"):  # np.fromstring alone reads " " as [-1.0]
        assert read_numbers(empty).values.size == 0 and read_numbers(empty).per_line.size == 0
    assert [line_start(b"a\nbc\n", k) for k in range(4)] == [0, 2, 5, 5]


def test_reading_in_pieces_cut_at_newlines_gives_the_same_numbers(monkeypatch: pytest.MonkeyPatch) -> None:
    """The text is read CHUNK bytes at a time: any piece size, lines longer than a piece included, gives the
    numbers and the per-line counts of one read."""
    text = b"\n1 2 3\n\n  4 5 6 7 8 9 10 11 12 13 14 15\n16\n\n17 18\n" * 3 + b"19 20"
    whole = read_numbers(text)
    starts = [line_start(text, k) for k in range(text.count(b"\n") + 2)]
    for chunk in (1, 2, 3, 5, 8, 13, 40, 1000):
        monkeypatch.setattr(text_numbers, "CHUNK", chunk)
        piecewise = read_numbers(text)
        assert np.array_equal(piecewise.values, whole.values) and np.array_equal(piecewise.per_line,
                                                                                 whole.per_line), chunk
        assert [line_start(text, k) for k in range(len(starts))] == starts, chunk
    with pytest.raises(ValueError):
        read_numbers(text + b"\n1 x 2")


@pytest.mark.parametrize("text", [b"1 2 a", b"1,2 3", b"1-2 3", b"1 2\x003", b"1\x012", b"0x10", b"1 2 3\xc2\xa04"])
def test_read_numbers_refuses_what_is_not_a_number(text: bytes) -> None:
    with pytest.raises(ValueError):
        read_numbers(text)


def test_float32_text_is_rounded_as_a_float64_parse_then_a_cast() -> None:
    """What strtod-then-cast readers (PCL, open3d) get, also for decimals halfway between two float32 values."""
    low = PTS.ravel()
    mid = (low.astype(np.float64) + np.nextafter(low, np.float32(np.inf)).astype(np.float64)) / 2
    text = " ".join(f"{v!r}" for v in [*mid.tolist(), *low.astype(np.float64).tolist()]).encode()
    assert np.array_equal(read_numbers(text, np.float32).values, read_numbers(text).values.astype(np.float32))


# ---- PCD -------------------------------------------------------------------------------------------------------------
def pcd(fields: list[tuple[str, str, int]], data: bytes, kind: str, n: int, extra: str = "") -> bytes:
    """A PCD file: fields as (name, numpy dtype of one value, count)."""
    types = {"f": "F", "i": "I", "u": "U"}
    head = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS {' '.join(f[0] for f in fields)}\n"
            f"SIZE {' '.join(str(np.dtype(f[1]).itemsize) for f in fields)}\n"
            f"TYPE {' '.join(types[np.dtype(f[1]).kind] for f in fields)}\n"
            f"COUNT {' '.join(str(f[2]) for f in fields)}\nWIDTH {n}\nHEIGHT 1\n{extra}POINTS {n}\nDATA {kind}\n")
    return head.encode() + data


def lzf_literals(raw: bytes) -> bytes:
    """A valid LZF stream of raw bytes made of literal runs only (graspd has no compressor)."""
    return b"".join(bytes([len(raw[i:i + 32]) - 1]) + raw[i:i + 32] for i in range(0, len(raw), 32))


LAYOUT = [("rgb", "<u4", 1), ("z", "<f8", 1), ("fpfh", "<f4", 3), ("y", "<f4", 1), ("label", "<i2", 1),
          ("x", "<f4", 1)]


def records() -> np.ndarray:
    rec = np.zeros(len(PTS), [(name, dt, (c,)) if c > 1 else (name, dt) for name, dt, c in LAYOUT])
    rec["x"], rec["y"], rec["z"] = PTS.T
    rec["rgb"], rec["label"], rec["fpfh"] = 0xFF8000, -3, 1.5
    return rec


def test_pcd_reads_xyz_by_name_in_every_layout() -> None:
    """z before y before x, a float64 z, a 3-value descriptor and integers around them: the same points from
    ascii, binary and binary_compressed (one block per field after LZF)."""
    rec, n = records(), len(PTS)
    rows = [f"{int(r['rgb'])} {float(r['z'])!r} 1.5 1.5 1.5 {float(r['y'])!r} -3 {float(r['x'])!r}" for r in rec]
    ascii_ = pcd(LAYOUT, ("\n".join(rows) + "\n").encode(), "ascii", n)
    binary = pcd(LAYOUT, rec.tobytes(), "binary", n)
    blocks = b"".join(np.ascontiguousarray(rec[name]).tobytes() for name, _, _ in LAYOUT)
    compressed = pcd(LAYOUT, np.array([len(lzf_literals(blocks)), len(blocks)], "<u4").tobytes()
                     + lzf_literals(blocks), "binary_compressed", n, "VIEWPOINT 0.5 0 1 1 0 0 0\n")
    for data in (ascii_, binary, compressed):
        points, viewpoint = parse_pcd(data)
        assert points.dtype == np.float32 and np.array_equal(points, PTS)
    assert np.allclose(parse_pcd(compressed)[1], [0.5, 0, 1]) and parse_pcd(binary)[1] is None


def test_pcd_integer_coordinates_and_an_organised_cloud_with_nan_pixels() -> None:
    xyz = np.array([[1, -2, 3], [4, 5, -6]], "<i2")
    points, _ = parse_pcd(pcd([("x", "<i2", 1), ("y", "<i2", 1), ("z", "<i2", 1)], xyz.tobytes(), "binary", 2))
    assert np.array_equal(points, xyz)
    text = b"0.1 0.2 0.5\nnan nan nan\n0.3 0.1 0.6\nNaN nan nan\n"
    data = pcd([("x", "<f4", 1), ("y", "<f4", 1), ("z", "<f4", 1)], text, "ascii", 4).replace(
        b"WIDTH 4\nHEIGHT 1", b"WIDTH 2\nHEIGHT 2")
    points, _ = parse_pcd(data)
    assert np.isnan(points[[1, 3]]).all() and np.allclose(points[[0, 2]], [[0.1, 0.2, 0.5], [0.3, 0.1, 0.6]])
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "o.pcd").write_bytes(data)
        got = read_input(Path(tmp) / "o.pcd")
    assert got.dropped == 2 and got.received == 4 and len(got.cloud) == 2


XYZ = [("x", "<f4", 1), ("y", "<f4", 1), ("z", "<f4", 1)]
BAD_ASCII = [
    ("uneven rows of the right total", b"1 2 3 4\n5 6\n", "unreadable"),
    ("a word", b"1 2 3\n4 five 6\n", "unreadable"),
    ("comma separated", b"1,2,3\n4,5,6\n", "the data holds 2 rows of 1"),  # the shape is checked first
    ("rows of 4", b"1 2 3 4\n5 6 7 8\n", "2 points of 3 values; the data holds 2 rows of 4"),
    ("3 rows", b"1 2 3\n4 5 6\n7 8 9\n", "the data holds 3 rows of 3"),
    ("no rows", b"\n \n", "the data holds 0 rows"),
]


@pytest.mark.parametrize(("name", "text", "why"), BAD_ASCII, ids=[c[0] for c in BAD_ASCII])
def test_pcd_ascii_data_that_is_no_table_of_the_declared_shape_is_refused(name: str, text: bytes, why: str) -> None:
    with pytest.raises(CloudError, match=why) as err:
        parse_pcd(pcd(XYZ, text, "ascii", 2))
    assert err.value.field == "cloud.points"


def test_pcd_ascii_blank_lines_and_crlf_are_fine() -> None:
    points, _ = parse_pcd(pcd(XYZ, b"\r\n1 2 3\r\n\r\n  4\t5 6  \r\n", "ascii", 2))
    assert np.array_equal(points, [[1, 2, 3], [4, 5, 6]])


def test_corrupt_lzf_is_refused_naming_the_points() -> None:
    raw = PTS[:10].astype("<f4").tobytes()
    stream = bytearray(lzf_literals(raw))
    stream[0] = 0xE0  # a back reference before the start of the output
    head = np.array([len(stream), len(raw)], "<u4").tobytes()
    with pytest.raises(CloudError, match="binary_compressed data unreadable") as err:
        parse_pcd(pcd(XYZ, head + bytes(stream), "binary_compressed", 10))
    assert err.value.field == "cloud.points"


def test_lzf_back_references_including_overlapping_ones() -> None:
    # "abc", then 6 bytes from 3 back (overlapping: abcabc), then 2 literals "xy", then 3 from distance 2
    stream = bytes([2]) + b"abc" + bytes([(4 << 5) | 0, 2]) + bytes([1]) + b"xy" + bytes([(1 << 5) | 0, 1])
    assert lzf_decompress(stream, 3 + 6 + 2 + 3) == b"abcabcabcxyxyx"
    long_ref = bytes([0]) + b"z" + bytes([(7 << 5) | 0, 3, 0])  # length 7 + 3 + 2 = 12 copies of the last byte
    assert lzf_decompress(long_ref, 13) == b"z" * 13
    for bad, size in ((bytes([5]) + b"ab", 6), (bytes([0]) + b"a" + bytes([0x20]), 3), (bytes([0]) + b"ab", 1),
                      (bytes([0]) + b"a", 2)):
        with pytest.raises(LzfError):
            lzf_decompress(bad, size)


# ---- PLY -------------------------------------------------------------------------------------------------------------
def ply(fmt: str, elements: list[tuple[str, int, list[str]]], data: bytes) -> bytes:
    head = f"ply\nformat {fmt} 1.0\ncomment made by a test\n"
    for name, count, props in elements:
        head += f"element {name} {count}\n" + "".join(f"property {p}\n" for p in props)
    return (head + "end_header\n").encode() + data


VERTEX = ["double x", "float nx", "float y", "float z", "uchar red", "ushort flags"]


@pytest.mark.parametrize("endian", ["<", ">"])
def test_binary_ply_reads_xyz_after_other_elements_and_lists(endian: str) -> None:
    """Both byte orders; the faces before the vertices (uniform triangles, then lists of varying length);
    normals and colours beside x y z."""
    fmt = "binary_little_endian" if endian == "<" else "binary_big_endian"
    rec = np.zeros(len(PTS), np.dtype([("x", f"{endian}f8"), ("nx", f"{endian}f4"), ("y", f"{endian}f4"),
                                       ("z", f"{endian}f4"), ("red", "u1"), ("flags", f"{endian}u2")]))
    rec["x"], rec["y"], rec["z"], rec["red"] = PTS[:, 0], PTS[:, 1], PTS[:, 2], 200
    triangles = np.zeros(4, np.dtype([("n", "u1"), ("i", f"{endian}i4", (3,))]))
    triangles["n"], triangles["i"] = 3, [[0, 1, 2]]
    mixed = b"".join(bytes([k]) + np.arange(k, dtype=f"{endian}i4").tobytes() for k in (3, 4, 0, 5))
    for faces in (triangles.tobytes(), mixed):
        data = ply(fmt, [("face", 4, ["list uchar int vertex_indices"]), ("vertex", len(PTS), VERTEX)],
                   faces + rec.tobytes())
        assert np.array_equal(parse_ply(data), PTS)
    with pytest.raises(CloudError, match="fewer"):  # the varying lists leave too few bytes for the vertices
        parse_ply(ply(fmt, [("face", 4, ["list uchar int vertex_indices"]), ("vertex", len(PTS), VERTEX)],
                      mixed + rec.tobytes()[:-8]))


def test_binary_ply_vertices_with_a_list_of_varying_length() -> None:
    rows = b"".join(np.array(p, "<f4").tobytes() + bytes([k]) + np.arange(k, dtype="<i4").tobytes()
                    for p, k in zip(PTS[:20].tolist(), [2, 0, 5, 1] * 5, strict=True))
    data = ply("binary_little_endian", [("vertex", 20, ["float x", "float y", "float z", "list uchar int idx"])],
               rows)
    assert np.array_equal(parse_ply(data), PTS[:20])


def test_ascii_ply_reads_xyz_around_lists_and_before_faces() -> None:
    lines = [f"{x!r} 2 7 8 {y!r} {z!r} 255" if i % 2 else f"{x!r} 0 {y!r} {z!r} 255"
             for i, (x, y, z) in enumerate(PTS.astype(np.float64).tolist())]
    props = ["float x", "list uchar int idx", "float y", "float z", "uchar red"]
    faces = "3 0 1 2\n4 0 1 2 3\n"
    data = ply("ascii", [("vertex", len(PTS), props), ("face", 2, ["list uchar int vertex_indices"])],
               ("\n".join(lines) + "\n" + faces).encode())
    assert np.array_equal(parse_ply(data), PTS)
    first = ply("ascii", [("face", 2, ["list uchar int vertex_indices"]), ("vertex", len(PTS), props)],
                (faces + "\n".join(lines)).encode())  # no newline after the last row
    assert np.array_equal(parse_ply(first), PTS)


XYZ_PLY = [("vertex", 2, ["float x", "float y", "float z"])]
BAD_PLY = [
    ("a word", b"1 2 3\n4 five 6\n", "unreadable"),
    ("a short row", b"1 2 3\n4 5\n", "fewer"),
    ("a blank row", b"1 2 3\n\n4 5 6\n", "fewer"),
    ("one row", b"1 2 3\n", "fewer"),
    ("a long row", b"1 2 3\n4 5 6 7\n", "do not hold"),
]


@pytest.mark.parametrize(("name", "text", "why"), BAD_PLY, ids=[c[0] for c in BAD_PLY])
def test_ascii_ply_rows_that_do_not_match_the_header_are_refused(name: str, text: bytes, why: str) -> None:
    with pytest.raises(CloudError, match=why) as err:
        parse_ply(ply("ascii", XYZ_PLY, text))
    assert err.value.field == "cloud.points"
    with pytest.raises(CloudError, match="not a non-negative integer"):
        parse_ply(ply("ascii", [("vertex", 1, ["float x", "list uchar int i", "float y", "float z"])],
                      b"1 -1 2 3\n"))


# ---- equal to open3d, where it is installed --------------------------------------------------------------------------
def _open3d_pcd(o3d: object, path: Path) -> np.ndarray:
    cloud = o3d.t.io.read_point_cloud(str(path), format="pcd")  # type: ignore[attr-defined]
    return np.asarray(cloud.point.positions.numpy(), np.float32)


def _open3d_ply(o3d: object, path: Path) -> np.ndarray:
    return np.asarray(o3d.io.read_point_cloud(str(path), format="ply").points, np.float32)  # type: ignore[attr-defined]


def test_decoders_equal_open3d(real_data: Path, tmp_path: Path) -> None:
    """The real Kinect clouds (ASCII), and a cloud with NaN rows, normals and colours written by open3d in every
    PCD and PLY layout it writes (float32 and, through its tensor API, float64): the same values, NaN included."""
    o3d = pytest.importorskip("open3d")
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    for path in sorted(real_data.glob("*.pcd")):
        assert np.array_equal(parse_pcd(path.read_bytes())[0], _open3d_pcd(o3d, path), equal_nan=True), path.name
    pts = PTS.astype(np.float64)
    pts[[3, 17]] = np.nan
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    legacy.normals = o3d.utility.Vector3dVector(RNG.normal(size=pts.shape))
    legacy.colors = o3d.utility.Vector3dVector(RNG.uniform(size=pts.shape))
    tensor = o3d.t.geometry.PointCloud(o3d.core.Tensor(pts * 1.000001))
    tensor.point.intensity = o3d.core.Tensor(RNG.uniform(size=(len(pts), 1)).astype(np.float32))
    written = 0
    for name, ascii_, compressed in (("a", True, False), ("b", False, False), ("c", False, True)):
        for api, cloud in (("legacy", legacy), ("tensor", tensor)):
            writer = o3d.io.write_point_cloud if api == "legacy" else o3d.t.io.write_point_cloud
            for suffix in (".pcd", ".ply"):
                path = tmp_path / f"{api}-{name}{suffix}"
                assert writer(str(path), cloud, write_ascii=ascii_, compressed=compressed)
                data = path.read_bytes()
                ours = parse_pcd(data)[0] if suffix == ".pcd" else parse_ply(data)
                theirs = _open3d_pcd(o3d, path) if suffix == ".pcd" else _open3d_ply(o3d, path)
                assert ours.shape == (len(pts), 3) and np.array_equal(ours, theirs, equal_nan=True), path.name
                written += 1
    assert written == 12
    mesh = o3d.geometry.TriangleMesh.create_sphere(0.05)  # a mesh file: vertices, then faces
    for ascii_ in (True, False):
        path = tmp_path / f"mesh-{ascii_}.ply"
        assert o3d.io.write_triangle_mesh(str(path), mesh, write_ascii=ascii_)
        assert np.array_equal(parse_ply(path.read_bytes()), _open3d_ply(o3d, path))


def test_ply_headers_the_readers_cannot_follow_are_refused() -> None:
    """x as a list, and a list counted by a float (its rows could not be walked), are refused from the header."""
    for props, why in ((["list uchar float x", "float y", "float z"], "is a list"),
                       (["float x", "float y", "float z", "list float int idx"], "not understood")):
        with pytest.raises(CloudError, match=why) as err:
            parse_ply(ply("binary_little_endian", [("vertex", 1, props)], bytes(64)))
        assert err.value.field == "cloud.points"
