"""Pictures a person can judge (PNG): what each point is, where the environment is, and the top grasps.

Three real projections of the cloud frame (metres): the view from camera 0 (perspective, degrees off its
optical axis), the top view looking down "up", and the side view looking along the table (horizontal line
of sight, height above the support).  Points are coloured by environment.Label (object, support, wall,
declared box); the support's outline and the wall / declared boxes are drawn, so a region without grasps
can be read (it is environment, or a hand there would enter it).  The top-k grippers are thin outlines,
numbered by rank and coloured by score on a colour bar.  The geometry helpers here (view_frames,
gripper_segments, box_edges, support_outline) are shared with the interactive viewer (graspd.viz.viewer).
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

from graspd.core.cloud import ViewpointCloud
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd.gpd.environment import Box, Environment, Label

#: Display name and colour of each point label (light colours for the environment, a strong one for objects).
LABEL_STYLE: dict[Label, tuple[str, str]] = {
    Label.OBJECT: ("object", "#1f4e9c"),
    Label.SUPPORT: ("support", "#d9cbb0"),
    Label.WALL: ("wall", "#8c8c8c"),
    Label.DECLARED: ("declared box", "#c39bd3"),
}
#: Outline colours of the environment's geometry.
SUPPORT_OUTLINE = "#8a6d3b"
WALL_EDGE = "#5a4a3a"
#: The box of the object a request targeted.
TARGET_EDGE = "#00a651"
DECLARED_EDGE = "#7d3c98"
#: Score colour map of the grippers: red (lowest shown) to yellow (best); no point label uses these hues.
SCORE_CMAP = "autumn"


def gripper_segments(grasps: GraspSet, hand: HandGeometry, stem: float = 0.04) -> F64:
    """Line segments (M, 4, 2, 3) drawing each open hand in the cloud frame (m): the palm bar across the finger
    roots, the two fingers (x in [0, hand_depth] of the hand frame, at the fingers' centre lines) and a stem
    of length stem (m) back along -approach."""
    half = hand.hand_outer_diameter / 2.0 - hand.finger_width / 2.0
    local = np.array([
        [[0.0, -half, 0.0], [0.0, half, 0.0]],
        [[0.0, -half, 0.0], [hand.hand_depth, -half, 0.0]],
        [[0.0, half, 0.0], [hand.hand_depth, half, 0.0]],
        [[-stem, 0.0, 0.0], [0.0, 0.0, 0.0]],
    ])
    return grasps.positions[:, None, None, :] + np.einsum("mij,abj->mabi", grasps.rotations, local)


def box_edges(box: Box) -> F64:
    """The 12 edges (12, 2, 3) of an oriented box in the cloud frame (m)."""
    signs, corners = Box.CORNER_SIGNS, box.corners()
    pairs = [(a, b) for a in range(8) for b in range(a + 1, 8) if np.sum(signs[a] != signs[b]) == 1]
    return np.stack([corners[[a, b]] for a, b in pairs])


@dataclass(frozen=True)
class ViewFrames:
    """The directions the pictures are drawn in, all unit vectors in the cloud frame.

    eye: camera 0's position (m); camera: rows [right, image up, forward] of camera 0 looking at the cloud's
    median point; up: which way is up (from gravity, the support's normal, or camera 0's image up when nothing
    says, see up_source); across, away: horizontal (perpendicular to up) directions to camera 0's right and
    away from it; base (m): height(p) = p . up + base, zero on the support plane when there is one."""

    eye: F64
    camera: F64
    up: F64
    up_source: str
    across: F64
    away: F64
    base: float

    def height(self, points: NDArray[np.floating]) -> F64:
        """Height (m) along up, zero on the support when one was found."""
        return np.asarray(np.asarray(points, np.float64) @ self.up + self.base)


def _unit(v: F64) -> F64:
    return np.asarray(v / max(float(np.linalg.norm(v)), 1e-12))


def view_frames(cloud: ViewpointCloud, environment: Environment | None = None,
                gravity: tuple[float, float, float] | None = None) -> ViewFrames:
    """Camera, top and side view directions for a cloud (see ViewFrames); up comes from the environment's up,
    else against gravity, else camera 0's image up (an optical frame's -y, or z when the camera is above)."""
    centre = np.median(cloud.points, axis=0).astype(np.float64) if len(cloud) else np.zeros(3)
    eye = cloud.viewpoints[0].astype(np.float64)
    forward = centre - eye
    if float(np.linalg.norm(forward)) < 1e-9:
        forward = np.array([0.0, 0.0, 1.0])
    forward = _unit(forward)
    up: F64 | None = None
    source = "camera"
    if environment is not None and environment.up is not None:
        up, source = _unit(np.asarray(environment.up, np.float64)), "support" if gravity is None else "gravity"
    elif gravity is not None:
        up, source = _unit(-np.asarray(gravity, np.float64)), "gravity"
    if up is not None and abs(float(forward @ up)) < 0.98:
        up_guess = up
    else:  # no up, or a camera looking straight along it
        up_guess = np.array([0.0, -1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
        if abs(forward[2]) < 0.95 and eye[2] > centre[2] + 0.1:
            up_guess = np.array([0.0, 0.0, 1.0])  # a camera above a table: world z up
        if up is not None:  # looking straight down (or up): the image up is the horizontal away direction
            up_guess = _unit(np.cross(np.cross(up, np.array([1.0, 0.0, 0.0])) if abs(up[0]) < 0.9
                                      else np.array([0.0, 1.0, 0.0]), up))
    right = _unit(np.cross(forward, up_guess))
    camera = np.stack([right, np.cross(right, forward), forward])
    if up is None:
        up = camera[1]
    across = right - (right @ up) * up
    if float(np.linalg.norm(across)) < 1e-6:
        across = np.cross(up, np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    across = _unit(across)
    away = np.cross(up, across)
    base = 0.0
    support = None if environment is None else environment.support
    if support is not None and abs(float(support.normal @ up)) > 0.5:
        base = float(support.offset * (support.normal @ up))  # the support's point -offset * normal at height 0
    return ViewFrames(eye, camera, up, source, across, away, base)


def support_outline(cloud: ViewpointCloud, environment: Environment | None, frames: ViewFrames) -> F64 | None:
    """The support's visible extent as a closed polygon (K, 3) on the support plane (cloud frame, m): the convex
    hull of the support points seen from above.  None without a support or its points."""
    if environment is None or environment.support is None or len(environment.labels) != len(cloud):
        return None
    pts = cloud.points[environment.labels == Label.SUPPORT].astype(np.float64)
    if len(pts) < 3:
        return None

    flat = np.stack([pts @ frames.across, pts @ frames.away], axis=1)
    try:
        hull = flat[ConvexHull(flat).vertices]
    except (QhullError, ValueError):
        return None
    hull = np.concatenate([hull, hull[:1]])
    plane = environment.support
    lateral = hull[:, :1] * frames.across + hull[:, 1:] * frames.away
    denom = float(plane.normal @ frames.up)
    if abs(denom) < 1e-6:
        return None
    t = -(plane.offset + lateral @ plane.normal) / denom
    return np.asarray(lateral + t[:, None] * frames.up)


def subsample_index(labels: NDArray[np.integer], max_points: int, seed: int = 0) -> NDArray[np.intp]:
    """At most max_points indices, sorted: object points first (all of them if they fit), then the environment's,
    each drawn uniformly; keeps a 100k-point cloud fast to draw without losing the object."""
    n = len(labels)
    if n <= max_points:
        return np.arange(n)
    rng = np.random.default_rng(seed)
    obj = np.flatnonzero(labels == Label.OBJECT)
    env = np.flatnonzero(labels != Label.OBJECT)
    take_obj = min(len(obj), max(max_points - len(env), max_points * 2 // 3))
    take_env = min(len(env), max_points - take_obj)
    pick = np.concatenate([rng.choice(obj, take_obj, replace=False), rng.choice(env, take_env, replace=False)])
    return np.sort(pick)


def score_colours(scores: F64) -> tuple[F64, float, float, str]:
    """(values, vmin, vmax, colour-bar label) to colour grippers by: the scores, or for unscored grasps
    (NaN) the rank reversed, so best is always the top of the colour map."""
    s = np.asarray(scores, np.float64)
    if len(s) and np.isfinite(s).all():
        lo, hi = float(s.min()), float(s.max())
        if hi - lo < 1e-6:
            lo, hi = lo - 0.5, hi + 0.5
        return s, lo, hi, "classifier score (probability of a grasp)"
    values = -np.arange(1, len(s) + 1, dtype=np.float64)
    return values, -float(max(len(s), 2)), -1.0, RANK_BAR_LABEL


#: Colour-bar label of unscored grasps, coloured by rank (the bar's ticks show the rank, 1 at the top).
RANK_BAR_LABEL = "rank (unscored grasps: 1 = best)"


def warning_lines(warnings: Sequence[Any] | None, width: int = 200) -> list[tuple[str, str]]:
    """(text, colour) lines saying a detection's warnings (graspd.core.warning.DetectionWarning or {code, message}),
    wrapped at width characters; 'warnings: none' when there are none; nothing when warnings is None (not
    known)."""
    if warnings is None:
        return []
    if not warnings:
        return [("warnings: none", "#1e7b34")]
    out: list[tuple[str, str]] = []
    for w in warnings:
        code, message = (w["code"], w["message"]) if isinstance(w, Mapping) else (w.code, w.message)
        out += [(line, "#b00020") for line in textwrap.wrap(f"warning {code}: {message}", width)]
    return out


def grasp_caption(grasps: GraspSet, k: int) -> str:
    """One line on grasp k of a ranked set: its rank, score, width and, when selection ranked it, the terms of
    its ranking key (graspd.core.grasp.RANKING_RULE)."""
    score = "  -  " if np.isnan(grasps.scores[k]) else f"{grasps.scores[k]:.3f}"
    line = f"#{k + 1:<2d} score {score} width {1000 * grasps.widths[k]:3.0f} mm"
    r = grasps.ranking
    if r is not None:
        line += (f"  key {r.key[k]:.3f} = {r.classifier[k]:.3f} x {r.utility[k]:.2f} x {r.width[k]:.2f} x "
                 f"{r.unknown[k]:.2f}")
    return line


def _project_camera(xyz: NDArray[np.floating], frames: ViewFrames) -> tuple[F64, NDArray[np.bool_]]:
    """Degrees right of / up from camera 0's optical axis (...,2), and whether each point is in front of it."""
    c = (np.asarray(xyz, np.float64) - frames.eye) @ frames.camera.T
    front = c[..., 2] > 1e-3
    z = np.maximum(c[..., 2], 1e-3)
    return np.degrees(np.arctan2(c[..., :2], z[..., None])), front


def _fmt_dir(v: F64) -> str:
    return "(" + ", ".join(f"{x:+.2f}" for x in v) + ")"


def plot_grasps(cloud: ViewpointCloud, grasps: GraspSet, hand: HandGeometry, path: str | Path,
                top: int = 10, title: str = "", gravity: tuple[float, float, float] | None = None,
                labels: NDArray[np.integer] | None = None, environment: Environment | None = None,
                max_points: int = 40_000, warnings: Sequence[Any] | None = None,
                marked: Box | None = None, marked_label: str = "target object") -> Path:
    """Write a PNG of cloud (the preprocessed cloud the environment labelled, cloud frame, m) with the top
    grasps of grasps (ranked best first).  labels (one environment.Label per point) default to environment's;
    up comes from the environment, else against gravity.  At most max_points points are drawn.  warnings: the
    detection's (warning_lines), written under the title in red, or 'warnings: none' in green; None: not shown.
    marked: a box to draw in TARGET_EDGE (the targeted object's bounds), named marked_label in the legend."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.collections import LineCollection  # noqa: PLC0415
    from matplotlib.colors import Normalize  # noqa: PLC0415
    from matplotlib.lines import Line2D  # noqa: PLC0415
    from matplotlib.ticker import FuncFormatter  # noqa: PLC0415

    path = Path(path)
    env = environment if environment is not None and len(environment.labels) == len(cloud) else None
    if labels is None or len(labels) != len(cloud):
        labels = env.labels if env is not None else np.zeros(len(cloud), np.int8)
    labels = np.asarray(labels)
    frames = view_frames(cloud, env if env is not None else environment, gravity)
    g = grasps[: max(top, 0)]
    stem = max(hand.palm_depth, 0.02)
    segs = gripper_segments(g, hand, stem=stem)
    tags = g.positions - stem * g.approach if len(g) else np.zeros((0, 3))  # rank numbers at the stem ends
    values, vmin, vmax, bar_label = score_colours(g.scores)
    cmap = plt.get_cmap(SCORE_CMAP)
    norm = Normalize(vmin, vmax)
    keep = subsample_index(labels, max_points)
    pts, lab = cloud.points[keep].astype(np.float64), labels[keep]
    outline = support_outline(cloud, env, frames)
    walls = () if env is None else env.walls
    declared = () if env is None else env.boxes

    def cam(x: NDArray[np.floating]) -> tuple[F64, NDArray[np.bool_]]:
        return _project_camera(x, frames)

    def topv(x: NDArray[np.floating]) -> tuple[F64, NDArray[np.bool_]]:
        x = np.asarray(x, np.float64)
        return np.stack([x @ frames.across, x @ frames.away], -1), np.ones(x.shape[:-1], bool)

    def side(x: NDArray[np.floating]) -> tuple[F64, NDArray[np.bool_]]:
        x = np.asarray(x, np.float64)
        return np.stack([x @ frames.away, frames.height(x)], -1), np.ones(x.shape[:-1], bool)

    height_name = "height above the support (m)" if env is not None and env.support is not None else \
        f"height along up {_fmt_dir(frames.up)} (m)"
    up_note = {"support": "up = support normal", "gravity": "up = -gravity", "camera": "up = camera 0 image up"}
    views = (
        (cam, lambda x: (np.asarray(x, np.float64) - frames.eye) @ frames.camera[2],
         f"camera 0 at {_fmt_dir(frames.eye)} m (perspective)",
         "deg right of the optical axis", "deg up from the optical axis"),
        (topv, lambda x: -frames.height(x),
         f"top view, looking down ({up_note[frames.up_source]})",
         f"across: m along {_fmt_dir(frames.across)}", f"away from camera 0: m along {_fmt_dir(frames.away)}"),
        (side, lambda x: -(np.asarray(x, np.float64) @ frames.across),
         "side view along the table (from camera 0's right)",
         f"away from camera 0: m along {_fmt_dir(frames.away)}", height_name),
    )
    fig = plt.figure(figsize=(18, 7.4), dpi=100)
    notes = warning_lines(warnings)
    grid = fig.add_gridspec(2, 4, width_ratios=[1.25, 1.0, 1.0, 0.035], height_ratios=[1.0, 0.17],
                            left=0.04, right=0.96, top=0.9 - 0.022 * max(len(notes) - 1, 0), bottom=0.04,
                            wspace=0.28, hspace=0.3)
    handles: list[Any] = []
    for col, (proj, depth, name, xlabel, ylabel) in enumerate(views):
        ax = fig.add_subplot(grid[0, col])
        uv, ok = proj(pts)
        order = np.argsort(-depth(pts))  # far first, so near points are drawn over them
        for label in (Label.SUPPORT, Label.WALL, Label.DECLARED, Label.OBJECT):
            m = order[(lab[order] == label) & ok[order]]
            if not len(m):
                continue
            text, colour = LABEL_STYLE[label]
            size = 2.2 if label == Label.OBJECT else 1.0
            h = ax.scatter(uv[m, 0], uv[m, 1], s=size, c=colour, linewidths=0, rasterized=True,
                           label=f"{text} points ({int(np.sum(labels == label)):,})")
            if col == 0:
                handles.append(h)
        if len(uv[ok]):
            lo, hi = np.percentile(uv[ok], [0.5, 99.5], axis=0)
            if len(g):  # the grippers stay in the picture
                s_uv, s_ok = proj(segs.reshape(-1, 3))
                if s_ok.any():
                    lo, hi = np.minimum(lo, s_uv[s_ok].min(axis=0)), np.maximum(hi, s_uv[s_ok].max(axis=0))
            pad = 0.06 * np.maximum(hi - lo, 1e-3)
            ax.set_xlim(lo[0] - pad[0], hi[0] + pad[0])
            ax.set_ylim(lo[1] - pad[1], hi[1] + pad[1])
        ax.autoscale(False)
        if outline is not None:
            o, ok_o = proj(outline)
            ax.plot(np.where(ok_o, o[:, 0], np.nan), o[:, 1], color=SUPPORT_OUTLINE, lw=1.0, ls="--")
        for boxes, colour, lw in ((walls, WALL_EDGE, 1.0), (declared, DECLARED_EDGE, 1.0),
                                  (() if marked is None else (marked,), TARGET_EDGE, 1.8)):
            for box in boxes:
                e, ok_e = proj(box_edges(box))
                keep_e = ok_e.all(axis=1)
                ax.add_collection(LineCollection(list(e[keep_e]), colors=colour, linewidths=lw, linestyles="-"))
        if len(g):
            s2, ok_s = proj(segs.reshape(-1, 2, 3))
            s2 = s2.reshape(len(g), 4, 2, 2)
            ok_g = np.asarray(np.asarray(ok_s).reshape(len(g), 8).all(axis=1))
            rank_order = [k for k in range(len(g) - 1, -1, -1) if ok_g[k]]  # best drawn last, on top
            lines = [seg for k in rank_order for seg in s2[k]]
            colours = [cmap(norm(values[k])) for k in rank_order for _ in range(4)]
            ax.add_collection(LineCollection(lines, colors="black", linewidths=2.1, capstyle="round"))
            ax.add_collection(LineCollection(lines, colors=colours, linewidths=1.1, capstyle="round"))
            t2, ok_t = proj(tags)
            for k in rank_order:
                if ok_t[k]:
                    ax.annotate(str(k + 1), t2[k], fontsize=7, weight="bold", ha="center", va="center",
                                color="black", bbox={"boxstyle": "round,pad=0.12", "fc": cmap(norm(values[k])),
                                                     "ec": "black", "lw": 0.4, "alpha": 0.85})
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel(xlabel, fontsize=8)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_title(name, fontsize=9)
    if len(g):
        bar = fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), cax=fig.add_subplot(grid[0, 3]))
        bar.set_label(bar_label, fontsize=8)
        bar.ax.tick_params(labelsize=7)
        if bar_label == RANK_BAR_LABEL:  # values are -rank: show the rank
            bar.ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{-v:.0f}"))
    if outline is not None:
        handles.append(Line2D([], [], color=SUPPORT_OUTLINE, lw=1.0, ls="--", label="support outline"))
    if walls:
        kinds = [f.kind for f in (() if env is None else env.surfaces) if f.box is not None and f.kind != "declared"]
        named = ", ".join(f"{kinds.count(k)} {k}{'s' if kinds.count(k) > 1 else ''}"
                          for k in ("floor", "platform", "board", "wall", "rim") if k in kinds)
        handles.append(Line2D([], [], color=WALL_EDGE, lw=1.0, label=f"environment solids: {named or len(walls)}"))
    if declared:
        handles.append(Line2D([], [], color=DECLARED_EDGE, lw=1.0, label=f"declared boxes ({len(declared)})"))
    if marked is not None:
        handles.append(Line2D([], [], color=TARGET_EDGE, lw=1.8, label=marked_label))
    colour_says = "rank" if bar_label == RANK_BAR_LABEL else "score"
    handles.append(Line2D([], [], color=cmap(1.0), lw=1.1, label=f"gripper: number = rank (1 = best),\ncolour = "
                          f"{colour_says} (bar at right)"))
    legend_ax = fig.add_subplot(grid[1, 0])
    legend_ax.axis("off")
    legend_ax.legend(handles=handles, loc="upper left", ncol=2, fontsize=8, markerscale=6, frameon=False)
    legend_ax.text(0.0, -0.02, "Grasps are sampled on object points only; a hand, and its approach path, may not enter "
                   "the support or a wall / declared box:\nregions of environment points, or too close to them, get "
                   "no grasps.", fontsize=7.5, transform=legend_ax.transAxes, va="top", color="#333333")
    table_ax = fig.add_subplot(grid[1, 1:])
    table_ax.axis("off")
    rows = [grasp_caption(g, k) for k in range(min(len(g), 12))]
    per_col = 6 if g.ranking is not None else 4  # the longer lines of ranked grasps: two columns
    cols = [rows[i : i + per_col] for i in range(0, len(rows), per_col)]
    for c, chunk in enumerate(cols):
        table_ax.text(c / len(cols), 1.0, "\n".join(chunk), fontsize=7, va="top", family="monospace",
                      transform=table_ax.transAxes)
    if g.ranking is not None:
        table_ax.text(0.0, -0.05, "key = classifier x utility J(h) x width preference x share of the hand seen: "
                      "the grasps are numbered by key, so a lower score can rank higher", fontsize=7, va="top",
                      transform=table_ax.transAxes, color="#333333")
    fig.suptitle(title or f"top {len(g)} grasps", fontsize=10)
    for k, (text, colour) in enumerate(notes):
        fig.text(0.5, 0.945 - 0.022 * k, text, ha="center", va="top", fontsize=8, color=colour)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
