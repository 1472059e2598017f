"""The training augmentation: mirroring grasp images across hand y or z equals encoding the mirrored scene."""

import numpy as np
import pytest

from graspd.core.cloud import ViewpointCloud
from graspd.core.hand import HandGeometry
from graspd.gpd.candidates import SamplingParams, search_hands
from graspd.gpd.images import channel_layout, encode_images
from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.gpd.scene import Scene
from graspd_lab.training.augment import augment, mirror_images
from graspd_lab.training.dataset import derive_images

HAND = HandGeometry()


def _box_and_cylinder(seed: int = 0) -> ViewpointCloud:
    """Front faces of a 5x3x8 cm box and a 2.5 cm-radius cylinder on a table, seen from two cameras 53 deg apart."""
    rng = np.random.default_rng(seed)
    s = 0.002
    g = np.arange(-0.15, 0.15, s)
    X, Y = np.meshgrid(g, g)
    table = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    parts, normals = [table], [np.tile([0, 0, 1.0], (len(table), 1))]
    half = (0.025, 0.015, 0.04)
    for d in range(3):
        for sign in (-1, 1):
            a, b = [k for k in range(3) if k != d]
            u, v = np.meshgrid(np.arange(-half[a], half[a], s), np.arange(-half[b], half[b], s))
            p = np.zeros((u.size, 3))
            p[:, a], p[:, b], p[:, d] = u.ravel(), v.ravel(), sign * half[d]
            n = np.zeros_like(p)
            n[:, d] = sign
            parts.append(p + [-0.04, 0, 0.04])
            normals.append(n)
    th, zz = np.meshgrid(np.arange(0, 2 * np.pi, s / 0.025), np.arange(0, 0.1, s))
    cyl = np.stack([0.05 + 0.025 * np.cos(th.ravel()), 0.025 * np.sin(th.ravel()), zz.ravel()], 1)
    parts.append(cyl)
    normals.append(np.stack([np.cos(th.ravel()), np.sin(th.ravel()), np.zeros(th.size)], 1))
    pts, nrm = np.concatenate(parts), np.concatenate(normals)
    cams = np.array([[0.5, 0.0, 0.45], [0.5 * np.cos(0.925), 0.5 * np.sin(0.925), 0.45]])
    out_p, out_s = [], []
    for k, cam in enumerate(cams):
        vis = np.einsum("ij,ij->i", nrm, cam - pts) > 0
        out_p.append(pts[vis])
        out_s.append(np.full(int(vis.sum()), k, np.int32))
    points = np.concatenate(out_p) + rng.normal(0, 4e-4, (sum(len(p) for p in out_p), 3))
    return ViewpointCloud(points=points.astype(np.float32), viewpoints=cams.astype(np.float32),
                          camera_source=np.concatenate(out_s))


@pytest.fixture(scope="module")
def scene_and_grasps():
    pre = preprocess(_box_and_cylinder(), PreprocessParams(voxel_size=0.003))
    scene = Scene.build(pre, HAND)
    on_objects = pre.points[:, 2] > 0.01
    grasps, _ = search_hands(scene, HAND, SamplingParams(num_samples=30, sample_pool=on_objects, seed=3))
    grasps = grasps[:8]
    mirrored = {axis: _mirrored_encoding(pre, grasps, axis, "15") for axis in (1, 2)}
    return pre, scene, grasps, mirrored


def _mirrored_encoding(pre: ViewpointCloud, grasps, axis: int, representation: str) -> np.ndarray:
    """Encode each grasp in the scene reflected through its own hand plane normal to hand axis `axis`."""
    out = []
    for k in range(len(grasps)):
        n = grasps.rotations[k][:, axis]
        c = grasps.positions[k]
        pts = pre.points - 2.0 * np.outer((pre.points - c) @ n, n)
        nrm = pre.normals - 2.0 * np.outer(pre.normals @ n, n)
        vps = pre.viewpoints - 2.0 * np.outer((pre.viewpoints - c) @ n, n)
        cloud = ViewpointCloud(points=pts.astype(np.float32), viewpoints=vps.astype(np.float32),
                               camera_source=pre.camera_source, normals=nrm.astype(np.float32))
        out.append(encode_images(Scene.build(cloud, HAND), grasps[k : k + 1], HAND, representation)[0])
    return np.array(out)


@pytest.mark.parametrize("representation", ["15", "herzog", "3"])
@pytest.mark.parametrize("axis", [1, 2])
def test_mirror_matches_mirrored_scene(scene_and_grasps, axis: int, representation: str) -> None:
    _, scene, grasps, mirrored = scene_and_grasps
    images = encode_images(scene, grasps, HAND, representation)
    np.testing.assert_array_equal(derive_images(encode_images(scene, grasps, HAND, "15"), representation), images)
    want = derive_images(mirrored[axis], representation).astype(int)
    got = mirror_images(images, representation, axis).astype(int)
    for c, name in enumerate(channel_layout(representation)):
        hit = (want[:, c] > 0) | (got[:, c] > 0)
        if not hit.any():
            continue
        if name.endswith(("unobs", "free")):
            # unobserved space lives on a world-aligned 4 mm voxel grid, which the reflection does not map onto
            # itself: compare the masks (IoU) and the depths where both are set
            both = (want[:, c] > 0) & (got[:, c] > 0)
            iou = both.sum() / hit.sum()
            assert iou > 0.85, (name, iou)
            if name.endswith("unobs"):  # depths agree to within one voxel along the projection axis
                extent = {"x": HAND.hand_depth, "y": HAND.max_aperture, "z": HAND.hand_height}[name[0]]
                assert np.abs(want[:, c] - got[:, c])[both].mean() < 255 * 0.004 / extent, name
            continue
        # float rounding moves the odd point across a pixel edge: allow 3% of the pixels to differ
        agree = float((np.abs(want[:, c] - got[:, c])[hit] <= 2).mean())
        assert agree > 0.97, (name, agree)
    assert np.abs(got.astype(int) - images.astype(int)).max() > 0  # the mirror is not the identity here


def test_mirroring_twice_is_the_identity_and_augment_keeps_shapes(scene_and_grasps) -> None:
    _, scene, grasps, _ = scene_and_grasps
    images = encode_images(scene, grasps, HAND, "15")
    for axis in (1, 2):
        np.testing.assert_array_equal(mirror_images(mirror_images(images, "15", axis), "15", axis), images)
    out = augment(images, "15", np.random.default_rng(0))
    assert out.shape == images.shape and out.dtype == np.uint8
    with pytest.raises(ValueError, match="axis"):
        mirror_images(images, "15", 0)
