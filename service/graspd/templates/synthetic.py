"""Small ray-cast scenes (objects on a table seen by pinhole depth cameras) for tests, benchmarks and
scripted demonstrations; open3d's RaycastingScene does the rendering.  Metres, world frame, z up."""

from __future__ import annotations

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from ..cloud import ViewpointCloud

F64 = NDArray[np.float64]


def box_mesh(extents: tuple[float, float, float], pose: F64 | None = None) -> o3d.geometry.TriangleMesh:
    """A box with the given extents (m), centred at the origin, then moved by the 4x4 pose."""
    mesh = o3d.geometry.TriangleMesh.create_box(*extents)
    mesh.translate(-0.5 * np.asarray(extents, np.float64))
    if pose is not None:
        mesh.transform(np.asarray(pose, np.float64))
    return mesh


def cylinder_mesh(radius: float, height: float, pose: F64 | None = None) -> o3d.geometry.TriangleMesh:
    """A closed cylinder along its z axis, centred at the origin, then moved by the 4x4 pose."""
    mesh = o3d.geometry.TriangleMesh.create_cylinder(radius=radius, height=height, resolution=48)
    if pose is not None:
        mesh.transform(np.asarray(pose, np.float64))
    return mesh


def table_mesh(half_size: float = 0.4, z: float = 0.0) -> o3d.geometry.TriangleMesh:
    """A thin table slab whose top face is the plane z = z."""
    return box_mesh((2 * half_size, 2 * half_size, 0.02), pose_from(np.eye(3), (0.0, 0.0, z - 0.01)))


def pose_from(rotation: F64, translation: tuple[float, float, float] | F64) -> F64:
    """The 4x4 pose of a rotation and a translation."""
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def rot_z(angle: float) -> F64:
    """Rotation by angle (rad) about z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def render_cloud(meshes: list[o3d.geometry.TriangleMesh], cameras: F64, look_at: tuple[float, float, float],
                 width: int = 160, height: int = 120, fov_deg: float = 45.0, noise: float = 0.0,
                 seed: int = 0) -> ViewpointCloud:
    """The points each pinhole camera (positions (K,3), all looking at look_at) sees of the meshes,
    with Gaussian range noise of std `noise` (m); camera_source says which camera saw each point."""
    scene = o3d.t.geometry.RaycastingScene()
    for mesh in meshes:
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    rng = np.random.default_rng(seed)
    cams = np.asarray(cameras, np.float64).reshape(-1, 3)
    pts, src = [], []
    for k, cam in enumerate(cams):
        rays = scene.create_rays_pinhole(fov_deg=fov_deg, center=list(look_at), eye=cam.tolist(),  # type: ignore[call-overload]
                                         up=[0.0, 0.0, 1.0], width_px=width, height_px=height)
        hit = scene.cast_rays(rays)
        t = hit["t_hit"].numpy().reshape(-1)
        d = rays.numpy().reshape(-1, 6)[:, 3:]
        ok = np.isfinite(t)
        t = t[ok] + (rng.normal(0.0, noise, ok.sum()) if noise > 0 else 0.0)
        pts.append(cam + d[ok] * t[:, None])
        src.append(np.full(ok.sum(), k, np.int32))
    return ViewpointCloud(points=np.concatenate(pts).astype(np.float32), viewpoints=cams.astype(np.float32),
                          camera_source=np.concatenate(src))


def box_top_grasp(box_pose: F64, extents: tuple[float, float, float], hand_depth: float = 0.06,
                  bite: float = 0.02) -> F64:
    """A vertical hand pose on a box (pose 4x4, extents m) closing across its local x side, fingertips
    bite (m) below the top face; rotation columns [approach, binormal, axis] (DESIGN.md)."""
    approach = np.array([0.0, 0.0, -1.0])
    binormal = box_pose[:3, :3] @ np.array([1.0, 0.0, 0.0])
    rot = np.column_stack([approach, binormal, np.cross(approach, binormal)])
    top = box_pose[:3, 3] + box_pose[:3, :3] @ np.array([0.0, 0.0, extents[2] / 2])
    return pose_from(rot, top - approach * (hand_depth - bite))


def box_side_grasp(box_pose: F64, extents: tuple[float, float, float], hand_depth: float = 0.06,
                   bite: float = 0.03, height: float = 0.2) -> F64:
    """A horizontal hand pose approaching a box's local +x face along -x, closing along its local y,
    at `height` (fraction of the box height) above its centre."""
    approach = box_pose[:3, :3] @ np.array([-1.0, 0.0, 0.0])
    binormal = box_pose[:3, :3] @ np.array([0.0, 1.0, 0.0])
    rot = np.column_stack([approach, binormal, np.cross(approach, binormal)])
    face = box_pose[:3, 3] + box_pose[:3, :3] @ np.array([extents[0] / 2, 0.0, extents[2] * height])
    return pose_from(rot, face - approach * (hand_depth - bite))


def grasp_angle_deg(rot_a: F64, rot_b: F64) -> float:
    """Angle (deg) between two hand orientations, counting a half turn about the approach as no change
    (a parallel-jaw hand is symmetric under it)."""
    flip = np.diag([1.0, -1.0, -1.0])
    best = 180.0
    for b in (rot_b, rot_b @ flip):
        c = (np.trace(rot_a.T @ b) - 1.0) / 2.0
        best = min(best, float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))))
    return best


def random_urdf_mesh(object_id: int, size: float, yaw: float = 0.0, xy: tuple[float, float] = (0.0, 0.0)
                     ) -> o3d.geometry.TriangleMesh:
    """pybullet_data's random_urdfs/<id> mesh scaled so its largest extent is size (m), turned by yaw (rad)
    about z and set on the table plane z = 0 at xy.  Ids 900-999 are held out (DESIGN.md): tests and
    demonstrations use 000-899 only."""
    from pathlib import Path

    import pybullet_data

    path = Path(pybullet_data.getDataPath()) / "random_urdfs" / f"{object_id:03d}" / f"{object_id:03d}.obj"
    mesh = o3d.io.read_triangle_mesh(path)
    if len(mesh.vertices) == 0:
        raise FileNotFoundError(f"object_id {object_id}: no mesh at {path}")
    verts = np.asarray(mesh.vertices)
    mesh.translate(-(verts.min(axis=0) + verts.max(axis=0)) / 2)
    mesh.scale(size / float(np.ptp(verts, axis=0).max()), center=np.zeros(3))
    mesh.rotate(rot_z(yaw), center=np.zeros(3))
    mesh.translate(np.array([xy[0], xy[1], -float(np.asarray(mesh.vertices)[:, 2].min())]))
    return mesh
