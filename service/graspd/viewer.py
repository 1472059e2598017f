"""The interactive 3D view: one self-contained HTML page (plotly.js inlined from the installed plotly package,
nothing fetched at view time) showing the cloud coloured by environment.Label, the environment (support outline,
wall and declared boxes) and the ranked grippers as wireframes, coloured by score, with hover text (rank, score,
width).  Everything is drawn in the cloud frame, metres.  `graspd detect --view out.html` writes it; the service's
GET /viewer can serve drop_page_html() and answer the dropped cloud with viewer_html().
"""

from __future__ import annotations

import html
import json
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .cloud import ViewpointCloud
from .detector import Detection
from .environment import Label
from .hand import HandGeometry
from .plot import (
    DECLARED_EDGE,
    LABEL_STYLE,
    SUPPORT_OUTLINE,
    WALL_EDGE,
    box_edges,
    gripper_segments,
    score_colours,
    subsample_index,
    support_outline,
    view_frames,
)

#: The grippers' colour scale (red = lowest shown score, yellow = best), as plot.SCORE_CMAP ("autumn").
GRIPPER_COLORSCALE: list[list[Any]] = [[0.0, "rgb(255,0,0)"], [0.5, "rgb(255,128,0)"], [1.0, "rgb(255,255,0)"]]
#: Element id of the plot in the page; the page sets data-drawn (ms since navigation) on it once drawn.
PLOT_ID = "graspd-view"


def _polyline(segments: NDArray[np.floating]) -> NDArray[np.float32]:
    """Segments (S, 2, 3) as one plotly line: their end points with a NaN row after each segment (S*3, 3)."""
    s = np.asarray(segments, np.float32).reshape(-1, 2, 3)
    gap = np.full((len(s), 1, 3), np.nan, np.float32)
    return np.concatenate([s, gap], axis=1).reshape(-1, 3)


def viewer_figure(cloud: ViewpointCloud, detection: Detection, hand: HandGeometry | None = None, *,
                  top: int = 50, max_points: int = 150_000, title: str = "",
                  gravity: tuple[float, float, float] | None = None) -> Any:
    """The plotly Figure behind viewer_html (see there)."""
    import plotly.graph_objects as go

    h = hand or detection.hand
    env = detection.environment
    labelled = env is not None and len(env.labels) == len(cloud)
    labels = env.labels if env is not None and labelled else np.zeros(len(cloud), np.int8)
    frames = view_frames(cloud, env if labelled else None, gravity)
    keep = subsample_index(labels, max_points)
    pts, lab = cloud.points[keep].astype(np.float32), labels[keep]
    traces: list[Any] = []
    for label in (Label.OBJECT, Label.SUPPORT, Label.WALL, Label.DECLARED):
        m = lab == label
        if not m.any():
            continue
        name, colour = LABEL_STYLE[label]
        p = pts[m]
        traces.append(go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers", name=f"{name} ({int(m.sum()):,})",
                                   marker={"size": 2.0 if label == Label.OBJECT else 1.3, "color": colour},
                                   hoverinfo="skip"))
    outline = support_outline(cloud, env if labelled else None, frames)
    if outline is not None:
        traces.append(go.Scatter3d(x=outline[:, 0], y=outline[:, 1], z=outline[:, 2], mode="lines",
                                   name="support outline", line={"color": SUPPORT_OUTLINE, "width": 3, "dash": "dash"},
                                   hoverinfo="name"))
    if env is not None:
        for boxes, colour, name in ((env.walls, WALL_EDGE, "wall box"), (env.boxes, DECLARED_EDGE, "declared box")):
            if boxes:
                line = _polyline(np.concatenate([box_edges(b) for b in boxes]))
                traces.append(go.Scatter3d(x=line[:, 0], y=line[:, 1], z=line[:, 2], mode="lines",
                                           name=f"{name}es ({len(boxes)})", line={"color": colour, "width": 4},
                                           hoverinfo="name"))
    g = detection.grasps[: max(top, 0)]
    if len(g):
        stem = max(h.palm_depth, 0.02)
        segs = gripper_segments(g, h, stem=stem)  # (M, 4, 2, 3)
        values, vmin, vmax, bar_label = score_colours(g.scores)
        order = np.arange(len(g))[::-1]  # best drawn last
        line = _polyline(segs[order].reshape(-1, 2, 3))
        colour_by = np.repeat(values[order], 4 * 3)
        hover = [f"#{k + 1}: score {'unscored' if np.isnan(g.scores[k]) else f'{g.scores[k]:.3f}'}, "
                 f"width {1000 * g.widths[k]:.0f} mm" for k in range(len(g))]
        traces.append(go.Scatter3d(
            x=line[:, 0], y=line[:, 1], z=line[:, 2], mode="lines", name=f"top {len(g)} grippers",
            line={"color": colour_by, "colorscale": GRIPPER_COLORSCALE, "cmin": vmin, "cmax": vmax, "width": 5,
                  "showscale": True, "colorbar": {"title": {"text": bar_label}, "x": 1.0, "len": 0.75}},
            text=np.repeat(np.asarray(hover, object)[order], 4 * 3), hoverinfo="text"))
        tags = g.positions - stem * g.approach
        traces.append(go.Scatter3d(
            x=tags[:, 0], y=tags[:, 1], z=tags[:, 2], mode="markers+text", name="ranks",
            text=[str(k + 1) for k in range(len(g))], textposition="top center",
            textfont={"size": 10, "color": "#202020"},
            marker={"size": 3, "color": values, "colorscale": GRIPPER_COLORSCALE, "cmin": vmin, "cmax": vmax},
            hovertext=[f"{t}<br>approach {np.round(a, 2).tolist()}" for t, a in zip(hover, g.approach, strict=True)],
            hoverinfo="text"))
    centre = np.median(cloud.points, axis=0) if len(cloud) else np.zeros(3)
    eye_dir = frames.eye - centre
    eye_dir = eye_dir / max(float(np.linalg.norm(eye_dir)), 1e-9)
    fig = go.Figure(traces)
    fig.update_layout(
        title={"text": html.escape(title or f"{len(detection.grasps)} grasps"), "font": {"size": 14}},
        margin={"l": 0, "r": 0, "t": 40, "b": 0},
        legend={"x": 0.0, "y": 1.0, "bgcolor": "rgba(255,255,255,0.7)"},
        paper_bgcolor="white",
        scene={
            "aspectmode": "data",
            "xaxis": {"title": {"text": "x (m)"}}, "yaxis": {"title": {"text": "y (m)"}},
            "zaxis": {"title": {"text": "z (m)"}},
            # start where camera 0 stands, image up along "up"; plotly's scene is normalised, so only directions
            "camera": {"eye": dict(zip("xyz", (1.6 * eye_dir).tolist(), strict=True)),
                       "up": dict(zip("xyz", frames.up.tolist(), strict=True)),
                       "center": {"x": 0.0, "y": 0.0, "z": 0.0}},
        },
        hoverlabel={"namelength": -1},
    )
    return fig


def viewer_html(cloud: ViewpointCloud, detection: Detection, hand: HandGeometry | None = None, *,
                top: int = 50, max_points: int = 150_000, title: str = "",
                gravity: tuple[float, float, float] | None = None) -> str:
    """One self-contained HTML page (about 5 MB of inlined plotly.js plus the data) drawing cloud (the
    preprocessed cloud detection.environment labelled, cloud frame, m) coloured by label, the environment and the
    top ranked grasps of detection as gripper wireframes (hover: rank, score, width).  At most max_points points
    are drawn (object points first).  It fetches nothing: it works offline, from file:// or served."""
    fig = viewer_figure(cloud, detection, hand, top=top, max_points=max_points, title=title, gravity=gravity)
    # once drawn, say so (and when) on the plot element: the browser tests and bench/viewer.py read it
    mark = ("var el = document.getElementById('{plot_id}');"
            "el.setAttribute('data-drawn', String(performance.now()));"
            "el.setAttribute('data-traces', String(el.data.length));")
    return str(fig.to_html(include_plotlyjs=True, full_html=True, div_id=PLOT_ID, default_width="100%",
                           default_height="100vh", post_script=mark,
                           config={"displaylogo": False, "responsive": True, "scrollZoom": True}))


def drop_page_html(post_url: str = "/viewer") -> str:
    """A small page for GET /viewer: a person drops (or picks) a .pcd / .ply / .npz cloud; it is POSTed as the
    multipart field "file" to post_url, whose answer (a viewer_html page) is shown in the page.  No script is
    fetched from anywhere."""
    url_js = json.dumps(post_url).replace("</", "<\\/")  # a JS string literal that cannot close the script
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>graspd viewer</title>
<style>
body {{ font-family: sans-serif; margin: 0; display: flex; flex-direction: column; height: 100vh; }}
#drop {{ margin: 12px; padding: 18px; border: 2px dashed #888; border-radius: 8px; text-align: center; }}
#drop.over {{ background: #eef4ff; border-color: #1f4e9c; }}
#status {{ color: #444; margin: 0 12px; min-height: 1.2em; }}
iframe {{ flex: 1; border: 0; width: 100%; }}
</style></head>
<body>
<div id="drop">Drop a point cloud (.pcd, .ply, .npz) here, or <input type="file" id="pick"
 accept=".pcd,.ply,.npz"></div>
<div id="status"></div>
<iframe id="view" title="detected grasps"></iframe>
<script>
const postUrl = {url_js};
const drop = document.getElementById("drop"), status = document.getElementById("status");
async function send(file) {{
  status.textContent = "detecting grasps in " + file.name + " ...";
  const form = new FormData();
  form.append("file", file, file.name);
  try {{
    const reply = await fetch(postUrl, {{ method: "POST", body: form }});
    const text = await reply.text();
    if (!reply.ok) {{ status.textContent = "error " + reply.status + ": " + text.slice(0, 400); return; }}
    const view = document.getElementById("view");
    if (view.dataset.url) URL.revokeObjectURL(view.dataset.url);
    view.dataset.url = URL.createObjectURL(new Blob([text], {{ type: "text/html" }}));
    view.src = view.dataset.url;
    status.textContent = file.name;
  }} catch (err) {{ status.textContent = "failed: " + err; }}
}}
drop.addEventListener("dragover", e => {{ e.preventDefault(); drop.classList.add("over"); }});
drop.addEventListener("dragleave", () => drop.classList.remove("over"));
drop.addEventListener("drop", e => {{
  e.preventDefault(); drop.classList.remove("over");
  if (e.dataTransfer.files.length) send(e.dataTransfer.files[0]);
}});
document.getElementById("pick").addEventListener("change", e => {{
  if (e.target.files.length) send(e.target.files[0]);
}});
</script>
</body></html>
"""
