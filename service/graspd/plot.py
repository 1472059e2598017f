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


def _view_basis(cloud: ViewpointCloud) -> NDArray[np.float64]:
    """Image axes (2,3) for a view from the first camera toward the cloud centroid."""
    centre = cloud.points.mean(axis=0).astype(np.float64)
    forward = centre - cloud.viewpoints[0].astype(np.float64)
    forward /= max(float(np.linalg.norm(forward)), 1e-9)
    up_guess = np.array([0.0, -1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
    right = np.cross(forward, up_guess)
    right /= max(float(np.linalg.norm(right)), 1e-9)
    up = np.cross(right, forward)
    return np.stack([right, up])


def plot_grasps(cloud: ViewpointCloud, grasps: GraspSet, hand: HandGeometry, path: str | Path,
                top: int = 10, title: str = "") -> Path:
    """Write a PNG: the cloud seen from its first camera and from the side, top grasps as grippers
    (best in green, then by rank from yellow to red)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    g = grasps[: max(top, 0)]
    segs = gripper_segments(g, hand)
    basis = _view_basis(cloud)
    side = np.stack([basis[0], np.cross(basis[0], basis[1])])  # looking along the up axis
    fig, axes = plt.subplots(1, 2, figsize=(12, 6), dpi=110)
    rng = np.random.default_rng(0)
    pts = cloud.points
    if len(pts) > 40_000:
        pts = pts[rng.choice(len(pts), 40_000, replace=False)]
    colours = plt.get_cmap("autumn")(np.linspace(0.0, 0.9, max(len(g), 1)))
    for ax, b, name in ((axes[0], basis, "camera view"), (axes[1], side, "view from above the camera's up axis")):
        uv = pts @ b.T
        depth = pts @ np.cross(b[0], b[1])
        ax.scatter(uv[:, 0], uv[:, 1], s=1.0, c=depth, cmap="viridis", alpha=0.8, linewidths=0)
        for k in range(len(g) - 1, -1, -1):
            colour = "limegreen" if k == 0 else colours[k]
            width = 3.0 if k == 0 else 1.6
            for seg in segs[k]:
                s2 = seg @ b.T
                ax.plot(s2[:, 0], s2[:, 1], color=colour, lw=width, solid_capstyle="round")
            c = g.positions[k] @ b.T
            ax.annotate(str(k + 1), c, fontsize=7, color="black")
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("m")
    fig.suptitle(title or f"top {len(g)} grasps (green = best)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
