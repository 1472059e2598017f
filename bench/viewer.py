"""How long headless Chromium takes to load the --view page of a 100k-point cloud with 50 grasps (target <= 2 s).

The cloud is ../shared/data/real/table_mug.pcd subsampled to 100,000 points, detected unscored without voxel
downsampling (so the environment labels every one of the 100k points, all drawn), top 50 grasps.  Measured per
run: "drawn", the page's own performance.now() when its first frame is drawn and finished (ms from navigation
start: reading the ~1.7 MB page, decoding the base64 typed arrays, the first WebGL frame in SwiftShader), "empty",
the same clock on an empty page (the browser's own floor), and "process", the whole headless Chromium run (start,
load, exit).  Needs Debian's chromium.  Usage: .venv/bin/python bench/viewer.py [--runs 3] [--points 100000]
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "service"))

from graspd.core.cloud import ViewpointCloud  # noqa: E402
from graspd.gpd.detector import DetectionParams, GraspDetector  # noqa: E402
from graspd.io.cloud_files import read_cloud  # noqa: E402
from graspd.viz.viewer import PLOT_ID, viewer_html  # noqa: E402

CLOUD = REPO.parent / "shared" / "data" / "real" / "table_mug.pcd"


def chromium_command(browser: str, profile: Path) -> list[str]:
    """Headless Chromium with software WebGL (no GPU), as tests/viz runs it."""
    return [browser, "--headless", "--no-sandbox", "--disable-dev-shm-usage", "--enable-unsafe-swiftshader",
            "--use-angle=swiftshader", f"--user-data-dir={profile}", "--no-first-run"]


def load_ms(browser: str, page: Path, profile: Path, attribute: str) -> tuple[float, float, str]:
    """(the page's own ms at which attribute was set, the Chromium process's wall seconds, the page's data-mode
    ("webgl", or "2d" when the browser gave it no WebGL) with its own timings: script start, decoding, set-up,
    first frame)."""
    t = time.perf_counter()
    dom = subprocess.run(chromium_command(browser, profile) + ["--dump-dom", page.resolve().as_uri()],
                         capture_output=True, text=True, timeout=300).stdout
    wall = time.perf_counter() - t
    found = re.search(rf'{attribute}="([0-9.]+)"', dom)
    if found is None:
        raise RuntimeError(f"{page.name}: the page never set {attribute} (not drawn)")
    mode = re.search(r'data-mode="(\w+)"', dom)
    timings = re.search(r'data-timings="([^"]*)"', dom)
    return float(found.group(1)), wall, (mode.group(1) if mode else "-") + (f" ({timings.group(1)})" if timings else "")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--grasps", type=int, default=50)
    ap.add_argument("--max-points", type=int, default=None,
                    help="points drawn (viewer_html's max_points; default: all of them)")
    args = ap.parse_args()
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        print("bench/viewer.py: chromium is not installed (Debian: apt-get install chromium)", file=sys.stderr)
        return 2
    raw = read_cloud(CLOUD, viewpoints=np.zeros((1, 3), np.float32))
    rng = np.random.default_rng(0)
    pick = np.sort(rng.choice(len(raw), min(args.points, len(raw)), replace=False))
    cloud = ViewpointCloud(points=raw.points[pick], viewpoints=raw.viewpoints)
    detection = GraspDetector(None).detect(cloud, DetectionParams(num_samples=300, use_classifier=False,
                                                                  max_grasps=args.grasps, voxel_size=0.0))
    assert detection.environment is not None and len(detection.environment.labels) == len(cloud)
    t = time.perf_counter()
    page = viewer_html(cloud, detection, top=args.grasps, max_points=args.max_points or len(cloud))
    build = time.perf_counter() - t
    with tempfile.TemporaryDirectory() as tmp:
        view, bare = Path(tmp) / "view.html", Path(tmp) / "empty.html"
        view.write_text(page, encoding="utf-8")
        bare.write_text("<html><body><script>"
                        "document.body.setAttribute('data-parsed', String(performance.now()));</script></body></html>",
                        encoding="utf-8")
        print(f"{len(cloud):,} points ({detection.environment.counts()}), {args.max_points or len(cloud):,} drawn, "
              f"{len(detection.grasps[: args.grasps])} "
              f"grasps; page {len(page) / 1e6:.1f} MB built in {build:.2f} s; id {PLOT_ID}")
        drawn, parsed, process = [], [], []
        print("| run | drawn (s after navigation) | empty page (s) | chromium process (s) | mode (page timings) |")
        print("|---|---|---|---|---|")
        for run in range(args.runs):
            ms, wall, mode = load_ms(browser, view, Path(tmp) / "profile", "data-drawn")
            js_ms, _, _ = load_ms(browser, bare, Path(tmp) / "profile", "data-parsed")
            drawn.append(ms)
            parsed.append(js_ms)
            process.append(wall)
            print(f"| {run + 1} | {ms / 1000:.2f} | {js_ms / 1000:.2f} | {wall:.2f} | {mode} |")
    d = statistics.median(drawn) / 1000
    print(f"| median | {d:.2f} | {statistics.median(parsed) / 1000:.2f} | {statistics.median(process):.2f} | |")
    print(f"target <= 2 s drawn: {'met' if d <= 2.0 else 'NOT met'}; load average {os.getloadavg()[0]:.2f} "
          f"on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
