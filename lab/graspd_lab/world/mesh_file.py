"""One grasp object from a mesh file the caller gives (.obj, .stl or .ply, in metres): read by open3d and
checked before anything is rendered or trained on it (instance models: graspd_lab.training.instance, POST /models).

The mesh keeps its size (no rescaling: an instance model is for that object as it is); it is cleaned and
centred on its bounding-box centre like every catalogue object.  Every refusal is a MeshError, a
graspd_client WireError naming the field the mesh came in (default "mesh"), so the CLI prints it and the
server answers 422 with that field.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d

from graspd.core.hand import HandGeometry
from graspd_client.codec import WireError
from graspd_lab.world.meshes import clean_mesh
from graspd_lab.world.objects import CATEGORY_NAMES, GraspObject

#: File types open3d reads as triangle meshes (chosen by suffix).
MESH_SUFFIXES = (".obj", ".stl", ".ply")


class MeshError(WireError):
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


def principal_extents(vertices: np.ndarray) -> np.ndarray:
    """Extents (m) along the vertices' principal axes, smallest first."""
    centred = vertices - vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    local = centred @ axes.T
    return np.sort(local.max(axis=0) - local.min(axis=0))


def read_mesh_object(path: str | Path, name: str, category: str = "other", hand: HandGeometry | None = None,
                     limits: MeshLimits | None = None, field: str = "mesh") -> GraspObject:
    """The object in a mesh file, validated: a known suffix, at most limits.max_bytes, readable, triangles
    (not a point cloud), finite vertices and valid indices, at most limits.max_triangles, sized in metres
    between limits.min_extent and limits.max_extent, and narrow enough somewhere for the hand to close on it
    (its smallest extent at most the hand's aperture).  MeshError(field, why) otherwise."""
    path = Path(path)
    limits = limits or MeshLimits()
    hand = hand or HandGeometry()
    _check(category in CATEGORY_NAMES, "category", f"must be one of {list(CATEGORY_NAMES)}, got {category!r}")
    _check(path.suffix.lower() in MESH_SUFFIXES, field,
           f"must be a {', '.join(MESH_SUFFIXES)} file, got {path.name!r}")
    _check(path.is_file(), field, f"{path} does not exist")
    size = path.stat().st_size
    _check(size > 0, field, "the file is empty")
    _check(size <= limits.max_bytes, field, f"the file has {size} bytes, more than the limit of {limits.max_bytes}")
    data = path.read_bytes()
    check_declared_counts(data, path.suffix, limits, field)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh = o3d.io.read_triangle_mesh(path)
    vertices = np.asarray(mesh.vertices, np.float64)
    triangles = np.asarray(mesh.triangles, np.int64)
    _check(len(triangles) > 0 and len(vertices) >= 3, field,
           f"no triangles in {path.name!r} (unreadable, empty, or a point cloud; an instance needs a surface mesh)")
    _check(len(triangles) <= limits.max_triangles, field,
           f"{len(triangles)} triangles, more than the limit of {limits.max_triangles} (simplify the mesh)")
    _check(bool(np.isfinite(vertices).all()), field, "has non-finite (NaN or infinite) vertex coordinates")
    _check(int(triangles.min()) >= 0 and int(triangles.max()) < len(vertices), field,
           "has triangles that index vertices it does not have")
    mesh = clean_mesh(o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices),
                                                o3d.utility.Vector3iVector(triangles.astype(np.int32))))
    vertices = np.asarray(mesh.vertices)
    _check(len(mesh.triangles) > 0, field, "has only degenerate triangles (zero area)")
    extent = np.ptp(vertices, axis=0)
    largest = float(extent.max())
    _check(largest <= limits.max_extent, field,
           f"largest extent {largest:.3g} m exceeds {limits.max_extent} m: sizes must be in metres "
           "(a mesh in millimetres is 1000x too large)")
    _check(largest >= limits.min_extent, field,
           f"largest extent {largest:.3g} m is below {limits.min_extent} m: sizes must be in metres")
    narrowest = float(min(principal_extents(vertices)[0], extent.min()))
    _check(narrowest <= hand.max_aperture, field,
           f"smallest extent {narrowest:.3g} m exceeds the hand's aperture {hand.max_aperture:.3g} m: the hand "
           "cannot close on it in any direction")
    mesh.compute_triangle_normals()
    digest = hashlib.sha256(data).hexdigest()
    return GraspObject(name=name, source=f"file:{path.name}:sha256={digest}", category=category, mesh=mesh,
                       scale=1.0)


def limit_process(max_memory_mb: int, max_cpu_s: int) -> None:
    """Cap this process's address space (MiB) and CPU time (s); 0 leaves one as it is.  Linux: RLIMIT_AS counts
    every mapping, so the cap must leave room for the libraries already loaded (see VmPeak of a normal check)."""
    import resource  # noqa: PLC0415  (POSIX only)

    if max_memory_mb > 0:
        cap = max_memory_mb << 20
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    if max_cpu_s > 0:
        resource.setrlimit(resource.RLIMIT_CPU, (max_cpu_s, max_cpu_s + 1))


def main(argv: list[str] | None = None) -> int:
    """`python -m graspd_lab.world.mesh_file MESH [--category C] [--hand JSON] [--max-bytes N]`: check a mesh in a
    process of its own (the server does, so that a hostile file cannot take the service down) and print one JSON
    line: {"ok": true, "extent", "triangles", "source"} or {"ok": false, "field", "error"}."""
    p = argparse.ArgumentParser(prog="python -m graspd_lab.world.mesh_file", description=main.__doc__)
    p.add_argument("mesh")
    p.add_argument("--category", default="other")
    p.add_argument("--hand", default="{}", help="HandGeometry fields as JSON (default: the gpd hand)")
    p.add_argument("--max-bytes", type=int, default=MeshLimits.max_bytes)
    p.add_argument("--field", default="mesh")
    p.add_argument("--max-memory-mb", type=int, default=0, help="address-space limit of this process (RLIMIT_AS, "
                   "MiB; 0: none): a parser that tries to allocate more fails instead of the machine swapping")
    p.add_argument("--max-cpu-s", type=int, default=0, help="CPU-time limit of this process (RLIMIT_CPU, s; 0: none)")
    args = p.parse_args(argv)
    limit_process(args.max_memory_mb, args.max_cpu_s)
    try:
        hand = HandGeometry(**json.loads(args.hand))
        limits = MeshLimits(**{**asdict(MeshLimits()), "max_bytes": args.max_bytes})
        obj = read_mesh_object(args.mesh, "check", args.category, hand, limits, args.field)
    except WireError as exc:
        print(json.dumps({"ok": False, "field": exc.field, "error": exc.message}))
        return 0
    except MemoryError:
        print(json.dumps({"ok": False, "field": args.field, "error": f"checking the mesh needs more than the "
                          f"limit of {args.max_memory_mb} MiB of memory (simplify the mesh)"}))
        return 0
    print(json.dumps({"ok": True, "extent": list(obj.extent), "triangles": len(obj.mesh.triangles),
                      "source": obj.source}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
