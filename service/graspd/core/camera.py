"""Pinhole depth cameras (one Camera for every renderer) and the rigs the project uses: the IJRR
paper's two cameras 53 degrees apart, random views for training data, a tabletop pair, and the
simulator's passive, side and active (wrist-arc) cameras.  World frame, metres, z up."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudError
from graspd.core.types import F64

FovAxis = Literal["horizontal", "vertical"]
PAPER_CAMERA_SEPARATION_DEG = 53.0  # IJRR paper: registered clouds from two viewpoints 53 degrees apart


@dataclass(frozen=True)
class Camera:
    """Pinhole depth camera at position looking at target (world frame, m); up fixes the roll.

    fov_deg is the field of view across the image's width (fov_axis "horizontal", the default: an Asus
    Xtion Pro / Kinect v1 at 640x480 sees 58 deg) or its height ("vertical", as pybullet's
    computeProjectionMatrixFOV takes it: the simulator's cameras).  near and far (m) bound what a
    rasterising renderer (pybullet) keeps; the raycast renderer ignores them."""

    position: tuple[float, float, float]
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    width: int = 640
    height: int = 480
    fov_deg: float = 58.0
    fov_axis: FovAxis = "horizontal"
    near: float = 0.1
    far: float = 2.0

    def __post_init__(self) -> None:
        if self.fov_axis not in ("horizontal", "vertical"):
            raise ValueError(f"fov_axis must be 'horizontal' or 'vertical', got {self.fov_axis!r}")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (square pixels)."""
        span = self.width if self.fov_axis == "horizontal" else self.height
        return 0.5 * span / float(np.tan(np.deg2rad(self.fov_deg) / 2.0))

    @property
    def vertical_fov_deg(self) -> float:
        """Field of view across the image's height (deg)."""
        if self.fov_axis == "vertical":
            return self.fov_deg
        return float(np.rad2deg(2.0 * np.arctan(0.5 * self.height / self.focal_px)))

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


def tabletop_cameras(num_cameras: int = 2, distance: float = 0.7, elevation_deg: float = 55.0,
                     azimuth_deg: float = 0.0, target: tuple[float, float, float] = (0.0, 0.0, 0.0),
                     separation_deg: float = PAPER_CAMERA_SEPARATION_DEG, **camera_kwargs: float) -> list[Camera]:
    """Cameras above a tabletop looking at target: the first at elevation/azimuth, the second
    separation_deg away in azimuth-direction (a robot's two head-mounted sensors)."""
    el, az = np.deg2rad(elevation_deg), np.deg2rad(azimuth_deg)
    d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return look_at_rig(np.asarray(target, float), d, distance, num_cameras, separation_deg,
                       roll_axis=np.array([0.0, 0.0, 1.0]), **camera_kwargs)



# ---- the simulator's rigs (graspd_lab.sim: pybullet renders them; 45/55 deg vertical fields of view) ----


def passive_cameras(target: tuple[float, float, float] = (0.0, 0.0, 0.03), distance: float = 0.75,
                    elevation_deg: float = 50.0, separation_deg: float = 53.0) -> list[Camera]:
    """Two fixed cameras on the robot's side (-x) of the tray, separation_deg apart in azimuth
    (IJRR passive setup, two Asus Xtion)."""
    cams = []
    for sign in (-1.0, 1.0):
        az = np.deg2rad(180.0 + sign * separation_deg / 2)
        el = np.deg2rad(elevation_deg)
        pos = np.asarray(target) + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cams.append(Camera(tuple(pos.tolist()), target, fov_deg=45.0, fov_axis="vertical"))
    return cams


def side_camera(target: tuple[float, float, float] = (0.0, 0.0, 0.03), distance: float = 0.6,
                elevation_deg: float = 35.0) -> list[Camera]:
    """One camera looking at the scene from the side and above (VGN's single noisy side view)."""
    el = np.deg2rad(elevation_deg)
    pos = np.asarray(target) + distance * np.array([-np.cos(el), 0.0, np.sin(el)])
    return [Camera(tuple(pos.tolist()), target, fov_deg=45.0, fov_axis="vertical")]


def sensing_cameras(sensing: str) -> list[Camera]:
    """The clutter benchmark's cameras for a sensing strategy: "passive" (two fixed cameras 53 degrees apart),
    "active" (views along an arc over the tray) or "side" (one camera)."""
    if sensing == "passive":
        return passive_cameras()
    if sensing == "active":
        return active_cameras()
    if sensing == "side":
        return side_camera()
    raise ValueError(f"sensing must be 'passive', 'active' or 'side', got {sensing!r}")


def overhead_camera(workspace: tuple[float, float, float, float, float, float], fov_deg: float = 55.0,
                    least_height: float = 0.4) -> Camera:
    """One camera straight above a workspace box [xmin, xmax, ymin, ymax, zmin, zmax] (m), looking down at its
    floor from high enough (at least least_height above it) that the vertical field of view spans the box: a
    wrist camera looking into a container."""
    x0, x1, y0, y1, z0, z1 = workspace
    half = max(x1 - x0, y1 - y0) / 2
    height = max(least_height, (z1 - z0) + half / float(np.tan(np.deg2rad(fov_deg) / 2)))
    centre = ((x0 + x1) / 2, (y0 + y1) / 2, z0)
    return Camera((centre[0], centre[1], z0 + height), centre, up=(1.0, 0.0, 0.0), fov_deg=fov_deg,
                  fov_axis="vertical")


def active_cameras(target: tuple[float, float, float] = (0.0, 0.0, 0.03), radius: float = 0.40,
                   num_views: int = 6, arc_deg: float = 100.0) -> list[Camera]:
    """num_views cameras along an arc of arc_deg over the tray (in the y-z plane, through the zenith),
    all at radius from target and aimed at it, like the wrist sensor sweeping a hemisphere (IJRR active)."""
    cams = []
    for ang in np.deg2rad(np.linspace(-arc_deg / 2, arc_deg / 2, num_views)):
        pos = np.asarray(target) + radius * np.array([-0.25 * np.cos(ang), np.sin(ang), np.cos(ang)])
        pos = np.asarray(target) + radius * (pos - target) / np.linalg.norm(pos - target)
        cams.append(Camera(tuple(pos.tolist()), target, fov_deg=55.0, fov_axis="vertical"))
    return cams


# ---- pixels <-> points with explicit pinhole intrinsics (depth images from a driver, ROS CameraInfo K) ----


class Intrinsics(NamedTuple):
    """Pinhole intrinsics in pixels: u = fx x/z + cx, v = fy y/z + cy in the optical frame (x right, y down, z
    forward), pixel centres at integer coordinates (ROS CameraInfo K = [fx 0 cx; 0 fy cy; 0 0 1]).  A tuple: it
    unpacks as fx, fy, cx, cy."""

    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def parse(cls, value: Mapping[str, float] | Sequence[float] | NDArray[np.floating],
              field: str = "intrinsics") -> Intrinsics:
        """From {"fx", "fy", "cx", "cy"} or 4 numbers fx, fy, cx, cy; CloudError naming field unless fx, fy > 0
        and all finite."""
        try:
            if isinstance(value, Mapping):
                nums = [float(value[k]) for k in ("fx", "fy", "cx", "cy")]
            else:
                nums = [float(v) for v in np.asarray(value, np.float64).reshape(-1)]
        except (KeyError, TypeError, ValueError):
            raise CloudError(field, f"fx, fy, cx, cy (pixels) expected, got {value!r}") from None
        if len(nums) != 4 or not np.isfinite(nums).all() or nums[0] <= 0 or nums[1] <= 0:
            raise CloudError(field, f"4 finite numbers fx, fy, cx, cy (pixels; fx, fy > 0) expected, got {value!r}")
        return cls(*nums)


def project_points(points: F64, camera_pose: F64, camera: Intrinsics) -> tuple[F64, NDArray[np.bool_]]:
    """Pixel coordinates (M,2) [u, v] of cloud-frame points and whether each lies in front of the camera.

    camera_pose is the 4x4 camera-to-cloud transform; points behind the camera get NaN pixels.
    """
    pose = np.asarray(camera_pose, np.float64)
    local = (np.asarray(points, np.float64) - pose[:3, 3]) @ pose[:3, :3]  # R^T (p - t), row form
    z = local[:, 2]
    front = z > 1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(front, camera.fx * local[:, 0] / z + camera.cx, np.nan)
        v = np.where(front, camera.fy * local[:, 1] / z + camera.cy, np.nan)
    return np.stack([u, v], axis=1), front


def camera_intrinsics(cam: Camera) -> Intrinsics:
    """The Intrinsics (fx, fy, cx, cy) of a Camera in the OpenCV / ROS CameraInfo convention (pixel centres at integer
    coordinates, u = fx x/z + cx): Camera.project puts pixel i's centre at i + 0.5, so cx = width/2 - 0.5."""
    f = cam.focal_px
    return Intrinsics(f, f, cam.width / 2.0 - 0.5, cam.height / 2.0 - 0.5)


def camera_pose(cam: Camera) -> F64:
    """The camera-to-world transform (4,4) of a Camera's optical frame (x right, y down, z forward)."""
    pose = np.eye(4)
    pose[:3, :3] = cam.rotation()
    pose[:3, 3] = cam.position
    return pose


def backproject(depth: NDArray[np.floating], fx: float, fy: float, cx: float, cy: float) -> NDArray[np.float32]:
    """Points (H,W,3) in the camera's optical frame (x right, y down, z forward; m) of a depth image (H,W) of
    z-depths in metres: x = (u - cx) z / fx, y = (v - cy) z / fy with u, v the pixel's column and row (pixel centres
    at integer coordinates: the OpenCV / ROS CameraInfo convention, the inverse of Camera.project with
    camera_intrinsics).  Pixels without depth (0, NaN) give rows with z 0 or NaN: the caller drops them."""
    z = np.asarray(depth, np.float32)
    if z.ndim != 2:
        raise ValueError(f"a depth image (H, W) expected, got shape {z.shape}")
    v, u = np.indices(z.shape, dtype=np.float32)
    return np.stack([(u - np.float32(cx)) * z / np.float32(fx), (v - np.float32(cy)) * z / np.float32(fy), z], axis=-1)


def depth_image(cam: Camera, points: NDArray[np.floating]) -> NDArray[np.float32]:
    """The depth image (height, width) of z-depths (m) a Camera records of world points: each point goes to the
    pixel it projects into (Camera.project), the nearest one wins; pixels with no point are 0 (no depth), as
    drivers write them.  With noise-free points from graspd_lab.world.render this is the camera's depth image."""
    uvz = cam.project(np.asarray(points, np.float64))
    u, v, z = np.floor(uvz[:, 0]).astype(np.int64), np.floor(uvz[:, 1]).astype(np.int64), uvz[:, 2]
    ok = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    image = np.full(cam.height * cam.width, np.inf)
    np.minimum.at(image, v[ok] * cam.width + u[ok], z[ok])
    image[~np.isfinite(image)] = 0.0
    return image.reshape(cam.height, cam.width).astype(np.float32)
