"""Space no camera saw is not free: the share of each hand (and its approach path) that lies in it.

The collision check of the hand search is right about what the cameras saw, but a neighbour seen only in part
goes on behind its visible surface.  The unobserved volume (Scene.unobserved_within: voxels behind the surface
from every camera that saw the cloud, holding no point) is marked as deep behind the surface as the open hand
and its path reach, and at least as deep as a bin's wall can hide (hand_shadow_length: a real object can hide
that far behind what was seen of it); each open hand is sampled on a grid at most SAMPLE_SPACING apart over the
real outline of its fingers, its palm and their path back from the pre-grasp pose, shrunk by a margin (sensor
noise; the fingers touch the object they grasp), and each sample is looked up in that volume.  All in the cloud
frame, metres; vectorised over hands.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from graspd.core.hand import HandGeometry
from graspd.core.jit import kernel
from graspd.core.parallel import THREADS
from graspd.core.types import F64
from graspd.gpd.scene import VoxelGrid

F32 = np.float32
UnknownSpace = Literal["avoid", "fallback", "allow"]
UNKNOWN_SPACE_MODES: tuple[str, ...] = ("avoid", "fallback", "allow")
#: Default most share of a hand's samples that may lie in unseen space under "avoid": none (the margin below
#: absorbs sensor noise at the surface; a tolerance let fingertips a centimetre into a hidden object through).
MAX_UNKNOWN_SHARE = 0.0
#: Most share under "fallback" when no hand keeps within MAX_UNKNOWN_SHARE (the floor of a deep bin beside its
#: walls, seen from one side, where every hand's fingertips dip into the walls' shadow): those hands come back, with
#: a warning, instead of no grasp.  Chosen on the training objects' deep bins (bench/containers.py --split
#: training); opt-in, since on held-out containers it traded success for cleared objects (docs: Benchmarks).
UNKNOWN_FALLBACK_SHARE = 0.05
#: Default distance (m) the hand's samples keep inside its faces: unseen space closer than this is tolerated.
UNKNOWN_MARGIN = 0.004
#: Most distance (m) between neighbouring samples of a hand along each of its axes: a shadow voxel and a half, so
#: a hidden object passes between them only where the volume itself has holes (a finger is sampled across its
#: width, the palm everywhere).
SAMPLE_SPACING = 0.006


#: Least depth (m) the unseen-space check looks behind a seen surface: a container's wall hides the space below
#: its rim as deep as the wall is tall and more (seen over a 20 cm wall from 45 degrees up, the floor beside it lies
#: up to 28 cm behind the wall's face along the camera's rays), far past what the hand itself reaches.
MIN_SHADOW_LENGTH = 0.30


def hand_shadow_length(hand: HandGeometry, approach_distance: float) -> float:
    """How deep (m) behind a seen surface the unseen-space check looks: as far as the open hand reaches along its
    approach, fingers, palm and path from the pre-grasp pose (hand_depth + palm_depth + approach_distance), at
    least the opening (the images' shadow), and at least MIN_SHADOW_LENGTH.  Shorter, the far side of an object
    larger than the opening reads as free, a pre-grasp pose inside its hidden part passes, and so does a finger
    reaching down beside a deep bin's wall into the space the wall hides."""
    return max(hand.hand_depth + hand.palm_depth + approach_distance, hand.max_aperture, MIN_SHADOW_LENGTH)


def hand_samples(hand: HandGeometry, approach_distance: float, margin: float = UNKNOWN_MARGIN,
                 spacing: float = SAMPLE_SPACING) -> F64:
    """Points (P,3) in the hand frame filling the open fingers, the palm and the path back along -approach by
    approach_distance (m) (the pre-grasp pose's outline and everything it sweeps), each box shrunk by margin (m)
    on every side (a box thinner than 2 x margin is sampled on its mid-plane), on a grid at most spacing (m)
    apart along each axis, its faces included.  The closing region between the fingers is not sampled: the
    object is there."""
    boxes = hand.swept_boxes(approach_distance)  # (3, 2, 3): left finger, right finger, palm
    out = []
    for lo, hi in boxes:
        lo_m, hi_m = lo + margin, hi - margin
        mid = (lo + hi) / 2.0
        thin = lo_m > hi_m
        lo_m, hi_m = np.where(thin, mid, lo_m), np.where(thin, mid, hi_m)
        steps = np.maximum(np.ceil((hi_m - lo_m) / spacing).astype(np.int64) + 1, 1)
        steps = np.where(hi_m > lo_m, np.maximum(steps, 2), 1)
        axes = [np.linspace(a, b, int(k)) for a, b, k in zip(lo_m, hi_m, steps, strict=True)]
        out.append(np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3))
    return np.concatenate(out)


def unknown_share(grid: VoxelGrid, positions: F64, rotations: F64, hand: HandGeometry, approach_distance: float,
                  margin: float = UNKNOWN_MARGIN, chunk: int = 256, spacing: float = SAMPLE_SPACING) -> F64:
    """The share (M,) in [0, 1] of each hand's samples (hand_samples) that lie in the unobserved volume, for
    hands at positions (M,3) with rotations (M,3,3) (grasp convention, cloud frame).  Chunks of hands run on the
    process's thread budget (graspd.core.parallel; each hand's share depends on that hand alone)."""
    m = len(positions)
    out = np.zeros(m)
    if m == 0 or not grid.cells.any():
        return out
    # in grid units (voxels from the grid's origin), float32: each hand's samples are its rotation times the local
    # grid plus its position, floored, clipped onto the grid (border cells read False) and looked up
    local = (hand_samples(hand, approach_distance, margin, spacing) / grid.voxel).astype(np.float32)  # (P, 3)
    origin = ((positions - grid.origin) / grid.voxel).astype(np.float32)  # (M, 3)
    rots = rotations.astype(np.float32)

    def share(a: int) -> None:
        _unseen_counts(grid.cells, origin[a : a + chunk], rots[a : a + chunk], local, out[a : a + chunk])

    THREADS.map(share, range(0, m, chunk))
    return out


@kernel
def _unseen_counts(cells: NDArray[np.bool_], origin: NDArray[np.float32], rots: NDArray[np.float32],
                   local: NDArray[np.float32], out: NDArray[np.float64]) -> None:
    """out[h]: the share of the samples local (P,3; grid units, hand frame) of hand h (origin (M,3) in grid units,
    rots (M,3,3)) that fall in a true cell; float32 arithmetic, positions clipped onto the grid."""
    s0, s1, s2 = cells.shape
    hi0, hi1, hi2 = F32(s0 - 1.0), F32(s1 - 1.0), F32(s2 - 1.0)
    zero = F32(0.0)
    for h in range(len(origin)):
        n = 0
        for q in range(len(local)):
            l0, l1, l2 = local[q, 0], local[q, 1], local[q, 2]
            g0 = np.floor(origin[h, 0] + rots[h, 0, 0] * l0 + rots[h, 0, 1] * l1 + rots[h, 0, 2] * l2)
            g1 = np.floor(origin[h, 1] + rots[h, 1, 0] * l0 + rots[h, 1, 1] * l1 + rots[h, 1, 2] * l2)
            g2 = np.floor(origin[h, 2] + rots[h, 2, 0] * l0 + rots[h, 2, 1] * l1 + rots[h, 2, 2] * l2)
            i0 = int(min(max(g0, zero), hi0))
            i1 = int(min(max(g1, zero), hi1))
            i2 = int(min(max(g2, zero), hi2))
            if cells[i0, i1, i2]:
                n += 1
        out[h] = n / len(local)
