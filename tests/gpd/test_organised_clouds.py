"""Organised clouds (a depth image's grid): mixed (flying) pixels at depth edges are kept out of sampling and of the
closing regions, and normals come from image neighbours, agreeing with the PCA estimator where both apply.

Scenes are depth images ray-cast with numpy (boxes, a plane, a cylinder) and read through graspd.io (a depth
.npy with intrinsics and a camera pose), so the cloud is organised as a depth camera's is."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from graspd.core.cloud import ViewpointCloud
from graspd.core.grid import grid_normals, veil_points
from graspd.core.hand import HandGeometry
from graspd.core.points import pca_normals
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.gpd.preprocess import PreprocessParams, orient_toward_cameras, preprocess, region, voxelize
from graspd.gpd.scene import closing_region_points
from graspd.io.cloud_files import read_input

W, H = 320, 240
FX = FY = 300.0
CX, CY = (W - 1) / 2, (H - 1) / 2
WORKSPACE = (-0.2, 0.2, -0.2, 0.25, -0.01, 0.3)
#: Two boxes on a table (axis-aligned; lo, hi corners, m): a 5 x 10 x 8 cm one and a taller 4 x 4 x 12 cm one.
BOXES = [((-0.025, -0.05, 0.0), (0.025, 0.05, 0.08)), ((-0.02, 0.08, 0.0), (0.02, 0.12, 0.12))]


def look_at(eye: tuple[float, float, float], target: tuple[float, float, float]) -> np.ndarray:
    """The camera-to-world pose (4x4) of an optical-frame camera (x right, y down, z forward) at eye, looking at
    target, the world's z up."""
    e, t = np.asarray(eye, float), np.asarray(target, float)
    z = (t - e) / np.linalg.norm(t - e)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    pose[:3, 3] = e
    return pose


def pixel_rays(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,), direction per pixel (H*W, 3) in the world, scaled so that its camera-z is 1: t is depth)."""
    v, u = np.mgrid[0:H, 0:W]
    d = np.stack([(u - CX) / FX, (v - CY) / FY, np.ones((H, W))], axis=-1).reshape(-1, 3)
    return pose[:3, 3], d @ pose[:3, :3].T


def render_boxes(pose: np.ndarray, boxes: Sequence[tuple[tuple[float, float, float], tuple[float, float, float]]],
                 table: float = 0.3) -> np.ndarray:
    """The depth image (H, W; m, 0 where nothing is hit) of boxes on a table square of half-side `table` (m) at
    z = 0, ray-cast (slab test for the boxes)."""
    o, d = pixel_rays(pose)
    best = np.full(len(d), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[:, 2]
        hit = o + t[:, None] * d
        on_table = (t > 0) & (np.abs(hit[:, 0]) < table) & (np.abs(hit[:, 1]) < table)
        best[on_table] = t[on_table]
        for lo, hi in boxes:
            t1, t2 = (np.asarray(lo) - o) / d, (np.asarray(hi) - o) / d
            near, far = np.nanmax(np.minimum(t1, t2), axis=1), np.nanmin(np.maximum(t1, t2), axis=1)
            hit_box = (far >= near) & (near > 0) & (near < best)
            best[hit_box] = near[hit_box]
    return np.where(np.isfinite(best), best, 0.0).reshape(H, W)


def add_mixed_pixels(depth: np.ndarray, width: int = 3, jump: float = 0.02, seed: int = 0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(depth with mixed pixels, their mask): beyond every depth edge of more than `jump` m, the `width` pixels
    behind the near surface's silhouette get depths between the two surfaces, the k-th at about k / (width + 1)
    of the way back, as a time-of-flight or structured-light camera's mixed pixels lie: veils hanging off the
    silhouette along the rays."""
    rng = np.random.default_rng(seed)
    out, mixed = depth.copy(), np.zeros(depth.shape, bool)
    h, w = depth.shape
    for k in range(1, width + 1):
        for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            src = (slice(max(0, -dv * k), h - max(0, dv * k)), slice(max(0, -du * k), w - max(0, du * k)))
            dst = (slice(max(0, dv * k), h - max(0, -dv * k)), slice(max(0, du * k), w - max(0, -du * k)))
            near, far = depth[src], depth[dst]
            edge = (near > 0) & (far > 0) & (far - near > jump) & ~mixed[dst]
            fraction = k / (width + 1) + rng.normal(0.0, 0.01, edge.shape)
            out[dst][edge] = (near + fraction * (far - near))[edge]
            mixed[dst][edge] = True
    return out, mixed


def organised_cloud(tmp_path: Path, depth: np.ndarray, pose: np.ndarray) -> ViewpointCloud:
    """The cloud of a depth image (m) as graspd reads it: a .npy with intrinsics and the camera's pose (the
    robot frame), organised."""
    path = tmp_path / "depth.npy"
    np.save(path, depth.astype(np.float32))
    cloud = read_input(path, intrinsics=(FX, FY, CX, CY), camera_poses=[pose.tolist()]).cloud
    assert cloud.grid is not None and (cloud.grid.height, cloud.grid.width) == (H, W)
    return cloud


@pytest.fixture(scope="module")
def veiled_scene(tmp_path_factory: pytest.TempPathFactory) -> tuple[ViewpointCloud, np.ndarray]:
    """Two boxes on a table seen from 55 cm, with mixed pixels at every depth edge: (cloud, mixed mask per
    point)."""
    pose = look_at((0.45, 0.1, 0.35), (0.0, 0.0, 0.05))
    depth, mixed = add_mixed_pixels(render_boxes(pose, BOXES))
    cloud = organised_cloud(tmp_path_factory.mktemp("veiled"), depth, pose)
    assert cloud.grid is not None
    return cloud, mixed.reshape(-1)[cloud.grid.pixel]


def flying_only(cloud: ViewpointCloud, mixed: np.ndarray, params: DetectionParams) -> list[bool]:
    """Per top-10 grasp of a detection on cloud: whether its closing region, over every point of the cloud as read
    (mixed pixels included), holds only mixed pixels."""
    det = GraspDetector().detect(cloud, params)
    top = det.grasps[:10]
    assert len(top) == 10
    region_points = closing_region_points(cKDTree(cloud.points.astype(np.float64)), cloud.points, top.positions,
                                          top.rotations, HandGeometry())
    return [bool(mixed[region_points.index[region_points.grasp == k]].all()) for k in range(len(top))]


def test_no_top_grasp_closes_on_mixed_pixels_only(veiled_scene: tuple[ViewpointCloud, np.ndarray]) -> None:
    cloud, mixed = veiled_scene
    params = DetectionParams(num_samples=400, workspace=WORKSPACE)
    assert not any(flying_only(cloud, mixed, params))


def test_without_the_grid_the_veils_are_grasped(veiled_scene: tuple[ViewpointCloud, np.ndarray]) -> None:
    """The same points as an unorganised cloud (no filter): some top grasps close on veils alone, so the test
    above has something to catch."""
    cloud, mixed = veiled_scene
    params = DetectionParams(num_samples=400, workspace=WORKSPACE)
    assert any(flying_only(replace(cloud, grid=None), mixed, params))


def test_mixed_pixels_are_found_and_surfaces_kept(veiled_scene: tuple[ViewpointCloud, np.ndarray]) -> None:
    """Most mixed pixels are flagged (those on the small jumps at the boxes' feet, a few mm off the table, may
    stay: the depth noise allows them), and few real surface points are."""
    cloud, mixed = veiled_scene
    assert cloud.grid is not None
    flagged = veil_points(cloud.points, cloud.camera_source, cloud.viewpoints, cloud.grid)
    assert (flagged & mixed).sum() > 0.75 * mixed.sum()
    assert (flagged & ~mixed).sum() < 0.01 * (~mixed).sum()


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (degrees) between unoriented unit vectors, row by row."""
    return np.degrees(np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", a, b)), 0.0, 1.0)))


def render_plane(pose: np.ndarray, normal: np.ndarray, through: np.ndarray) -> np.ndarray:
    """Depth image of an infinite plane (unit normal, a point on it)."""
    o, d = pixel_rays(pose)
    with np.errstate(divide="ignore"):
        t = ((through - o) @ normal) / (d @ normal)
    return np.where(t > 0, t, 0.0).reshape(H, W)


def render_cylinder(pose: np.ndarray, radius: float, height: float) -> np.ndarray:
    """Depth image of an upright cylinder (axis z through the origin, z from 0 to height), nothing behind it."""
    o, d = pixel_rays(pose)
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (o[0] * d[:, 0] + o[1] * d[:, 1])
    c = o[0] ** 2 + o[1] ** 2 - radius**2
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / (2 * a)
    z = o[2] + t * d[:, 2]
    return np.where((disc > 0) & (t > 0) & (z > 0) & (z < height), t, 0.0).reshape(H, W)


@pytest.mark.parametrize("scene", ["plane", "cylinder"])
def test_grid_normals_agree_with_pca(tmp_path: Path, scene: str) -> None:
    """On a tilted plane and a cylinder, grid normals and the PCA estimator (1 cm, 30 neighbours) agree, and both
    match the true normals; the grid's face the camera."""
    pose = look_at((0.5, 0.15, 0.3) if scene == "plane" else (0.3, 0.1, 0.15), (0.0, 0.0, 0.06))
    if scene == "plane":
        normal = np.array([0.3, 0.1, 1.0]) / np.linalg.norm([0.3, 0.1, 1.0])
        depth = render_plane(pose, normal, np.zeros(3))
    else:
        depth = render_cylinder(pose, 0.04, 0.12)
    cloud = organised_cloud(tmp_path, depth, pose)
    assert cloud.grid is not None
    grid = grid_normals(cloud.points, cloud.camera_source, cloud.viewpoints, cloud.grid, 0.01)
    near = np.linalg.norm(cloud.points - cloud.viewpoints[0], axis=1) < 0.9  # the plane's far reaches are sparse
    pts = cloud.points[near]
    grid = grid[near]
    pca = pca_normals(pts, 0.01, 30)
    if scene == "plane":
        truth = np.tile(normal, (len(pts), 1))
    else:
        truth = np.c_[pts[:, :2], np.zeros(len(pts))]
        truth /= np.linalg.norm(truth, axis=1, keepdims=True)
        # away from the silhouette (rays grazing the surface) and the caps' rims, where neither has a full patch
        inner = (np.abs(np.einsum("ij,ij->i", truth, cloud.viewpoints[0] - pts))
                 / np.linalg.norm(cloud.viewpoints[0] - pts, axis=1) > 0.3) & (pts[:, 2] > 0.01) & (pts[:, 2] < 0.11)
        pts, grid, pca, truth = pts[inner], grid[inner], pca[inner], truth[inner]
    assert len(pts) > 2000 and np.isfinite(grid).all()
    assert (np.einsum("ij,ij->i", grid, cloud.viewpoints[0] - pts) > 0).all()  # toward the camera
    between = angles_deg(grid, pca)
    assert np.median(between) < 1.0 and np.percentile(between, 95) < 3.0, np.percentile(between, [50, 95])
    assert np.percentile(angles_deg(grid, truth), 95) < 2.0
    assert np.percentile(angles_deg(pca, truth), 95) < 3.0


def test_organised_input_takes_its_normals_from_the_grid(
        veiled_scene: tuple[ViewpointCloud, np.ndarray]) -> None:
    """preprocess of an organised cloud: the voxels' normals are the means of the grid normals of their points
    (mixed pixels out), not PCA of the voxels; the same points unorganised give PCA's."""
    cloud, _ = veiled_scene
    assert cloud.grid is not None
    params = PreprocessParams(workspace=WORKSPACE)
    got = preprocess(cloud, params)
    kept = region(cloud, WORKSPACE, 0.0, finite_normals=True).mask
    kept &= ~veil_points(cloud.points, cloud.camera_source, cloud.viewpoints, cloud.grid, kept)
    normals = grid_normals(cloud.points, cloud.camera_source, cloud.viewpoints, cloud.grid, params.normal_radius,
                           kept)
    kept &= np.isfinite(normals[:, 0])
    pts, src, nrm = voxelize(cloud.points[kept], cloud.camera_source[kept], params.voxel_size, normals[kept])
    assert nrm is not None and got.normals is not None
    assert np.array_equal(got.points, pts)
    assert np.allclose(got.normals, orient_toward_cameras(pts, nrm, src, cloud.viewpoints), atol=1e-6)
    flat = preprocess(replace(cloud, grid=None), params)
    assert len(flat) > len(got)  # the mixed pixels' voxels too
