"""The household objects: 295 real models (boxes, bottles, cans, cups, tools, toys) at their true size, vendored
in graspd_lab/data/household (URDF, visual OBJ, convex-decomposed collision OBJ; metres; README and licences there).

They are never rescaled for the hand: a real hand does not get to rescale the world.  Each model's mass is its
URDF's; its centre of mass and inertia come from its collision mesh at uniform density (mass_properties) and are
written into the vendored URDF's <inertial> (origin = centre of mass, rpy = principal axes, diagonal inertia), so
pybullet simulates them when it loads the URDF with URDF_USE_INERTIA_FROM_FILE (graspd_lab.sim.objects).

HELD_OUT is the project's own benchmark set of these models, written down here and nowhere else: loading one for
training raises HeldOutObjectError (check_household_not_held_out), as random_urdfs 900-999 do.

Object ids: the simulator and scene data name an object by an int; household model k (HOUSEHOLD_NAMES order,
sorted by name) is HOUSEHOLD_ID_BASE + k, beside random_urdfs 0-999.

  python -m graspd_lab.world.household vendor SRC   (copy SRC's models into the package with computed inertials)
"""

from __future__ import annotations

import argparse
import re
import shutil
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from graspd.core.types import F64
from graspd_lab.world.held_out import HeldOutObjectError
from graspd_lab.world.meshes import clean_mesh

#: The vendored models (package data of graspd-lab).
HOUSEHOLD_DIR = Path(__file__).resolve().parents[1] / "data" / "household"
#: Simulator / scene-data object id of household model k: HOUSEHOLD_ID_BASE + k (random_urdfs are 0-999).
HOUSEHOLD_ID_BASE = 10_000
#: Seed and share of the held-out draw (draw_held_out): 20% of each name family.
HELD_OUT_SEED = 31
HELD_OUT_SHARE = 0.2

#: The project's held-out household models (its own benchmark; never train or tune on them): draw_held_out's
#: seeded draw of 20% of each name family (hashed ShapeNet-style names, KIT "_800_tex" scans, "_poisson_"
#: meshes, the rest), written out so the list is read, not recomputed.  59 of 295.
HELD_OUT: tuple[str, ...] = (
    "8bb057d18e2fcc4779368d1198f406e7", "BlueSaltCube_800_tex", "CatLying_800_tex", "CatSitting_800_tex",
    "CoughDropsBerries_800_tex", "GreenSaltCylinder_800_tex", "InstantMousse_800_tex", "Knaeckebrot_800_tex",
    "MuesliBars_800_tex", "OrgHerbTea_800_tex", "Patches_800_tex", "PowderedSugar_800_tex",
    "Sprudelflasche_800_tex", "VitalisCereals_800_tex", "WedgeShoe2", "WhippedCream_800_tex",
    "YellowSaltCube2_800_tex", "YellowSaltCylinderSmall_800_tex", "YellowSaltCylinder_800_tex",
    "banana_poisson_000", "banana_poisson_002", "band_aid_clear_strips", "box_poisson_002",
    "camera_poisson_010", "cheez_it_white_cheddar", "chewy_dipps_chocolate_chip", "chewy_dipps_peanut_butter",
    "cinnamon_toast_crunch", "detergent", "detergent_bottle_poisson_002", "e94e46bc5833f2f5e57b873e4f3ef3a4",
    "egg_poisson_004", "figurine_poisson_005", "honey_bunches_of_oats_honey_roasted", "jar_poisson_000",
    "light_bulb_poisson_006", "light_bulb_poisson_009", "light_bulb_poisson_011", "lime_poisson_001",
    "mushroom_poisson_002", "mushroom_poisson_004", "nutrigrain_apple_cinnamon", "peach",
    "philipps_screwdriver", "progresso_new_england_clam_chowder", "red_cup", "rubber_duck_poisson_000",
    "rubber_duck_poisson_002", "screwdriver_poisson_002", "shampoo_new_poisson_000", "sponge",
    "spray_bottle_poisson_000", "spray_bottle_poisson_003", "stapler_poisson_010", "tetra_pak_poisson_001",
    "toilet_paper_poisson_003", "toy_poisson_001", "toy_poisson_003", "vase_poisson_004",
)


@dataclass(frozen=True)
class MassProperties:
    """Rigid-body mass properties in the model's URDF link frame: mass (kg), volume (m^3), centre of mass (3,) (m),
    inertia (3, 3) about the centre of mass (kg m^2), and its principal moments (3,) and axes (3, 3; columns)."""

    mass: float
    volume: float
    com: F64
    inertia: F64
    principal_moments: F64
    principal_axes: F64


@cache
def household_names() -> tuple[str, ...]:
    """Every vendored model's name (its URDF's stem), sorted: index k is household model k."""
    return tuple(sorted(p.stem for p in HOUSEHOLD_DIR.glob("*.urdf")))


def training_names() -> tuple[str, ...]:
    """The models training may use: every model but HELD_OUT, sorted."""
    held = set(HELD_OUT)
    return tuple(n for n in household_names() if n not in held)


def household_id(name: str) -> int:
    """The simulator's object id of a model (ValueError for an unknown name)."""
    names = household_names()
    if name not in names:
        raise ValueError(f"no household model named {name!r} in {HOUSEHOLD_DIR}")
    return HOUSEHOLD_ID_BASE + names.index(name)


def is_household_id(object_id: int) -> bool:
    """Whether an object id names a household model (HOUSEHOLD_ID_BASE + k)."""
    return HOUSEHOLD_ID_BASE <= int(object_id) < HOUSEHOLD_ID_BASE + len(household_names())


def household_name(object_id: int) -> str:
    """The model an object id names (ValueError outside the household range)."""
    if not is_household_id(object_id):
        raise ValueError(f"object_id {object_id} is not a household model (ids {HOUSEHOLD_ID_BASE}.."
                         f"{HOUSEHOLD_ID_BASE + len(household_names()) - 1})")
    return household_names()[int(object_id) - HOUSEHOLD_ID_BASE]


def check_household_not_held_out(name: str, held_out_ok: bool = False) -> None:
    """The held-out rule of the household models: HeldOutObjectError for a HELD_OUT name unless held_out_ok
    (held-out evaluation only), ValueError for an unknown name."""
    if name not in household_names():
        raise ValueError(f"no household model named {name!r} in {HOUSEHOLD_DIR}")
    if name in HELD_OUT and not held_out_ok:
        raise HeldOutObjectError(f"household model {name!r} is held out for the project's benchmark "
                                 "(graspd_lab.world.household.HELD_OUT): never load it for training or validation; "
                                 "pass held_out_ok=True only in the held-out evaluation")


def household_urdf(name: str, held_out_ok: bool = False) -> Path:
    """The vendored URDF of a model (guarded), as pybullet.loadURDF takes it."""
    check_household_not_held_out(name, held_out_ok)
    return HOUSEHOLD_DIR / f"{name}.urdf"


def name_family(name: str) -> str:
    """The model's source family by its name: "hashed" (ShapeNet-style ids), "kit" (_800_tex scans),
    "poisson" (_poisson_ meshes) or "named" (the rest: BigBIRD-style products, fruit, tools)."""
    if re.fullmatch(r"[0-9a-f]{32}", name):
        return "hashed"
    if name.endswith("_800_tex"):
        return "kit"
    if "_poisson_" in name:
        return "poisson"
    return "named"


def draw_held_out(names: tuple[str, ...], seed: int = HELD_OUT_SEED, share: float = HELD_OUT_SHARE
                  ) -> tuple[str, ...]:
    """A seeded draw of round(share x family size) names from each name family (stratified), sorted."""
    rng = np.random.default_rng(seed)
    chosen: list[str] = []
    for family in ("hashed", "kit", "poisson", "named"):
        members = sorted(n for n in names if name_family(n) == family)
        k = int(round(share * len(members)))
        chosen.extend(members[i] for i in rng.choice(len(members), size=k, replace=False))
    return tuple(sorted(chosen))


# ---- meshes and mass properties ----


def read_obj_parts(path: Path) -> list[F64]:
    """The vertices (N_k, 3) of each part ("o" group) of an OBJ file, in its own units (m here)."""
    verts: list[list[float]] = []
    parts: list[set[int]] = []
    for line in path.read_text().splitlines():
        if line.startswith("o ") or line.startswith("g "):
            parts.append(set())
        elif line.startswith("v "):
            verts.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            if not parts:
                parts.append(set())
            for tok in line.split()[1:]:
                i = int(tok.split("/")[0])
                parts[-1].add(i - 1 if i > 0 else len(verts) + i)
    v = np.asarray(verts, np.float64)
    return [v[sorted(p)] for p in parts if len(p) >= 4]


def convex_volume_integrals(points: F64) -> tuple[float, F64, F64]:
    """Volume (m^3), first moment (3,) (m^4) and second moment sum(x x^T) dV (3, 3) (m^5) of the convex hull of
    points (N, 3): tetrahedra from an interior point to each outward hull triangle."""
    hull = ConvexHull(points)
    centre = points[hull.vertices].mean(axis=0)
    a = points[hull.simplices[:, 0]]
    b = points[hull.simplices[:, 1]]
    c = points[hull.simplices[:, 2]]
    n = np.cross(b - a, c - a)
    flip = np.einsum("ij,ij->i", n, hull.equations[:, :3]) < 0  # orient every triangle outward
    b, c = np.where(flip[:, None], c, b), np.where(flip[:, None], b, c)
    vol = np.einsum("ij,ij->i", a - centre, np.cross(b - centre, c - centre)) / 6.0
    s = centre + a + b + c
    first = (vol[:, None] * s / 4.0).sum(axis=0)
    second = np.zeros((3, 3))
    for p in (centre, a, b, c):
        pp = np.broadcast_to(p, a.shape)
        second += np.einsum("i,ij,ik->jk", vol, pp, pp)
    second += np.einsum("i,ij,ik->jk", vol, s, s)
    return float(vol.sum()), first, second / 20.0


def mass_properties(parts: list[F64], mass: float) -> MassProperties:
    """Mass properties of a body made of convex parts (each part's points; their hulls are the solid) at uniform
    density with total mass (kg): the parts' volume integrals summed."""
    volume, first, second = 0.0, np.zeros(3), np.zeros((3, 3))
    for pts in parts:
        v, f, s = convex_volume_integrals(pts)
        volume, first, second = volume + v, first + f, second + s
    if volume <= 0.0:
        raise ValueError("the parts enclose no volume")
    density = mass / volume
    com = first / volume
    cov = density * second - mass * np.outer(com, com)  # second moment about the centre of mass (kg m^2)
    inertia = np.trace(cov) * np.eye(3) - cov
    inertia = 0.5 * (inertia + inertia.T)
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    return MassProperties(mass=float(mass), volume=float(volume), com=com, inertia=inertia,
                          principal_moments=moments, principal_axes=axes)


def urdf_mass(urdf_text: str) -> float:
    """The <mass value=...> of a URDF (kg)."""
    match = re.search(r'<mass\s+value="([^"]+)"', urdf_text)
    if match is None:
        raise ValueError("no <mass value=...> in the URDF")
    return float(match.group(1))


#: The lightest model (kg) counted heavy: from 0.5 kg up, held-out household objects slip out of the Panda-like
#: hand in one lift of two (bench/results/slips-household-pile.md), lighter ones in one of ten.
HEAVY_MASS = 0.5


@cache
def heavy_training_names() -> tuple[str, ...]:
    """The training models of HEAVY_MASS or more (their URDF's mass), sorted: the objects that slip."""
    return tuple(n for n in training_names() if urdf_mass((HOUSEHOLD_DIR / f"{n}.urdf").read_text()) >= HEAVY_MASS)


#: The thickest model (m, smallest side of its collision mesh's box in its link frame) counted flat: packets and
#: tools that lie flat on the table, held only by their edges between fingertips that stop above it.
FLAT_THICKNESS = 0.02


@cache
def flat_training_names() -> tuple[str, ...]:
    """The training models thinner than FLAT_THICKNESS, sorted: the objects a hand holds only by their edges."""
    return tuple(n for n in training_names()
                 if float(np.min(_collision_mesh(n).get_axis_aligned_bounding_box().get_extent())) < FLAT_THICKNESS)


@cache
def household_mass_properties(name: str) -> MassProperties:
    """A model's mass properties from its collision mesh and its URDF's mass (link frame)."""
    mass = urdf_mass((HOUSEHOLD_DIR / f"{name}.urdf").read_text())
    return mass_properties(read_obj_parts(HOUSEHOLD_DIR / f"{name}_collision.obj"), mass)


def collision_mesh(name: str, held_out_ok: bool = False) -> o3d.geometry.TriangleMesh:
    """A model's collision mesh (its convex parts, as pybullet simulates them) in its URDF link frame, m, at its
    true size, cleaned, with triangle normals (guarded)."""
    check_household_not_held_out(name, held_out_ok)
    return _collision_mesh(name)


@cache
def _collision_mesh(name: str) -> o3d.geometry.TriangleMesh:
    mesh = o3d.io.read_triangle_mesh(HOUSEHOLD_DIR / f"{name}_collision.obj")
    if len(mesh.triangles) == 0:
        raise FileNotFoundError(f"household model {name!r}: no collision mesh in {HOUSEHOLD_DIR}")
    return clean_mesh(mesh, centre=False)


def body_frame_mesh(name: str, held_out_ok: bool = False) -> o3d.geometry.TriangleMesh:
    """The collision mesh in the body frame pybullet reports a loaded model's pose in (its inertial frame: origin
    at the centre of mass, axes the principal axes), m: pose it with getBasePositionAndOrientation."""
    mesh = o3d.geometry.TriangleMesh(collision_mesh(name, held_out_ok))
    props = household_mass_properties(name)
    v = (np.asarray(mesh.vertices) - props.com) @ props.principal_axes
    mesh.vertices = o3d.utility.Vector3dVector(v)
    mesh.compute_triangle_normals()
    return mesh


# ---- vendoring ----


def inertial_xml(props: MassProperties) -> str:
    """The URDF <inertial> element of mass properties: origin at the centre of mass, rpy turning the link frame
    onto the principal axes, diagonal inertia (kg m^2)."""
    rpy = Rotation.from_matrix(props.principal_axes).as_euler("xyz")
    ixx, iyy, izz = props.principal_moments
    return (f'<inertial>\n      <origin xyz="{props.com[0]:.9g} {props.com[1]:.9g} {props.com[2]:.9g}" '
            f'rpy="{rpy[0]:.9g} {rpy[1]:.9g} {rpy[2]:.9g}"/>\n'
            f'      <mass value="{props.mass:.12g}"/>\n'
            f'      <inertia ixx="{ixx:.9g}" ixy="0" ixz="0" iyy="{iyy:.9g}" iyz="0" izz="{izz:.9g}"/>\n'
            f'    </inertial>')


def vendor(src: Path, dst: Path = HOUSEHOLD_DIR) -> int:
    """Copy every model of src (URDF, visual and collision OBJ) into dst with its <inertial> computed from the
    collision mesh (the source URDFs carry placeholders); the README stays as written.  Returns the count."""
    dst.mkdir(parents=True, exist_ok=True)
    count = 0
    for urdf in sorted(src.glob("*.urdf")):
        name = urdf.stem
        for suffix in ("_visual.obj", "_collision.obj"):
            shutil.copyfile(src / f"{name}{suffix}", dst / f"{name}{suffix}")
        text = urdf.read_text()
        props = mass_properties(read_obj_parts(src / f"{name}_collision.obj"), urdf_mass(text))
        text = re.sub(r"<inertial>.*?</inertial>", inertial_xml(props), text, count=1, flags=re.S)
        (dst / urdf.name).write_text(text)
        count += 1
    household_names.cache_clear()
    household_mass_properties.cache_clear()
    return count


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m graspd_lab.world.household", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    v = sub.add_parser("vendor", help="copy models into the package with computed inertials")
    v.add_argument("src", type=Path)
    sub.add_parser("draw", help="print the seeded held-out draw (to compare with HELD_OUT)")
    args = ap.parse_args(argv)
    if args.command == "vendor":
        print(f"{vendor(args.src)} models vendored into {HOUSEHOLD_DIR}")
    else:
        print("\n".join(draw_held_out(household_names())))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
