"""Partial point clouds of meshes by open3d raycasting from pinhole depth cameras, with sensor noise.

A camera is a graspd.core.camera.Camera (by default an Asus Xtion Pro / Kinect v1: 640x480, 58 deg
horizontal field of view) at a position looking at a target.  render_scene casts one ray per pixel (only
over the pixels the meshes can project to), applies graspd_lab.world.noise to the depth image, back-projects,
and returns a graspd.core.cloud.ViewpointCloud exactly as the service receives one: points in the world frame
(m), per-point camera_source, camera positions as viewpoints, no normals.  render_cloud is the plainer
renderer of the templates' scripted scenes (open3d's pinhole rays, Gaussian range noise).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from graspd.core.camera import Camera
from graspd.core.cloud import ViewpointCloud
from graspd.core.types import F64
from graspd_lab.world.noise import DepthNoise, apply_depth_noise


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


def render_cloud(meshes: list[o3d.geometry.TriangleMesh], cameras: F64, look_at: tuple[float, float, float],
                 width: int = 160, height: int = 120, fov_deg: float = 45.0, noise: float = 0.0,
                 seed: int = 0) -> ViewpointCloud:
    """The points each pinhole camera (positions (K,3), all looking at look_at, fov_deg vertical) sees of
    the meshes, with Gaussian range noise of std `noise` (m); camera_source says which camera saw each point."""
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
