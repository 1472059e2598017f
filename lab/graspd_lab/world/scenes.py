"""Scenes the project builds itself: tabletops of catalogue objects (the demo's cluttered tabletop,
the training and benchmark tabletops) and the tray the simulator pours objects into.

Table-top frame: the table's top face is z = 0, gravity is -z, cameras look down from ~0.7 m.
The demo's tabletop is the IJRR paper's passive setup: two depth cameras 53 degrees apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from graspd.core.camera import tabletop_cameras
from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd_lab.world.objects import HELD_OUT_URDFS, PROCEDURAL_KINDS, procedural_object, random_urdf_mesh
from graspd_lab.world.render import render_scene

#: Table-top frame: the table's top face is z = 0, gravity is -z, cameras look down from ~0.7 m.
GRAVITY = (0.0, 0.0, -1.0)


def _resting_pose(mesh: o3d.geometry.TriangleMesh, rng: np.random.Generator) -> F64:
    """A rotation that lays the mesh on one of its principal-axis faces with a random yaw."""
    v = np.asarray(mesh.vertices)
    _, _, axes = np.linalg.svd(v - v.mean(axis=0), full_matrices=False)
    if np.linalg.det(axes) < 0:
        axes[2] *= -1.0
    # axes rows are principal directions; lay the chosen one (index k) along world z.
    k = int(rng.choice(3, p=[0.15, 0.25, 0.6]))  # mostly the thinnest axis up: the stable pose
    order = [(k + 1) % 3, (k + 2) % 3, k]
    base = axes[order]
    if np.linalg.det(base) < 0:
        base[0] *= -1.0
    yaw = rng.uniform(0, 2 * np.pi)
    c, s = np.cos(yaw), np.sin(yaw)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rz @ base


def tabletop_scene(objects: list[o3d.geometry.TriangleMesh], seed: int = 0,
                   table_size: tuple[float, float] = (0.6, 0.6), table_thickness: float = 0.02,
                   spacing: float = 0.005, max_tries: int = 200) -> list[o3d.geometry.TriangleMesh]:
    """A cluttered tabletop: a table box (top face at z = 0, centred at the origin) followed by copies of
    the objects resting on it at random yaw and position, their footprints (bounding circles) not
    overlapping; deterministic from seed.  Raises ValueError if an object cannot be placed."""
    rng = np.random.default_rng(seed)
    table = o3d.geometry.TriangleMesh.create_box(table_size[0], table_size[1], table_thickness)
    table.translate([-table_size[0] / 2, -table_size[1] / 2, -table_thickness])
    table.compute_triangle_normals()
    out = [table]
    placed: list[tuple[float, float, float]] = []
    for i, obj in enumerate(objects):
        m = o3d.geometry.TriangleMesh(obj)
        m.translate(-m.get_axis_aligned_bounding_box().get_center())
        m.rotate(_resting_pose(m, rng), center=np.zeros(3))
        v = np.asarray(m.vertices)
        radius = float(np.linalg.norm(v[:, :2], axis=1).max())
        for _ in range(max_tries):
            xy = rng.uniform(-0.5, 0.5, 2) * (np.array(table_size) - 2 * radius)
            if all(np.hypot(xy[0] - x, xy[1] - y) >= radius + r + spacing for x, y, r in placed):
                break
        else:
            raise ValueError(f"objects[{i}]: no free spot on the {table_size} m table after {max_tries} tries")
        placed.append((float(xy[0]), float(xy[1]), radius))
        m.translate([xy[0], xy[1], -v[:, 2].min()])
        m.compute_triangle_normals()
        out.append(m)
    return out


def random_tabletop(num_objects: int, seed: int = 0, held_out: bool = False, hand: HandGeometry | None = None,
                    table_size: tuple[float, float] = (0.6, 0.6)) -> list[o3d.geometry.TriangleMesh]:
    """tabletop_scene of num_objects objects drawn (seeded) from the training catalogue (procedural shapes
    and random_urdfs 000-899) or, with held_out, from the held-out test objects random_urdfs 900-999 (for
    benchmarks only: never train or tune on such a scene)."""
    rng = np.random.default_rng([seed, 5])
    meshes = []
    for _ in range(num_objects):
        if held_out:
            meshes.append(random_urdf_mesh(int(rng.choice(HELD_OUT_URDFS)), hand, held_out_ok=True).mesh)
        elif rng.random() < 0.5:
            meshes.append(random_urdf_mesh(int(rng.integers(0, HELD_OUT_URDFS.start)), hand).mesh)
        else:
            kind = str(rng.choice(PROCEDURAL_KINDS))
            meshes.append(procedural_object(kind, int(rng.integers(10_000)), seed, hand).mesh)
    return tabletop_scene(meshes, seed, table_size)


def cluttered_tabletop(num_objects: int = 6, seed: int = 7, num_cameras: int = 2, resolution_scale: float = 1.0,
                       table_size: tuple[float, float] = (0.5, 0.5)) -> ViewpointCloud:
    """A deterministic cluttered tabletop (procedural boxes, cylinders, spheres, cones, capsules,
    composites on a table), rendered with depth noise; camera resolution 640x480 x resolution_scale."""
    rng = np.random.default_rng(seed)
    kinds = [PROCEDURAL_KINDS[int(k)] for k in rng.integers(0, len(PROCEDURAL_KINDS), num_objects)]
    meshes = [procedural_object(kind, 1000 + i, seed=seed).mesh for i, kind in enumerate(kinds)]
    scene = tabletop_scene(meshes, seed=seed, table_size=table_size)
    w, h = int(round(640 * resolution_scale)), int(round(480 * resolution_scale))
    cams = tabletop_cameras(num_cameras, distance=0.75, elevation_deg=55.0, width=w, height=h)
    return render_scene(scene, cams, seed=seed)


def subsample(cloud: ViewpointCloud, num_points: int, seed: int = 0) -> ViewpointCloud:
    """At most num_points of the cloud, uniformly at random (camera indices kept)."""
    if len(cloud) <= num_points:
        return cloud
    idx = np.sort(np.random.default_rng(seed).choice(len(cloud), num_points, replace=False))
    return cloud.select(idx)


@dataclass(frozen=True)
class TrayGeometry:
    """Inner size (m) of the simulator's tray (x, y), wall height and thickness; the floor is the tray bottom."""

    size_x: float = 0.36
    size_y: float = 0.28
    wall_height: float = 0.06
    wall_thickness: float = 0.01

    @property
    def interior(self) -> tuple[float, float, float, float]:
        """[xmin, xmax, ymin, ymax] of the tray's inside (m)."""
        return (-self.size_x / 2, self.size_x / 2, -self.size_y / 2, self.size_y / 2)
