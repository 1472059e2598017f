"""Pictures a person can judge: the cloud with the top grasps drawn as two-finger grippers (PNG)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .cloud import ViewpointCloud
from .grasp import GraspSet
from .hand import HandGeometry


def gripper_segments(grasps: GraspSet, hand: HandGeometry, stem: float = 0.04) -> NDArray[np.float64]:
    """Line segments (M, 4, 2, 3) drawing each hand: palm, two fingers, and a stem back along the approach."""
    half = hand.hand_outer_diameter / 2.0 - hand.finger_width / 2.0
    local = np.array([
        [[0.0, -half, 0.0], [0.0, half, 0.0]],
        [[0.0, -half, 0.0], [hand.hand_depth, -half, 0.0]],
        [[0.0, half, 0.0], [hand.hand_depth, half, 0.0]],
        [[-stem, 0.0, 0.0], [0.0, 0.0, 0.0]],
    ])
    return grasps.positions[:, None, None, :] + np.einsum("mij,abj->mabi", grasps.rotations, local)


def _camera_basis(cloud: ViewpointCloud) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(origin, rows right/up/forward) of a view from the first camera toward the cloud's centroid."""
    centre = np.median(cloud.points, axis=0).astype(np.float64)
    eye = cloud.viewpoints[0].astype(np.float64)
    forward = centre - eye
    forward /= max(float(np.linalg.norm(forward)), 1e-9)
    up_guess = np.array([0.0, -1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
    if abs(forward[2]) < 0.95 and cloud.viewpoints[0, 2] > centre[2] + 0.1:
        up_guess = np.array([0.0, 0.0, 1.0])  # a camera above a table: world z up
    right = np.cross(forward, up_guess)
    right /= max(float(np.linalg.norm(right)), 1e-9)
    return eye, np.stack([right, np.cross(right, forward), forward])


def _project(xyz: NDArray[np.floating], eye: NDArray[np.float64], basis: NDArray[np.float64],
             perspective: bool) -> NDArray[np.float64]:
    """Image coordinates (...,2): pinhole (normalised) when perspective, else orthographic (m)."""
    c = (np.asarray(xyz, np.float64) - eye) @ basis.T
    if not perspective:
        return c[..., :2]
    return c[..., :2] / np.maximum(c[..., 2:3], 1e-6)


def plot_grasps(cloud: ViewpointCloud, grasps: GraspSet, hand: HandGeometry, path: str | Path,
                top: int = 10, title: str = "", gravity: tuple[float, float, float] | None = None,
                labels: NDArray[np.integer] | None = None) -> Path:
    """Write a PNG: the cloud seen from its first camera and from above (along gravity when given,
    else along the camera's up axis), top grasps drawn as grippers (best thick green, then yellow to red).
    With labels (environment.Label per point), environment points are drawn light grey, objects by height."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    g = grasps[: max(top, 0)]
    segs = gripper_segments(g, hand)
    eye, cam = _camera_basis(cloud)
    if gravity is not None:
        down = np.asarray(gravity, np.float64) / max(float(np.linalg.norm(gravity)), 1e-9)
        right = cam[0] - (cam[0] @ down) * down
        right /= max(float(np.linalg.norm(right)), 1e-9)
        above = np.stack([right, np.cross(right, down), down])  # image up = away from the camera
        height = -(cloud.points @ down)
    else:
        above = np.stack([cam[0], cam[2], -cam[1]])
        height = cloud.points @ cam[1]
    rng = np.random.default_rng(0)
    keep = np.arange(len(cloud.points))
    if len(keep) > 60_000:
        keep = np.sort(rng.choice(len(keep), 60_000, replace=False))
    pts, colour_by = cloud.points[keep], height[keep]
    fig, axes = plt.subplots(1, 2, figsize=(13, 6.2), dpi=110)
    colours = plt.get_cmap("autumn")(np.linspace(0.0, 0.9, max(len(g), 1)))
    views = ((axes[0], cam, True, "seen from camera 0"),
             (axes[1], above, False, "seen from above" if gravity is not None else "seen from the side"))
    for ax, basis, persp, name in views:
        origin = eye if persp else np.zeros(3)
        uv = _project(pts, origin, basis, persp)
        order = np.argsort(colour_by)
        if labels is not None:
            env = np.asarray(labels)[keep][order] != 0
            ax.scatter(uv[order][env, 0], uv[order][env, 1], s=1.0, c="#c8c8c8", linewidths=0,
                       label="environment (support, walls, boxes)")
            order = order[~env]
        ax.scatter(uv[order, 0], uv[order, 1], s=1.2, c=colour_by[order], cmap="viridis", linewidths=0)
        for k in range(len(g) - 1, -1, -1):
            colour = "limegreen" if k == 0 else colours[k]
            for seg in segs[k]:
                s2 = _project(seg, origin, basis, persp)
                ax.plot(s2[:, 0], s2[:, 1], color="black", lw=(5.0 if k == 0 else 3.2), solid_capstyle="round")
                ax.plot(s2[:, 0], s2[:, 1], color=colour, lw=(3.0 if k == 0 else 1.8), solid_capstyle="round")
            ax.annotate(str(k + 1), _project(g.positions[k], origin, basis, persp), fontsize=8, weight="bold")
        ax.set_aspect("equal")
        if persp:
            ax.set_xticks([])
            ax.set_yticks([])
        else:
            ax.set_xlabel("m")
        ax.set_title(name, fontsize=10)
    fig.suptitle(title or f"top {len(g)} grasps (green = best)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
