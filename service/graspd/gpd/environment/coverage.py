"""How much of a container's floor the cameras saw: the floor between the walls found, on a grid of cells in the
support plane, each seen when a point that is not wall lies over it (the floor itself or something on it).

A bin seen over one wall hides the floor beside that wall from every camera: an object lying there yields no
point and so no grasp, and "no grasp" would wrongly read as "the bin is empty".  Cloud frame, metres."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.spatial import ConvexHull, Delaunay, QhullError

from graspd.core.types import F64
from graspd.core.warning import DetectionWarning
from graspd.gpd.environment.planes import in_plane_axes
from graspd.gpd.environment.types import Environment, Label

#: Cell edge of the floor grid (m): a few of the 3 mm voxels' points fall in each seen cell.
FLOOR_CELL = 0.01
#: A wall's footprint grown by this (m) is not floor: its face's own points and the noise beside them.
WALL_MARGIN = 0.01
#: The least width (m) of floor no camera saw that is worth a warning: room for an object a hand could hold to lie
#: there unseen.  The thin strip at a tray wall's foot is narrower.
MIN_HIDDEN_WIDTH = 0.04


@dataclass(frozen=True)
class FloorCoverage:
    """The container floor between the walls found: its area (m²), the area no camera saw (m²), the widest
    that unseen floor gets (m, the largest disc that fits in it, to a cell) and that disc's centre on the floor
    (cloud frame, m; None when no floor went unseen): where a second camera should look."""

    floor_area: float
    unseen_area: float
    hidden_width: float
    hidden_centre: tuple[float, float, float] | None = None

    @property
    def unseen_share(self) -> float:
        return self.unseen_area / self.floor_area if self.floor_area > 0 else 0.0


def floor_coverage(points: NDArray[np.floating], env: Environment) -> FloorCoverage | None:
    """The coverage of the floor inside the walls of env (two or more walls or rims; None without them, or
    without an up direction).  points: the preprocessed cloud env labels (N, 3)."""
    boxes = [s.box for s in env.surfaces if s.kind in ("wall", "rim") and s.box is not None]
    if len(boxes) < 2 or env.up is None or len(points) != len(env.labels):
        return None
    axes = in_plane_axes(np.asarray(env.up, np.float64))
    corners = np.concatenate([b.corners() for b in boxes]) @ axes.T  # (8 k, 2) in the support plane
    try:
        hull = ConvexHull(corners)
    except QhullError:  # walls in one line: nothing lies between them
        return None
    inside = Delaunay(corners[hull.vertices])
    lo = corners.min(axis=0)
    shape = np.ceil((corners.max(axis=0) - lo) / FLOOR_CELL).astype(np.int64) + 1
    ij = np.stack(np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij"), axis=-1).reshape(-1, 2)
    centres = lo + (ij + 0.5) * FLOOR_CELL
    floor = inside.find_simplex(centres) >= 0
    for b in boxes:  # at each wall's mid-height, so its footprint is tested whatever its height
        lifted = centres @ axes + (np.asarray(b.centre) @ np.asarray(env.up)) * np.asarray(env.up)
        floor &= ~b.contains(lifted, margin=WALL_MARGIN)
    if not floor.any():
        return None
    seen = np.zeros(int(shape[0] * shape[1]), bool)
    flat = np.asarray(points, np.float64)[env.labels != Label.WALL] @ axes.T
    cell = np.floor((flat - lo) / FLOOR_CELL).astype(np.int64)
    ok = np.all((cell >= 0) & (cell < shape), axis=1)
    seen[cell[ok, 0] * shape[1] + cell[ok, 1]] = True
    unseen = (floor & ~seen).reshape(int(shape[0]), int(shape[1]))
    area = FLOOR_CELL**2
    if not unseen.any():
        return FloorCoverage(float(floor.sum()) * area, 0.0, 0.0)
    # a cell's distance to the nearest seen or non-floor cell, in cells: a strip w cells wide peaks at (w + 1) / 2
    distance = ndimage.distance_transform_edt(unseen)
    widest = np.unravel_index(int(np.argmax(distance)), distance.shape)
    depth = float(distance[widest])
    return FloorCoverage(float(floor.sum()) * area, float(unseen.sum()) * area,
                         max(0.0, 2.0 * depth - 1.0) * FLOOR_CELL,
                         _on_floor(lo + (np.asarray(widest) + 0.5) * FLOOR_CELL, axes, points, env))


def _on_floor(planar: F64, axes: F64, points: NDArray[np.floating], env: Environment) -> tuple[float, float, float]:
    """The point of the floor (cloud frame, m) over in-plane coordinates planar (2,): on the support plane, or
    without one at the height of the lowest point."""
    up = np.asarray(env.up, np.float64)
    at = planar @ axes
    if env.support is not None and abs(float(env.support.normal @ up)) > 1e-6:
        at = at - float(env.support.distance(at[None])[0]) / float(env.support.normal @ up) * up
    else:
        at = at + float(np.min(np.asarray(points, np.float64) @ up)) * up
    return (float(at[0]), float(at[1]), float(at[2]))


def unseen_floor_warning(points: NDArray[np.floating], env: Environment) -> DetectionWarning | None:
    """unseen_floor when a part of the container's floor wide enough to hide a graspable object was seen by no
    camera (for an answer without a grasp: the container may not be empty)."""
    cover = floor_coverage(points, env)
    if cover is None or cover.hidden_width < MIN_HIDDEN_WIDTH:
        return None
    return DetectionWarning(
        "unseen_floor", f"no camera saw {100 * cover.unseen_share:.0f}% of the floor between the container's walls "
        f"({1e4 * cover.unseen_area:.0f} cm², up to {100 * cover.hidden_width:.0f} cm wide, hidden behind them"
        f"{_where(cover.hidden_centre)}): objects lying there give no point and no grasp, so no grasp does not mean "
        "the container is empty; look into it from above or from the other side")


def _where(centre: tuple[float, float, float] | None) -> str:
    return "" if centre is None else ", the widest around ({:.2f}, {:.2f}, {:.2f}) m in the answer's frame".format(
        *centre)


__all__ = ["FLOOR_CELL", "MIN_HIDDEN_WIDTH", "FloorCoverage", "floor_coverage", "unseen_floor_warning"]
