"""Mesh files at the edge (.obj, .stl, .ply, in metres): the limits an uploaded mesh must meet and the checks of
its declared sizes that run on the bytes before any parser allocates (POST /models).  Every refusal is a
MeshError naming the field the mesh came in.  Reading the mesh itself (open3d) is graspd_lab.world.mesh_file."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from graspd.core.errors import FieldError

#: File types open3d reads as triangle meshes (chosen by suffix).
MESH_SUFFIXES = (".obj", ".stl", ".ply")


class MeshError(FieldError):
    """A mesh file that cannot be an instance object; .field names where it came from."""


@dataclass(frozen=True)
class MeshLimits:
    """What a mesh for an instance model may be.  Sizes in metres: an object in millimetres fails the largest
    extent (60 mm read as 60 m), one in kilometres the smallest."""

    max_extent: float = 0.5          # largest bounding-box side: what a hand on an arm can reach around
    min_extent: float = 0.01         # largest side at least 1 cm
    max_triangles: int = 300_000     # raycasting and labelling time grow with it
    max_vertices: int = 1_000_000    # a clean mesh has about half as many vertices as triangles
    max_bytes: int = 32 << 20


def _check(ok: bool, field: str, message: str) -> None:
    if not ok:
        raise MeshError(field, message)


#: Bytes of each PLY scalar type.
PLY_TYPE_BYTES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
                  "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}
#: Longest PLY header read (bytes); a header that does not end within it is refused.
PLY_MAX_HEADER = 64 << 10


def _ply_declared(data: bytes, limits: MeshLimits, field: str) -> None:
    """Check a PLY header's element counts against the bytes after the header (see check_declared_counts)."""
    end = data.find(b"end_header", 0, PLY_MAX_HEADER)
    _check(end >= 0, field, f"a PLY whose header does not end (no end_header in its first {PLY_MAX_HEADER} bytes)")
    newline = data.find(b"\n", end)
    body = len(data) - (newline + 1 if newline >= 0 else len(data))
    fmt = ""
    elements: list[list[Any]] = []  # [name, count, min bytes of one]
    for raw in data[:end].decode("ascii", "replace").splitlines():
        words = raw.split()
        if not words:
            continue
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element" and len(words) >= 3:
            _check(words[2].isdigit() and len(words[2]) <= 12, field,
                   f"PLY element {words[1][:40]!r} declares an invalid count {words[2][:40]!r}")
            elements.append([words[1], int(words[2]), 0])
        elif words[0] == "property" and elements:
            ascii_ = fmt == "ascii"
            if len(words) >= 5 and words[1] == "list":  # a list may be empty: its count alone
                size = PLY_TYPE_BYTES.get(words[2])
            else:
                size = PLY_TYPE_BYTES.get(words[1]) if len(words) >= 3 else None
            _check(size is not None, field, f"PLY property with an unknown type: {raw.strip()[:80]!r}")
            elements[-1][2] += 2 if ascii_ else int(size or 0)  # ascii: one digit and one separator at least
    _check(fmt in ("ascii", "binary_little_endian", "binary_big_endian"), field,
           f"a PLY of unknown format {fmt[:40]!r}")
    counts = {name: count for name, count, _ in elements}
    vertices, faces = counts.get("vertex", 0), counts.get("face", 0)
    _check(vertices <= limits.max_vertices, field,
           f"declares {vertices} vertices, more than the limit of {limits.max_vertices} (simplify the mesh)")
    _check(faces <= limits.max_triangles, field,
           f"declares {faces} faces, more than the limit of {limits.max_triangles} (simplify the mesh)")
    need = sum(count * size for _, count, size in elements)
    _check(need <= body, field,
           f"its header declares {vertices} vertices and {faces} faces, which need at least {need} bytes, but only "
           f"{body} bytes follow the header (a truncated or lying file)")


def check_declared_counts(data: bytes, suffix: str, limits: MeshLimits | None = None, field: str = "mesh") -> None:
    """Refuse (MeshError naming field) a mesh file whose declared sizes cannot be true or are over the limits,
    before any parser allocates for them: a PLY's element counts against the bytes after its header (an ASCII
    vertex of 3 coordinates needs at least 6 bytes, a binary one its stride), a binary STL's triangle count
    against its size (84 + 50 bytes per triangle), and the face and vertex lines of OBJ and ASCII STL files
    against limits.max_triangles / max_vertices.  Reads only bytes already in memory (at most limits.max_bytes):
    the 204-byte PLY declaring 1e9 vertices is refused in microseconds instead of a parser reserving 24 GB."""
    limits = limits or MeshLimits()
    suffix = suffix.lower()
    _check(len(data) <= limits.max_bytes, field, f"the file has {len(data)} bytes, more than the limit of "
           f"{limits.max_bytes}")
    if suffix == ".ply":
        _check(data[:3] == b"ply", field, "not a PLY file (it does not start with 'ply')")
        _ply_declared(data, limits, field)
    elif suffix == ".stl":
        count = int.from_bytes(data[80:84], "little") if len(data) >= 84 else -1
        if count >= 0 and len(data) == 84 + 50 * count:  # binary STL
            _check(count <= limits.max_triangles, field,
                   f"{count} triangles, more than the limit of {limits.max_triangles} (simplify the mesh)")
        else:
            _check(data[:5].lower() == b"solid", field,
                   f"a binary STL declaring {max(count, 0)} triangles needs {84 + 50 * max(count, 0)} bytes, but "
                   f"the file has {len(data)} (a truncated or lying file)")
            facets = data.count(b"facet") // 2  # 'facet normal' and 'endfacet'
            _check(facets <= limits.max_triangles, field,
                   f"{facets} triangles, more than the limit of {limits.max_triangles} (simplify the mesh)")
    elif suffix == ".obj":
        faces = data.count(b"\nf ") + data.startswith(b"f ")
        vertices = data.count(b"\nv ") + data.startswith(b"v ")
        _check(faces <= limits.max_triangles, field,
               f"{faces} faces, more than the limit of {limits.max_triangles} (simplify the mesh)")
        _check(vertices <= limits.max_vertices, field,
               f"{vertices} vertices, more than the limit of {limits.max_vertices} (simplify the mesh)")
