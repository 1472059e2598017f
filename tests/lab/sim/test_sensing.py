"""Depth cameras: metric depth back-projects onto the true geometry; noise spreads and drops points."""

import numpy as np

from graspd.core.camera import active_cameras, passive_cameras, side_camera
from graspd_lab.sim.sensing import NO_NOISE, observe, render_depth
from graspd_lab.sim.world import SimWorld
from graspd_lab.world.noise import DepthNoise

REGION = (-0.15, 0.15, -0.12, 0.12, -0.05, 0.3)


def test_floor_points_lie_on_the_floor_without_noise() -> None:
    with SimWorld.create(has_tray=True) as world:
        cloud = observe(world.client, passive_cameras(), NO_NOISE, np.random.default_rng(0), REGION)
    assert len(cloud) > 10_000
    assert np.abs(cloud.points[:, 2]).max() < 0.002  # inside the tray only the floor (z = 0) is visible
    assert set(np.unique(cloud.camera_source)) == {0, 1}
    assert cloud.viewpoints.shape == (2, 3)


def test_passive_cameras_are_53_degrees_apart() -> None:
    a, b = (np.subtract(c.position, c.target)[:2] for c in passive_cameras())
    ang = np.degrees(np.arccos(a @ b / np.linalg.norm(a) / np.linalg.norm(b)))
    assert abs(ang - 53.0) < 1e-6  # in azimuth around the tray


def test_noise_spreads_depth_and_drops_pixels() -> None:
    with SimWorld.create(has_tray=True) as world:
        rng = np.random.default_rng(1)
        clean = observe(world.client, side_camera(), NO_NOISE, rng, REGION)
        noisy = observe(world.client, side_camera(), DepthNoise.benchmark(), rng, REGION)
        depth = render_depth(world.client, side_camera()[0])
    assert np.isfinite(depth).any()
    assert len(noisy) < len(clean)
    assert noisy.points[:, 2].std() > 5 * clean.points[:, 2].std()
    assert np.abs(noisy.points[:, 2]).mean() < 0.01


def test_active_views_are_fused_with_one_index_per_view() -> None:
    cams = active_cameras(num_views=4)
    for c in cams:
        assert abs(np.linalg.norm(np.subtract(c.position, c.target)) - 0.40) < 1e-9
    with SimWorld.create(has_tray=True) as world:
        cloud = observe(world.client, cams, NO_NOISE, np.random.default_rng(0), REGION)
    assert set(np.unique(cloud.camera_source)) == {0, 1, 2, 3}
    assert np.allclose(cloud.viewpoints, [c.position for c in cams])
