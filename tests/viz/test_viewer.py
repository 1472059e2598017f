"""What a person sees: the --plot PNG colours points by label and draws the environment; the --view HTML page is
self-contained, holds the ranked grasps, and draws grippers in real headless Chromium (Debian's chromium)."""

from __future__ import annotations

import re
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from graspd.cli.main import main
from graspd.core.cloud import ViewpointCloud
from graspd.gpd.detector import Detection, DetectionParams, GraspDetector
from graspd.gpd.environment import Box, EnvironmentParams, Label
from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.io.cloud_files import read_cloud
from graspd.viz.plot import LABEL_STYLE, box_edges, plot_grasps, view_frames
from graspd.viz.viewer import PLOT_ID, drop_page_html, viewer_html

#: A declared box over the table's left part, away from the mug (camera frame of table_mug.pcd, m).
DECLARED = (-0.20, -0.10, -0.05, 0.20, 0.65, 1.00)


@pytest.fixture(scope="module")
def mug(real_data: Path) -> tuple[ViewpointCloud, Detection]:
    """table_mug.pcd (camera at the origin) through the unscored pipeline with a declared box: the preprocessed
    cloud the environment labelled, and the detection."""
    cloud = read_cloud(real_data / "table_mug.pcd", viewpoints=np.zeros((1, 3), np.float32))
    params = DetectionParams(num_samples=120, use_classifier=False, max_grasps=50,
                             environment=EnvironmentParams(boxes=(Box.from_bounds(DECLARED),)))
    detection = GraspDetector(None).detect(cloud, params)
    shown = preprocess(cloud, PreprocessParams(voxel_size=params.voxel_size))
    assert detection.environment is not None and len(detection.environment.labels) == len(shown)
    assert len(detection.grasps) >= 10
    return shown, detection


def _hex_rgb(colour: str) -> np.ndarray:
    return np.array([int(colour[i : i + 2], 16) for i in (1, 3, 5)], np.int32)


def _count_near(image: np.ndarray, rgb: np.ndarray, tol: int = 10) -> int:
    return int(np.sum(np.abs(image[..., :3].astype(np.int32) - rgb).max(axis=-1) <= tol))


def _gripper_pixels(image: np.ndarray) -> np.ndarray:
    """Pixels of the score colour map (red to yellow): strong red, little blue; no point label has these."""
    rgb = image[..., :3].astype(np.int32)
    return (rgb[..., 0] > 200) & (rgb[..., 2] < 90) & (rgb[..., 0] - rgb[..., 2] > 150)


def test_the_picture_colours_points_by_label_and_draws_the_environment(mug, tmp_path: Path) -> None:
    shown, detection = mug
    env = detection.environment
    assert env is not None
    counts = env.counts()
    assert counts["object"] > 500 and counts["support"] > 5000 and counts["declared"] > 100
    png = plot_grasps(shown, detection.grasps, detection.hand, tmp_path / "p.png", top=10, title="mug",
                      environment=env)
    image = np.asarray(Image.open(png).convert("RGB"))
    for label in (Label.OBJECT, Label.SUPPORT, Label.DECLARED):
        name, colour = LABEL_STYLE[label]
        assert _count_near(image, _hex_rgb(colour)) > 100, f"no {name} points in the picture"
    assert _gripper_pixels(image).sum() > 100  # the grippers and the colour bar


def test_views_follow_the_support(mug) -> None:
    shown, detection = mug
    frames = view_frames(shown, detection.environment)
    assert frames.up_source == "support"
    # the table's points are at height ~0, the mug's above it; across, away, up are a right-handed frame
    env = detection.environment
    assert env is not None
    assert abs(float(np.median(frames.height(shown.points[env.labels == Label.SUPPORT])))) < 0.005
    assert np.percentile(frames.height(shown.points[env.labels == Label.OBJECT]), 90) > 0.05
    assert np.allclose(np.cross(frames.across, frames.away), frames.up, atol=1e-9)
    edges = box_edges(env.boxes[0])
    assert edges.shape == (12, 2, 3)
    assert np.isclose(np.linalg.norm(edges[:, 1] - edges[:, 0], axis=1).max(), 0.35)


def test_a_100k_point_picture_is_quick(mug, tmp_path: Path) -> None:
    shown, detection = mug
    reps = int(np.ceil(100_000 / len(shown)))
    big = ViewpointCloud(points=np.tile(shown.points, (reps, 1))[:100_000], viewpoints=shown.viewpoints)
    labels = np.tile(detection.environment.labels, reps)[:100_000]  # type: ignore[union-attr]
    t = time.perf_counter()
    plot_grasps(big, detection.grasps, detection.hand, tmp_path / "big.png", labels=labels)
    assert time.perf_counter() - t < 15.0  # ~2 s on an idle core; shared CI cores are slower


def test_the_page_is_self_contained_and_holds_the_grasps(mug) -> None:
    shown, detection = mug
    page = viewer_html(shown, detection, top=20, title="mug <test>")
    assert page.lstrip().lower().startswith("<!doctype html") or page.lstrip().startswith("<html")
    # no script is loaded from anywhere: every <script> is inline
    assert not re.findall(r"<script[^>]*\bsrc\s*=", page, flags=re.I)
    assert not re.findall(r"<link[^>]*href\s*=\s*[\"']https?://", page, flags=re.I)
    # a small hand-written WebGL page (no plotly.js), the points as base64 typed arrays, not JSON number lists
    assert "plotly" not in page.lower() and 'getContext("webgl"' in page and len(page) < 1_500_000
    assert f'<canvas id="{PLOT_ID}"' in page and "atob(" in page
    for k in range(20):
        assert f"#{k + 1}: score unscored, width {1000 * detection.grasps.widths[k]:.0f} mm" in page
    assert "#21:" not in page
    assert "mug &lt;test&gt;" in page  # the title is escaped
    assert "declared box" in page and "support outline" in page


def test_the_drop_page_posts_the_file() -> None:
    page = drop_page_html("/viewer")
    assert 'data-post="/viewer"' in page and 'form.append("file"' in page
    assert not re.findall(r"<script[^>]*\bsrc\s*=", page, flags=re.I)
    hostile = drop_page_html('"><script>alert(1)</script>')
    assert "<script>alert(1)" not in hostile and 'data-post="&quot;&gt;&lt;script&gt;' in hostile


def test_graspd_detect_writes_the_picture_and_the_page(real_data: Path, tmp_path: Path) -> None:
    png, page = tmp_path / "d.png", tmp_path / "d.html"
    rc = main(["detect", str(real_data / "table_mug.pcd"), "--viewpoint", "0", "0", "0", "--samples", "80",
               "--no-classifier", "--out", str(tmp_path / "d.json"), "--plot", str(png), "--view", str(page),
               "--view-top", "5"])
    assert rc == 0
    assert png.stat().st_size > 50_000
    text = page.read_text(encoding="utf-8")
    assert "#5: score unscored" in text and "#6:" not in text


def chromium() -> str | None:
    """Debian's chromium (or chromium-browser) on PATH, else None."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


def chromium_command(browser: str, profile: Path) -> list[str]:
    """Headless Chromium with software WebGL (SwiftShader): no GPU, no sandbox (root in containers)."""
    return [browser, "--headless", "--no-sandbox", "--disable-dev-shm-usage", "--enable-unsafe-swiftshader",
            "--use-angle=swiftshader", "--hide-scrollbars", f"--user-data-dir={profile}", "--no-first-run"]


def screenshot(page: Path, out: Path, profile: Path, size: tuple[int, int] = (1200, 800),
               extra: tuple[str, ...] = ()) -> np.ndarray:
    browser = chromium()
    assert browser is not None
    cmd = chromium_command(browser, profile) + [f"--window-size={size[0]},{size[1]}", "--virtual-time-budget=20000",
                                                f"--screenshot={out}", *extra, page.resolve().as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert out.exists(), proc.stderr[-2000:]
    return np.asarray(Image.open(out).convert("RGB"))


@pytest.mark.slow
def test_headless_chromium_draws_the_grippers(mug, tmp_path: Path) -> None:
    if chromium() is None:
        pytest.skip("chromium is not installed (Debian: apt-get install chromium)")
    shown, detection = mug
    with_grasps, without = tmp_path / "with.html", tmp_path / "without.html"
    with_grasps.write_text(viewer_html(shown, detection, top=50), encoding="utf-8")
    without.write_text(viewer_html(shown, detection, top=0), encoding="utf-8")
    shot = screenshot(with_grasps, tmp_path / "with.png", tmp_path / "profile")
    bare = screenshot(without, tmp_path / "without.png", tmp_path / "profile")
    h, w, _ = shot.shape
    scene = np.zeros((h, w), bool)
    scene[:, int(0.15 * w) : int(0.85 * w)] = True  # leave out the side panel (legend, colour bar, grasp list)
    drawn = int((_gripper_pixels(shot) & scene).sum())
    assert drawn > 500, f"only {drawn} gripper-coloured pixels in the page"
    assert int((_gripper_pixels(bare) & scene).sum()) < 50  # nothing else on the page has their colour
    # and the cloud is drawn too, in its label colours
    assert _count_near(shot, _hex_rgb(LABEL_STYLE[Label.OBJECT][1]), tol=30) > 300
    dom = subprocess.run(chromium_command(chromium() or "", tmp_path / "profile") + [
        "--dump-dom", with_grasps.resolve().as_uri()], capture_output=True, text=True, timeout=180).stdout
    canvas = re.search(rf'<canvas id="{PLOT_ID}"[^>]*>', dom)
    assert canvas is not None and re.search(r'data-drawn="[0-9.]+"', canvas.group(0))
    assert 'data-mode="webgl"' in canvas.group(0)  # SwiftShader gave the page WebGL with these flags
    # without WebGL the page draws on a 2D canvas: the grippers and the object are still there
    flat = screenshot(with_grasps, tmp_path / "flat.png", tmp_path / "profile", extra=("--disable-3d-apis",))
    assert int((_gripper_pixels(flat) & scene).sum()) > 500
    assert _count_near(flat, _hex_rgb(LABEL_STYLE[Label.OBJECT][1]), tol=30) > 300
