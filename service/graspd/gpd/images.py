"""Step 4 of Algorithm 1: grasp images, the closing region of each hand seen from three directions.

Points in a hand's closing region (hand frame: x approach from the base, y closing direction,
z hand axis) are scaled into the unit cube and projected along each hand axis onto 60x60 images:
Io, the mean depth of occupied points; Iu, the mean depth of unobserved space (graspd.gpd.scene);
In, the mean outward surface normal (3 channels, in the hand frame).  Depth d in [0, 1] is stored
as round(255 * d) and normal components n as round(255 * (n + 1) / 2); empty pixels are 0.

Representations (IJRR paper, "Comparison Between Different Representations"):
  "15": for each projection (along x, y, z): In (3), Io, Iu  -> 15 channels
  "12": "15" without the three Iu channels
  "3":  In projected along the hand axis z (the curvature axis)
  "herzog": along the approach axis x: Io, Iu, If = columns with neither occupied nor unobserved space
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.parallel import THREADS
from graspd.gpd.rasterize import depth_maps, project_points, unobserved_cells
from graspd.gpd.scene import ClosingRegionPoints, Scene, closing_region_points

REPRESENTATIONS: dict[str, int] = {"15": 15, "12": 12, "3": 3, "herzog": 3}

# Projection p views along hand axis p; image rows/cols are the other two axes, in this order.
_PROJECTIONS: tuple[tuple[int, int, int], ...] = ((0, 1, 2), (1, 0, 2), (2, 0, 1))  # (depth, row, col)


def channel_layout(representation: str) -> list[str]:
    """Names of the channels of a representation, in order (e.g. 'x:nx', 'x:occ', 'x:unobs')."""
    names = "xyz"
    full = [f"{names[p]}:{c}" for p in range(3) for c in ("nx", "ny", "nz", "occ", "unobs")]
    if representation == "15":
        return full
    if representation == "12":
        return [c for c in full if not c.endswith("unobs")]
    if representation == "3":
        return ["z:nx", "z:ny", "z:nz"]
    if representation == "herzog":
        return ["x:occ", "x:unobs", "x:free"]
    raise KeyError(f"unknown representation {representation!r}; known: {sorted(REPRESENTATIONS)}")


def _unit_coords(local: NDArray[np.float32], hand: HandGeometry) -> NDArray[np.float32]:
    """Hand-frame closing-region coordinates scaled into [0, 1]^3."""
    half_w = hand.closing_half_width
    lo = np.array([0.0, -half_w, -hand.hand_height / 2.0], np.float32)
    size = np.array([hand.hand_depth, 2.0 * half_w, hand.hand_height], np.float32)
    return np.clip((local - lo) / size, 0.0, 1.0)


def unobserved_grids(scene: Scene, grasps: GraspSet, hand: HandGeometry, chunk: int = 256
                     ) -> NDArray[np.bool_]:
    """Which cells of a regular grid over each closing region (M, nx, ny, nz), at the scene's shadow
    voxel pitch, lie in unobserved space."""
    grid = scene.unobserved
    v = grid.voxel
    half_w = hand.closing_half_width
    n = [max(int(np.ceil(e / v)), 1) for e in (hand.hand_depth, 2 * half_w, hand.hand_height)]
    axes = [(np.arange(k) + 0.5) / k for k in n]
    unit = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    lo = np.array([0.0, -half_w, -hand.hand_height / 2.0])
    local = (lo + unit * np.array([hand.hand_depth, 2 * half_w, hand.hand_height])).astype(np.float32)
    grid_cells = np.ascontiguousarray(grid.cells)
    out = np.zeros((len(grasps), int(np.prod(n))), bool)
    for a in range(0, len(grasps), chunk):
        unobserved_cells(grid_cells, grid.origin.astype(np.float32), 1.0 / v,
                         grasps.positions[a : a + chunk].astype(np.float32),
                         grasps.rotations[a : a + chunk].astype(np.float32), local, out[a : a + chunk])
    return out.reshape(len(grasps), *n)


ENCODE_CHUNK = 256  # grasps encoded together: keeps temporaries in cache and time linear in grasps


def encode_images(scene: Scene, grasps: GraspSet, hand: HandGeometry, representation: str = "15",
                  size: int = 60, region: ClosingRegionPoints | None = None) -> NDArray[np.uint8]:
    """Grasp images (M, C, size, size) uint8, channels first, for every grasp in the set.

    region: the closing-region points of these grasps if already known (graspd.gpd.candidates.search_hands);
    otherwise they are looked up in the scene.
    """
    n_ch = REPRESENTATIONS.get(representation)
    if n_ch is None:
        raise KeyError(f"unknown representation {representation!r}; known: {sorted(REPRESENTATIONS)}")
    m = len(grasps)
    out = np.zeros((m, n_ch, size, size), np.uint8)
    if m == 0:
        return out
    def encode(job: tuple[int, int, ClosingRegionPoints]) -> None:
        a, b, part = job
        _encode_chunk(out[a:b], scene, grasps[a:b], hand, representation, part)

    THREADS.map(encode, list(_chunks(scene, grasps, hand, region, ENCODE_CHUNK)))  # on the thread budget
    return out


def encode_batches(scene: Scene, grasps: GraspSet, hand: HandGeometry, representation: str = "15",
                   size: int = 60, region: ClosingRegionPoints | None = None, batch: int = 512
                   ) -> Iterator[tuple[int, NDArray[np.uint8]]]:
    """(start, images of grasps[start : start + batch]) for consecutive batches: what encode_images
    makes, in bounded memory (the detector scores each batch before encoding the next)."""
    n_ch = REPRESENTATIONS.get(representation)
    if n_ch is None:
        raise KeyError(f"unknown representation {representation!r}; known: {sorted(REPRESENTATIONS)}")
    for a, b, part in _chunks(scene, grasps, hand, region, batch):
        out = np.zeros((b - a, n_ch, size, size), np.uint8)
        _encode_parallel(out, scene, grasps[a:b], hand, representation, part)
        yield a, out


MIN_PARALLEL_CHUNK = 64  # grasps: smaller pieces cost more in overhead than a second thread saves


def _encode_parallel(out: NDArray[np.uint8], scene: Scene, grasps: GraspSet, hand: HandGeometry,
                     representation: str, occ: ClosingRegionPoints) -> None:
    """_encode_chunk over pieces of the grasps on the process's thread budget (each grasp's images depend on
    that grasp alone, so the pieces give the same images)."""
    m = len(grasps)
    share = THREADS.share()
    piece = max(MIN_PARALLEL_CHUNK, -(-m // share))
    if share <= 1 or m <= piece:
        _encode_chunk(out, scene, grasps, hand, representation, occ)
        return
    pieces = list(_split(occ, m, piece))

    def encode(job: tuple[int, int, ClosingRegionPoints]) -> None:
        a, b, part = job
        _encode_chunk(out[a:b], scene, grasps[a:b], hand, representation, part)

    THREADS.map(encode, pieces)


def _split(occ: ClosingRegionPoints, m: int, chunk: int) -> Iterator[tuple[int, int, ClosingRegionPoints]]:
    """(a, b, the points of grasps [a, b) renumbered from 0) for consecutive chunks; occ sorted by grasp."""
    for a in range(0, m, chunk):
        b = min(m, a + chunk)
        lo, hi = np.searchsorted(occ.grasp, [a, b])
        yield a, b, ClosingRegionPoints(occ.grasp[lo:hi] - a, occ.local[lo:hi], occ.index[lo:hi])


def _chunks(scene: Scene, grasps: GraspSet, hand: HandGeometry, region: ClosingRegionPoints | None, chunk: int
            ) -> Iterator[tuple[int, int, ClosingRegionPoints]]:
    """(a, b, closing-region points of grasps[a:b] renumbered from 0) over consecutive chunks of grasps."""
    m = len(grasps)
    if m == 0:
        return
    occ = region or closing_region_points(scene.tree, scene.points, grasps.positions, grasps.rotations, hand)
    if len(occ.grasp) > 1 and not bool(np.all(occ.grasp[1:] >= occ.grasp[:-1])):
        order = np.argsort(occ.grasp, kind="stable")
        occ = ClosingRegionPoints(occ.grasp[order], occ.local[order], occ.index[order])
    yield from _split(occ, m, chunk)


def _encode_chunk(out: NDArray[np.uint8], scene: Scene, grasps: GraspSet, hand: HandGeometry,
                  representation: str, occ: ClosingRegionPoints) -> None:
    """Fill out (M, C, size, size), a C-contiguous block of the result, with the images of grasps."""
    occ_unit = _unit_coords(occ.local, hand)
    unobs = unobserved_grids(scene, grasps, hand) if representation in ("15", "herzog") else None
    gid = np.ascontiguousarray(occ.grasp)
    if representation != "herzog":
        rot = grasps.rotations.astype(np.float32)
        nrm = np.einsum("tj,tjk->tk", scene.normals[occ.index], rot[occ.grasp])
        nrm_scaled = (nrm + 1.0) * 0.5
        projections = (2,) if representation == "3" else (0, 1, 2)
        ch = 0
        for p in projections:
            proj = _PROJECTIONS[p]
            take = 3 if representation == "3" else 4
            values = np.concatenate([nrm_scaled, occ_unit[:, proj[0] : proj[0] + 1]], axis=1)[:, :take]
            project_points(gid, occ_unit, np.ascontiguousarray(values), proj[1], proj[2], ch, out)
            ch += take
            if unobs is not None:
                depth_maps(unobs, p, ch, out)
                ch += 1
        return
    assert unobs is not None
    project_points(gid, occ_unit, np.ascontiguousarray(occ_unit[:, 0:1]), _PROJECTIONS[0][1], _PROJECTIONS[0][2], 0,
                   out)
    depth_maps(unobs, 0, 1, out)
    out[:, 2] = np.where((out[:, 0] > 0) | (out[:, 1] > 0), 0, 255).astype(np.uint8)
