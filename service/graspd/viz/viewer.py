"""The interactive 3D view: one self-contained HTML page (a small hand-written WebGL viewer, no library, nothing
fetched at view time) showing the cloud coloured by environment.Label, the environment (support outline, wall and
declared boxes) and the ranked grippers as wireframes (palm and fingers), coloured by score on plot.py's colour
map, with a side list (rank, score, width) whose rows highlight their gripper.  The scene's objects (the
answer's objects: graspd.gpd.objects) are drawn as boxes of a colour each, listed with their grasps (each grasp's
object is the answer's), and one can be picked: in the service's drop page the view asks it (postMessage) to send
the cloud again with target.object (the query parameter target_object); a saved page says how to ask.  Drag
orbits, the wheel zooms, right- or shift-drag pans; it opens from camera 0 with "up" up.  Without WebGL it draws
once on a 2D canvas.  Everything is in the cloud frame, metres.  `graspd detect --view out.html` writes it; the
service's GET /viewer serves drop_page_html() and answers the dropped cloud with viewer_html().
"""

from __future__ import annotations

import base64
import hashlib
import html
import json
import re
from collections.abc import Mapping, Sequence
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


_PAGE = r"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="@@CSP@@">
<meta name="referrer" content="no-referrer"><title>@@TITLE@@</title>
<style>
html, body { margin: 0; height: 100%; overflow: hidden; font: 12px sans-serif; color: #202020; background: #fff; }
body { display: flex; }
#panel { box-sizing: border-box; width: 176px; flex: none; height: 100%; overflow-y: auto; padding: 6px;
  border-right: 1px solid #ddd; background: #fafafa; }
#panel h1 { font-size: 12px; margin: 0 0 6px; overflow-wrap: anywhere; }
#panel ul { list-style: none; padding: 0; margin: 0 0 6px; font-size: 11px; }
#panel li { margin: 2px 0; }
.dot { display: inline-block; width: 9px; height: 9px; border-radius: 50%; margin-right: 4px; }
.bar { display: inline-block; width: 14px; height: 0; margin: 0 4px 3px 0; vertical-align: middle; }
.cbar { height: 8px; background: linear-gradient(to right, #ff0000, #ffff00); border: 1px solid #999; }
.ticks { display: flex; justify-content: space-between; font-size: 10px; margin-bottom: 6px; }
button { font-size: 11px; margin-bottom: 4px; }
.help { font-size: 10px; color: #666; margin-bottom: 6px; }
#grasps { border-collapse: collapse; width: 100%; font-size: 11px; }
#grasps td, #grasps th { padding: 1px 3px; text-align: right; }
#grasps td:first-child, #grasps th:first-child { text-align: left; }
#grasps tbody tr { cursor: pointer; }
#grasps tbody tr:hover, #grasps tr.on { background: #dde6f7; }
#scene { position: relative; flex: 1; min-width: 0; height: 100%; }
#scene canvas { position: absolute; left: 0; top: 0; width: 100%; height: 100%; }
#labels { pointer-events: none; }
#warnings { list-style: none; padding: 4px; margin: 0 0 6px; font-size: 11px; background: #fff4d6;
  border: 1px solid #e0b040; overflow-wrap: anywhere; }
#filters label { display: block; font-size: 11px; margin: 2px 0; }
#filters input, #filters select { width: 70px; font-size: 11px; }
#shown { font-size: 10px; color: #666; margin: 2px 0 6px; }
#objects ul { margin: 2px 0 4px; }
#objects li.picked { font-weight: bold; }
#objects button { margin: 0 0 0 2px; padding: 0 3px; }
#tip { position: absolute; display: none; pointer-events: none; background: rgba(255,255,255,0.9);
  border: 1px solid #999; padding: 2px 4px; font-size: 11px; }
</style></head>
<body>
<div id="panel"><h1>@@TITLE@@</h1>
<button id="reset" type="button">reset view</button>
<div class="help">drag: orbit; wheel: zoom; right- or shift-drag: pan</div>
@@WARNINGS@@<ul>@@LEGEND@@</ul>@@BAR@@@@OBJECTS@@@@FILTERS@@@@TABLE@@</div>
<div id="scene"><canvas id="@@ID@@"></canvas><canvas id="labels"></canvas><div id="tip"></div></div>
<script type="application/json" id="graspd-data">@@DATA@@</script>
<script>
"use strict";
(function () {
const T0 = performance.now();
const D = JSON.parse(document.getElementById("graspd-data").textContent);
function bytes(s) {
  if (Uint8Array.fromBase64) return Uint8Array.fromBase64(s).buffer;
  const b = atob(s), u = new Uint8Array(b.length);
  for (let i = 0; i < b.length; i++) u[i] = b.charCodeAt(i);
  return u.buffer;
}
const P = new Float32Array(bytes(D.points)), L = new Uint8Array(bytes(D.labels));
const S = new Float32Array(bytes(D.segs)), SC = new Uint8Array(bytes(D.segColours));
const SR = new Int16Array(bytes(D.segRanks));
const NG = D.scores.length, visible = new Uint8Array(NG).fill(1);  // ranks the filters let through
let setVisible = null;
const T1 = performance.now();
const scene = document.getElementById("scene"), over = document.getElementById("labels");
const tip = document.getElementById("tip");
let canvas = document.getElementById("@@ID@@");

// vectors and column-major 4x4 matrices
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b, s) => [a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const unit = a => { const n = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / n, a[1] / n, a[2] / n]; };
function mul(a, b) {
  const o = new Float32Array(16);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) {
    let s = 0;
    for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
    o[c * 4 + r] = s;
  }
  return o;
}

// orbit camera about a target: yaw about "up", pitch above the horizontal basis (A, B)
const U = unit(D.up), A = unit(D.across), B = cross(U, A), FOV = 40 * Math.PI / 180;
function home() {
  let d = D.eye, r = Math.hypot(d[0], d[1], d[2]);
  if (r < 1e-6) { d = add(A, U, 0.5); r = 2 * D.extent; }
  d = unit(d);
  return { t: [0, 0, 0], r: r, yaw: Math.atan2(dot(d, B), dot(d, A)),
           pitch: Math.asin(Math.max(-1, Math.min(1, dot(d, U)))) };
}
let cam = home();
function view() {
  const cp = Math.cos(cam.pitch), sp = Math.sin(cam.pitch), cy = Math.cos(cam.yaw), sy = Math.sin(cam.yaw);
  const dir = [0, 1, 2].map(i => cp * (cy * A[i] + sy * B[i]) + sp * U[i]);
  const eye = add(cam.t, dir, cam.r), z = unit(dir);
  let x = cross(U, z);
  if (Math.hypot(x[0], x[1], x[2]) < 1e-6) x = A; else x = unit(x);
  const y = cross(z, x);
  const w = canvas.width, h = canvas.height, f = 1 / Math.tan(FOV / 2);
  const n = Math.max(cam.r * 0.005, 1e-4), far = cam.r + 4 * D.extent + 1;
  const proj = new Float32Array([f * h / w, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + n) / (n - far), -1,
                                 0, 0, 2 * far * n / (n - far), 0]);
  const look = new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
                                 -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
  return { m: mul(proj, look), x: x, y: y };
}
function project(m, p) {  // pixel position (css px) and whether in front
  const cx = m[0] * p[0] + m[4] * p[1] + m[8] * p[2] + m[12], cy = m[1] * p[0] + m[5] * p[1] + m[9] * p[2] + m[13];
  const cw = m[3] * p[0] + m[7] * p[1] + m[11] * p[2] + m[15];
  return [(cx / cw * 0.5 + 0.5) * scene.clientWidth, (0.5 - cy / cw * 0.5) * scene.clientHeight, cw > 0];
}

let hl = -1, pinned = -1;
const dpr = window.devicePixelRatio || 1;
function size() {
  const w = Math.max(1, Math.round(scene.clientWidth * dpr)), h = Math.max(1, Math.round(scene.clientHeight * dpr));
  for (const c of [canvas, over]) if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
}

// WebGL: points by label, segments as screen-space quads (ranked grippers thicker when highlighted)
let gl = null;
// no multisampling: SwiftShader (headless, no GPU) takes about twice as long for the first frame with it
try { gl = canvas.getContext("webgl", { antialias: false, preserveDrawingBuffer: true }); } catch (e) { gl = null; }
const TC = performance.now();
let drawGL = null;
if (gl) {
  const prog = (vs, fs) => {
    const p = gl.createProgram();
    for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
      const s = gl.createShader(type);
      gl.shaderSource(s, src); gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
      gl.attachShader(p, s);
    }
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
    return p;
  };
  const FS = "precision mediump float; varying vec3 c; void main() { gl_FragColor = vec4(c, 1.0); }";
  const pp = prog("attribute vec3 p; attribute float l; uniform mat4 m; uniform vec3 k[4]; uniform float s;" +
    "varying vec3 c; void main() { gl_Position = m * vec4(p, 1.0); int i = int(l + 0.5);" +
    "c = i == 0 ? k[0] : i == 1 ? k[1] : i == 2 ? k[2] : k[3]; gl_PointSize = i == 0 ? 1.5 * s : s; }", FS);
  const lp = prog("attribute vec3 a; attribute vec3 b; attribute vec2 e; attribute vec3 q; attribute float r;" +
    "attribute float v; uniform mat4 m; uniform vec2 vp; uniform float h; uniform float s; varying vec3 c;" +
    "void main() { vec4 ca = m * vec4(a, 1.0), cb = m * vec4(b, 1.0); vec4 o = e.x < 0.5 ? ca : cb;" +
    "if (v < 0.5 || ca.w <= 0.0 || cb.w <= 0.0) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); c = q; return; }" +
    "vec2 d = (cb.xy / cb.w - ca.xy / ca.w) * vp; float n = length(d); d = n > 1e-6 ? d / n : vec2(1.0, 0.0);" +
    "float on = (h < -0.5 || r < -0.5) ? 1.0 : (abs(r - h) < 0.5 ? 2.0 : 0.0);" +
    "float w = s * (r < -0.5 ? 1.5 : on > 1.5 ? 4.5 : 2.2);" +
    "o.xy += vec2(-d.y, d.x) * e.y * w / vp * o.w; o.z -= (on > 1.5 ? 0.01 : 0.001) * o.w; gl_Position = o;" +
    "c = on < 0.5 ? mix(q, vec3(0.85), 0.75) : q; }", FS);
  const buf = (data, loc, n, type, norm) => {
    const bo = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, bo); gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    return () => { gl.bindBuffer(gl.ARRAY_BUFFER, bo); gl.enableVertexAttribArray(loc);
                   gl.vertexAttribPointer(loc, n, type, norm, 0, 0); };
  };
  const ptsAttr = [buf(P, gl.getAttribLocation(pp, "p"), 3, gl.FLOAT, false),
                   buf(L, gl.getAttribLocation(pp, "l"), 1, gl.UNSIGNED_BYTE, false)];
  // six vertices (two triangles) per segment: both ends, both sides
  const ns = D.s, VA = new Float32Array(ns * 18), VB = new Float32Array(ns * 18), VE = new Float32Array(ns * 12);
  const VC = new Uint8Array(ns * 18), VR = new Float32Array(ns * 6);
  const corner = [[0, -1], [0, 1], [1, 1], [0, -1], [1, 1], [1, -1]];
  for (let i = 0; i < ns; i++) for (let j = 0; j < 6; j++) {
    const v = i * 6 + j;
    for (let k = 0; k < 3; k++) {
      VA[v * 3 + k] = S[i * 6 + k]; VB[v * 3 + k] = S[i * 6 + 3 + k]; VC[v * 3 + k] = SC[i * 3 + k];
    }
    VE[v * 2] = corner[j][0]; VE[v * 2 + 1] = corner[j][1]; VR[v] = SR[i];
  }
  const segAttr = [buf(VA, gl.getAttribLocation(lp, "a"), 3, gl.FLOAT, false),
                   buf(VB, gl.getAttribLocation(lp, "b"), 3, gl.FLOAT, false),
                   buf(VE, gl.getAttribLocation(lp, "e"), 2, gl.FLOAT, false),
                   buf(VC, gl.getAttribLocation(lp, "q"), 3, gl.UNSIGNED_BYTE, true),
                   buf(VR, gl.getAttribLocation(lp, "r"), 1, gl.FLOAT, false)];
  const VV = new Float32Array(ns * 6).fill(1), vvBuf = gl.createBuffer(), vvLoc = gl.getAttribLocation(lp, "v");
  setVisible = () => {
    for (let i = 0; i < ns; i++) VV.fill(SR[i] < 0 || visible[SR[i]] ? 1 : 0, i * 6, i * 6 + 6);
    gl.bindBuffer(gl.ARRAY_BUFFER, vvBuf); gl.bufferData(gl.ARRAY_BUFFER, VV, gl.DYNAMIC_DRAW);
  };
  setVisible();
  segAttr.push(() => { gl.bindBuffer(gl.ARRAY_BUFFER, vvBuf); gl.enableVertexAttribArray(vvLoc);
                       gl.vertexAttribPointer(vvLoc, 1, gl.FLOAT, false, 0, 0); });
  const colours = new Float32Array([].concat(...D.colours).map(v => v / 255));
  drawGL = (m) => {
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(1, 1, 1, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST); gl.depthFunc(gl.LEQUAL);
    gl.useProgram(pp); ptsAttr.forEach(f => f());
    gl.uniformMatrix4fv(gl.getUniformLocation(pp, "m"), false, m);
    gl.uniform3fv(gl.getUniformLocation(pp, "k"), colours);
    gl.uniform1f(gl.getUniformLocation(pp, "s"), 2 * dpr);
    gl.drawArrays(gl.POINTS, 0, D.n);
    for (let i = 0; i < 2; i++) gl.disableVertexAttribArray(i);
    if (ns) {
      gl.useProgram(lp); segAttr.forEach(f => f());
      gl.uniformMatrix4fv(gl.getUniformLocation(lp, "m"), false, m);
      gl.uniform2f(gl.getUniformLocation(lp, "vp"), canvas.width, canvas.height);
      gl.uniform1f(gl.getUniformLocation(lp, "h"), hl);
      gl.uniform1f(gl.getUniformLocation(lp, "s"), dpr);
      gl.drawArrays(gl.TRIANGLES, 0, ns * 6);
      for (let i = 0; i < 6; i++) gl.disableVertexAttribArray(i);
    }
  };
}
const T2 = performance.now();
if (!gl) {  // no WebGL: a fresh canvas (the failed one cannot give a 2D context in every browser)
  const c2 = document.createElement("canvas");
  c2.id = canvas.id; canvas.replaceWith(c2); canvas = c2;
}

function draw2D(m) {  // the same picture without depth test: environment, then object points, then grippers
  const ctx = canvas.getContext("2d"), w = canvas.width, h = canvas.height;
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0); ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  for (const label of [1, 2, 3, 0]) {
    const k = D.colours[label], s = label === 0 ? 3 : 2;
    ctx.fillStyle = "rgb(" + k.join(",") + ")";
    for (let i = 0; i < D.n; i++) if (L[i] === label) {
      const q = project(m, [P[3 * i], P[3 * i + 1], P[3 * i + 2]]);
      if (q[2]) ctx.fillRect(q[0] - s / 2, q[1] - s / 2, s, s);
    }
  }
  for (let i = 0; i < D.s; i++) {
    const a = project(m, [S[6 * i], S[6 * i + 1], S[6 * i + 2]]);
    const b = project(m, [S[6 * i + 3], S[6 * i + 4], S[6 * i + 5]]);
    if (!a[2] || !b[2]) continue;
    const r = SR[i], dim = hl >= 0 && r >= 0 && r !== hl;
    if (r >= 0 && !visible[r]) continue;
    ctx.strokeStyle = dim ? "#e0c8c8" : "rgb(" + SC[3 * i] + "," + SC[3 * i + 1] + "," + SC[3 * i + 2] + ")";
    ctx.lineWidth = r < 0 ? 1.5 : r === hl ? 4.5 : 2.2;
    ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke();
  }
}

function frame() {
  size();
  const v = view();
  if (drawGL) drawGL(v.m); else draw2D(v.m);
  const ctx = over.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0); ctx.clearRect(0, 0, over.width, over.height);
  ctx.font = "bold 11px sans-serif"; ctx.textAlign = "center"; ctx.textBaseline = "middle";
  ctx.lineWidth = 3; ctx.strokeStyle = "#fff"; ctx.fillStyle = "#000";
  D.tags.forEach((t, k) => {  // the first ranks' numbers, or only the highlighted one's
    if (!visible[k] || (hl >= 0 ? k !== hl : k >= D.labelled)) return;
    const q = project(v.m, t);
    if (q[2]) { ctx.strokeText(String(k + 1), q[0], q[1]); ctx.fillText(String(k + 1), q[0], q[1]); }
  });
  return v;
}
let queued = false;
function redraw() { if (!queued) { queued = true; requestAnimationFrame(() => { queued = false; frame(); }); } }

// the first frame, and when it is drawn (the browser tests and bench/viewer.py read data-drawn)
frame();
if (gl) gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));  // wait for the GPU
canvas.setAttribute("data-mode", gl ? "webgl" : "2d");
const T3 = performance.now();
const ms = x => x.toFixed(0);
canvas.setAttribute("data-timings", "script start " + ms(T0) + " ms, data decoded +" + ms(T1 - T0) +
  ", context +" + ms(TC - T1) + ", set up +" + ms(T2 - TC) + ", first frame +" + ms(T3 - T2));
canvas.setAttribute("data-drawn", String(T3));

// the side list: hovering or clicking a row highlights its gripper
const rows = document.querySelectorAll("#grasps tbody tr");
function highlight(k) {
  if (k === hl) return;
  hl = k; rows.forEach(r => r.classList.toggle("on", +r.dataset.rank === k)); redraw();
}
// the filters: least score (unscored grasps hidden once it is set), the first k ranks, one object
const minIn = document.getElementById("min-score"), topIn = document.getElementById("top-k");
const objIn = document.getElementById("object"), shownEl = document.getElementById("shown");
function applyFilters() {
  const lo = minIn && minIn.value !== "" ? +minIn.value : null;
  const top = topIn && topIn.value !== "" ? Math.max(1, +topIn.value) : NG;
  const obj = objIn ? +objIn.value : -1;
  let n = 0;
  for (let k = 0; k < NG; k++) {
    const sc = D.scores[k];
    visible[k] = k < top && (lo === null || (sc !== null && sc >= lo)) && (obj < 0 || D.objects[k] === obj) ? 1 : 0;
    n += visible[k];
  }
  rows.forEach(r => { r.hidden = !visible[+r.dataset.rank]; });
  if (shownEl) shownEl.textContent = n + " of " + NG + " grasps shown";
  if (pinned >= 0 && !visible[pinned]) pinned = -1;
  if (setVisible) setVisible();
  hl = -2; highlight(pinned);
}
for (const el of [minIn, topIn]) if (el) el.addEventListener("input", applyFilters);
if (objIn) objIn.addEventListener("change", applyFilters);
rows.forEach(r => {
  const k = +r.dataset.rank;
  r.addEventListener("mouseenter", () => highlight(k));
  r.addEventListener("mouseleave", () => highlight(pinned));
  r.addEventListener("click", () => { pinned = pinned === k ? -1 : k; highlight(pinned); });
});

// orbit (drag), pan (right- or shift-drag), zoom (wheel); hovering a rank number names its grasp
let drag = null;
canvas.addEventListener("contextmenu", e => e.preventDefault());
canvas.addEventListener("pointerdown", e => {
  drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey };
  try { canvas.setPointerCapture(e.pointerId); } catch (err) { /* a synthetic pointer */ }
  tip.style.display = "none";
});
canvas.addEventListener("pointerup", () => { drag = null; });
canvas.addEventListener("pointermove", e => {
  if (drag) {
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      const v = view(), s = 2 * cam.r * Math.tan(FOV / 2) / scene.clientHeight;
      cam.t = add(add(cam.t, v.x, -dx * s), v.y, dy * s);
    } else {
      cam.yaw -= dx * 0.008;
      cam.pitch = Math.max(-1.55, Math.min(1.55, cam.pitch + dy * 0.008));
    }
    redraw(); return;
  }
  const box = canvas.getBoundingClientRect(), m = view().m;
  let best = -1, bd = 12;
  D.tags.forEach((t, k) => {
    if (!visible[k]) return;
    const q = project(m, t), d = Math.hypot(q[0] - (e.clientX - box.left), q[1] - (e.clientY - box.top));
    if (q[2] && d < bd) { bd = d; best = k; }
  });
  if (best >= 0) {
    tip.textContent = rows[best] ? rows[best].title : String(best + 1);
    tip.style.left = (e.clientX - box.left + 12) + "px"; tip.style.top = (e.clientY - box.top + 12) + "px";
    tip.style.display = "block";
  } else tip.style.display = "none";
  highlight(best >= 0 ? best : pinned);
});
canvas.addEventListener("wheel", e => {
  e.preventDefault(); cam.r *= Math.exp(Math.max(-0.5, Math.min(0.5, e.deltaY * 0.0015))); redraw();
}, { passive: false });
document.getElementById("reset").addEventListener("click", () => {
  cam = home(); pinned = -1; highlight(-1); redraw();
});
window.addEventListener("resize", redraw);
// picking an object: in the service's drop page (a frame) the page there sends the cloud again with
// target.object; a page of its own says how to ask (nothing is sent from here)
const ask = document.getElementById("ask");
document.querySelectorAll("#objects button[data-pick]").forEach(b => {
  b.addEventListener("click", () => {
    const k = parseInt(b.dataset.pick, 10);
    if (window.parent !== window) {
      window.parent.postMessage({ graspdTarget: k }, "*");
      if (ask) ask.textContent = k < 0 ? "asking again for every object ..." : "asking again for object " + k + " ...";
    } else if (ask) {
      ask.textContent = k < 0 ? "ask again without a target" :
        "ask again with target {\"object\": " + k + "} (graspd detect --target-object " + k + ")";
    }
  });
});
applyFilters();
})();
</script>
</body></html>
"""


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

_DROP_PAGE = r"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="referrer" content="no-referrer"><title>graspd viewer</title>
<style>
body { font-family: sans-serif; margin: 0; display: flex; flex-direction: column; height: 100vh; }
#bar { display: flex; flex-wrap: wrap; gap: 12px; align-items: center; margin: 12px 12px 0; }
#drop { flex: 1; min-width: 260px; padding: 18px; border: 2px dashed #888; border-radius: 8px; text-align: center; }
#drop.over { background: #eef4ff; border-color: #1f4e9c; }
#status { color: #444; margin: 6px 12px; min-height: 1.2em; overflow-wrap: anywhere; }
#warnings { margin: 0 12px; padding: 0; list-style: none; color: #7a4b00; overflow-wrap: anywhere; }
iframe { flex: 1; border: 0; width: 100%; }
</style></head>
<body data-post="@@POST@@">
<div id="bar">
<div id="drop">Drop a point cloud (.pcd, .ply, .npz) here, or <input type="file" id="pick"
 accept=".pcd,.ply,.npz"></div>
<label>token <input type="password" id="token" autocomplete="off" size="24"
 placeholder="when the server sets GRASPD_TOKEN"></label>
</div>
<div id="status"></div>
<ul id="warnings"></ul>
<iframe id="view" title="detected grasps" sandbox="allow-scripts" referrerpolicy="no-referrer"></iframe>
<script>
"use strict";
(function () {
const postUrl = document.body.dataset.post;
const drop = document.getElementById("drop"), status = document.getElementById("status");
const warnList = document.getElementById("warnings"), token = document.getElementById("token");
function say(text) { status.textContent = text; }
function showWarnings(list) {
  warnList.replaceChildren();
  for (const w of list) {
    const li = document.createElement("li");
    li.textContent = "warning " + String(w.code) + ": " + String(w.message);
    warnList.appendChild(li);
  }
}
const view = document.getElementById("view");
let lastFile = null;
async function send(file, target) {
  const picked = Number.isInteger(target) && target >= 0;
  say("detecting grasps in " + file.name + (picked ? " on object " + target : "") + " ...");
  showWarnings([]);
  lastFile = file;
  const form = new FormData();
  form.append("file", file, file.name);
  const headers = {};
  if (token.value) headers["Authorization"] = "Bearer " + token.value;
  const url = new URL(postUrl, window.location.href);
  if (picked) url.searchParams.set("target_object", String(target));
  try {
    const reply = await fetch(url.toString(), { method: "POST", body: form, headers: headers, credentials: "omit",
                                                referrerPolicy: "no-referrer" });
    const text = await reply.text();
    if (!reply.ok) {
      let why = text.slice(0, 400);
      try {
        const e = JSON.parse(text);
        why = e.error + (e.field ? " (" + e.field + ")" : "");
      } catch (err) { /* not JSON: its text */ }
      say("error " + reply.status + ": " + why);
      return;
    }
    let warnings = [];
    try { warnings = JSON.parse(reply.headers.get("X-Graspd-Warnings") || "[]"); } catch (err) { warnings = []; }
    showWarnings(Array.isArray(warnings) ? warnings : []);
    // the answer is shown in a sandboxed frame: its own opaque origin, no access to this page or the token
    view.srcdoc = text;
    say(file.name + (picked ? ": object " + target : ""));
  } catch (err) { say("failed: " + err); }
}
drop.addEventListener("dragover", e => { e.preventDefault(); drop.classList.add("over"); });
drop.addEventListener("dragleave", () => drop.classList.remove("over"));
drop.addEventListener("drop", e => {
  e.preventDefault(); drop.classList.remove("over");
  if (e.dataTransfer.files.length) send(e.dataTransfer.files[0]);
});
document.getElementById("pick").addEventListener("change", e => {
  if (e.target.files.length) send(e.target.files[0]);
});
// the view in the frame picked an object (or every object: -1): send the same file again with that target
window.addEventListener("message", e => {
  if (e.source !== view.contentWindow || !lastFile || !e.data || typeof e.data !== "object") return;
  const k = e.data.graspdTarget;
  if (!Number.isInteger(k) || k < -1 || k > 100000) return;
  send(lastFile, k);
});
document.body.setAttribute("data-ready", "1");
})();
</script>
</body></html>
"""
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
