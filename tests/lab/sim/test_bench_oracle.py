"""bench/oracle.py tries a detection's top grasps in physics, executes the first that holds, and leaves the world as
it found it; the protocol's round takes a chooser's pick without changing anything else."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet as pb

from box_scene import pose_from, render_boxes, rot_z, table_box
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.gpd.classifier import load_model
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd_lab.sim.detectors import TopDownBaseline
from graspd_lab.sim.object_sets import PANDA_LIKE
from graspd_lab.sim.protocol import Setting, run_round
from graspd_lab.sim.world import SimWorld
from repo_module import load_bench


def test_the_oracle_picks_the_first_of_its_top_grasps_that_holds_and_puts_the_world_back() -> None:
    bench = load_bench("oracle")
    hand = PANDA_LIKE
    world = SimWorld.create(has_tray=False)
    with world:
        body = world._box([0.04, 0.02, 0.03], [0.05, 0.0, 0.03], mass=0.3)  # 8 x 4 x 6 cm, centre 3 cm up
        world.objects[body] = 7
        world.settle()
        before = pb.getBasePositionAndOrientation(body, physicsClientId=world.client)
        rot = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # approach -z, closing along y
        on_box = [0.05, 0.0, 0.03 + hand.hand_depth]  # fingertips 3 cm up, half the box's height
        beside = [0.05, 0.15, 0.03 + hand.hand_depth]  # 15 cm to the side: closes on nothing
        grasps = GraspSet(positions=np.array([beside, on_box]), rotations=np.stack([rot, rot]),
                          widths=np.array([0.04, 0.04]), scores=np.array([0.9, 0.8]), samples=np.zeros((2, 3)))
        records: list[dict] = []
        choose = bench.oracle_chooser(5, hand, records)
        assert choose(world, grasps, np.array([0, 1])) == 1
        truth = records[0].pop("trial_truth")
        assert records == [{"feasible": 2, "tried": 2, "held": 1, "first_held_rank": 2,
                            "trial_outcomes": ["empty_close", "success"], "trial_scores": [0.9, 0.8],
                            "trial_widths": [0.04, 0.04], "trial_from_down": [0.0, 0.0], "predicted": "success",
                            "trial_seen": [{}, {}],  # no answer to read: a chooser made without its detector
                            "trial_objects": [-1, 7]}]  # nothing near the first hand; the box's id
        # nothing near the hand beside the box; the box's 0.3 kg centre of mass lies between the fingertips
        assert truth[0] == {"mass": None}
        assert truth[1]["mass"] == 0.3
        assert all(abs(truth[1][k]) < 0.002 for k in ("com_approach", "com_binormal", "com_axis"))
        assert choose(world, grasps, np.array([0])) == 0  # none of the top held: the service's first
        assert records[-1]["first_held_rank"] is None and records[-1]["predicted"] == "empty_close"
        after = pb.getBasePositionAndOrientation(body, physicsClientId=world.client)
        assert list(world.objects) == [body]
        assert np.allclose(before[0], after[0], atol=1e-6) and np.allclose(before[1], after[1], atol=1e-6)


def test_a_round_executes_the_choosers_pick_and_draws_the_same_scene_and_noise() -> None:
    setting = Setting(scene="pour", num_objects=3, sensing="passive")
    plain = run_round(TopDownBaseline(), setting, seed=0)
    seen: list[list[int]] = []

    def first(world: SimWorld, grasps: GraspSet, ok: np.ndarray) -> int:
        seen.append(ok.tolist())
        return int(ok[0])

    chosen = run_round(TopDownBaseline(), setting, seed=0, choose=first)
    assert len(seen) == chosen.attempts >= 1
    assert chosen.outcomes == plain.outcomes and chosen.cleared == plain.cleared


def test_tried_images_are_the_images_the_detector_scored() -> None:
    bench = load_bench("oracle")
    hand = PANDA_LIKE
    box = ((0.05, 0.04, 0.08), pose_from(rot_z(0.3), [0.0, 0.0, 0.04]))
    cams = np.array([[0.5, -0.3, 0.5], [-0.4, -0.4, 0.5]])
    cloud = render_boxes([table_box(), box], cams, look_at=[0.0, 0.0, 0.03], noise=0.0005)
    workspace = (-0.2, 0.2, -0.2, 0.2, -0.02, 0.3)
    model = load_model("household15", threads=1)
    grasps = GraspDetector(model, hand).detect(cloud, DetectionParams(workspace=workspace, num_samples=100),
                                               hand=hand).grasps[:6]
    assert len(grasps) >= 3
    images = bench.tried_images(cloud, workspace, grasps, hand)
    assert images.shape == (len(grasps), 15, 60, 60) and images.dtype == np.uint8
    # the same images up to points on the closing region's edges, which the search and a fresh lookup may count apart
    assert np.allclose(model.score(images), grasps.scores, atol=0.01)
    other = bench.tried_images(cloud, workspace, grasps, HandGeometry())  # another hand: other images
    assert not np.allclose(model.score(other), grasps.scores, atol=0.01)


def test_saved_images_line_up_with_their_detections_and_perturbed_shares(tmp_path: Path) -> None:
    bench = load_bench("oracle")
    shots = [np.full((2, 15, 60, 60), 1, np.uint8), np.full((1, 15, 60, 60), 2, np.uint8)]
    detections = [{"tried": 2, "trial_outcomes": ["success", "slipped"], "trial_robust": [0.75, 0.0],
                   "trial_scores": [0.9, 0.8], "trial_objects": [4, 9], "seed": 100},
                  {"tried": 1, "trial_outcomes": ["empty_close"], "trial_robust": [0.25], "trial_scores": [0.7],
                   "seed": 101}]  # a record made before objects were recorded
    bench.save_images(tmp_path / "t.npz", shots, detections)
    d = np.load(tmp_path / "t.npz")
    assert d["images"][:, 0, 0, 0].tolist() == [1, 1, 2]
    assert d["detection"].tolist() == [0, 0, 1] and d["rank"].tolist() == [0, 1, 0]
    assert d["seed"].tolist() == [100, 100, 101] and d["held"].tolist() == [1, 0, 0]
    assert d["robust"].tolist() == [0.75, 0.0, 0.25] and d["score"].tolist() == [0.9, 0.8, 0.7]
    assert d["object"].tolist() == [4, 9, -1]
