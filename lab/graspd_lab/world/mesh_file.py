"""One grasp object from a mesh file the caller gives (.obj, .stl or .ply, in metres): read by open3d and
checked before anything is rendered or trained on it (instance models: graspd_lab.training.instance, POST /models).

The mesh keeps its size (no rescaling: an instance model is for that object as it is); it is cleaned and
centred on its bounding-box centre like every catalogue object.  Every refusal is a MeshError, a
graspd.core.errors.FieldError naming the field the mesh came in (default "mesh"), so the CLI prints it and the
server answers 422 with that field.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
import open3d as o3d

from graspd.core.errors import FieldError
from graspd.core.hand import HandGeometry
from graspd.io.mesh_file import MESH_SUFFIXES, MeshLimits, _check, check_declared_counts
from graspd_lab.world.meshes import clean_mesh
from graspd_lab.world.objects import CATEGORY_NAMES, GraspObject


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
    except FieldError as exc:
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
