"""Grasp images: channel layouts, mirror symmetry, and what the unobserved channel sees."""

from __future__ import annotations

import numpy as np
import pytest

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.gpd.candidates import SamplingParams, search_hands
from graspd.gpd.images import REPRESENTATIONS, channel_layout, encode_batches, encode_images
from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.gpd.scene import ClosingRegionPoints, Scene

HAND = HandGeometry()


@pytest.fixture
def scene_and_grasps(cylinder_two_cameras: ViewpointCloud):
    rng = np.random.default_rng(0)  # sensor-like jitter, so points do not sit on pixel edges
    noisy = ViewpointCloud(points=cylinder_two_cameras.points + rng.normal(0, 5e-4, cylinder_two_cameras.points.shape),
                           viewpoints=cylinder_two_cameras.viewpoints, camera_source=cylinder_two_cameras.camera_source)
    pre = preprocess(noisy, PreprocessParams(voxel_size=0.003))
    scene = Scene.build(pre, HAND)
    on_cyl = (np.hypot(pre.points[:, 0], pre.points[:, 1]) < 0.035) & (pre.points[:, 2] > 0.01)
    grasps, region = search_hands(scene, HAND, SamplingParams(num_samples=40, sample_pool=on_cyl))
    return pre, scene, grasps, region


def test_every_representation_has_its_channels_and_uses_the_range(scene_and_grasps) -> None:
    _, scene, grasps, region = scene_and_grasps
    for name, channels in REPRESENTATIONS.items():
        images = encode_images(scene, grasps, HAND, name, region=region)
        assert images.shape == (len(grasps), channels, 60, 60) and images.dtype == np.uint8
        assert len(channel_layout(name)) == channels
        assert (images.reshape(len(grasps), channels, -1).max(axis=2) > 0).any(axis=0).all(), name


def test_region_from_the_sampler_matches_a_fresh_lookup(scene_and_grasps) -> None:
    _, scene, grasps, region = scene_and_grasps
    a = encode_images(scene, grasps, HAND, "15", region=region)
    b = encode_images(scene, grasps, HAND, "15")
    assert (a != b).mean() < 1e-3


def test_images_in_batches_and_in_any_point_order_are_the_same_images(scene_and_grasps) -> None:
    _, scene, grasps, region = scene_and_grasps
    assert len(grasps) > 40
    whole = encode_images(scene, grasps, HAND, "15", region=region)
    batches = list(encode_batches(scene, grasps, HAND, "15", region=region, batch=7))
    assert [a for a, _ in batches] == list(range(0, len(grasps), 7))
    assert np.array_equal(np.concatenate([b for _, b in batches]), whole)
    shuffled = np.random.default_rng(1).permutation(len(region.grasp))
    reordered = ClosingRegionPoints(region.grasp[shuffled], region.local[shuffled], region.index[shuffled])
    assert np.array_equal(encode_images(scene, grasps, HAND, "15", region=reordered), whole)


def test_twelve_channels_are_fifteen_without_the_unobserved_ones(scene_and_grasps) -> None:
    _, scene, grasps, region = scene_and_grasps
    full = encode_images(scene, grasps, HAND, "15", region=region)
    keep = [i for i, c in enumerate(channel_layout("15")) if not c.endswith("unobs")]
    assert np.array_equal(full[:, keep], encode_images(scene, grasps, HAND, "12", region=region))
    three = encode_images(scene, grasps, HAND, "3", region=region)
    z_normals = [channel_layout("15").index(c) for c in ("z:nx", "z:ny", "z:nz")]
    assert np.array_equal(full[:, z_normals], three)


def test_unobserved_space_lies_behind_the_visible_surface(scene_and_grasps) -> None:
    _, scene, grasps, region = scene_and_grasps
    images = encode_images(scene, grasps, HAND, "15", region=region)
    # Looking down the hand axis (x: depth along the approach), occluded space sits deeper than the surface.
    occ, unobs = images[:, channel_layout("15").index("z:occ")], images[:, channel_layout("15").index("z:unobs")]
    assert unobs.any()
    hx = np.arange(60)[None, :, None]  # rows are hand x (approach) for the projection along z
    mean_row_occ = (hx * (occ > 0)).sum() / max((occ > 0).sum(), 1)
    mean_row_unobs = (hx * (unobs > 0)).sum() / max((unobs > 0).sum(), 1)
    assert mean_row_unobs > mean_row_occ


def test_images_of_a_mirrored_scene_are_mirrored(scene_and_grasps) -> None:
    pre, scene, grasps, region = scene_and_grasps
    g = grasps[:10]
    # Each hand's own sampled point sits exactly on a pixel edge along y (finger offsets are whole pixels),
    # where a mirror rounds it into the neighbouring pixel: leave those points out of both scenes.
    far = np.min(np.linalg.norm(pre.points[:, None, :] - g.samples[None, :, :], axis=2), axis=1) > 1e-6
    pre = pre.select(far)
    scene = Scene.build(pre, HAND)
    # Reflect the cloud through each hand's (approach, axis) plane: hand-frame y -> -y.
    flipped = []
    for k in range(len(g)):
        n = g.binormal[k]
        d = pre.points - g.positions[k]
        pts = pre.points - 2.0 * np.outer(d @ n, n)
        nrm = pre.normals - 2.0 * np.outer(pre.normals @ n, n)
        vps = pre.viewpoints - 2.0 * np.outer((pre.viewpoints - g.positions[k]) @ n, n)
        mirrored = ViewpointCloud(points=pts, viewpoints=vps, camera_source=pre.camera_source, normals=nrm)
        flipped.append(encode_images(Scene.build(mirrored, HAND), g[k], HAND, "12")[0])
    a = encode_images(scene, g, HAND, "12").astype(int)
    b = np.array(flipped).astype(int)
    layout = channel_layout("12")
    # Along x the image rows are hand y; along z the columns are hand y; along y the depth is hand y.
    # (float32 rounding moves the odd point across a pixel edge: allow 1% of the occupied pixels to differ)
    def agree(x: np.ndarray, y: np.ndarray) -> float:
        hit = (x > 0) | (y > 0)
        return float((np.abs(x - y)[hit] <= 2).mean())

    for name in ("x:nx", "x:nz", "x:occ"):
        c = layout.index(name)
        assert agree(a[:, c], b[:, c, ::-1, :]) > 0.99, name
    for name in ("z:nx", "z:nz", "z:occ"):
        c = layout.index(name)
        assert agree(a[:, c], b[:, c, :, ::-1]) > 0.99, name
    ny = layout.index("x:ny")
    assert agree(a[:, ny], np.where(b[:, ny, ::-1, :] > 0, 255 - b[:, ny, ::-1, :], 0)) > 0.99
    occ_y = layout.index("y:occ")
    assert agree(a[:, occ_y], np.where(b[:, occ_y] > 0, 255 - b[:, occ_y], 0)) > 0.99


def test_unknown_representation_is_named() -> None:
    with pytest.raises(KeyError, match="unknown representation 'rgb'"):
        channel_layout("rgb")
