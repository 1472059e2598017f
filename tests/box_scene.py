"""Depth pictures of boxes by ray casting in numpy (no simulator, no mesh library): what pinhole cameras see of
oriented boxes, e.g. a box standing on a table slab.  The cameras follow open3d's RaycastingScene
create_rays_pinhole (the lab's renderer): fov_deg across the image width, pixel (u, v) looking through its
centre, along forward + ((W/2 - u - 1/2) right + (H/2 - v - 1/2) down) / f with right = forward x z and
f = W / 2 / tan(fov / 2), range noise added to the hit parameter along that (unnormalised) ray; the lab's
render_cloud of the same boxes gives the same points to within 3 micrometres.  Metres, world frame, z up.

Importable as `box_scene` (pyproject.toml: [tool.pytest.ini_options] pythonpath = ["tests"])."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import ViewpointCloud

F64 = NDArray[np.float64]
#: A box: its extents (m, along its own x, y, z) and its 4x4 pose (centre and axes in the world frame).
BoxSpec = tuple[tuple[float, float, float], F64]


def pose_from(rotation: F64, translation: Sequence[float] | F64) -> F64:
    """The 4x4 pose of a rotation (3,3) and a translation (m)."""
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def rot_z(angle: float) -> F64:
    """Rotation by angle (rad) about z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def table_box(half_size: float = 0.4, z: float = 0.0) -> BoxSpec:
    """A 2 cm thick square table slab (half_size m) whose top face is the plane z = z."""
    return (2 * half_size, 2 * half_size, 0.02), pose_from(np.eye(3), (0.0, 0.0, z - 0.01))


def pinhole_rays(eye: F64, look_at: Sequence[float], width: int, height: int, fov_deg: float) -> F64:
    """The (unnormalised) ray directions (height * width, 3) of a camera at eye looking at look_at, z up, row by
    row."""
    forward = np.asarray(look_at, np.float64) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    f = 0.5 * width / np.tan(0.5 * np.radians(fov_deg))
    v, u = np.mgrid[0:height, 0:width]
    du, dv = (0.5 * width - 0.5 - u.reshape(-1, 1)) / f, (0.5 * height - 0.5 - v.reshape(-1, 1)) / f
    return np.asarray(forward + du * right + dv * down)


def first_hits(eye: F64, rays: F64, boxes: Sequence[BoxSpec]) -> F64:
    """The least positive ray parameter t at which each ray (eye + t ray) enters any box; inf where it hits none
    (the slab test in each box's frame)."""
    t_hit = np.full(len(rays), np.inf)
    for extents, pose in boxes:
        rot, centre = pose[:3, :3], pose[:3, 3]
        o = rot.T @ (eye - centre)
        d = rays @ rot  # the rays in the box frame
        half = 0.5 * np.asarray(extents, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (-half - o) / d, (half - o) / d
        near = np.nanmax(np.minimum(t0, t1), axis=1)
        far = np.nanmin(np.maximum(t0, t1), axis=1)
        hit = (near <= far) & (near > 0.0)
        t_hit = np.where(hit & (near < t_hit), near, t_hit)
    return t_hit


def render_boxes(boxes: Sequence[BoxSpec], cameras: F64, look_at: Sequence[float], width: int = 160,
                 height: int = 120, fov_deg: float = 45.0, noise: float = 0.0, seed: int = 0) -> ViewpointCloud:
    """The points each camera (positions (K,3), all looking at look_at) sees of the boxes, with Gaussian range
    noise of std `noise` (m along a unit-length ray: times the ray's length); camera_source says which camera saw
    each point."""
    rng = np.random.default_rng(seed)
    cams = np.asarray(cameras, np.float64).reshape(-1, 3)
    pts, src = [], []
    for k, cam in enumerate(cams):
        rays = pinhole_rays(cam, look_at, width, height, fov_deg)
        t = first_hits(cam, rays, boxes)
        ok = np.isfinite(t)
        t = t[ok] + (rng.normal(0.0, noise, ok.sum()) if noise > 0 else 0.0)
        pts.append(cam + rays[ok] * t[:, None])
        src.append(np.full(ok.sum(), k, np.int32))
    return ViewpointCloud(points=np.concatenate(pts).astype(np.float32), viewpoints=cams.astype(np.float32),
                          camera_source=np.concatenate(src))
