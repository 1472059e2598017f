"""The one object catalogue: procedural shapes, pybullet_data's random_urdfs and the household models, with no
download.

Every catalogue object is an open3d TriangleMesh in metres, centred on its bounding-box centre, scaled so a
two-finger hand can close on it (smallest bounding extent at most `fit` x the hand's max aperture),
and tagged with a category as in the IJRR paper's dataset: box-like, cylinder-like or other.

pybullet_data random_urdfs 900-999 are the project's held-out test objects (the project's design notes, "Data
rules"). The rule is written once, in urdf_folder: every loader of a random_urdfs file (the training
meshes, the sized meshes of scripted scenes, the simulator's URDFs and extents) goes through it and
is refused a held-out object unless the caller says it is the held-out evaluation (held_out_ok).
pybullet_data ships inside the pybullet wheel (the lab distribution graspd-lab).

Household models (graspd_lab.world.household, kind "household", index k = the k-th model by name) are the
exception to the fitting: they keep their true size (scale 1).  Their held-out rule is household.HELD_OUT,
enforced by check_not_held_out for their simulator ids and by load_object.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
import open3d as o3d

from graspd.core.hand import HandGeometry
from graspd_lab.world import household
from graspd_lab.world.held_out import HeldOutObjectError
from graspd_lab.world.meshes import (
    box_mesh,
    capsule_mesh,
    clean_mesh,
    composite_mesh,
    cone_mesh,
    cylinder_mesh,
    rot_z,
    sphere_mesh,
)

CATEGORY_NAMES = ("box", "cylinder", "other")
HELD_OUT_URDFS = range(900, 1000)
TRAINING_URDFS = range(0, 900)
#: A broken source mesh (non-finite vertices) pybullet loads but no ground truth can be made of.
BROKEN_URDFS = frozenset({168})
#: The training random_urdfs scenes and tuning sets draw from: every one but the broken.
USABLE_TRAINING_URDFS: tuple[int, ...] = tuple(i for i in TRAINING_URDFS if i not in BROKEN_URDFS)
PROCEDURAL_KINDS = ("box", "cylinder", "sphere", "cone", "capsule", "composite")
#: Scale of the random_urdfs meshes in their own URDF files (mesh units -> metres).
URDF_MESH_SCALE = 0.015


@dataclass(frozen=True)
class GraspObject:
    """A mesh (metres, centred) with its name, source (where it came from), category and applied scale."""

    name: str
    source: str
    category: str
    mesh: o3d.geometry.TriangleMesh
    scale: float

    @property
    def extent(self) -> tuple[float, float, float]:
        """Axis-aligned bounding-box size (m)."""
        bb = self.mesh.get_axis_aligned_bounding_box()
        e = bb.get_extent()
        return (float(e[0]), float(e[1]), float(e[2]))

    def to_dict(self) -> dict[str, object]:
        return {"name": self.name, "source": self.source, "category": self.category,
                "scale": self.scale, "extent": list(self.extent)}


def pybullet_data_dir() -> Path:
    """The pybullet_data folder shipped inside the pybullet wheel (an optional dependency)."""
    import pybullet_data  # noqa: PLC0415

    return Path(pybullet_data.getDataPath())


def check_not_held_out(index: int, held_out_ok: bool = False) -> None:
    """The held-out rule of a simulator object id: raise HeldOutObjectError for random_urdfs 900-999 and the
    held-out household models unless held_out_ok (held-out evaluation only), ValueError for an id that is neither
    a random_urdfs index in [0, 999] nor a household model (household.HOUSEHOLD_ID_BASE + k)."""
    if household.is_household_id(index):
        household.check_household_not_held_out(household.household_name(index), held_out_ok)
        return
    if index in HELD_OUT_URDFS and not held_out_ok:
        raise HeldOutObjectError(
            f"random_urdfs/{index:03d} is a held-out test object (900-999): never load it for training or "
            "validation; pass held_out_ok=True only in the held-out evaluation"
        )
    if not 0 <= index <= 999:
        raise ValueError(f"random_urdfs index must lie in [0, 999], got {index}")


def urdf_folder(index: int, held_out_ok: bool = False) -> Path:
    """The folder of random_urdfs/<index>, after the held-out guard: every random_urdfs loader starts here."""
    check_not_held_out(index, held_out_ok)
    return pybullet_data_dir() / "random_urdfs" / f"{index:03d}"


def urdf_path(index: int, held_out_ok: bool = False) -> Path:
    """The URDF file of random_urdfs/<index> (guarded), as pybullet.loadURDF takes it."""
    return urdf_folder(index, held_out_ok) / f"{index:03d}.urdf"


def mesh_extents(index: int, held_out_ok: bool = False) -> tuple[float, float, float]:
    """Sorted extents (m, smallest first) of random_urdfs/<index>'s mesh at its URDF scale."""
    return _mesh_extents(urdf_folder(index, held_out_ok), index)


@cache
def _mesh_extents(folder: Path, index: int) -> tuple[float, float, float]:
    path = folder / f"{index:03d}.obj"
    verts = np.array(
        [ln.split()[1:4] for ln in path.read_text().splitlines() if ln.startswith("v ")], np.float64
    )
    ext = np.sort(np.ptp(verts, axis=0)) * URDF_MESH_SCALE
    return float(ext[0]), float(ext[1]), float(ext[2])


def graspable_scale(index: int, hand: HandGeometry, fill: float = 0.7, held_out_ok: bool = False) -> float:
    """pybullet globalScaling (<= 1) so random_urdfs/<index>'s middle extent is at most fill * the hand's max
    aperture: every object then has a way to fit between the open fingers, as the paper chose its test set."""
    middle = mesh_extents(index, held_out_ok)[1]
    return float(min(1.0, fill * hand.max_aperture / middle))


def sized_urdf_mesh(index: int, size: float, yaw: float = 0.0, xy: tuple[float, float] = (0.0, 0.0),
                    held_out_ok: bool = False) -> o3d.geometry.TriangleMesh:
    """random_urdfs/<index>'s mesh scaled so its largest extent is size (m), turned by yaw (rad) about z
    and set on the table plane z = 0 at xy (scripted scenes: template tests and benchmarks)."""
    path = urdf_folder(index, held_out_ok) / f"{index:03d}.obj"
    mesh = o3d.io.read_triangle_mesh(path)
    if len(mesh.vertices) == 0:
        raise FileNotFoundError(f"object_id {index}: no mesh at {path}")
    verts = np.asarray(mesh.vertices)
    mesh.translate(-(verts.min(axis=0) + verts.max(axis=0)) / 2)
    mesh.scale(size / float(np.ptp(verts, axis=0).max()), center=np.zeros(3))
    mesh.rotate(rot_z(yaw), center=np.zeros(3))
    mesh.translate(np.array([xy[0], xy[1], -float(np.asarray(mesh.vertices)[:, 2].min())]))
    return mesh


def fit_to_hand(mesh: o3d.geometry.TriangleMesh, hand: HandGeometry, fit: float = 0.8,
                max_extent: float = 0.25) -> float:
    """Scale the mesh in place so its smallest extent along its principal axes <= fit * max_aperture and its largest
    <= max_extent (m); returns the factor applied (1 when it already fits)."""
    v = np.asarray(mesh.vertices)
    _, _, axes = np.linalg.svd(v - v.mean(axis=0), full_matrices=False)
    local = v @ axes.T
    ext = np.sort(local.max(axis=0) - local.min(axis=0))
    factor = min(1.0, fit * hand.max_aperture / max(float(ext[0]), 1e-9), max_extent / max(float(ext[2]), 1e-9))
    if factor < 1.0:
        mesh.scale(factor, center=np.zeros(3))
    return float(factor)


def _urdf_mesh_and_scale(index: int, global_scale: float, held_out_ok: bool
                         ) -> tuple[o3d.geometry.TriangleMesh, float]:
    """random_urdfs/<index>'s mesh scaled as pybullet loads it (link frame, m, not centred) and the URDF's scale."""
    folder = urdf_folder(index, held_out_ok)
    urdf = (folder / f"{index:03d}.urdf").read_text()
    match = re.search(r'<mesh\s+filename="([^"]+)"(?:\s+scale="([^"]+)")?', urdf)
    if match is None:
        raise ValueError(f"{folder}: no <mesh filename=...> in the URDF")
    scale_xyz = np.array([float(v) for v in (match.group(2) or "1 1 1").split()], np.float64)
    mesh = o3d.io.read_triangle_mesh(folder / match.group(1))
    verts = np.asarray(mesh.vertices) * scale_xyz * global_scale
    if len(mesh.triangles) == 0 or not np.isfinite(verts).all():
        raise ValueError(f"{folder / match.group(1)}: no triangles or non-finite vertices (a broken mesh)")
    mesh = clean_mesh(o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts), mesh.triangles), centre=False)
    return mesh, float(scale_xyz[0])


def urdf_mesh(index: int, global_scale: float = 1.0, held_out_ok: bool = False) -> o3d.geometry.TriangleMesh:
    """random_urdfs/<index>'s mesh in its URDF link frame (m): the URDF's mesh scale times pybullet's
    globalScaling, cleaned, with triangle normals; the body pybullet simulates (pose it with the body's pose)."""
    return _urdf_mesh_and_scale(index, global_scale, held_out_ok)[0]


def random_urdf_mesh(index: int, hand: HandGeometry | None = None, held_out_ok: bool = False) -> GraspObject:
    """The mesh of pybullet_data random_urdfs/<index>, with the URDF's scale, fitted to the hand."""
    mesh, urdf_scale = _urdf_mesh_and_scale(index, 1.0, held_out_ok)
    mesh = clean_mesh(mesh)
    factor = fit_to_hand(mesh, hand or HandGeometry())
    mesh.compute_triangle_normals()
    return GraspObject(name=f"urdf_{index:03d}", source=f"pybullet_data:random_urdfs/{index:03d}/{index:03d}.urdf",
                       category="other", mesh=mesh, scale=float(urdf_scale * factor))


def procedural_object(kind: str, index: int, seed: int = 0, hand: HandGeometry | None = None) -> GraspObject:
    """The index-th procedural shape of a kind (deterministic from kind, index and seed)."""
    if kind not in PROCEDURAL_KINDS:
        raise ValueError(f"kind must be one of {PROCEDURAL_KINDS}, got {kind!r}")
    rng = np.random.default_rng([seed, PROCEDURAL_KINDS.index(kind), index])
    category = kind if kind in ("box", "cylinder") else "other"
    if kind == "box":
        dims = rng.uniform([0.02, 0.03, 0.04], [0.08, 0.10, 0.22])
        mesh = box_mesh(*rng.permutation(dims))
    elif kind == "cylinder":
        r, h = rng.uniform([0.01, 0.04], [0.045, 0.22])
        mesh = cylinder_mesh(float(r), float(h))
    elif kind == "sphere":
        mesh = sphere_mesh(float(rng.uniform(0.015, 0.045)))
    elif kind == "cone":
        r, h = rng.uniform([0.015, 0.04], [0.045, 0.15])
        mesh = cone_mesh(float(r), float(h))
    elif kind == "capsule":
        r, length = rng.uniform([0.01, 0.02], [0.04, 0.12])
        mesh = capsule_mesh(float(r), float(length))
    else:
        mesh = composite_mesh(rng)
    factor = fit_to_hand(mesh, hand or HandGeometry())
    mesh.compute_triangle_normals()
    return GraspObject(name=f"{kind}_{index:04d}", source=f"procedural:{kind}:seed={seed}:index={index}",
                       category=category, mesh=mesh, scale=factor)


def household_object(index: int, held_out_ok: bool = False) -> GraspObject:
    """Household model `index` (household.household_names() order) at its true size: its collision mesh (the
    convex parts pybullet simulates), centred on its bounding-box centre, scale 1; held-out models refused."""
    names = household.household_names()
    if not 0 <= index < len(names):
        raise ValueError(f"household index must lie in [0, {len(names) - 1}], got {index}")
    name = names[index]
    mesh = clean_mesh(o3d.geometry.TriangleMesh(household.collision_mesh(name, held_out_ok)))
    return GraspObject(name=f"household_{name}", source=f"graspd_lab:data/household/{name}.urdf",
                       category=_household_category(mesh), mesh=mesh, scale=1.0)


def _household_category(mesh: o3d.geometry.TriangleMesh) -> str:
    """box, cylinder or other, by how much of its bounding box along the principal axes its convex hull fills
    (a box fills it, a cylinder pi/4 of it)."""
    hull, _ = mesh.compute_convex_hull()
    v = np.asarray(hull.vertices)
    _, _, axes = np.linalg.svd(v - v.mean(axis=0), full_matrices=False)
    local = v @ axes.T
    fill = hull.get_volume() / max(float(np.prod(local.max(axis=0) - local.min(axis=0))), 1e-12)
    return "box" if fill > 0.85 else "cylinder" if 0.72 < fill <= 0.82 else "other"


def object_catalogue(num_urdfs: int = 900, procedural_per_kind: dict[str, int] | None = None,
                     household_models: bool = False) -> list[tuple[str, int]]:
    """Object specs (kind, index) for a dataset: kind "urdf" for random_urdfs 000..num_urdfs-1 (at most
    900: the held-out objects are never listed), a procedural kind, and (household_models) kind "household"
    for every household model that is not held out."""
    if not 0 <= num_urdfs <= len(TRAINING_URDFS):
        raise ValueError(f"num_urdfs must lie in [0, {len(TRAINING_URDFS)}] (900-999 are held out), got {num_urdfs}")
    specs: list[tuple[str, int]] = [("urdf", i) for i in TRAINING_URDFS[:num_urdfs]]
    for kind, count in (procedural_per_kind or {}).items():
        if kind not in PROCEDURAL_KINDS:
            raise ValueError(f"procedural kind must be one of {PROCEDURAL_KINDS}, got {kind!r}")
        specs.extend((kind, i) for i in range(count))
    if household_models:
        names = household.household_names()
        specs.extend(("household", names.index(n)) for n in household.training_names())
    return specs


def load_object(kind: str, index: int, seed: int = 0, hand: HandGeometry | None = None) -> GraspObject:
    """One object of object_catalogue: a training random_urdf or household model (never a held-out one:
    HeldOutObjectError) or a procedural shape."""
    if kind == "urdf":
        return random_urdf_mesh(index, hand)
    if kind == "household":
        return household_object(index)
    return procedural_object(kind, index, seed, hand)
