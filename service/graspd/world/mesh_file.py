"""One grasp object from a mesh file the caller gives (.obj, .stl or .ply, in metres): read by open3d and
checked before anything is rendered or trained on it (instance models: graspd.training.instance, POST /models).

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

import numpy as np
import open3d as o3d

from graspd_client.codec import WireError

from ..hand import HandGeometry
from .meshes import clean_mesh
from .objects import CATEGORY_NAMES, GraspObject

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
    max_bytes: int = 32 << 20


def _check(ok: bool, field: str, message: str) -> None:
    if not ok:
        raise MeshError(field, message)


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


def main(argv: list[str] | None = None) -> int:
    """`python -m graspd.world.mesh_file MESH [--category C] [--hand JSON] [--max-bytes N]`: check a mesh in a
    process of its own (the server does, so that a hostile file cannot take the service down) and print one JSON
    line: {"ok": true, "extent", "triangles", "source"} or {"ok": false, "field", "error"}."""
    p = argparse.ArgumentParser(prog="python -m graspd.world.mesh_file", description=main.__doc__)
    p.add_argument("mesh")
    p.add_argument("--category", default="other")
    p.add_argument("--hand", default="{}", help="HandGeometry fields as JSON (default: the gpd hand)")
    p.add_argument("--max-bytes", type=int, default=MeshLimits.max_bytes)
    p.add_argument("--field", default="mesh")
    args = p.parse_args(argv)
    try:
        hand = HandGeometry(**json.loads(args.hand))
        limits = MeshLimits(**{**asdict(MeshLimits()), "max_bytes": args.max_bytes})
        obj = read_mesh_object(args.mesh, "check", args.category, hand, limits, args.field)
    except WireError as exc:
        print(json.dumps({"ok": False, "field": exc.field, "error": exc.message}))
        return 0
    print(json.dumps({"ok": True, "extent": list(obj.extent), "triangles": len(obj.mesh.triangles),
                      "source": obj.source}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
