"""Simulated depth cameras: pybullet's CPU renderer (ER_TINY_RENDERER), metric depth, a structured-light
noise model, and back-projection into world-frame points, fused into a ViewpointCloud as a robot sends it.

Passive: two fixed cameras 53 degrees apart on the robot's side of the tray (IJRR, two Asus Xtion).
Active: views along a 40 cm-radius arc over the tray, all aimed at one point above it (IJRR, wrist camera).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb
from numpy.typing import NDArray

from ..cloud import ViewpointCloud

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Camera:
    """A pinhole depth camera at position (m, world) looking at target; vertical field of view in degrees."""

    position: tuple[float, float, float]
    target: tuple[float, float, float]
    width: int = 640
    height: int = 480
    fov_deg: float = 45.0
    near: float = 0.1
    far: float = 2.0

    def matrices(self) -> tuple[list[float], list[float]]:
        up = (0.0, 0.0, 1.0)
        forward = np.subtract(self.target, self.position)
        if abs(forward[2]) > 0.999 * np.linalg.norm(forward):  # looking straight down: any horizontal up
            up = (1.0, 0.0, 0.0)
        view = pb.computeViewMatrix(self.position, self.target, up)
        proj = pb.computeProjectionMatrixFOV(self.fov_deg, self.width / self.height, self.near, self.far)
        return list(view), list(proj)


@dataclass(frozen=True)
class DepthNoise:
    """Axial Gaussian noise sigma(z) = a + b (z - 0.4)^2 (m; Nguyen et al. 2012 for Kinect-class sensors),
    pixels dropped where the surface is seen at more than grazing_deg from its normal, at depth edges
    (jump > edge_jump m to a neighbour, each dropped with edge_drop probability) and at random."""

    sigma_a: float = 0.0012
    sigma_b: float = 0.0019
    grazing_deg: float = 78.0
    edge_jump: float = 0.01
    edge_drop: float = 0.5
    random_drop: float = 0.01


NO_NOISE = DepthNoise(0.0, 0.0, 90.0, np.inf, 0.0, 0.0)


def render_depth(client: int, camera: Camera) -> F64:
    """Metric depth along the optical axis (H, W) in metres; inf where nothing was hit."""
    view, proj = camera.matrices()
    _, _, _, depth_buf, _ = pb.getCameraImage(
        camera.width, camera.height, view, proj, renderer=pb.ER_TINY_RENDERER,
        flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=client)
    d = np.asarray(depth_buf, np.float64).reshape(camera.height, camera.width)
    n, f = camera.near, camera.far
    z = f * n / (f - (f - n) * d)
    z[d >= 1.0] = np.inf
    return z


def pixel_rays(camera: Camera) -> F64:
    """Unit-depth rays (H, W, 3) in world frame: point = position + z * ray for optical-axis depth z."""
    view, proj = camera.matrices()
    v_mat = np.asarray(view).reshape(4, 4).T
    p_mat = np.asarray(proj).reshape(4, 4).T
    u = (np.arange(camera.width) + 0.5) / camera.width * 2.0 - 1.0
    v = 1.0 - (np.arange(camera.height) + 0.5) / camera.height * 2.0
    # eye-frame direction at depth 1 (camera looks along -z in OpenGL eye coordinates)
    ex = u[None, :] / p_mat[0, 0]
    ey = v[:, None] / p_mat[1, 1]
    eye = np.stack(np.broadcast_arrays(ex, ey, -np.ones_like(ex * ey)), axis=-1)
    cam_to_world = np.linalg.inv(v_mat)[:3, :3]
    return eye @ cam_to_world.T


def noisy_depth(depth: F64, rays: F64, noise: DepthNoise, rng: np.random.Generator) -> F64:
    """Depth with the noise model applied; dropped pixels become inf."""
    z = depth.copy()
    finite = np.isfinite(z)
    pts = rays * np.where(finite, z, 0.0)[..., None]
    # surface normals from neighbouring points (central differences), viewing angle against the ray
    du = np.zeros_like(pts)
    dv = np.zeros_like(pts)
    du[:, 1:-1] = pts[:, 2:] - pts[:, :-2]
    dv[1:-1] = pts[2:] - pts[:-2]
    nrm = np.cross(du, dv)
    nlen = np.linalg.norm(nrm, axis=-1)
    cosang = np.abs(np.einsum("hwk,hwk->hw", nrm, rays)) / np.maximum(nlen * np.linalg.norm(rays, axis=-1), 1e-12)
    grazing = (nlen > 0) & (cosang < np.cos(np.deg2rad(noise.grazing_deg)))
    zf = np.where(finite, z, 1e3)
    jump = np.zeros(z.shape, bool)
    jump[:, 1:] |= np.abs(np.diff(zf, axis=1)) > noise.edge_jump
    jump[:, :-1] |= np.abs(np.diff(zf, axis=1)) > noise.edge_jump
    jump[1:] |= np.abs(np.diff(zf, axis=0)) > noise.edge_jump
    jump[:-1] |= np.abs(np.diff(zf, axis=0)) > noise.edge_jump
    drop = grazing | (jump & (rng.random(z.shape) < noise.edge_drop)) | (rng.random(z.shape) < noise.random_drop)
    sigma = noise.sigma_a + noise.sigma_b * (np.where(finite, z, 0.4) - 0.4) ** 2
    z = z + rng.normal(size=z.shape) * sigma
    z[drop] = np.inf
    return z


def observe(client: int, cameras: list[Camera], noise: DepthNoise, rng: np.random.Generator,
            region: tuple[float, float, float, float, float, float]) -> ViewpointCloud:
    """Render every camera, add noise, back-project and keep points inside region
    [xmin, xmax, ymin, ymax, zmin, zmax] (world, m); camera_source indexes the camera list."""
    pts_all, src_all = [], []
    lo = np.asarray(region[0::2])
    hi = np.asarray(region[1::2])
    for k, cam in enumerate(cameras):
        rays = pixel_rays(cam)
        z = noisy_depth(render_depth(client, cam), rays, noise, rng)
        ok = np.isfinite(z)
        pts = np.asarray(cam.position) + rays[ok] * z[ok][:, None]
        keep = np.all((pts >= lo) & (pts <= hi), axis=1)
        pts_all.append(pts[keep])
        src_all.append(np.full(int(keep.sum()), k, np.int32))
    return ViewpointCloud(
        points=np.concatenate(pts_all).astype(np.float32),
        viewpoints=np.array([c.position for c in cameras], np.float32),
        camera_source=np.concatenate(src_all),
    )


def passive_cameras(target: tuple[float, float, float] = (0.0, 0.0, 0.03), distance: float = 0.75,
                    elevation_deg: float = 50.0, separation_deg: float = 53.0) -> list[Camera]:
    """Two fixed cameras on the robot's side (-x) of the tray, separation_deg apart in azimuth."""
    cams = []
    for sign in (-1.0, 1.0):
        az = np.deg2rad(180.0 + sign * separation_deg / 2)
        el = np.deg2rad(elevation_deg)
        pos = np.asarray(target) + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cams.append(Camera(tuple(pos.tolist()), target, fov_deg=45.0))
    return cams


def side_camera(target: tuple[float, float, float] = (0.0, 0.0, 0.03), distance: float = 0.6,
                elevation_deg: float = 35.0) -> list[Camera]:
    """One camera looking at the scene from the side and above (VGN's single noisy side view)."""
    el = np.deg2rad(elevation_deg)
    pos = np.asarray(target) + distance * np.array([-np.cos(el), 0.0, np.sin(el)])
    return [Camera(tuple(pos.tolist()), target, fov_deg=45.0)]


def active_cameras(target: tuple[float, float, float] = (0.0, 0.0, 0.03), radius: float = 0.40,
                   num_views: int = 6, arc_deg: float = 100.0) -> list[Camera]:
    """num_views cameras along an arc of arc_deg over the tray (in the y-z plane, through the zenith),
    all at radius from target and aimed at it, like the wrist sensor sweeping a hemisphere."""
    cams = []
    for ang in np.deg2rad(np.linspace(-arc_deg / 2, arc_deg / 2, num_views)):
        pos = np.asarray(target) + radius * np.array([-0.25 * np.cos(ang), np.sin(ang), np.cos(ang)])
        pos = np.asarray(target) + radius * (pos - target) / np.linalg.norm(pos - target)
        cams.append(Camera(tuple(pos.tolist()), target, fov_deg=55.0))
    return cams


def render_rgb(client: int, camera: Camera) -> NDArray[np.uint8]:
    """Colour image (H, W, 3) of the world, for pictures of scenes and grasps."""
    view, proj = camera.matrices()
    _, _, rgba, _, _ = pb.getCameraImage(camera.width, camera.height, view, proj, renderer=pb.ER_TINY_RENDERER,
                                         flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=client)
    return np.asarray(rgba, np.uint8).reshape(camera.height, camera.width, 4)[..., :3]
