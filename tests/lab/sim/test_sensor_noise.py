"""The sensors' noise models on small rendered depth images: the ToF camera's flying pixels at depth edges and
multipath bias in concave corners, the stereo camera's range-squared noise, edge streaks and holes on dark and
shiny surfaces, and the Kinect model unchanged behind the same interface."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from graspd.core.camera import Camera
from graspd_lab.sim.sensing import pixel_rays, render_depth, render_depth_and_surfaces
from graspd_lab.sim.world import SimWorld
from graspd_lab.world.noise import (
    DepthNoise,
    StereoNoise,
    Surfaces,
    ToFNoise,
    jump_mask,
    noisy_depth,
    sensor_noise,
)

BOX_TOP = 0.08  # m: a 10 x 10 x 8 cm box on the table


def _box_world() -> tuple[SimWorld, int]:
    world = SimWorld.create(has_tray=False)
    box = world._box([0.05, 0.05, BOX_TOP / 2], [0.0, 0.0, BOX_TOP / 2])
    return world, box


def _camera(position: tuple[float, float, float], size: int = 96) -> Camera:
    return Camera(position, (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), width=size, height=size, fov_deg=40.0,
                  fov_axis="vertical", near=0.05, far=3.0)


def test_tof_flying_pixels_hang_between_foreground_and_background_at_edges() -> None:
    world, _ = _box_world()
    with world:
        cam = _camera((0.0, 0.0, 0.5))
        depth, rays = render_depth(world.client, cam), pixel_rays(cam)
    noisy = ToFNoise(axial_base=0.0, axial_linear=0.0, random_dropout=0.0).rasterised(depth, rays,
                                                                                  np.random.default_rng(0))
    top, table = 0.5 - BOX_TOP, 0.5
    between = np.isfinite(noisy) & (noisy > top + 0.01) & (noisy < table - 0.01)
    assert not ((depth > top + 0.01) & (depth < table - 0.01)).any()  # the exact image has no such depth
    assert between.sum() > 30
    near_edge = np.zeros(depth.shape, bool)
    edge = jump_mask(depth, 0.01)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            near_edge |= np.roll(np.roll(edge, dy, axis=0), dx, axis=1)
    assert near_edge[between].all()


def test_tof_multipath_pushes_concave_corners_back_and_leaves_planes_alone() -> None:
    world, _ = _box_world()
    with world:
        cam = _camera((0.45, 0.0, 0.25))  # sees the box's side wall meet the table
        depth = render_depth(world.client, cam)
        pts = cam.position + pixel_rays(cam) * np.where(np.isfinite(depth), depth, 0.0)[..., None]
    bias = ToFNoise().multipath_bias(depth)
    on_wall_foot = (np.abs(pts[..., 0] - 0.05) < 0.01) & (pts[..., 2] < 0.01) & (np.abs(pts[..., 1]) < 0.03)
    open_table = (np.abs(pts[..., 2]) < 3e-3) & (np.abs(pts[..., 1]) > 0.1)  # 5 cm and more beside the box
    assert on_wall_foot.any() and open_table.any()
    assert bias[on_wall_foot].max() > 0.002
    assert np.all(bias >= 0.0) and bias.max() <= ToFNoise().multipath_max
    assert np.percentile(bias[open_table], 99) < 1e-4


def test_stereo_noise_grows_with_range_squared() -> None:
    spreads = []
    model = StereoNoise(speckle_share=0.0, streak_px=0, edge_dropout=0.0, random_dropout=0.0)
    with SimWorld.create(has_tray=False) as world:
        for height in (0.5, 1.0):
            cam = _camera((0.0, 0.0, height), size=64)
            depth, rays = render_depth(world.client, cam), pixel_rays(cam)
            err = model.rasterised(depth, rays, np.random.default_rng(1)) - depth
            spreads.append(float(np.std(err[np.isfinite(err)])))
    assert spreads[0] == pytest.approx(model.sigma(np.array(0.5)), rel=0.1)
    assert spreads[1] / spreads[0] == pytest.approx(4.0, rel=0.15)


def test_stereo_edge_streaks_run_foreground_depth_along_rows_into_the_background() -> None:
    world, _ = _box_world()
    with world:
        cam = _camera((0.0, 0.0, 0.5))
        depth, rays = render_depth(world.client, cam), pixel_rays(cam)
    model = StereoNoise(subpixel=0.0, speckle_share=0.0, edge_dropout=0.0, random_dropout=0.0)
    noisy = model.rasterised(depth, rays, np.random.default_rng(2))
    top = 0.5 - BOX_TOP
    streak = (depth > top + 0.05) & np.isfinite(noisy) & (np.abs(noisy - top) < 0.005)
    assert streak.sum() > 10
    rows_with_box = np.flatnonzero((np.abs(depth - top) < 0.005).any(axis=1))
    assert set(np.flatnonzero(streak.any(axis=1))) <= set(rows_with_box)  # along rows only, never above or below


def test_stereo_holes_open_on_dark_and_shiny_surfaces() -> None:
    world, box = _box_world()
    with world:
        cam = _camera((0.0, 0.0, 0.5))
        depth, ids = render_depth_and_surfaces(world.client, cam)
        rays = pixel_rays(cam)
    model = StereoNoise(random_dropout=0.0)
    on_box, on_table = ids == box, (ids >= 0) & (ids != box)
    for material in ("dark", "shiny"):
        surfaces = Surfaces(ids=ids, **{material: frozenset({box})})  # type: ignore[arg-type]
        noisy = model.rasterised(depth, rays, np.random.default_rng(3), surfaces)
        assert (~np.isfinite(noisy[on_box])).mean() > 0.7  # the box's top faces the camera: dark or specular
        assert (~np.isfinite(noisy[on_table & ~jump_mask(depth, 0.01)])).mean() < 0.05
    plain = model.rasterised(depth, rays, np.random.default_rng(3), Surfaces(ids=ids))
    assert (~np.isfinite(plain[on_box & ~jump_mask(depth, 0.01)])).mean() < 0.05


def test_the_kinect_model_behind_the_interface_is_noisy_depth() -> None:
    with SimWorld.create(has_tray=False) as world:
        cam = _camera((0.1, 0.0, 0.6), size=48)
        depth, rays = render_depth(world.client, cam), pixel_rays(cam)
    model = sensor_noise("kinect")
    assert model == DepthNoise.benchmark() and model.draw_surfaces(np.arange(3), np.random.default_rng(0)) is None
    np.testing.assert_array_equal(model.rasterised(depth, rays, np.random.default_rng(4)),
                                  noisy_depth(depth, rays, DepthNoise.benchmark(), np.random.default_rng(4)))
    with pytest.raises(ValueError, match="sensor"):
        sensor_noise("lidar")


def test_materials_are_drawn_once_per_observation_for_every_camera() -> None:
    model = StereoNoise(dark_share=0.5, shiny_share=0.5)
    drawn = model.draw_surfaces(np.arange(40), np.random.default_rng(5))
    assert drawn is not None and drawn.dark and drawn.shiny and not drawn.dark & drawn.shiny
    assert pb.isNumpyEnabled() in (0, 1)  # pybullet is importable beside the models
