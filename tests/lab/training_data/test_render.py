"""Rendering: points lie on the mesh (exactly without noise, within the noise model's bound with it),
each tagged with the camera that saw it; rigs are 53 degrees apart; tabletops are deterministic."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from graspd.core.camera import Camera, look_at_rig, random_view, tabletop_cameras
from graspd_lab.world.meshes import box_mesh
from graspd_lab.world.noise import DepthNoise, axial_sigma, depth_edges, quantize_depth
from graspd_lab.world.objects import procedural_object
from graspd_lab.world.render import MeshScene, render_scene, render_scene_with_ids
from graspd_lab.world.scenes import random_tabletop, tabletop_scene


def distances(mesh: o3d.geometry.TriangleMesh, points: np.ndarray) -> np.ndarray:
    scene = MeshScene([mesh])
    return scene.scene.compute_distance(o3d.core.Tensor.from_numpy(points.astype(np.float32))).numpy()


def test_two_camera_rig_is_53_degrees_apart_and_looks_at_the_target() -> None:
    cams = random_view(np.random.default_rng(4), num_cameras=2)
    a, b = (np.asarray(c.position) / np.linalg.norm(c.position) for c in cams)
    assert np.rad2deg(np.arccos(np.clip(a @ b, -1, 1))) == pytest.approx(53.0, abs=1e-6)
    for c in cams:
        centre = c.project(np.zeros((1, 3)))[0]
        assert centre[:2] == pytest.approx([c.width / 2, c.height / 2], abs=1e-6)


def test_exact_render_lies_on_the_surface_with_camera_sources() -> None:
    mesh = box_mesh(0.06, 0.04, 0.10)
    cams = look_at_rig(np.zeros(3), np.array([1.0, 0.3, 0.5]), 0.6, num_cameras=2)
    cloud = render_scene([mesh], cams, DepthNoise.none(), seed=0)
    assert cloud.num_cameras == 2 and len(cloud) > 2000
    assert np.allclose(cloud.viewpoints, [c.position for c in cams])
    assert set(np.unique(cloud.camera_source)) == {0, 1}
    assert distances(mesh, cloud.points).max() < 1e-5
    # each point faces the camera that saw it: it lies on a box face whose outward side holds that camera
    half = np.array([0.03, 0.02, 0.05])
    on_face = np.abs(np.abs(cloud.points) - half) < 1e-5
    for k in range(2):
        cam = np.asarray(cams[k].position)
        pts, faces = cloud.points[cloud.camera_source == k], on_face[cloud.camera_source == k]
        signs = np.sign(pts)
        visible = np.abs(cam) > half  # the faces a camera outside the box can see
        assert np.all(np.any(faces & visible & (signs == np.sign(cam)), axis=1))


def test_noisy_render_within_the_noise_bound() -> None:
    obj = procedural_object("cylinder", 1)
    cams = random_view(np.random.default_rng(7), num_cameras=2, distance_range=(0.6, 0.6))
    cloud = render_scene([obj.mesh], cams, DepthNoise(), seed=1)
    d = distances(obj.mesh, cloud.points)
    z = 0.6 + 0.05
    # 6 sigma of the axial noise at the 80 deg dropout limit, plus one disparity quantization step
    bound = 6 * float(axial_sigma(np.float32(z), np.float32(np.deg2rad(80.0)))) + z**2 / (8 * cams[0].focal_px * 0.075)
    assert d.max() < bound
    assert np.median(d) < 2e-3
    exact = render_scene([obj.mesh], cams, DepthNoise.none(), seed=1)
    assert len(cloud) < len(exact)  # grazing, edge and random dropouts


def test_single_camera_and_seed_determinism() -> None:
    mesh = box_mesh(0.05, 0.05, 0.05)
    cams = look_at_rig(np.zeros(3), np.array([0.0, -1.0, 1.0]), 0.7, num_cameras=1)
    a = render_scene([mesh], cams, seed=3)
    b = render_scene([mesh], cams, seed=3)
    c = render_scene([mesh], cams, seed=4)
    assert a.num_cameras == 1 and np.all(a.camera_source == 0)
    assert np.array_equal(a.points, b.points) and not np.array_equal(a.points, c.points)


def test_tabletop_scene_is_deterministic_and_objects_rest_on_the_table() -> None:
    objs = [procedural_object(k, i).mesh for k, i in (("box", 0), ("cylinder", 0), ("sphere", 0), ("cone", 1))]
    a = tabletop_scene(objs, seed=5)
    b = tabletop_scene(objs, seed=5)
    assert len(a) == len(objs) + 1
    for ma, mb in zip(a, b, strict=True):
        assert np.array_equal(np.asarray(ma.vertices), np.asarray(mb.vertices))
    for m in a[1:]:
        assert np.asarray(m.vertices)[:, 2].min() == pytest.approx(0.0, abs=1e-9)
    cloud, ids = render_scene_with_ids(a, tabletop_cameras(), seed=0)
    assert set(np.unique(ids)) == set(range(len(a)))  # the table and every object are seen
    assert np.all(cloud.points[ids == 0][:, 2] < 0.01)


def test_noise_helpers() -> None:
    z = np.array([[0.5, 0.5, 0.9], [0.5, np.nan, 0.9]], np.float32)
    edges = depth_edges(z, 0.01)
    assert edges.tolist() == [[False, True, True], [True, False, True]]  # NaN and 0.4 m jumps are edges
    q = quantize_depth(np.float32(1.0), 570.0, 0.075, 0.125)
    assert abs(float(q) - 1.0) <= 1.0 / (8 * 570 * 0.075)
    with pytest.raises(ValueError, match="num_cameras"):
        look_at_rig(np.zeros(3), np.ones(3), 0.5, num_cameras=3)
    assert Camera(position=(0.0, 0.0, 1.0)).rotation().shape == (3, 3)


def test_random_tabletop_is_deterministic() -> None:
    pytest.importorskip("pybullet")  # pybullet_data holds the random_urdfs (the lab, graspd-lab)

    a = random_tabletop(4, seed=2)
    b = random_tabletop(4, seed=2)
    c = random_tabletop(4, seed=2, held_out=True)
    assert len(a) == 5 and len(c) == 5
    assert all(np.array_equal(np.asarray(x.vertices), np.asarray(y.vertices)) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(np.asarray(a[1].vertices), np.asarray(c[1].vertices))
