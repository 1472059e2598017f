"""The container family (graspd_lab.sim.containers) in the simulated world: every style builds and settles with
objects inside its (turned) interior, the split is one table with no style on both sides, the workspace
holds the container and table around it, and static_meshes / static_labels are the bodies pybullet
simulates, yaw included."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import open3d as o3d
import pybullet as pb
import pytest

from graspd.core.camera import sensing_cameras
from graspd.core.hand import HandGeometry
from graspd_lab.sim.containers import (
    HELD_OUT_STYLES,
    RANGES,
    STYLES,
    TRAINING_STYLES,
    TUNED_ON,
    WORKSPACE_MARGIN,
    ContainerSpec,
    StyleRanges,
    sample_container,
    scene_container,
)
from graspd_lab.sim.detectors import TopDownBaseline
from graspd_lab.sim.objects import TEST_OBJECT_IDS
from graspd_lab.sim.protocol import Setting, run_round
from graspd_lab.sim.sensing import NO_NOISE, observe
from graspd_lab.sim.world import SimWorld, build_scene
from graspd_lab.world.objects import USABLE_TRAINING_URDFS


def _split(style: str) -> str:
    return "training" if style in TRAINING_STYLES else "held_out"


def test_the_split_is_one_table_with_no_style_on_both_sides() -> None:
    assert not set(TRAINING_STYLES) & set(HELD_OUT_STYLES)
    assert set(TRAINING_STYLES) | set(HELD_OUT_STYLES) == set(STYLES) == set(RANGES)
    for style in HELD_OUT_STYLES:
        assert set(RANGES[style]) == {"held_out"}
        with pytest.raises(ValueError, match="held out"):
            sample_container(style, np.random.default_rng(0), "training")
    ranged = [f.name for f in fields(StyleRanges) if f.name not in ("walls", "slab_probability",
                                                                    "ceiling_probability")]
    assert set(TUNED_ON) <= set(TRAINING_STYLES)  # a style once looked at is never counted as held out
    for style in TRAINING_STYLES:
        if style in TUNED_ON:
            continue  # held out at first: its training ranges are its former held-out ones
        train, held = RANGES[style]["training"], RANGES[style]["held_out"]
        # a training style's held-out ranges leave its training ranges in at least one parameter
        assert any(getattr(held, n)[0] >= getattr(train, n)[1] or getattr(held, n)[1] <= getattr(train, n)[0]
                   for n in ranged if getattr(train, n) != (0.0, 0.0))


@pytest.mark.parametrize("style", STYLES)
def test_samples_stay_in_their_ranges(style: str) -> None:
    split = _split(style)
    r = RANGES[style][split]
    rng = np.random.default_rng(1)
    for _ in range(50):
        s = sample_container(style, rng, split)
        assert r.inner_x[0] <= s.inner_x <= r.inner_x[1] and r.inner_y[0] <= s.inner_y <= r.inner_y[1]
        assert r.yaw[0] <= s.yaw <= r.yaw[1]
        assert s.floor_height == 0.0 or r.floor_height[0] <= s.floor_height <= r.floor_height[1]
        assert s.walls == r.walls
        if s.ceiling_height:
            assert s.wall_top == pytest.approx(s.ceiling_height)
        elif s.walls:
            assert r.wall_height[0] <= s.wall_height <= r.wall_height[1]
    assert scene_container(style, 3, split) == scene_container(style, 3, split)


@pytest.mark.parametrize("style", STYLES)
def test_each_style_builds_and_settles_with_objects_inside(style: str) -> None:
    spec = scene_container(style, 0, _split(style))
    ids = USABLE_TRAINING_URDFS[:200] if style in TRAINING_STYLES \
        else TEST_OBJECT_IDS
    with build_scene("container", 3, seed=0, hand=HandGeometry(), object_ids=ids, container=spec) as world:
        # a round object may roll off a platform's edge once the guides are lifted away: it is removed
        assert len(world.objects) == 3 or (style == "platform" and len(world.objects) == 2)
        for body in world.objects:
            p = world.object_position(body)
            local = spec.to_container(p)[0]
            assert abs(local[0]) <= spec.inner_x / 2 and abs(local[1]) <= spec.inner_y / 2, (style, local)
            assert p[2] > spec.floor_height  # on the floor, not under it
            assert np.linalg.norm(pb.getBaseVelocity(body, physicsClientId=world.client)[0]) < 0.05
        names = [world.static_names[b] for b in world.static_bodies]
        assert names[0] == "table"
        assert sorted(n for n in names if n.startswith("wall")) == sorted(f"wall{w}" for w in spec.walls)
        assert ("floor" in names) == (spec.floor_height > 0)
        assert ("ceiling" in names) == (spec.ceiling_height > 0)


def test_in_play_tests_the_turned_interior_not_its_bounding_box() -> None:
    spec = ContainerSpec("tray", 0.30, 0.30, 0.05, 0.01, 0.02, np.pi / 4)
    with SimWorld.create(has_tray=False, container=spec) as world:
        x0, x1, y0, y1 = world.inside_region()
        assert x1 == pytest.approx(0.15 * np.sqrt(2)) and y0 == pytest.approx(-0.15 * np.sqrt(2))
        # both inside the bounding box; only the first inside the turned interior
        inside, corner = [0.2, 0.0, 0.05], [0.2, 0.2, 0.05]
        assert world.in_play(np.array([inside, corner])).tolist() == [True, False]
        assert not world.in_play(np.array([0.0, 0.0, -0.05]))[0]


@pytest.mark.parametrize("style", STYLES)
def test_workspace_holds_the_container_and_table_around_it(style: str) -> None:
    spec = scene_container(style, 2, _split(style))
    with SimWorld.create(has_tray=False, container=spec) as world:
        ws = np.asarray(world.workspace())
        assert ws[4] < 0.0 < spec.wall_top + 0.05 <= ws[5]
        for body in world.static_bodies[1:]:  # everything but the table
            lo, hi = (np.asarray(v) for v in pb.getAABB(body, physicsClientId=world.client))
            assert np.all(lo[:2] >= ws[[0, 2]] + WORKSPACE_MARGIN - 1e-6)
            assert np.all(hi[:2] <= ws[[1, 3]] - WORKSPACE_MARGIN + 1e-6)
            assert hi[2] <= ws[5]
        # the margin is tight: the bodies touch the box less its margin on every side (where they cover the
        # interior: a corner on the bare table has no body over its open sides)
        lo = np.min([pb.getAABB(b, physicsClientId=world.client)[0] for b in world.static_bodies[1:]], axis=0)
        hi = np.max([pb.getAABB(b, physicsClientId=world.client)[1] for b in world.static_bodies[1:]], axis=0)
        if spec.floor_height > 0 or len(spec.walls) == 4:
            assert np.allclose(lo[:2] - WORKSPACE_MARGIN, ws[[0, 2]], atol=1e-6)
            assert np.allclose(hi[:2] + WORKSPACE_MARGIN, ws[[1, 3]], atol=1e-6)


@pytest.mark.parametrize("style", ["thin_box", "corner", "shelf", "platform"])
def test_static_meshes_are_the_simulated_bodies_under_yaw(style: str) -> None:
    seed = 4 if style == "shelf" else 1  # shelf 4 has a ceiling board
    spec = scene_container(style, seed, _split(style))
    assert abs(np.sin(2 * spec.yaw)) > 0.05  # turned: an axis-aligned reading would be wrong
    with SimWorld.create(has_tray=False, container=spec) as world:
        meshes = world.static_meshes()
        assert len(meshes) == len(world.static_bodies) == len(spec.boxes()) + 1
        for k, (body, mesh) in enumerate(zip(world.static_bodies, meshes, strict=True)):
            lo, hi = (np.asarray(v) for v in pb.getAABB(body, physicsClientId=world.client))
            box = mesh.get_axis_aligned_bounding_box()
            assert np.allclose(box.get_min_bound(), lo, atol=1e-6) and np.allclose(box.get_max_bound(), hi, atol=1e-6)
            if k == 0:
                continue  # the 10 m table: its faces are far outside every ray budget
            # rays from 5 mm outside each face's triangle centres to 1 mm inside hit this body there (within
            # bullet's 1 mm ray margin), where the way in crosses no other static body (walls stand against the
            # floor slab, slabs on the table)
            tri = np.asarray(mesh.triangles)
            v = np.asarray(mesh.vertices)
            centre = v[tri].mean(axis=1)
            normal = np.asarray(mesh.triangle_normals)
            start, end = centre + 0.005 * normal, centre - 0.001 * normal
            way = start[:, None, :] - np.linspace(0.0, 0.0045, 10)[None, :, None] * normal[:, None, :]
            free = np.all(world.static_labels(way.reshape(-1, 3), tol=0.0).reshape(len(start), -1) < 0, axis=1)
            hits = pb.rayTestBatch(start[free].tolist(), end[free].tolist(), physicsClientId=world.client)
            assert len(hits) >= 2
            for (uid, _, _, where, _), expected in zip(hits, centre[free], strict=True):
                assert uid == body and np.linalg.norm(np.asarray(where) - expected) < 1e-3


def test_every_wall_and_floor_point_is_labelled_environment() -> None:
    spec = scene_container("thin_box", 0, "held_out")
    with build_scene("container", 3, seed=0, hand=HandGeometry(), container=spec) as world:
        cloud = observe(world.client, sensing_cameras("passive"), NO_NOISE, np.random.default_rng(0),
                        world.workspace())
        pts = cloud.points.astype(np.float64)
        labels = world.static_labels(pts, tol=0.002)
        scene = o3d.t.geometry.RaycastingScene()
        for _, mesh in world.object_meshes():
            scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        on_object = scene.compute_distance(o3d.core.Tensor.from_numpy(pts.astype(np.float32))).numpy() < 0.002
        names = [world.static_names[b] for b in world.static_bodies]
        # every point not on an object is on a static body, and none on an object far from one is
        assert np.all(labels[~on_object] >= 0)
        assert np.mean(labels[on_object] < 0) > 0.95
        seen = {names[i] for i in np.unique(labels[labels >= 0])}
        assert {"table", "floor"} <= seen and len([n for n in seen if n.startswith("wall")]) >= 3


def test_scene_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="container"):
        build_scene("container", 2, 0, HandGeometry())
    with pytest.raises(ValueError, match="container"):
        build_scene("pour", 2, 0, HandGeometry(), container=scene_container("tray", 0, "training"))
    with pytest.raises(ValueError, match="container"):
        Setting(scene="container")
    with pytest.raises(ValueError, match="held out"):
        Setting(scene="container", container="thin_box", container_split="training")
    with pytest.raises(ValueError, match="style"):
        scene_container("bucket", 0)


def test_a_protocol_round_runs_in_a_container() -> None:
    setting = Setting(scene="container", container="corner", num_objects=2, max_attempts=3)
    result = run_round(TopDownBaseline(), setting, seed=0)
    assert result.num_objects == 2 and 1 <= len(result.outcomes) <= 3
    assert result.end_reason
