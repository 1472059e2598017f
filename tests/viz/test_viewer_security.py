"""The viewer as a hostile page would meet it: a strict Content-Security-Policy
(only the pages' own hashed scripts run, nothing loads from elsewhere, never framed), nosniff and no referrer; the
answer shown in a sandboxed frame (no blob URL, no same-origin); a token field, score / top-k / object filters and
the response's warnings; and, in real headless Chromium, pages that work under their own policy while script hidden
in a file name or a warning does not run."""

from __future__ import annotations

import base64
import hashlib
import html
import re
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from graspd.core.cloud import ViewpointCloud
from graspd.gpd.detector import Detection, DetectionParams, GraspDetector
from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.io.cloud_files import read_cloud
from graspd.server.app import create_app
from graspd.server.runner import serve_in_thread
from graspd.server.settings import Settings
from graspd.viz.viewer import DROP_CSP, PLOT_ID, VIEWER_CSP, VIEWER_CSP_META, drop_page_html, viewer_html

#: Script a hostile caller hides in a file name or a warning: it marks the page if it ever runs.
HOSTILE = '<img src=x onerror="document.body.dataset.pwned=1"><script>document.body.dataset.pwned=1</script>'
HOSTILE_WARNINGS = [{"code": "no_support", "message": HOSTILE}]


@pytest.fixture(scope="module")
def mug(real_data: Path) -> tuple[ViewpointCloud, Detection]:
    cloud = read_cloud(real_data / "table_mug.pcd", viewpoints=np.zeros((1, 3), np.float32))
    params = DetectionParams(num_samples=120, use_classifier=False, max_grasps=50)
    detection = GraspDetector(None).detect(cloud, params)
    shown = preprocess(cloud, PreprocessParams(voxel_size=params.voxel_size))
    assert len(detection.grasps) >= 10
    return shown, detection


@pytest.fixture
def make_settings(tmp_path: Path) -> Callable[..., Settings]:
    """Settings of a test server: no Zenoh, no models (unscored), no warm-up, data in the test's folder."""

    def make(**overrides: object) -> Settings:
        base: dict[str, object] = {"zenoh_enabled": False, "models_dir": tmp_path / "no-models", "warmup": False,
                                   "data_dir": tmp_path / "data", "allow_unscored": True, "detect_workers": 1}
        return Settings(**{**base, **overrides})  # type: ignore[arg-type]

    return make


def executable_scripts(page: str) -> list[str]:
    """The text of every inline script a browser would run (JSON data blocks are not run)."""
    return [body for attrs, body in re.findall(r"<script([^>]*)>(.*?)</script>", page, flags=re.S)
            if "application/json" not in attrs]


def sha256_source(script: str) -> str:
    return "'sha256-" + base64.b64encode(hashlib.sha256(script.encode()).digest()).decode() + "'"


def script_sources(csp: str) -> list[str]:
    directive = next(d for d in csp.split(";") if d.strip().startswith("script-src"))
    return directive.split()[1:]


def test_pages_run_only_their_own_hashed_scripts(mug: tuple[ViewpointCloud, Detection]) -> None:
    shown, detection = mug
    page = viewer_html(shown, detection, top=20, title=HOSTILE, warnings=HOSTILE_WARNINGS)
    for text, csp in ((page, VIEWER_CSP), (drop_page_html(), DROP_CSP)):
        scripts = executable_scripts(text)
        assert len(scripts) == 1 and sha256_source(scripts[0]) in script_sources(csp)
        assert all(s.startswith("'sha256-") for s in script_sources(csp)), csp  # no 'unsafe-inline', no host
        assert "default-src 'none'" in csp and "frame-ancestors 'none'" in csp and "object-src 'none'" in csp
        assert "http" not in csp and "blob:" not in csp
    assert f'content="{VIEWER_CSP_META}"' in page and "frame-ancestors" not in VIEWER_CSP_META
    assert "connect-src 'none'" in VIEWER_CSP and "connect-src 'self'" in DROP_CSP
    assert "pwned" not in "".join(executable_scripts(page)) and "<img src=x" not in page  # all escaped
    assert html.escape(HOSTILE).split("&lt;script")[0] in page


def test_the_drop_page_has_a_token_field_and_a_sandboxed_frame() -> None:
    page = drop_page_html()
    assert '<input type="password" id="token"' in page and '"Bearer " + token.value' in page
    frame = re.search(r"<iframe[^>]*>", page)
    assert frame is not None and 'sandbox="allow-scripts"' in frame.group(0)
    assert "allow-same-origin" not in page and "createObjectURL" not in page and "blob" not in page.lower()
    assert "localStorage" not in page and "sessionStorage" not in page  # the token stays in the page's memory
    assert ".srcdoc = text" in page and "textContent" in page and "innerHTML" not in page


def test_the_viewer_page_has_filters_and_warnings(mug: tuple[ViewpointCloud, Detection]) -> None:
    shown, detection = mug
    page = viewer_html(shown, detection, top=20, warnings=[{"code": "no_support", "message": "no table seen"}])
    assert '<ul id="warnings"><li><b>no_support</b>: no table seen</li></ul>' in page
    for control in ('id="min-score"', 'id="top-k"', 'id="object"', 'max="20" value="20"'):
        assert control in page
    assert re.search(r'<option value="0">object 0 \(\d+ grasps\)</option>', page)
    assert '"scores":[' in page and '"objects":[' in page


def test_viewer_routes_send_the_security_headers(make_settings: Callable[..., Settings], real_data: Path) -> None:
    token = "viewer-sec-token-77"
    settings = make_settings(token=token)
    with TestClient(create_app(settings)) as client:
        page = client.get("/viewer")
        assert page.status_code == 200
        answer = client.post("/viewer", files={"file": (HOSTILE + ".pcd", (real_data / "table_mug.pcd").read_bytes(),
                                                        "application/octet-stream")},
                             params={"num_samples": 40}, headers={"Authorization": f"Bearer {token}"})
        assert answer.status_code == 200, answer.text[:300]
        for reply, csp in ((page, DROP_CSP), (answer, VIEWER_CSP)):
            assert reply.headers["content-security-policy"] == csp
            assert reply.headers["x-content-type-options"] == "nosniff"
            assert reply.headers["x-frame-options"] == "DENY" and reply.headers["referrer-policy"] == "no-referrer"
        assert "<img src=x" not in answer.text and "pwned" not in "".join(executable_scripts(answer.text))
        assert answer.headers["x-graspd-warnings"].startswith("[")


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def run_chromium(profile: Path, *args: str) -> subprocess.CompletedProcess[str]:
    browser = chromium()
    if browser is None:
        pytest.skip("chromium is not installed (Debian: apt-get install chromium)")
    cmd = [browser, "--headless", "--no-sandbox", "--disable-dev-shm-usage", "--enable-unsafe-swiftshader",
           "--use-angle=swiftshader", "--hide-scrollbars", f"--user-data-dir={profile}", "--no-first-run",
           "--virtual-time-budget=20000", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=180)


@pytest.mark.slow
def test_chromium_runs_the_pages_under_their_policy_and_never_the_hostile_script(
        mug: tuple[ViewpointCloud, Detection], make_settings: Callable[..., Settings], tmp_path: Path) -> None:
    shown, detection = mug
    page = viewer_html(shown, detection, top=30, title=HOSTILE, warnings=HOSTILE_WARNINGS)
    # an escaping bug simulated: a raw unhashed script in the page must be stopped by the policy alone
    page = page.replace("<body>", "<body><script>document.body.dataset.pwned=1</script>", 1)
    saved = tmp_path / "view.html"
    saved.write_text(page, encoding="utf-8")
    dom = run_chromium(tmp_path / "p1", "--dump-dom", saved.resolve().as_uri()).stdout
    canvas = re.search(rf'<canvas id="{PLOT_ID}"[^>]*>', dom)
    assert canvas is not None and re.search(r'data-drawn="[0-9.]+"', canvas.group(0)), dom[:500]
    assert "data-pwned" not in dom
    assert re.search(r'<div id="shown">30 of 30 grasps shown</div>', dom)  # the filters' script ran too

    with serve_in_thread(make_settings(port=0, token="t0k3n")) as url:  # the drop page under its header policy
        dom = run_chromium(tmp_path / "p2", "--dump-dom", f"{url}/viewer").stdout
    assert 'data-ready="1"' in dom, dom[:500]

    # the answer shown as the drop page shows it: a sandboxed srcdoc frame under the drop page's policy
    framed = drop_page_html().replace(
        "<head>", f'<head><meta http-equiv="Content-Security-Policy" content="{DROP_CSP.rsplit(";", 1)[0]}">', 1)
    framed = framed.replace('referrerpolicy="no-referrer">',
                            f'referrerpolicy="no-referrer" srcdoc="{html.escape(page)}">')
    shell = tmp_path / "framed.html"
    shell.write_text(framed, encoding="utf-8")
    shot = tmp_path / "framed.png"
    run_chromium(tmp_path / "p3", "--window-size=1200,900", f"--screenshot={shot}", shell.resolve().as_uri())
    image = np.asarray(Image.open(shot).convert("RGB")).astype(np.int32)
    grippers = (image[..., 0] > 200) & (image[..., 2] < 90) & (image[..., 0] - image[..., 2] > 150)
    assert int(grippers[150:].sum()) > 300, "the sandboxed frame drew no grippers"
