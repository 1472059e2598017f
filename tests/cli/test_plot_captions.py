"""Pictures that explain themselves: the title says how many of the returned grasps are
drawn, each drawn grasp's line gives the terms of its ranking key, and the colour bar says what the colours
are (score, or rank for unscored grasps)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graspd.cli.main import _drawn
from graspd.gpd.detector import Detection, DetectionParams, GraspDetector
from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.io.cloud_files import read_cloud
from graspd.viz.plot import RANK_BAR_LABEL, grasp_caption, plot_grasps, score_colours


@pytest.fixture(scope="module")
def mug_detection(real_data: Path) -> tuple[Detection, object]:
    cloud = read_cloud(real_data / "table_mug.pcd")
    det = GraspDetector(None).detect(cloud, DetectionParams(num_samples=150, max_grasps=20))
    return det, cloud


def test_title_counts_what_is_drawn(mug_detection: tuple[Detection, object]) -> None:
    det, _ = mug_detection
    n = len(det.grasps)
    assert n > 8
    assert _drawn(8, det).startswith(f"the best 8 of the {n} grasps returned ({det.num_candidates} candidates")
    assert _drawn(500, det).startswith(f"the best {n} of the {n} grasps")


def test_each_caption_gives_the_ranking_terms(mug_detection: tuple[Detection, object]) -> None:
    det, _ = mug_detection
    g = det.grasps
    assert g.ranking is not None
    line = grasp_caption(g, 0)
    assert line.startswith("#1 ") and "score   -  " in line
    key, product = line.split("key ")[1].split(" = ")
    terms = [float(t) for t in product.split(" x ")]
    assert float(key) == pytest.approx(float(np.prod(terms)), abs=0.01)  # terms printed to 2-3 decimals
    unranked = g[:3].__class__(positions=g.positions[:3], rotations=g.rotations[:3], widths=g.widths[:3],
                               scores=g.scores[:3], samples=g.samples[:3])
    assert "key" not in grasp_caption(unranked, 0)


def test_colour_bar_label_says_score_or_rank() -> None:
    assert score_colours(np.array([0.9, 0.5]))[3].startswith("classifier score")
    values, lo, hi, label = score_colours(np.array([np.nan, np.nan, np.nan]))
    assert label == RANK_BAR_LABEL and values.tolist() == [-1.0, -2.0, -3.0] and (lo, hi) == (-3.0, -1.0)


def test_the_picture_is_written(mug_detection: tuple[Detection, object], tmp_path: Path) -> None:
    det, cloud = mug_detection
    shown = preprocess(cloud, PreprocessParams())  # type: ignore[arg-type]
    png = plot_grasps(shown, det.grasps, det.hand, tmp_path / "mug.png", top=8, title=_drawn(8, det),
                      environment=det.environment)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 50_000
