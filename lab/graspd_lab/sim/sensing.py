"""Simulated depth cameras: pybullet's CPU renderer (ER_TINY_RENDERER), metric depth, a sensor's noise
(graspd_lab.world.noise: the Kinect model noisy_depth, or another SensorNoise) and back-projection into
world-frame points, fused into a ViewpointCloud as a robot sends it.

The cameras are graspd.core.camera.Camera (the simulator's rigs use vertical fields of view, as
pybullet takes them) and the noise parameters graspd_lab.world.noise.DepthNoise; only the pybullet
rendering lives here.  Passive: two fixed cameras 53 degrees apart on the robot's side of the tray
(IJRR, two Asus Xtion).  Active: views along a 40 cm-radius arc over the tray (IJRR, wrist camera).
"""

from __future__ import annotations

import numpy as np
import pybullet as pb
from numpy.typing import NDArray

from graspd.core.camera import Camera, active_cameras, passive_cameras, side_camera
from graspd.core.cloud import ViewpointCloud
from graspd.core.types import F64
from graspd_lab.world.noise import DepthNoise, SensorNoise, Surfaces, noisy_depth

#: The clutter benchmark's sensor noise (its figures were measured with it) and exact depth.
SIM_NOISE = DepthNoise.benchmark()
NO_NOISE = DepthNoise.none()

__all__ = ["NO_NOISE", "SIM_NOISE", "Camera", "active_cameras", "camera_matrices", "noisy_depth",
           "observe", "passive_cameras", "pixel_rays", "render_depth", "render_rgb", "side_camera"]


def camera_matrices(camera: Camera) -> tuple[list[float], list[float]]:
    """pybullet view and projection matrices (column-major, as pybullet returns them) of a camera."""
    up = camera.up
    forward = np.subtract(camera.target, camera.position)
    if abs(forward[2]) > 0.999 * np.linalg.norm(forward):  # looking straight down: any horizontal up
        up = (1.0, 0.0, 0.0)
    view = pb.computeViewMatrix(camera.position, camera.target, up)
    proj = pb.computeProjectionMatrixFOV(camera.vertical_fov_deg, camera.width / camera.height, camera.near,
                                         camera.far)
    return list(view), list(proj)


def render_depth(client: int, camera: Camera) -> F64:
    """Metric depth along the optical axis (H, W) in metres; inf where nothing was hit."""
    view, proj = camera_matrices(camera)
    _, _, _, depth_buf, _ = pb.getCameraImage(
        camera.width, camera.height, view, proj, renderer=pb.ER_TINY_RENDERER,
        flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=client)
    d = np.asarray(depth_buf, np.float64).reshape(camera.height, camera.width)
    n, f = camera.near, camera.far
    z = f * n / (f - (f - n) * d)
    z[d >= 1.0] = np.inf
    return z


def render_depth_and_surfaces(client: int, camera: Camera) -> tuple[F64, NDArray[np.int64]]:
    """render_depth and the body id each pixel shows (H, W; -1 where nothing was hit)."""
    view, proj = camera_matrices(camera)
    _, _, _, depth_buf, seg = pb.getCameraImage(
        camera.width, camera.height, view, proj, renderer=pb.ER_TINY_RENDERER, physicsClientId=client)
    d = np.asarray(depth_buf, np.float64).reshape(camera.height, camera.width)
    n, f = camera.near, camera.far
    z = f * n / (f - (f - n) * d)
    z[d >= 1.0] = np.inf
    ids = np.asarray(seg, np.int64).reshape(camera.height, camera.width)
    return z, np.where(d >= 1.0, -1, ids)


def pixel_rays(camera: Camera) -> F64:
    """Unit-depth rays (H, W, 3) in world frame: point = position + z * ray for optical-axis depth z."""
    view, proj = camera_matrices(camera)
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


def observe(client: int, cameras: list[Camera], noise: DepthNoise | SensorNoise, rng: np.random.Generator,
            region: tuple[float, float, float, float, float, float]) -> ViewpointCloud:
    """Render every camera, add the sensor's noise, back-project and keep points inside region
    [xmin, xmax, ymin, ymax, zmin, zmax] (world, m); camera_source indexes the camera list.  A model with
    materials (dark, shiny surfaces) draws them once per observation, for every body, so all cameras agree."""
    pts_all, src_all = [], []
    lo = np.asarray(region[0::2])
    hi = np.asarray(region[1::2])
    bodies = np.array([pb.getBodyUniqueId(i, physicsClientId=client)
                       for i in range(pb.getNumBodies(physicsClientId=client))], np.int64)
    materials = noise.draw_surfaces(bodies, rng)
    for k, cam in enumerate(cameras):
        rays = pixel_rays(cam)
        if materials is None:
            z = noise.rasterised(render_depth(client, cam), rays, rng)
        else:
            depth, ids = render_depth_and_surfaces(client, cam)
            z = noise.rasterised(depth, rays, rng, Surfaces(ids=ids, dark=materials.dark, shiny=materials.shiny))
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


def render_rgb(client: int, camera: Camera) -> NDArray[np.uint8]:
    """Colour image (H, W, 3) of the world, for pictures of scenes and grasps."""
    view, proj = camera_matrices(camera)
    _, _, rgba, _, _ = pb.getCameraImage(camera.width, camera.height, view, proj, renderer=pb.ER_TINY_RENDERER,
                                         flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=client)
    return np.asarray(rgba, np.uint8).reshape(camera.height, camera.width, 4)[..., :3]
