"""The interactive 3D view: one self-contained HTML page (a small hand-written WebGL viewer, no library, nothing
fetched at view time) showing the cloud coloured by environment.Label, the environment (support outline, wall and
declared boxes) and the ranked grippers as wireframes (palm and fingers), coloured by score on plot.py's colour
map, with a side list (rank, score, width) whose rows highlight their gripper.  The scene's objects (the
answer's objects: graspd.gpd.objects) are drawn as boxes of a colour each, listed with their grasps (each grasp's
object is the answer's), and one can be picked: in the service's drop page the view asks it (postMessage) to send
the cloud again with target.object (the query parameter target_object); a saved page says how to ask.  Drag
orbits, the wheel zooms, right- or shift-drag pans; it opens from camera 0 with "up" up.  Without WebGL it draws
once on a 2D canvas.  Everything is in the cloud frame, metres.  `graspd detect --view out.html` writes it; the
service's GET /viewer serves drop_page_html() and answers the dropped cloud with viewer_html().  The pages'
HTML, stylesheets and scripts are package data (graspd/viz/static/), put together here.
"""

from __future__ import annotations

import base64
import hashlib
import html
import json
import re
from collections.abc import Mapping, Sequence
from importlib.resources import files
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import ViewpointCloud
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.points import eps_clusters, voxel_downsample
from graspd.gpd.detector import Detection
from graspd.gpd.environment import Box, Label
from graspd.gpd.objects import SceneObject
from graspd.viz.plot import (
    DECLARED_EDGE,
    LABEL_STYLE,
    SUPPORT_OUTLINE,
    WALL_EDGE,
    box_edges,
    score_colours,
    subsample_index,
    support_outline,
    view_frames,
)

#: Element id of the drawing canvas; the page sets data-drawn (ms since navigation) on it once the first frame is
#: drawn (and data-mode: "webgl" or "2d").
PLOT_ID = "graspd-view"
#: How many rank numbers are written next to their grippers in the scene (all are in the side list).
LABELLED_RANKS = 20
#: The colours of the scene's objects, by id in turn (tab10 without its reds and yellows, which the grippers use).
OBJECT_COLOURS = ("#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#7f7f7f", "#3b5b92",
                  "#006d5b", "#6a3d9a")
#: Most objects listed and drawn (the rest are counted).
MAX_LISTED_OBJECTS = 100


def _b64(a: NDArray[Any], dtype: str) -> str:
    """A little-endian typed array as base64, for atob + a JS typed array."""
    return base64.b64encode(np.ascontiguousarray(a, dtype=dtype).tobytes()).decode("ascii")


def _rgb(colour: str) -> list[int]:
    """'#rrggbb' as [r, g, b] (0-255)."""
    return [int(colour[i : i + 2], 16) for i in (1, 3, 5)]


def _autumn(t: NDArray[np.floating]) -> NDArray[np.uint8]:
    """matplotlib's "autumn" (plot.SCORE_CMAP) at t in [0, 1]: red to yellow, (M, 3) uint8."""
    t = np.clip(np.nan_to_num(np.asarray(t, np.float64), nan=1.0), 0.0, 1.0)
    return np.stack([np.full_like(t, 255.0), np.round(255.0 * t), np.zeros_like(t)], -1).astype(np.uint8)


def gripper_wireframes(grasps: GraspSet, hand: HandGeometry) -> NDArray[np.float64]:
    """Edges (M, 36, 2, 3) of each open hand's left finger, right finger and palm boxes (hand.swept_boxes: x
    approach, y closing, z hand axis, origin at the hand base) in the cloud frame (m)."""
    boxes = hand.swept_boxes(0.0)  # (3, 2, 3) low / high corners
    signs = np.array([[sx, sy, sz] for sx in (0, 1) for sy in (0, 1) for sz in (0, 1)])
    pairs = [(a, b) for a in range(8) for b in range(a + 1, 8) if np.sum(signs[a] != signs[b]) == 1]
    corners = np.where(signs[None] == 0, boxes[:, None, 0], boxes[:, None, 1])  # (3, 8, 3)
    local = np.concatenate([corners[:, [a, b]] for a, b in pairs], axis=0)  # (36, 2, 3)... grouped by edge
    return grasps.positions[:, None, None, :] + np.einsum("mij,abj->mabi", grasps.rotations, local)


def grasp_objects(points: NDArray[np.floating], labels: NDArray[np.integer], samples: NDArray[np.floating],
                  voxel: float = 0.005, eps: float = 0.015, min_points: int = 20,
                  reach: float = 0.02) -> NDArray[np.int16]:
    """The object each grasp is on, for the viewer's object filter: the object points (environment label OBJECT),
    down-sampled to `voxel` (m), split into clusters by DBSCAN (neighbours within eps m; clusters of at least
    min_points voxels, numbered largest first from 0), and each grasp's sample point given the cluster of its
    nearest object voxel within reach m, else -1.  (M,) int16."""
    from scipy.spatial import cKDTree  # noqa: PLC0415

    out = np.full(len(samples), -1, np.int16)
    obj = np.asarray(points, np.float64)[np.asarray(labels) == Label.OBJECT]
    if len(obj) == 0 or len(samples) == 0:
        return out
    down = voxel_downsample(obj, voxel)
    cluster = eps_clusters(down, eps)  # DBSCAN with min_points 1
    ids, counts = np.unique(cluster[cluster >= 0], return_counts=True)
    order = ids[np.argsort(-counts, kind="stable")][counts[np.argsort(-counts, kind="stable")] >= min_points]
    order = order[:100]  # at most 100 objects in the filter
    rank = np.full(int(cluster.max()) + 1 if len(cluster) else 0, -1, np.int16)
    rank[order] = np.arange(len(order), dtype=np.int16)
    keep = cluster >= 0
    if not keep.any() or not len(order):
        return out
    dist, nearest = cKDTree(down[keep]).query(np.asarray(samples, np.float64), k=1)
    found = rank[cluster[keep][nearest]]
    return np.where(dist <= reach, found, -1).astype(np.int16)


def object_colour(object_id: int) -> str:
    """The colour ('#rrggbb') of a scene object by its id."""
    return OBJECT_COLOURS[object_id % len(OBJECT_COLOURS)]


def object_box(obj: SceneObject) -> Box:
    """The axis-aligned box of an object's points (cloud frame, m)."""
    return Box(centre=np.asarray(obj.centre, np.float64), rotation=np.eye(3),
               half_extents=np.asarray(obj.extent, np.float64) / 2)


def targeted_object(detection: Detection, object_id: int | None, targeted: bool) -> int | None:
    """The object a request's target is on, for the view and the plot to mark: the id it named (target.object),
    else, for a target of another kind (targeted), the object of the best grasp; None without either."""
    if object_id is not None:
        return int(object_id)
    ids = detection.grasps.object_ids
    return int(ids[0]) if targeted and len(ids) and ids[0] >= 0 else None


def _object_rows(objects: Sequence[SceneObject], grasp_objects_: NDArray[np.integer], picked: int | None) -> str:
    """The objects list of the panel (HTML): per object its colour, id, points and grasps shown, and a button
    that picks it (data-pick: the id); the picked one marked."""
    if not objects:
        return ""
    counts = np.bincount(np.asarray(grasp_objects_, np.int64)[np.asarray(grasp_objects_) >= 0],
                         minlength=len(objects)) if len(grasp_objects_) else np.zeros(len(objects), np.int64)
    rows = []
    for obj in objects[:MAX_LISTED_OBJECTS]:
        k = int(obj.id)
        mark = ' class="picked"' if picked == k else ""
        rows.append(f'<li data-object="{k}"{mark}><span class="dot" style="background:{object_colour(k)}"></span>'
                    f"object {k}: {int(counts[k]) if k < len(counts) else 0} grasps, {int(obj.num_points):,} "
                    f'points <button type="button" data-pick="{k}">grasp this</button></li>')
    more = len(objects) - MAX_LISTED_OBJECTS
    if more > 0:
        rows.append(f"<li>and {more} more objects</li>")
    title = "objects (target: object " + str(picked) + ")" if picked is not None else "objects"
    back = '<button type="button" data-pick="-1">all objects</button>' if picked is not None else ""
    return (f'<div id="objects"><b>{html.escape(title)}</b> {back}<ul>{"".join(rows)}</ul>'
            '<div id="ask" class="help"></div></div>')


def _scene(cloud: ViewpointCloud, detection: Detection, hand: HandGeometry | None, top: int, max_points: int,
           gravity: tuple[float, float, float] | None, picked: int | None = None
           ) -> tuple[dict[str, Any], list[str], list[str]]:
    """(the page's data: points, lines, camera; legend rows (HTML); grasp rows (HTML)) of viewer_html; the
    picked object's box drawn thicker (twice)."""
    h = hand or detection.hand
    env = detection.environment
    labelled = env is not None and len(env.labels) == len(cloud)
    labels = env.labels if env is not None and labelled else np.zeros(len(cloud), np.int8)
    frames = view_frames(cloud, env if labelled else None, gravity)
    centre = np.median(cloud.points, axis=0).astype(np.float64) if len(cloud) else np.zeros(3)
    keep = subsample_index(labels, max_points)
    pts = cloud.points[keep].astype(np.float64) - centre  # centred: float32 keeps sub-mm detail
    lab = np.asarray(labels[keep], np.uint8)
    extent = float(np.linalg.norm(np.ptp(pts, axis=0))) if len(pts) else 1.0

    segs: list[NDArray[np.float64]] = []  # (S, 2, 3) line segments, their colours and gripper ranks (-1: none)
    cols: list[NDArray[np.uint8]] = []
    ranks: list[NDArray[np.int16]] = []

    def add(s: NDArray[np.floating], rgb: NDArray[np.uint8] | list[int], rank: NDArray[np.int16] | int) -> None:
        s = np.asarray(s, np.float64).reshape(-1, 2, 3)
        segs.append(s)
        cols.append(np.broadcast_to(np.asarray(rgb, np.uint8), (len(s), 3)))
        ranks.append(np.broadcast_to(np.asarray(rank, np.int16), (len(s),)))

    legend: list[str] = []
    counts = np.bincount(np.asarray(labels, np.int64), minlength=4) if len(labels) else np.zeros(4, np.int64)
    for label in (Label.OBJECT, Label.SUPPORT, Label.WALL, Label.DECLARED):
        if counts[label]:
            name, colour = LABEL_STYLE[label]
            legend.append(f'<li><span class="dot" style="background:{colour}"></span>{name} points '
                          f'({int(counts[label]):,})</li>')
    outline = support_outline(cloud, env if labelled else None, frames)
    if outline is not None:
        add(np.stack([outline[:-1], outline[1:]], axis=1), _rgb(SUPPORT_OUTLINE), -1)
        legend.append(f'<li><span class="bar" style="border-top:2px dashed {SUPPORT_OUTLINE}"></span>'
                      "support outline</li>")
    if env is not None:
        for boxes, colour, name in ((env.walls, WALL_EDGE, "wall box"), (env.boxes, DECLARED_EDGE, "declared box")):
            if boxes:
                add(np.concatenate([box_edges(b) for b in boxes]), _rgb(colour), -1)
                legend.append(f'<li><span class="bar" style="border-top:2px solid {colour}"></span>{name}es '
                              f"({len(boxes)})</li>")
    listed = detection.objects[:MAX_LISTED_OBJECTS]
    for obj in listed:
        edges = box_edges(object_box(obj))
        add(np.concatenate([edges, edges]) if picked == obj.id else edges, _rgb(object_colour(obj.id)), -1)
    if listed:
        legend.append(f'<li><span class="bar" style="border-top:2px solid {object_colour(0)}"></span>object boxes '
                      f"({len(detection.objects)}, a colour each)</li>")
    g = detection.grasps[: max(top, 0)]
    rows: list[str] = []
    bar: dict[str, Any] = {}
    objects = np.zeros(0, np.int16)
    tags = np.zeros((0, 3))
    if len(g):
        values, vmin, vmax, bar_label = score_colours(g.scores)
        rgb = _autumn((values - vmin) / (vmax - vmin))
        wire = gripper_wireframes(g, h)  # (M, 36, 2, 3)
        order = np.arange(len(g))[::-1]  # best drawn last, on top
        add(wire[order].reshape(-1, 2, 3), np.repeat(rgb[order], wire.shape[1], axis=0),
            np.repeat(order.astype(np.int16), wire.shape[1]))
        tags = g.positions - (h.palm_depth + 0.01) * g.approach - centre  # rank numbers behind the palms
        bar = {"label": bar_label, "lo": vmin, "hi": vmax}
        objects = g.object_ids.astype(np.int16) if detection.objects else (
            grasp_objects(cloud.points, labels, g.samples) if labelled else np.full(len(g), -1, np.int16))
        for k in range(len(g)):
            score = "unscored" if np.isnan(g.scores[k]) else f"{g.scores[k]:.3f}"
            width = f"{1000 * g.widths[k]:.0f}"
            r, gg, b = (int(c) for c in rgb[k])
            oid = int(objects[k])
            on = "-" if oid < 0 else f'<span class="dot" style="background:{object_colour(oid)}"></span>{oid}'
            rows.append(f'<tr data-rank="{k}" title="#{k + 1}: score {score}, width {width} mm, object '
                        f'{"none" if oid < 0 else oid}"><td><span class="dot" style="background:rgb({r},{gg},{b})">'
                        f"</span>{k + 1}</td><td>{'-' if score == 'unscored' else score}</td><td>{width}</td>"
                        f"<td>{on}</td></tr>")
    seg = np.concatenate(segs) - centre if segs else np.zeros((0, 2, 3))
    data = {
        "n": len(pts), "points": _b64(pts, "<f4"), "labels": _b64(lab, "u1"),
        "colours": [_rgb(LABEL_STYLE[label][1]) for label in (Label.OBJECT, Label.SUPPORT, Label.WALL,
                                                                Label.DECLARED)],
        "s": len(seg), "segs": _b64(seg, "<f4"),
        "segColours": _b64(np.concatenate(cols) if cols else np.zeros((0, 3)), "u1"),
        "segRanks": _b64(np.concatenate(ranks) if ranks else np.zeros(0), "<i2"),
        "tags": np.round(tags, 5).tolist(), "labelled": LABELLED_RANKS,
        "eye": (frames.eye - centre).tolist(), "up": frames.up.tolist(), "across": frames.across.tolist(),
        "extent": max(extent, 1e-3), "bar": bar,
        "scores": [None if np.isnan(v) else round(float(v), 6) for v in g.scores],  # per rank, for the filters
        "objects": objects.tolist(),  # per rank: the object (the answer's ids; else grasp_objects) or -1
        "sceneObjects": [int(o.id) for o in listed],
    }
    return data, legend, rows


def viewer_html(cloud: ViewpointCloud, detection: Detection, hand: HandGeometry | None = None, *,
                top: int = 50, max_points: int = 150_000, title: str = "",
                gravity: tuple[float, float, float] | None = None,
                warnings: Sequence[Mapping[str, Any]] = (), picked: int | None = None) -> str:
    """One self-contained HTML page drawing cloud (the preprocessed cloud detection.environment labelled, cloud
    frame, m) coloured by label, the environment and the top ranked grasps of detection as gripper wireframes, with
    a side list of them (rank, score, width; hover or click a row to highlight its gripper).  At most max_points
    points are drawn (object points first), sent as base64 float32.  It fetches nothing: it works offline, from
    file:// or served.  warnings (each {code, message}, the response's) are listed above the grasps; the filters
    (least score, top k, object) hide grippers and rows in the page.  Its script runs under VIEWER_CSP (a meta
    tag in the page; the service also sends it as a header): every text in it is escaped, only the hashed
    script runs.  The scene's objects (detection.objects) are boxes of a colour each, listed with their grasps and
    a button that picks one (the drop page sends the cloud again with that target.object; a saved page says how
    to ask); picked: the object the request targeted, marked."""
    data, legend, rows = _scene(cloud, detection, hand, top, max_points, gravity, picked)
    n = len(detection.grasps[: max(top, 0)])
    bar = data["bar"]
    bar_html = "" if not bar else (
        f'<div class="cbar"></div><div class="ticks"><span>{bar["lo"]:.3g}</span><span>{html.escape(bar["label"])}'
        f'</span><span>{bar["hi"]:.3g}</span></div>')
    table = "" if not rows else (
        '<table id="grasps"><thead><tr><th>#</th><th>score</th><th>mm</th><th>obj</th></tr></thead><tbody>'
        + "".join(rows) + "</tbody></table>")
    notes = "".join(f'<li><b>{html.escape(str(w.get("code", "")))}</b>: {html.escape(str(w.get("message", "")))}'
                    "</li>" for w in warnings)
    ids = data["sceneObjects"] or list(range(max(data["objects"], default=-1) + 1))
    filters = "" if not n else (
        '<div id="filters"><label>least score <input id="min-score" type="number" min="0" max="1" step="0.05" '
        f'value=""></label><label>top <input id="top-k" type="number" min="1" max="{n}" value="{n}"></label>'
        '<label>object <select id="object"><option value="-1">all</option>'
        + "".join(f'<option value="{k}">object {k} ({data["objects"].count(k)} grasps)</option>' for k in ids)
        + '</select></label><div id="shown"></div></div>')
    parts = {
        "CSP": VIEWER_CSP_META,
        "WARNINGS": f'<ul id="warnings">{notes}</ul>' if notes else "",
        "FILTERS": filters,
        "OBJECTS": _object_rows(detection.objects, np.asarray(data["objects"], np.int64), picked),
        "TITLE": html.escape(title or f"{len(detection.grasps)} grasps"),
        "ID": PLOT_ID,
        "LEGEND": "".join(legend)
        + ('<li><span class="bar" style="border-top:2px solid #ff8000"></span>gripper (colour = score)</li>'
           if n else ""),
        "BAR": bar_html,
        "TABLE": table,
        "DATA": json.dumps(data, separators=(",", ":")).replace("</", "<\\/"),
    }
    return re.sub(r"@@(\w+)@@", lambda m: parts[m.group(1)], _PAGE)


def script_hash(script: str) -> str:
    """The CSP source of an inline script: 'sha256-<base64 of the SHA-256 of its UTF-8 text>'."""
    return "'sha256-" + base64.b64encode(hashlib.sha256(script.encode("utf-8")).digest()).decode("ascii") + "'"


def content_security_policy(*scripts: str, connect: bool = False, frame: bool = True) -> str:
    """A strict policy: nothing loads from anywhere, only the given inline scripts run (by hash), styles inline
    (the pages' style attributes; no script), images from data: only, no plugins, no base or form targets,
    fetch to this origin only when connect, and (as a header; a meta tag cannot) never framed by anyone."""
    fetches = "'self'" if connect else "'none'"
    parts = ["default-src 'none'", f"script-src {' '.join(script_hash(x) for x in scripts)}",
             "style-src 'unsafe-inline'", "img-src data:", "object-src 'none'", "base-uri 'none'",
             "form-action 'none'", f"connect-src {fetches}"]
    if frame:
        parts.append("frame-ancestors 'none'")
    return "; ".join(parts)


def _page(name: str) -> str:
    """The page template static/<name>.html (package data) with its stylesheet and script (static/<name>.css,
    static/<name>.js) put inline: the page stays one self-contained file, whose policy runs its inline script only
    (by hash)."""
    static = files("graspd.viz").joinpath("static")
    text = static.joinpath(f"{name}.html").read_text(encoding="utf-8")
    return (text.replace("@@STYLE@@", static.joinpath(f"{name}.css").read_text(encoding="utf-8"))
            .replace("@@SCRIPT@@", static.joinpath(f"{name}.js").read_text(encoding="utf-8")))


#: The viewer page: @@NAME@@ marks what viewer_html fills in (@@ID@@ in its script: PLOT_ID).
_PAGE = _page("viewer")


def _inline_script(page: str) -> str:
    """The text of the one executable inline <script> of a page template (what its CSP hash covers)."""
    start = page.index("<script>\n") + len("<script>")
    return page[start:page.index("</script>", start)]


#: The viewer page's script (its hash is the only script source of its policy).
VIEWER_SCRIPT = _inline_script(_PAGE.replace("@@ID@@", PLOT_ID))
assert "@@" not in VIEWER_SCRIPT, "the viewer script must not depend on the page's data"
#: The viewer page's Content-Security-Policy: as a header (the service) and as a meta tag (saved files; a meta tag
#: cannot carry frame-ancestors).
VIEWER_CSP = content_security_policy(VIEWER_SCRIPT)
VIEWER_CSP_META = content_security_policy(VIEWER_SCRIPT, frame=False)

#: The drop page of GET /viewer: @@POST@@ marks the URL drop_page_html fills in.
_DROP_PAGE = _page("drop")
#: The drop page's script and policy: it may fetch from this origin (POST /viewer); the sandboxed frame showing the
#: answer inherits the policy, so the viewer script's hash is in it too.
DROP_SCRIPT = _inline_script(_DROP_PAGE)
DROP_CSP = content_security_policy(DROP_SCRIPT, VIEWER_SCRIPT, connect=True)


def security_headers(csp: str) -> dict[str, str]:
    """The headers of an HTML page of the service: its policy, no MIME sniffing, never framed, no referrer."""
    return {"Content-Security-Policy": csp, "X-Content-Type-Options": "nosniff", "X-Frame-Options": "DENY",
            "Referrer-Policy": "no-referrer", "Cross-Origin-Opener-Policy": "same-origin",
            "Cache-Control": "no-store"}


def drop_page_html(post_url: str = "/viewer") -> str:
    """A small page for GET /viewer: a person gives the token (kept in the page's memory only, sent as the bearer
    header) and drops (or picks) a .pcd / .ply / .npz cloud; it is POSTed as the multipart field "file" to
    post_url, and the answer (a viewer_html page) is shown in a sandboxed frame (allow-scripts only: an opaque
    origin that cannot reach this page, its token or the service), with the response's warnings listed above.
    When the view picks an object it posts {graspdTarget: id} to this page, which (only from its own frame, only
    an integer id) sends the same file again with the query parameter target_object (-1: none).
    Its only script is constant (the URL is an escaped attribute), so DROP_CSP holds its hash."""
    return _DROP_PAGE.replace("@@POST@@", html.escape(post_url, quote=True))
