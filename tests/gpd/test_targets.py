"""Targets on a rendered table of six objects: grasps close on the target object only, a neighbour still blocks
the hand, every kind of target that means the same object gives the same grasps, and a covering top list."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.gpd.classifier import default_model_name, load_model
from graspd.gpd.detector import Detection, DetectionParams, GraspDetector
from graspd.gpd.scene import closing_region_points
from graspd.gpd.selection import DEFAULT_MAX_PER_OBJECT, cover_order
from graspd.gpd.target import OrientedBox, Target, TargetError
from target_scene import NEIGHBOUR, NINE, SIX, OrganisedScene, finite, render_table

SAMPLES = 300


@pytest.fixture(scope="module")
def detector() -> GraspDetector:
    return GraspDetector(load_model(default_model_name()))


@pytest.fixture(scope="module")
def six() -> OrganisedScene:
    return render_table()


def _detect(detector: GraspDetector, scene: OrganisedScene, target: Target | None = None, **kw: object) -> Detection:
    cloud, _ = finite(scene)
    return detector.detect(cloud, DetectionParams(num_samples=int(kw.pop("num_samples", SAMPLES)),  # type: ignore[call-overload]
                                                  target=target, **kw))


def _rows(scene: OrganisedScene, k: int) -> Target:
    _, ids = finite(scene)
    return Target("indices", rows=ids == k)


def _between_fingers(scene: OrganisedScene, grasps: GraspSet) -> list[set[int]]:
    """The meshes whose (raw, unvoxelized) points lie in each grasp's closing region."""
    cloud, ids = finite(scene)
    region = closing_region_points(cKDTree(cloud.points), cloud.points, grasps.positions, grasps.rotations,
                                   HandGeometry())
    out: list[set[int]] = [set() for _ in range(len(grasps))]
    for g, i in zip(region.grasp.tolist(), ids[region.index].tolist(), strict=True):
        out[g].add(i)
    return out


def _hand_holds(grasps: GraspSet, points: np.ndarray, hand: HandGeometry, inset: float = 0.0) -> np.ndarray:
    """Which grasps' hands (fingers, the closing region between them and the palm behind, shrunk by inset m on
    every side) hold any of points."""
    local = np.einsum("mij,mni->mnj", grasps.rotations, points[None, :, :] - grasps.positions[:, None, :])
    inside = ((local[..., 0] >= -hand.palm_depth + inset) & (local[..., 0] <= hand.hand_depth - inset)
              & (np.abs(local[..., 1]) <= hand.hand_outer_diameter / 2 - inset)
              & (np.abs(local[..., 2]) <= hand.hand_height / 2 - inset))
    return np.asarray(inside.any(axis=1))


def test_each_objects_grasps_close_on_that_object_alone(detector: GraspDetector, six: OrganisedScene) -> None:
    for k in range(1, len(SIX) + 1):
        det = _detect(detector, six, _rows(six, k))
        assert len(det.grasps) >= 5, f"object {k}: {len(det.grasps)} grasps"
        for meshes in _between_fingers(six, det.grasps):
            assert k in meshes and not meshes - {0, k}, f"object {k}: a grasp closes on meshes {meshes}"
        assert len(set(det.grasps.object_ids.tolist())) == 1  # one scene object: the target's


def test_every_tenth_row_of_an_object_targets_that_object(detector: GraspDetector, six: OrganisedScene) -> None:
    """A sparse row list (gpd_ros CloudIndexed users often send a subsample) selects the object its rows lie on."""
    k = 2
    rows = _rows(six, k).rows
    assert rows is not None
    sparse = np.zeros_like(rows)
    sparse[np.flatnonzero(rows)[::10]] = True
    det = _detect(detector, six, Target("indices", rows=sparse))
    assert len(det.grasps) >= 5
    for meshes in _between_fingers(six, det.grasps):
        assert k in meshes and not meshes - {0, k}, meshes


def test_a_neighbour_close_enough_blocks_the_easy_grasp(detector: GraspDetector) -> None:
    alone = render_table(SIX)
    crowded = render_table((*SIX, NEIGHBOUR))
    hand = HandGeometry()
    neighbour_points = finite(crowded)[0].points[finite(crowded)[1] == len(SIX) + 1].astype(np.float64)
    free = _detect(detector, alone, _rows(alone, 2))
    blocked = _detect(detector, crowded, _rows(crowded, 2))
    would_hit = _hand_holds(free.grasps, neighbour_points, hand)
    assert would_hit[:5].any(), "the neighbour is not close enough to block any of the best grasps"
    # the detector sees 3 mm voxels (means of the points in each): a raw point may lie that much inside
    assert len(blocked.grasps) and not _hand_holds(blocked.grasps, neighbour_points, hand, inset=0.003).any()
    assert not np.allclose(blocked.grasps.positions[0], free.grasps.positions[0])


def test_indices_box_and_object_id_give_the_same_grasps(detector: GraspDetector, six: OrganisedScene) -> None:
    plain = _detect(detector, six)
    for k in (1, 4):
        centre, rotation, half = six.boxes[k - 1]
        box = Target("box", box=OrientedBox(centre, rotation, half + 0.01))
        oid = int(np.argmin([np.linalg.norm(o.centre[:2] - centre[:2]) for o in plain.objects]))
        answers = [_detect(detector, six, t) for t in (_rows(six, k), box, Target("object", object_id=oid))]
        for other in answers[1:]:
            assert np.allclose(other.grasps.positions, answers[0].grasps.positions)
            assert np.allclose(other.grasps.rotations, answers[0].grasps.rotations)
        assert set(answers[0].grasps.object_ids.tolist()) == {oid}


def test_object_ids_stay_the_same_whatever_samples_seed_or_target(detector: GraspDetector,
                                                                  six: OrganisedScene) -> None:
    runs = [_detect(detector, six), _detect(detector, six, num_samples=120, seed=7),
            _detect(detector, six, _rows(six, 3), seed=3)]
    assert len(runs[0].objects) == len(SIX)
    for det in runs[1:]:
        assert [(o.id, o.num_points) for o in det.objects] == [(o.id, o.num_points) for o in runs[0].objects]
        assert all(np.allclose(a.centre, b.centre) for a, b in zip(det.objects, runs[0].objects, strict=True))


def test_a_target_too_small_gets_no_grasp_and_a_warning(detector: GraspDetector, six: OrganisedScene) -> None:
    _, ids = finite(six)
    rows = np.zeros(len(ids), bool)
    rows[np.flatnonzero(ids == 3)[:4]] = True
    det = _detect(detector, six, Target("indices", rows=rows))
    assert len(det.grasps) == 0
    [warning] = [w for w in det.warnings if w.code == "target_too_small"]
    assert "target.indices" in warning.message and "object points" in warning.message


def test_a_target_selecting_nothing_names_its_field(detector: GraspDetector, six: OrganisedScene) -> None:
    far = OrientedBox(np.array([2.0, 2.0, 2.0]), np.eye(3), np.full(3, 0.05))
    with pytest.raises(TargetError) as err:
        _detect(detector, six, Target("box", box=far))
    assert err.value.field == "target.box"
    with pytest.raises(TargetError) as err:
        _detect(detector, six, Target("object", object_id=99))
    assert err.value.field == "target.object"
    with pytest.raises(TargetError) as err:
        _detect(detector, six, Target("points", points=np.array([[3.0, 0.0, 0.0]])))
    assert err.value.field == "target.points"


def test_sample_points_target_samples_there(detector: GraspDetector, six: OrganisedScene) -> None:
    centre = six.boxes[1][0] + np.array([0.0, 0.0, six.boxes[1][2][2]])  # the top of object 2
    det = _detect(detector, six, Target("points", points=centre[None, :]))
    assert len(det.grasps) and np.linalg.norm(det.grasps.samples - centre, axis=1).max() < 0.011


def test_the_default_top_ten_covers_the_table(detector: GraspDetector) -> None:
    nine = render_table(NINE)
    covering = _detect(detector, nine, num_samples=1000)
    ranked = _detect(detector, nine, num_samples=1000, max_per_object=0)
    graspable = {int(o) for o in ranked.grasps.object_ids if o >= 0}
    assert len(graspable) >= 8
    top = {int(o) for o in covering.grasps.object_ids[:10]}
    assert len(top) >= 4, f"the top 10 cover objects {sorted(top)}"
    assert np.allclose(covering.grasps.positions[0], ranked.grasps.positions[0])
    assert covering.max_per_object == DEFAULT_MAX_PER_OBJECT and ranked.max_per_object == 0


def test_cover_order_takes_rounds_of_each_object_best_first() -> None:
    objects = np.array([0, 0, 0, 1, 0, 2, 1, 1, -1, 0])
    assert objects[cover_order(objects, 1)].tolist() == [0, 1, 2, -1, 0, 1, 0, 1, 0, 0]
    assert objects[cover_order(objects, 2)].tolist() == [0, 0, 1, 2, 1, -1, 0, 0, 1, 0]
    assert cover_order(objects, 0).tolist() == list(range(10))
    order = cover_order(objects, 2)
    assert order[0] == 0 and sorted(order.tolist()) == list(range(10))
