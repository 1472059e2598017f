"""Any container, any support: the environment stage finds raised floors, walls of any height, thin
walls and two-wall corners of the container family (graspd_lab.sim.containers), no top grasp closes on or enters
them, a platform's top is the support, and no hand reaches into space no camera saw unless asked to.

Scenes are the simulator's own (pybullet, passive camera pair with the benchmark's noise, training objects),
or rendered from boxes with one camera, where the hidden part of an object is known exactly."""

from __future__ import annotations

from typing import Any

import numpy as np
import open3d as o3d
import pytest

from graspd.core.camera import sensing_cameras, tabletop_cameras
from graspd.core.hand import HandGeometry
from graspd.gpd.candidates import search_hands
from graspd.gpd.classifier import DEFAULT_CASCADE_MODEL, default_model_name, load_model
from graspd.gpd.detector import Detection, DetectionParams, GraspDetector, environment_conflicts
from graspd.gpd.environment import EnvironmentParams, Label
from graspd.gpd.occlusion import hand_samples
from graspd.gpd.selection import feasible_mask
from graspd_lab.sim.containers import ContainerSpec, sample_container
from graspd_lab.sim.sensing import observe
from graspd_lab.sim.world import SimWorld, build_scene
from graspd_lab.world.noise import DepthNoise
from graspd_lab.world.objects import TRAINING_URDFS
from graspd_lab.world.render import render_scene

HAND = HandGeometry()
OBJECTS = tuple(TRAINING_URDFS[:300])


def _container(style: str, **fixed: Any) -> ContainerSpec:
    split = "training" if style in ("tray", "deep_bin", "platform", "tote", "shelf") else "held_out"
    spec = sample_container(style, np.random.default_rng(7), split)
    return ContainerSpec(**{**spec.__dict__, **fixed})


def _scene(spec: ContainerSpec, seed: int = 3) -> tuple[SimWorld, Any]:
    world = build_scene("container", 4, seed, HAND, object_ids=OBJECTS, container=spec)
    cloud = observe(world.client, sensing_cameras("passive"), DepthNoise.benchmark(), np.random.default_rng(seed),
                    world.workspace())
    return world, cloud


def _detect(cloud: Any, workspace: Any, **options: Any) -> Detection:
    detector = GraspDetector(load_model(default_model_name()), HAND, prefilter=load_model(DEFAULT_CASCADE_MODEL))
    return detector.detect(cloud, DetectionParams(num_samples=300, workspace=workspace, **options))


def _hand_points(det: Detection, k: int = 10) -> np.ndarray:
    """World points filling the open hands (fingers, palm, 5 cm of approach path) of the top k grasps."""
    top = det.grasps[:k]
    local = hand_samples(HAND, 0.05, margin=0.0)
    return (top.positions[:, None, :] + np.einsum("mij,pj->mpi", top.rotations, local)).reshape(-1, 3)


CASES = {
    "tray, floor 1 cm up": ("tray", {"floor_height": 0.01}),
    "tray, floor 3 cm up": ("tray", {"floor_height": 0.03}),
    "deep bin": ("deep_bin", {}),
    "thin-walled box": ("thin_box", {}),
    "two-wall corner": ("corner", {}),
}


@pytest.fixture(scope="module", params=list(CASES))
def container_detection(request: pytest.FixtureRequest) -> Any:
    style, fixed = CASES[request.param]
    world, cloud = _scene(_container(style, **fixed))
    try:
        det = _detect(cloud, world.workspace())
        # what the environment stage saw: the detector's preprocessed cloud, labelled
        prep = GraspDetector(None, HAND).prepare(cloud, DetectionParams(workspace=world.workspace()), HAND)
        on_static = world.static_labels(prep.cloud.points, tol=0.004) >= 0
        hand_in_static = world.static_labels(_hand_points(det), tol=-0.002) >= 0
        samples_on_static = world.static_labels(det.grasps[:10].samples, tol=0.004) >= 0
        yield request.param, prep.environment, on_static, det, hand_in_static, samples_on_static
    finally:
        world.close()


def test_every_wall_and_floor_point_is_environment(container_detection: Any) -> None:
    name, env, on_static, _, _, _ = container_detection
    assert on_static.sum() > 1000
    labelled = env.labels[on_static] != Label.OBJECT
    assert labelled.mean() >= 0.98, f"{name}: {labelled.mean():.3f} of wall and floor points are environment"
    assert env.support is not None and any(s.kind in ("wall", "floor", "rim") for s in env.surfaces) \
        or name == "two-wall corner"


def test_no_top_grasp_closes_on_or_enters_a_wall_rim_or_floor(container_detection: Any) -> None:
    name, _, _, det, hand_in_static, samples_on_static = container_detection
    assert len(det.grasps) >= 10, f"{name}: {len(det.grasps)} grasps"
    assert not samples_on_static.any(), f"{name}: a top-10 grasp was sampled on the container"
    assert not hand_in_static.any(), f"{name}: a top-10 hand enters the container or the support"
    assert not any(w.code == "environment_unsure" for w in det.warnings), name


def test_a_platform_top_is_the_support_and_its_edge_is_not_grasped() -> None:
    world, cloud = _scene(_container("platform", floor_height=0.06))
    try:
        det = _detect(cloud, world.workspace())
        env = det.environment
        assert env is not None
        kinds = [s.kind for s in env.surfaces]
        assert kinds.count("support") == 1 and kinds.count("platform") == 1, kinds
        top = [s for s in env.surfaces if s.kind == "platform"][0]
        assert abs(-top.plane.offset / top.plane.normal[2] - 0.06) < 0.006  # the platform's top, 6 cm up
        assert len(det.grasps) >= 10
        # nothing between the fingers or in the hand is the platform (its top, its edge, its sides)
        assert not (world.static_labels(det.grasps[:10].samples, tol=0.004) >= 0).any()
        assert not (world.static_labels(_hand_points(det), tol=-0.002) >= 0).any()
    finally:
        world.close()


def _box(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float) -> o3d.geometry.TriangleMesh:
    return o3d.geometry.TriangleMesh.create_box(x1 - x0, y1 - y0, z1 - z0).translate((x0, y0, z0))


HIDDEN = (-0.07, -0.01, -0.06, 0.06, 0.0, 0.05)  # a low box behind a tall one, seen from +x: mostly hidden
TALL = (0.0, 0.03, -0.05, 0.05, 0.0, 0.16)


@pytest.fixture(scope="module")
def hidden_scene() -> Any:
    table = _box(-0.3, 0.3, -0.3, 0.3, -0.02, 0.0)
    cams = tabletop_cameras(1, distance=0.7, elevation_deg=30.0, azimuth_deg=0.0)
    return render_scene([table, _box(*HIDDEN), _box(*TALL)], cams, DepthNoise(), 0)


def _fingers_in(det: Detection, bounds: tuple[float, ...]) -> int:
    """How many grasps put a finger, the palm or the approach path into the box bounds: their outline kept the
    unseen-space check's margin (4 mm) inside its faces, on a grid 6 mm apart."""
    g = det.grasps
    local = hand_samples(HAND, 0.05)
    world = g.positions[:, None, :] + np.einsum("mij,pj->mpi", g.rotations, local)
    lo, hi = np.array(bounds[0::2]), np.array(bounds[1::2])
    return int(np.all((world > lo) & (world < hi), axis=2).any(axis=1).sum())


def test_no_grasp_puts_a_finger_into_the_hidden_part_of_an_object(hidden_scene: Any) -> None:
    params: dict[str, Any] = {"num_samples": 400, "use_classifier": False, "max_grasps": 1000, "use_selection": False}
    safe = GraspDetector(None, HAND).detect(hidden_scene, DetectionParams(**params))
    loose = GraspDetector(None, HAND).detect(hidden_scene, DetectionParams(unknown_space="allow", **params))
    assert len(safe.grasps) > 20
    assert _fingers_in(loose, HIDDEN) > 0, "the scene must tempt the unseen-space check (else it tests nothing)"
    assert _fingers_in(safe, HIDDEN) == 0
    assert np.nanmax(safe.grasps.unknown_share) == 0.0
    assert any(w.code == "unknown_space" for w in GraspDetector(None, HAND).detect(
        hidden_scene, DetectionParams(unknown_space="allow", num_samples=400, use_classifier=False)).warnings)


def test_unknown_space_allowed_reproduces_the_seen_points_only_check(hidden_scene: Any) -> None:
    """With unknown_space "allow" the candidates are exactly those of the search without the unseen-space check:
    the environment and seen-point collision checks alone."""
    p = DetectionParams(num_samples=200, use_classifier=False, unknown_space="allow")
    det = GraspDetector(None, HAND)
    prep = det.prepare(hidden_scene, p, HAND)
    allowed, _ = det.search(prep, prep.sampling, p, HAND)
    raw, region = search_hands(prep.scene, HAND, prep.sampling)
    keep = feasible_mask(raw, prep.selection.__class__(**{**prep.selection.__dict__, "min_score": None}))
    keep[keep] = ~environment_conflicts(raw[keep], region.subset(keep), prep.environment, HAND, p.approach_distance)
    assert np.array_equal(allowed.positions, raw[keep].positions)
    assert np.isnan(allowed.unknown_share).all()
    avoided, _ = det.search(prep, prep.sampling, DetectionParams(num_samples=200, use_classifier=False), HAND)
    assert 0 < len(avoided) < len(allowed)


def test_walls_the_stage_misses_are_said_not_kept_silently() -> None:
    """With wall finding switched off, the raised tray floor's edges are lined by wall points kept as objects:
    the answer warns container_as_object; with the default stage it finds the walls and warns of nothing."""
    world, cloud = _scene(_container("tray", floor_height=0.02))
    try:
        ws = world.workspace()
        blind = EnvironmentParams(wall_rounds=0, rim_min_length=10.0)
        missed = GraspDetector(None, HAND).prepare(cloud, DetectionParams(workspace=ws, environment=blind), HAND)
        found = GraspDetector(None, HAND).prepare(cloud, DetectionParams(workspace=ws), HAND)
    finally:
        world.close()
    assert [w.code for w in missed.environment.warnings] == ["container_as_object"]
    assert found.environment.warnings == () and [s.kind for s in found.environment.surfaces].count("wall") >= 3
