"""Triangle-mesh primitives (open3d, metres): the procedural shapes of the object catalogue, posed
boxes and cylinders, a table slab, and 4x4 pose helpers.  Frames: a mesh's own frame unless a pose
(4x4, world from mesh) is given; z up."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from graspd.core.types import F64


def clean_mesh(mesh: o3d.geometry.TriangleMesh, centre: bool = True) -> o3d.geometry.TriangleMesh:
    """Merged duplicate vertices, no degenerate triangles, and (centre) centred on the bounding-box centre;
    centre=False keeps the mesh's own frame (a body pybullet poses)."""
    mesh.merge_close_vertices(1e-7)
    mesh.remove_degenerate_triangles()
    mesh.remove_duplicated_triangles()
    mesh.remove_unreferenced_vertices()
    if centre:
        mesh.translate(-mesh.get_axis_aligned_bounding_box().get_center())
    mesh.compute_triangle_normals()
    return mesh


# ---- procedural shapes (sizes in metres, graspable by a hand with a 10 cm aperture) ----


def box_mesh(x: float, y: float, z: float) -> o3d.geometry.TriangleMesh:
    return clean_mesh(o3d.geometry.TriangleMesh.create_box(x, y, z))


def cylinder_mesh(radius: float, height: float, resolution: int = 40) -> o3d.geometry.TriangleMesh:
    return clean_mesh(o3d.geometry.TriangleMesh.create_cylinder(radius, height, resolution=resolution, split=4))


def sphere_mesh(radius: float, resolution: int = 24) -> o3d.geometry.TriangleMesh:
    return clean_mesh(o3d.geometry.TriangleMesh.create_sphere(radius, resolution=resolution))


def cone_mesh(radius: float, height: float, resolution: int = 40) -> o3d.geometry.TriangleMesh:
    return clean_mesh(o3d.geometry.TriangleMesh.create_cone(radius, height, resolution=resolution, split=4))


def capsule_mesh(radius: float, length: float, resolution: int = 24) -> o3d.geometry.TriangleMesh:
    """A closed capsule along z: a sphere whose upper and lower halves are pulled length/2 apart."""
    sphere = o3d.geometry.TriangleMesh.create_sphere(radius, resolution=resolution)
    v = np.asarray(sphere.vertices).copy()
    v[:, 2] += np.where(v[:, 2] >= 0.0, 0.5 * length, -0.5 * length)
    return clean_mesh(o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), sphere.triangles))


def composite_mesh(rng: np.random.Generator) -> o3d.geometry.TriangleMesh:
    """Two parts that touch without overlapping (so every ray starting inside hits a back face first):
    an L of two boxes, a box on a cylinder, or a mallet (cylinder handle with a box head)."""
    kind = int(rng.integers(3))
    if kind == 0:
        a = o3d.geometry.TriangleMesh.create_box(*rng.uniform([0.03, 0.02, 0.02], [0.12, 0.06, 0.05]))
        ea = a.get_axis_aligned_bounding_box().get_extent()
        b = o3d.geometry.TriangleMesh.create_box(float(rng.uniform(0.02, 0.05)), ea[1], float(rng.uniform(0.03, 0.1)))
        b.translate([0.0, 0.0, ea[2]])
    elif kind == 1:
        r, h = rng.uniform([0.015, 0.03], [0.04, 0.1])
        a = o3d.geometry.TriangleMesh.create_cylinder(float(r), float(h), resolution=40, split=4)
        a.translate([0.0, 0.0, h / 2])
        bx, by, bz = rng.uniform([0.03, 0.03, 0.02], [0.08, 0.08, 0.05])
        b = o3d.geometry.TriangleMesh.create_box(bx, by, bz)
        b.translate([-bx / 2, -by / 2, h])
    else:
        r, h = rng.uniform([0.008, 0.06], [0.02, 0.15])
        a = o3d.geometry.TriangleMesh.create_cylinder(float(r), float(h), resolution=32, split=4)
        a.translate([0.0, 0.0, h / 2])
        bx, by, bz = rng.uniform([0.06, 0.025, 0.025], [0.12, 0.05, 0.05])
        b = o3d.geometry.TriangleMesh.create_box(bx, by, bz)
        b.translate([-bx / 2, -by / 2, h])
    return clean_mesh(a + b)




# ---- posed primitives (scripted scenes: templates tests, benchmarks, demonstrations) ----


def pose_from(rotation: F64, translation: tuple[float, float, float] | F64) -> F64:
    """The 4x4 pose of a rotation (3,3) and a translation (m)."""
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def rot_z(angle: float) -> F64:
    """Rotation by angle (rad) about z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def posed_box(extents: tuple[float, float, float], pose: F64 | None = None) -> o3d.geometry.TriangleMesh:
    """A box with the given extents (m), centred at the origin, then moved by the 4x4 pose."""
    mesh = o3d.geometry.TriangleMesh.create_box(*extents)
    mesh.translate(-0.5 * np.asarray(extents, np.float64))
    if pose is not None:
        mesh.transform(np.asarray(pose, np.float64))
    return mesh


def posed_cylinder(radius: float, height: float, pose: F64 | None = None) -> o3d.geometry.TriangleMesh:
    """A closed cylinder (m) along its z axis, centred at the origin, then moved by the 4x4 pose."""
    mesh = o3d.geometry.TriangleMesh.create_cylinder(radius=radius, height=height, resolution=48)
    if pose is not None:
        mesh.transform(np.asarray(pose, np.float64))
    return mesh


def table_mesh(half_size: float = 0.4, z: float = 0.0) -> o3d.geometry.TriangleMesh:
    """A 2 cm thick square table slab (half_size m) whose top face is the plane z = z."""
    return posed_box((2 * half_size, 2 * half_size, 0.02), pose_from(np.eye(3), (0.0, 0.0, z - 0.01)))
