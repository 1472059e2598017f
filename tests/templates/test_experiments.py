"""The simulated experiments' pieces: the Fig. 6 curve, and one scripted demonstration then one trial."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet")  # graspd_lab.sim is the lab distribution graspd-lab

from fixtures import box_top_grasp  # noqa: E402
from graspd.core.hand import HandGeometry  # noqa: E402
from graspd.templates import TemplateDetector, TemplateLibrary, TemplateParams  # noqa: E402
from graspd_lab.sim.experiments import (  # noqa: E402
    TemplateSimDetector,
    attempt,
    last_ten,
    scripted_demonstrations,
    training_urdf,
)


def test_last_ten_is_the_success_rate_over_the_last_ten_trials() -> None:
    s = np.array([0] * 10 + [1] * 10, bool)
    curve = last_ten(s)
    assert curve[0] == 0 and curve[9] == 0 and curve[14] == 0.5 and curve[19] == 1.0
    assert np.isclose(last_ten(np.array([1, 0, 1], bool))[2], 2 / 3)


def test_held_out_objects_cannot_be_demonstrated() -> None:
    with pytest.raises(ValueError, match="object_id"):
        training_urdf(905)


@pytest.mark.slow
def test_one_scripted_demonstration_then_one_template_grasp(tmp_path) -> None:
    lib = TemplateLibrary(f"sqlite:///{tmp_path}/lib.db", hand=HandGeometry())
    taught = scripted_demonstrations(lib, [0], demos=1, log=lambda *_: None)
    assert len(taught) == 1 and lib.summary()["num_entries"] == 1
    outcome, seconds = attempt(TemplateDetector(lib, TemplateParams(keep_cloud=False)), 900, seed=1, feedback=True)
    assert outcome in {"success", "no_grasp", "collision", "empty_close", "slipped"} and seconds > 0
    if outcome != "no_grasp":
        assert lib.summary()["num_outcomes"] == 1


def test_template_detector_behind_the_sim_interface(render_box, box_pose, tmp_path) -> None:
    pose = box_pose()
    cloud = render_box(pose)
    lib = TemplateLibrary(f"sqlite:///{tmp_path}/lib.db")
    lib.add_demonstration(cloud, box_top_grasp(pose, (0.05, 0.10, 0.08)))
    sim_det = TemplateSimDetector(lib, max_grasps=5)
    grasps = sim_det.detect(cloud, (-0.3, 0.3, -0.3, 0.3, -0.05, 0.5), HandGeometry(), seed=0)
    assert 1 <= len(grasps) <= 5 and len(sim_det.last_ids) == len(grasps)
    assert lib.add_feedback(sim_det.last_ids[0], success=True).entry_id == 1
    with pytest.raises(Exception, match="hand"):
        sim_det.detect(cloud, (-0.3, 0.3, -0.3, 0.3, -0.05, 0.5), HandGeometry(hand_depth=0.05), seed=0)
