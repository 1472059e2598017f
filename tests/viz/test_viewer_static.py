"""The viewer's pages are package data (graspd/viz/static/: HTML, stylesheet, script), put together into one
self-contained page each: the stylesheet and script inline, whole, the policy's hash over the script file's
text, and the wheel's package-data globs carry every file."""

from __future__ import annotations

import fnmatch
import tomllib
from pathlib import Path

import graspd.viz.viewer as viewer
from graspd.viz.viewer import DROP_CSP, DROP_SCRIPT, PLOT_ID, VIEWER_CSP, VIEWER_SCRIPT, drop_page_html, script_hash

STATIC = Path(viewer.__file__).parent / "static"
REPO = Path(__file__).resolve().parents[2]


def test_each_page_holds_its_stylesheet_and_script_inline() -> None:
    for name, script in (("viewer", VIEWER_SCRIPT), ("drop", DROP_SCRIPT)):
        css = (STATIC / f"{name}.css").read_text(encoding="utf-8")
        js = (STATIC / f"{name}.js").read_text(encoding="utf-8")
        assert len(css) > 200 and len(js) > 1000
        assert script == "\n" + js.replace("@@ID@@", PLOT_ID)  # what the policy's hash covers
    page = drop_page_html("/viewer")
    assert (STATIC / "drop.css").read_text(encoding="utf-8") in page and "@@" not in page
    assert page.count("<script") == 1 and "<link" not in page and " src=" not in page  # nothing fetched
    assert script_hash(DROP_SCRIPT) in DROP_CSP and script_hash(VIEWER_SCRIPT) in VIEWER_CSP


def test_the_wheel_ships_every_static_file() -> None:
    globs = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["graspd"]
    shipped = sorted(p.name for p in STATIC.iterdir()
                     if any(fnmatch.fnmatch(f"viz/static/{p.name}", g) for g in globs))
    assert shipped == ["drop.css", "drop.html", "drop.js", "viewer.css", "viewer.html", "viewer.js"]
