"""Partial point clouds of meshes by open3d raycasting from pinhole depth cameras, with sensor noise.

A camera is a pinhole (Asus Xtion Pro / Kinect v1: 640x480, 58 deg horizontal field of view) at a
position looking at a target.  render_scene casts one ray per pixel (only over the pixels the
meshes can project to), applies graspd.training.noise to the depth image, back-projects, and returns
a graspd.cloud.ViewpointCloud exactly as the service receives one: points in the world frame (m),
per-point camera_source, camera positions as viewpoints, no normals.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from ..cloud import ViewpointCloud
from ..hand import HandGeometry
from .noise import DepthNoise, apply_depth_noise

F64 = NDArray[np.float64]
PAPER_CAMERA_SEPARATION_DEG = 53.0  # IJRR paper: registered clouds from two viewpoints 53 degrees apart


@dataclass(frozen=True)
class Camera:
    """Pinhole depth camera at position looking at target (world frame, m); up fixes the roll."""

    position: tuple[float, float, float]
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    width: int = 640
    height: int = 480
    fov_deg: float = 58.0

    @property
    def focal_px(self) -> float:
        return 0.5 * self.width / float(np.tan(np.deg2rad(self.fov_deg) / 2.0))

    def rotation(self) -> F64:
        """Camera-to-world rotation (3,3), columns: image right, image down, optical axis (OpenCV)."""
        pos, tgt = np.asarray(self.position, float), np.asarray(self.target, float)
        fwd = tgt - pos
        fwd /= np.linalg.norm(fwd)
        up = np.asarray(self.up, float)
        right = np.cross(fwd, up)
        if np.linalg.norm(right) < 1e-6:  # looking along up: pick any perpendicular
            right = np.cross(fwd, [1.0, 0.0, 0.0] if abs(fwd[0]) < 0.9 else [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        return np.stack([right, down, fwd], axis=1)

    def project(self, xyz: F64) -> F64:
        """Pixel coordinates (N,2) u, v and depth (N,) of world points, as (N,3)."""
        cam = (np.asarray(xyz, float) - np.asarray(self.position, float)) @ self.rotation()
        z = cam[:, 2]
        f = self.focal_px
        u = f * cam[:, 0] / np.maximum(z, 1e-9) + self.width / 2.0
        v = f * cam[:, 1] / np.maximum(z, 1e-9) + self.height / 2.0
        return np.stack([u, v, z], axis=1)


def look_at_rig(target: F64, direction: F64, distance: float, num_cameras: int = 2,
                separation_deg: float = PAPER_CAMERA_SEPARATION_DEG, roll_axis: F64 | None = None,
                **camera_kwargs: float) -> list[Camera]:
    """One or two cameras at distance (m) from target: the first along direction (target -> camera),
    the second rotated by separation_deg about roll_axis (default: the most vertical axis
    perpendicular to direction), both looking at the target."""
    if num_cameras not in (1, 2):
        raise ValueError(f"num_cameras must be 1 or 2, got {num_cameras}")
    d = np.asarray(direction, float)
    d /= np.linalg.norm(d)
    t = np.asarray(target, float)
    dirs = [d]
    if num_cameras == 2:
        axis = np.cross(d, [0.0, 0.0, 1.0]) if roll_axis is None else np.asarray(roll_axis, float)
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(d, [1.0, 0.0, 0.0])
        axis = axis - d * (axis @ d)
        axis /= np.linalg.norm(axis)
        a = np.deg2rad(separation_deg)
        dirs.append(d * np.cos(a) + np.cross(axis, d) * np.sin(a))
    up = (0.0, 0.0, 1.0)
    return [Camera(position=tuple(t + distance * v), target=tuple(t), up=up, **camera_kwargs)  # type: ignore[arg-type]
            for v in dirs]


def random_view(rng: np.random.Generator, target: F64 | None = None, num_cameras: int = 2,
                distance_range: tuple[float, float] = (0.5, 0.8),
                separation_deg: float = PAPER_CAMERA_SEPARATION_DEG) -> list[Camera]:
    """A rig looking at target from a direction uniform on the sphere, the second camera about a random
    axis perpendicular to it (so all relative orientations of object and rig occur)."""
    d = rng.standard_normal(3)
    d /= np.linalg.norm(d)
    roll = np.cross(d, rng.standard_normal(3))
    dist = float(rng.uniform(*distance_range))
    return look_at_rig(np.zeros(3) if target is None else target, d, dist, num_cameras, separation_deg, roll)


@dataclass
class MeshScene:
    """An open3d RaycastingScene over a list of meshes, with each mesh's triangle normals (per geometry id)."""

    meshes: list[o3d.geometry.TriangleMesh]
    scene: o3d.t.geometry.RaycastingScene = field(init=False)
    triangle_normals: list[NDArray[np.float32]] = field(init=False)

    def __post_init__(self) -> None:
        self.scene = o3d.t.geometry.RaycastingScene()
        self.triangle_normals = []
        for m in self.meshes:
            if not m.has_triangle_normals():
                m.compute_triangle_normals()
            self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
            self.triangle_normals.append(np.asarray(m.triangle_normals, np.float32))

    def bounds(self) -> tuple[F64, F64]:
        lo = np.min([np.asarray(m.get_min_bound()) for m in self.meshes], axis=0)
        hi = np.max([np.asarray(m.get_max_bound()) for m in self.meshes], axis=0)
        return lo, hi

    def cast_rays(self, rays: NDArray[np.float32], nthreads: int = 0) -> dict[str, o3d.core.Tensor]:
        """open3d cast_rays over rays (R,6) float32 [origin, direction]."""
        tensor = o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays, np.float32))
        return dict(self.scene.cast_rays(tensor, nthreads=nthreads))

    def cast(self, origins: NDArray[np.float32], directions: NDArray[np.float32], nthreads: int = 0
             ) -> dict[str, NDArray]:
        """t_hit (in units of |direction|, inf = miss), geometry_ids, primitive_ids, primitive_normals."""
        rays = np.concatenate([origins, directions], axis=-1).astype(np.float32).reshape(-1, 6)
        out = self.cast_rays(rays, nthreads)
        shape = origins.shape[:-1]
        return {
            "t_hit": out["t_hit"].numpy().reshape(shape),
            "geometry_ids": out["geometry_ids"].numpy().astype(np.int64).reshape(shape),
            "primitive_ids": out["primitive_ids"].numpy().astype(np.int64).reshape(shape),
            "primitive_normals": out["primitive_normals"].numpy().reshape(*shape, 3),
        }


def _pixel_window(cam: Camera, lo: F64, hi: F64, margin: int = 4) -> tuple[int, int, int, int]:
    """Pixel box [u0, u1) x [v0, v1) covering the projection of the box [lo, hi] (whole image if the
    box reaches behind the camera)."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    uvz = cam.project(corners)
    if np.any(uvz[:, 2] <= 1e-3):
        return 0, cam.width, 0, cam.height
    u0 = int(np.clip(np.floor(uvz[:, 0].min()) - margin, 0, cam.width))
    u1 = int(np.clip(np.ceil(uvz[:, 0].max()) + margin, 0, cam.width))
    v0 = int(np.clip(np.floor(uvz[:, 1].min()) - margin, 0, cam.height))
    v1 = int(np.clip(np.ceil(uvz[:, 1].max()) + margin, 0, cam.height))
    return u0, u1, v0, v1


def render_camera(scene: MeshScene, cam: Camera, noise: DepthNoise, rng: np.random.Generator
                  ) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
    """World points (P,3) seen by one camera (noisy, missing pixels removed) and their geometry ids (P,)."""
    lo, hi = scene.bounds()
    u0, u1, v0, v1 = _pixel_window(cam, lo, hi)
    if u1 <= u0 or v1 <= v0:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.int64)
    f = cam.focal_px
    uu, vv = np.meshgrid(np.arange(u0, u1) + 0.5, np.arange(v0, v1) + 0.5)
    rot = cam.rotation()
    dirs_cam = np.stack([(uu - cam.width / 2) / f, (vv - cam.height / 2) / f, np.ones_like(uu)], axis=-1)
    dirs = (dirs_cam @ rot.T).astype(np.float32)  # camera-z component 1: t_hit is the depth z
    origins = np.broadcast_to(np.asarray(cam.position, np.float32), dirs.shape)
    hit = scene.cast(np.ascontiguousarray(origins), dirs)
    z = np.where(np.isfinite(hit["t_hit"]), hit["t_hit"], np.nan).astype(np.float32)
    unit = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    cos_inc = np.abs(np.einsum("hwk,hwk->hw", unit, hit["primitive_normals"])).astype(np.float32)
    noisy, du, dv = apply_depth_noise(z, cos_inc, f, noise, rng)
    ok = np.isfinite(noisy)
    x_cam = (uu[ok] + du[ok] - cam.width / 2) / f * noisy[ok]
    y_cam = (vv[ok] + dv[ok] - cam.height / 2) / f * noisy[ok]
    pts_cam = np.stack([x_cam, y_cam, noisy[ok]], axis=1)
    pts = pts_cam @ rot.T + np.asarray(cam.position, float)
    return pts.astype(np.float32), hit["geometry_ids"][ok]


def render_scene_with_ids(meshes: list[o3d.geometry.TriangleMesh] | MeshScene, cameras: list[Camera],
                          noise: DepthNoise | None = None, seed: int | np.random.Generator = 0
                          ) -> tuple[ViewpointCloud, NDArray[np.int64]]:
    """render_scene, also returning for each point the index of the mesh it was seen on."""
    if not cameras:
        raise ValueError("cameras: need at least one camera")
    scene = meshes if isinstance(meshes, MeshScene) else MeshScene(list(meshes))
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    params = DepthNoise() if noise is None else noise
    pts, src, ids = [], [], []
    for k, cam in enumerate(cameras):
        p, g = render_camera(scene, cam, params, rng)
        pts.append(p)
        ids.append(g)
        src.append(np.full(len(p), k, np.int32))
    cloud = ViewpointCloud(points=np.concatenate(pts), viewpoints=np.array([c.position for c in cameras], np.float32),
                           camera_source=np.concatenate(src))
    return cloud, np.concatenate(ids)


def render_scene(meshes: list[o3d.geometry.TriangleMesh] | MeshScene, cameras: list[Camera],
                 noise: DepthNoise | None = None, seed: int | np.random.Generator = 0) -> ViewpointCloud:
    """The cloud the cameras see of the meshes (world frame, m), with sensor noise (default DepthNoise();
    DepthNoise.none() for exact surface points), camera_source per point, camera positions as viewpoints."""
    return render_scene_with_ids(meshes, cameras, noise, seed)[0]


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


def tabletop_cameras(num_cameras: int = 2, distance: float = 0.7, elevation_deg: float = 55.0,
                     azimuth_deg: float = 0.0, target: tuple[float, float, float] = (0.0, 0.0, 0.0),
                     separation_deg: float = PAPER_CAMERA_SEPARATION_DEG, **camera_kwargs: float) -> list[Camera]:
    """Cameras above a tabletop looking at target: the first at elevation/azimuth, the second
    separation_deg away in azimuth-direction (a robot's two head-mounted sensors)."""
    el, az = np.deg2rad(elevation_deg), np.deg2rad(azimuth_deg)
    d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return look_at_rig(np.asarray(target, float), d, distance, num_cameras, separation_deg,
                       roll_axis=np.array([0.0, 0.0, 1.0]), **camera_kwargs)


def random_tabletop(num_objects: int, seed: int = 0, held_out: bool = False, hand: HandGeometry | None = None,
                    table_size: tuple[float, float] = (0.6, 0.6)) -> list[o3d.geometry.TriangleMesh]:
    """tabletop_scene of num_objects objects drawn (seeded) from the training catalogue (procedural shapes
    and random_urdfs 000-899) or, with held_out, from the held-out test objects random_urdfs 900-999 (for
    benchmarks only: never train or tune on such a scene)."""
    from .objects import HELD_OUT_URDFS, PROCEDURAL_KINDS, procedural_object, random_urdf_mesh

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
