"""With flat_objects, a packet lying flat, thinner than the hand's init_bite plus the table clearance, is grasped by
its edges: where the support plane, not a point, stops the fingertips of a hand at its top, they need reach only
SUPPORT_BITE past the sample.  Without it (the default), no hand fits such a packet, as in GPD.

Clouds are rendered from boxes (graspd_lab.world.render), so the packet's size and the table are exact."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import open3d as o3d
import pytest

from graspd.core.camera import tabletop_cameras
from graspd.core.hand import HandGeometry
from graspd.gpd.candidates import SUPPORT_BITE, search_hands
from graspd.gpd.detector import DetectionParams, GraspDetector, flat_objects_warning
from graspd_lab.world.noise import DepthNoise
from graspd_lab.world.render import render_scene

HAND = HandGeometry()
TABLE = (-0.3, 0.3, -0.3, 0.3, -0.02, 0.0)
PACKET = (-0.0225, 0.0225, -0.035, 0.035, 0.0, 0.01)  # 4.5 x 7 cm, 1 cm thick: a muesli bar's packet
BLOCK = (0.08, 0.12, -0.02, 0.02, 0.0, 0.06)  # a 4 cm block 6 cm tall beside it
CAMERAS = tabletop_cameras(2, distance=0.7, elevation_deg=50.0, azimuth_deg=-90.0)


def _box(b: tuple[float, ...]) -> o3d.geometry.TriangleMesh:
    x0, x1, y0, y1, z0, z1 = b
    return o3d.geometry.TriangleMesh.create_box(x1 - x0, y1 - y0, z1 - z0).translate((x0, y0, z0))


def _on_packet(points: np.ndarray) -> np.ndarray:
    lo, hi = np.array(PACKET[0::2]) - 0.004, np.array(PACKET[1::2]) + 0.004
    return np.all((points > lo) & (points < hi), axis=1)


@pytest.fixture(scope="module")
def packet_scene() -> Any:
    return render_scene([_box(TABLE), _box(PACKET), _box(BLOCK)], CAMERAS, DepthNoise(), 0)


def test_a_flat_packet_is_grasped_across_its_width_with_the_fingertips_above_the_table(packet_scene: Any) -> None:
    p = DetectionParams(num_samples=300, use_classifier=False, max_grasps=1000, use_selection=False, seed=0,
                        flat_objects=True)
    found = GraspDetector(None, HAND).detect(packet_scene, p)
    assert found.environment is not None and found.environment.support is not None
    grasps = found.grasps[_on_packet(found.grasps.samples)]
    assert len(grasps) >= 5
    tips = grasps.positions + HAND.hand_depth * grasps.approach  # the fingertips' middle, m
    lowest = tips[:, 2] - HAND.hand_outer_diameter / 2.0 * np.abs(grasps.binormal[:, 2]) \
        - HAND.hand_height / 2.0 * np.abs(grasps.axis[:, 2])
    clearance = found.environment.clearance
    assert (lowest >= clearance - 0.002).all(), "the hand keeps clear of the table"
    top_down = grasps.approach[:, 2] < -0.9
    assert top_down.sum() >= 3
    # from above, the fingers close across the packet's short side, with a band of its edges between them
    across = top_down & (np.abs(grasps.binormal[:, 0]) > 0.9)
    assert across.any()
    assert abs(float(np.median(grasps.widths[across])) - 0.045) < 0.01  # the 4.5 cm side, and its edges' noise
    assert np.median(tips[top_down, 2]) < PACKET[5] - SUPPORT_BITE  # the fingertips reach down its edges


def test_by_default_no_hand_fits_the_flat_packet(packet_scene: Any) -> None:
    det = GraspDetector(None, HAND)
    p = DetectionParams(num_samples=300, use_classifier=False, seed=0)
    prep = det.prepare(packet_scene, p, HAND)
    assert prep.sampling.support_bite is None
    assert det.prepare(packet_scene, replace(p, flat_objects=True), HAND).sampling.support_bite == SUPPORT_BITE
    assert SUPPORT_BITE < HAND.init_bite
    without, _ = search_hands(prep.scene, HAND, prep.sampling)
    with_bite, _ = search_hands(prep.scene, HAND, replace(prep.sampling, support_bite=SUPPORT_BITE))
    assert _on_packet(without.samples).sum() == 0
    assert _on_packet(with_bite.samples).sum() >= 5


def test_hands_low_on_a_taller_object_still_bite_init_bite_deep(packet_scene: Any) -> None:
    """The shallow bite is for the tops of flat objects only: a hand whose fingertips the table stops low on the
    block's side would hold a sliver of its edge."""
    p = DetectionParams(num_samples=400, use_classifier=False, max_grasps=1000, use_selection=False, seed=0,
                        flat_objects=True)
    found = GraspDetector(None, HAND).detect(packet_scene, p)
    lo, hi = np.array(BLOCK[0::2]) - 0.004, np.array(BLOCK[1::2]) + 0.004
    grasps = found.grasps[np.all((found.grasps.samples > lo) & (found.grasps.samples < hi), axis=1)]
    assert len(grasps) >= 20
    bite = HAND.hand_depth - np.einsum("ij,ij->i", grasps.samples - grasps.positions, grasps.approach)
    assert (bite >= HAND.init_bite - 1e-6).all()
    low = grasps.samples[:, 2] < 0.03  # hands on its lower half: the ones the table can stop
    assert low.sum() >= 3


def test_no_grasp_on_a_lone_flat_packet_says_flat_objects_would_try_it() -> None:
    alone = render_scene([_box(TABLE), _box(PACKET)], CAMERAS, DepthNoise(), 0)
    p = DetectionParams(num_samples=300, use_classifier=False, seed=0)
    default = GraspDetector(None, HAND).detect(alone, p)
    assert len(default.grasps) == 0
    flat = [w for w in default.warnings if w.code == "flat_objects"]
    assert len(flat) == 1 and "1 object(s) lie flat" in flat[0].message and "flat_objects: true" in flat[0].message
    asked = GraspDetector(None, HAND).detect(alone, replace(p, flat_objects=True))
    assert len(asked.grasps) > 0
    assert "flat_objects" not in [w.code for w in asked.warnings]


def test_a_flat_packet_beside_a_graspable_block_gets_no_flat_objects_warning(packet_scene: Any) -> None:
    det = GraspDetector(None, HAND).detect(packet_scene, DetectionParams(num_samples=300, use_classifier=False, seed=0))
    assert len(det.grasps) > 0
    assert "flat_objects" not in [w.code for w in det.warnings]


def test_a_block_standing_6_cm_tall_is_not_flat() -> None:
    """Only objects the default bite leaves no hand on are named: a block a hand fits from above is not."""
    scene = render_scene([_box(TABLE), _box(BLOCK)], CAMERAS, DepthNoise(), 0)
    prep = GraspDetector(None, HAND).prepare(scene, DetectionParams(num_samples=300, use_classifier=False), HAND)
    assert len(prep.segmentation.objects) == 1
    assert flat_objects_warning(prep, HAND) is None
