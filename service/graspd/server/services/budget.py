"""The memory budget of detection: admission by a request's estimated cost.

A detection's working set is estimated from what the request asks for (measured on this service: see
bench/hostile.py, bench/big_clouds.py and the README's hardening section):

- BASE_MB for any detection (candidate geometry, thread buffers, the response),
- SAMPLE_MB per sample (num_samples: candidates, their grasp images and scores),
- POINT_BYTES per cloud point (the decoded arrays, the region and voxel passes over them),
- VOXEL_BYTES per occupied voxel the detection keeps (occupied_voxels: what preprocessing leaves of the cloud,
  which normals, the scene, the objects and the hand search all work on): a 5M-point surface scan keeps ~0.13M
  voxels of 3 mm, a 5M-point volume (random blobs) ~2.4M, and costs ~6x the memory and ~10x the time,
- the crops' image and windows, when crops are asked for.

The budget (GRASPD_DETECT_MEMORY_MB) caps the sum over the detections running at once.  A request that can never
fit gets 413 naming the field that costs most (and how far it must shrink); one that cannot fit now waits on its
worker up to GRASPD_DETECT_MEMORY_WAIT_S for running detections to finish, then gets 503 with Retry-After.
HTTP checks the body's size before reading it (BudgetGate in graspd.server.api.guards: the densest cloud is 12 bytes
a point), and every transport (HTTP, Zenoh, the ROS streams) takes its exact share on the worker
right after the request is parsed, before any detection work.

The same place refuses a request by its expected time (work_units x the learned seconds per unit): 413 naming
the costliest field when even alone it would not end within the deadline, 503 with Retry-After when it would not
now (other detections share the cores).  The engine (engine.py) refuses queued work that cannot start in time
with 503 too: under a flood of 5M-point clouds every request is answered 200, 413 or 503, and what starts is
awaited to its end.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import ViewpointCloud
from graspd.core.jit import kernel
from graspd.gpd.preprocess import RANGE_SAMPLE, Workspace, range_limit, region_mask
from graspd.server.problems import Problem

MB = float(1 << 20)
#: Working set of any detection (MiB), per sample (MiB), per cloud point (bytes); measured on 100k-5M point
#: clouds, unscored (2026-11, peak RSS above an idle warm process: one detection of 300 samples +475-520 MiB,
#: four at once +1501 MiB, 1000 samples +821 MiB, 3000 samples +896 MiB; 100k to 5M points +90 MiB).
BASE_MB = 350.0
SAMPLE_MB = 0.25
POINT_BYTES = 40.0
#: Bytes per occupied voxel a detection keeps (kd-trees, normals, the scene, object segmentation, the hand
#: search's neighbourhoods); peak RSS above the parsed request, 300 samples, 2 cores (2026-11): random blobs of
#: 0.3M/1M/2M/5M points (0.28M/0.80M/1.37M/2.45M voxels) +120/+351/+689/+1600 MiB, a 5M-point tabletop scan
#: (0.13M voxels) +271 MiB.  Per voxel it grows with the density (more neighbours): sized for the densest.
VOXEL_BYTES = 512.0
#: The densest cloud encoding (binary float32 x, y, z): the most points a body of n bytes can hold is n / 12.
DENSEST_POINT_BYTES = 12


def request_cost(points: int, samples: int, crops: int = 0, crop_size: int = 0,
                 image_pixels: int = 0, voxels: int = 0) -> dict[str, float]:
    """Estimated MiB by part: cloud (points as sent), voxels (the occupied voxels the detection keeps, 0 before
    they are counted), num_samples, crops (the decoded image and one RGB window per grasp), plus "base"."""
    return {"base": BASE_MB, "cloud": points * POINT_BYTES / MB, "voxels": voxels * VOXEL_BYTES / MB,
            "num_samples": samples * SAMPLE_MB,
            "crops": (image_pixels * 3 * 2 + crops * crop_size * crop_size * 3 * 2) / MB}


#: Copies of a ROS 2 service request alive while the node decodes it: the sample DDS hands over and the bytes the
#: node keeps (graspd.io.ros decodes in place, on views of them).
MESSAGE_COPIES = 2


def message_cost(message_bytes: int, work_mb: float = 0.0) -> dict[str, float]:
    """Estimated MiB of a ROS 2 service request while its message is decoded, before its detection (which takes
    cost_of): the message's copies ("message") plus work_mb of bounded work arrays ("base")."""
    return {"base": work_mb, "message": MESSAGE_COPIES * message_bytes / MB}


def cost_of(req: Any, voxels: int = 0) -> dict[str, float]:
    """request_cost of a parsed DetectRequest whose cloud keeps `voxels` occupied voxels (occupied_voxels)."""
    crops = getattr(req, "crops", None)
    image = getattr(crops, "image", None) if crops is not None else None
    pixels = int(image.shape[0] * image.shape[1]) if image is not None and getattr(image, "ndim", 0) >= 2 else 0
    return request_cost(len(req.cloud.points), int(req.num_samples),
                        int(req.max_grasps) if crops is not None else 0,
                        int(getattr(crops, "size", 0) or 0), pixels, voxels)


#: Points of one block of occupied_voxels (8 bytes a point of transient memory).
VOXEL_BLOCK = 1 << 20
#: occupied_voxels counts every voxel of clouds up to this many points; of a larger one it counts the voxels
#: of one hash class in k (k = points // VOXEL_SAMPLE) and multiplies by k: relative error ~sqrt(k / voxels).
VOXEL_SAMPLE = 1 << 20
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


@kernel
def _mix(h: np.uint64) -> np.uint64:
    """splitmix64's finaliser: a bijection of 64-bit words whose outputs look independent of their inputs."""
    h ^= h >> np.uint64(30)
    h *= _MIX1
    h ^= h >> np.uint64(27)
    h *= _MIX2
    h ^= h >> np.uint64(31)
    return h


@kernel
def _kept_cell_hashes(points: NDArray[np.float32], source: NDArray[np.int32], cams: NDArray[np.float32],
                      mode: int, lo: NDArray[np.float64], hi: NDArray[np.float64], far: float, voxel: float,
                      every: int, out: NDArray[np.uint64]) -> int:
    """One pass over points (N,3 float32, m): of each finite point inside the region (mode 1: the box lo..hi; 2:
    at most `far` m from its camera, cams[source[i]] or cams[0]; 0: all), the 64-bit hash of its voxel (the cell
    floor(p / voxel) of graspd.core.points.voxel_groups, float32 division as numpy's); the hashes divisible by
    `every` go into out (not twice in a row).  Returns how many."""
    v = np.float32(voxel)
    f = np.float32(far)
    k = np.uint64(every)
    n = 0
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        if mode == 1:
            if x < lo[0] or x > hi[0] or y < lo[1] or y > hi[1] or z < lo[2] or z > hi[2]:
                continue
        elif mode == 2:
            c = source[i] if source.shape[0] > 0 else 0
            dx, dy, dz = x - cams[c, 0], y - cams[c, 1], z - cams[c, 2]
            if not np.sqrt(dx * dx + dy * dy + dz * dz) <= f:
                continue
        h = _mix(np.uint64(np.int64(np.floor(x / v))) + _GOLDEN)
        h = _mix(h ^ np.uint64(np.int64(np.floor(y / v))))
        h = _mix(h ^ np.uint64(np.int64(np.floor(z / v))))
        if h % k == np.uint64(0) and (n == 0 or out[n - 1] != h):  # neighbours in a scan share voxels
            out[n] = h
            n += 1
    return n


def occupied_voxels(cloud: ViewpointCloud, voxel_size: float, workspace: Workspace | None = None,
                    range_window: float = 0.0) -> int:
    """How many points a detection keeps of `cloud` after preprocessing's region (the workspace box, else the range
    window with the same near range: graspd.gpd.preprocess.range_limit) and its voxel grid of edge voxel_size (m;
    0: no voxelisation, every kept point stays).  What a detection costs grows with this count, not with the
    points sent: a surface keeps few voxels, a volume many.  Exact (but for hash collisions, ~1e-6 at 5M points)
    up to VOXEL_SAMPLE points, a hash-sampled estimate beyond; one compiled pass, 0.1-0.2 s for 5M points (one
    core), ~5% of what their detection takes."""
    if voxel_size <= 0.0:  # no voxel grid: every point of the region stays
        return int(np.count_nonzero(region_mask(cloud, workspace, range_window)))
    points = np.ascontiguousarray(cloud.points, np.float32)
    source = np.ascontiguousarray(cloud.camera_source, np.int32)
    cams = np.ascontiguousarray(np.asarray(cloud.viewpoints, np.float32).reshape(-1, 3))
    mode, far = 0, 0.0
    lo = hi = np.zeros(3)
    if workspace is not None:
        mode, lo, hi = 1, np.asarray(workspace[0::2], np.float64), np.asarray(workspace[1::2], np.float64)
    elif range_window > 0.0 and len(points):
        step = max(1, len(points) // RANGE_SAMPLE)  # the rows range_limit takes its near range from
        _, far = range_limit(points[::step], source[::step] if len(source) else source, cams, range_window)
        mode = 2 if np.isfinite(far) else 0
    out = np.empty(min(len(points), VOXEL_BLOCK), np.uint64)
    every = max(1, len(points) // VOXEL_SAMPLE)
    picked = [np.zeros(0, np.uint64)]
    for a in range(0, len(points), VOXEL_BLOCK):
        n = _kept_cell_hashes(points[a:a + VOXEL_BLOCK], source[a:a + VOXEL_BLOCK] if len(source) else source,
                              cams, mode, lo, hi, far, float(voxel_size), every, out)
        picked.append(_distinct(out[:n]))
    return every * len(_distinct(np.concatenate(picked)))


def _distinct(values: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """The distinct values, sorted (a sort and a comparison: several times faster than np.unique's hash table on
    a million 64-bit hashes)."""
    v = np.sort(values)
    return v[np.r_[True, v[1:] != v[:-1]]] if len(v) else v


#: A detection's work units: 1 + points / POINTS_PER_UNIT + voxel_units(voxels) + samples / SAMPLES_PER_UNIT
#: (points as sent: decoding, the region and the voxel grid; occupied voxels: normals, the scene, objects and the
#: hand search, whose cost per voxel grows with how many voxels there are, in a volume more neighbours each).  A
#: unit is about the smallest detection's time.  Fitted to detections alone on 2 shared cores (2026-11; 300
#: samples unless said; estimate in brackets): tabletop scans of 0.2M/5M points (79k/127k voxels) 0.96/3.2 s
#: (1.0/3.2 s); random blobs of 0.3M (60 samples)/1M/2M/5M points (0.28M/0.80M/1.37M/2.45M voxels)
#: 2.0/7.0/13.7/26-35 s (2.2/7.4/14.5/32.7 s).  Small clouds take less than their estimate (a 28k-point one, 60
#: samples: 0.05 s for 0.28 s), and teach the learnt seconds per unit little (MemoryBudget.observe).
POINTS_PER_UNIT = 250_000
VOXELS_PER_UNIT = 16_000
#: The cost of a voxel doubles every this many occupied voxels (see above).
VOXELS_DOUBLING = 2_500_000
SAMPLES_PER_UNIT = 100
#: Seconds per work unit of a detection running alone on REFERENCE_CORES cores, before any detection was timed
#: (the fit above); with more cores the engine starts from proportionally less.  Only a start: the detector gets
#: faster (the same 5M-point blobs took 26-35 s, then 20 s a few commits later) and machines differ, so the
#: engine learns the seconds per unit from every detection that runs (MemoryBudget.observe) and never refuses a
#: request for good on the start alone (engine.py: best effort when idle).
UNIT_SECONDS = 0.1
REFERENCE_CORES = 2
#: A timed detection of this many work units or more counts fully in the learnt seconds per unit, a smaller one
#: proportionally less (a small detection's time is mostly fixed costs): the first full one replaces the start,
#: the next ones average with it, down to an EWMA weight of LEARN_WEIGHT.
LEARN_UNITS = 20.0
LEARN_WEIGHT = 0.2


def voxel_units(voxels: float) -> float:
    """Work units of a detection's occupied voxels (see POINTS_PER_UNIT)."""
    return voxels / VOXELS_PER_UNIT * (1.0 + voxels / VOXELS_DOUBLING)


def voxels_for_units(units: float) -> int:
    """The most occupied voxels that fit in `units` work units (voxel_units inverted)."""
    if units <= 0:
        return 0
    a, b = 1.0 / (VOXELS_PER_UNIT * VOXELS_DOUBLING), 1.0 / VOXELS_PER_UNIT
    return int((-b + (b * b + 4.0 * a * units) ** 0.5) / (2.0 * a))


def work_parts(req: Any, voxels: int = 0) -> dict[str, float]:
    """The work units of a parsed DetectRequest whose cloud keeps `voxels` occupied voxels, by part: base,
    cloud (points as sent), voxels, num_samples (see POINTS_PER_UNIT)."""
    return {"base": 1.0, "cloud": len(req.cloud.points) / POINTS_PER_UNIT, "voxels": voxel_units(voxels),
            "num_samples": int(req.num_samples) / SAMPLES_PER_UNIT}


def work_units(req: Any, voxels: int = 0) -> float:
    """How much detection work a parsed DetectRequest asks for (work_parts summed): its expected seconds are
    units x MemoryBudget.unit_seconds x the detections sharing the cores, learned from the detections that ran."""
    return sum(work_parts(req, voxels).values())


def _shrink_hint(part: str, allowed: int, count: int, voxel_size: float) -> str:
    """What to send instead when `part` (cloud: points; voxels: occupied voxels; num_samples) must come down from
    `count` to `allowed`; voxel_size: the request's (m)."""
    if part == "cloud":
        return f"at most about {allowed} points (or a coarser voxel_size before sending)"
    if part == "num_samples":
        return f"num_samples at most {allowed}"
    if part == "voxels":  # a surface's voxels shrink as the cell^-2, a volume's as ^-3: the surface's is safe
        cell = voxel_size * (count / max(allowed, 1)) ** 0.5 if voxel_size > 0 else 0.003
        return (f"a cloud that keeps at most about {allowed} of its {count} occupied {voxel_size * 1000:g} mm "
                f"voxels: one point per {min(cell, 0.05) * 1000:.0f} mm cell or coarser (downsampled before "
                "sending), a workspace around what is to be grasped, or a surface scan rather than a volume")
    return "fewer grasps (max_grasps) or a smaller crops.size or image" if part == "crops" else f"a smaller {part}"


#: The request field each cost part belongs to (a 413 names it).
PART_FIELDS = {"cloud": "cloud", "voxels": "cloud", "num_samples": "num_samples", "crops": "crops"}


def too_slow(req: Any, voxels: int, unit_seconds: float, limit_s: float, deadline_s: float,
             voxel_size: float) -> Problem:
    """413 for a parsed DetectRequest (its cloud keeping `voxels` occupied voxels) whose work would take longer
    alone than limit_s, the most a request may take here: names the field of the costliest part and how far it
    must shrink to end within the deadline (deadline_s)."""
    parts = work_parts(req, voxels)
    seconds = sum(parts.values()) * unit_seconds
    part = max((k for k in parts if k != "base"), key=lambda k: parts[k])
    left = max(0.0, parts[part] - (seconds - deadline_s) / unit_seconds)  # the units the part may keep
    count, allowed = {"cloud": (len(req.cloud.points), int(left * POINTS_PER_UNIT)),
                      "voxels": (voxels, voxels_for_units(left)),
                      "num_samples": (int(req.num_samples), int(left * SAMPLES_PER_UNIT))}[part]
    return Problem(413, f"this request needs about {seconds:.0f} s of detection on this server even alone, more "
                        f"than the {limit_s:g} s it may take (twice the deadline, GRASPD_DEADLINE_S = {deadline_s:g} "
                        f"s): send {_shrink_hint(part, allowed, count, voxel_size)}", PART_FIELDS[part])


class MemoryBudget:
    """MiB held by the detections admitted now, at most budget_mb (0: no budget)."""

    def __init__(self, budget_mb: float, cores: int = REFERENCE_CORES) -> None:
        self.budget_mb = float(budget_mb)
        self.used_mb = 0.0
        self.waiters = 0  # requests waiting in take() for memory to be given back
        self._cond = threading.Condition()
        #: a detection's seconds per work unit alone: UNIT_SECONDS scaled to `cores`, then learnt (observe())
        self.unit_seconds = UNIT_SECONDS * min(1.0, REFERENCE_CORES / max(1, cores))
        self.learnt = 0.0  # full-size detections timed so far (LEARN_UNITS)

    def observe(self, units: float, seconds: float) -> None:
        """Learn seconds per work unit from a detection that ran, `units` of work (work_units x the detections
        sharing the cores; 0: it was refused before detection): a running mean by size (LEARN_UNITS), then an
        EWMA (LEARN_WEIGHT)."""
        if units > 0 and seconds > 0.0:
            size = min(1.0, units / LEARN_UNITS)
            with self._cond:
                weight = size * max(LEARN_WEIGHT, 1.0 / (1.0 + self.learnt))
                self.unit_seconds = (1.0 - weight) * self.unit_seconds + weight * seconds / units
                self.learnt += size

    def _too_big(self, parts: dict[str, float], voxel_size: float) -> Problem:
        total = sum(parts.values())
        part = max((k for k in parts if k != "base"), key=lambda k: parts[k])
        count = int(round({"cloud": parts.get("cloud", 0.0) * MB / POINT_BYTES,
                           "voxels": parts.get("voxels", 0.0) * MB / VOXEL_BYTES,
                           "num_samples": parts.get("num_samples", 0.0) / SAMPLE_MB}.get(part, 0.0)))
        share = max(0.0, parts[part] - (total - self.budget_mb)) / parts[part] if parts[part] > 0 else 0.0
        hint = _shrink_hint(part, int(share * count), count, voxel_size)
        return Problem(413, f"this request needs about {total:.0f} MiB of detection memory, more than the server's "
                            f"budget of {self.budget_mb:.0f} MiB (GRASPD_DETECT_MEMORY_MB): send {hint}",
                       PART_FIELDS.get(part, part))

    def check(self, parts: dict[str, float], voxel_size: float = 0.003) -> None:
        """Problem 413 naming the costliest field when the request's estimated MiB exceed the whole budget (it
        can never fit); voxel_size (m): the request's, for the hint."""
        if 0 < self.budget_mb < sum(parts.values()):
            raise self._too_big(parts, voxel_size)

    def take(self, parts: dict[str, float], retry_after: float, wait_s: float = 0.0,
             voxel_size: float = 0.003) -> float:
        """Hold the request's estimated MiB: Problem 413 naming the costliest field when it exceeds the whole
        budget; when the detections running now leave too little, wait up to wait_s seconds for them to give
        some back, then 503 with Retry-After.  Returns the MiB to give back."""
        total = sum(parts.values())
        if self.budget_mb <= 0:
            return 0.0
        self.check(parts, voxel_size)
        with self._cond:
            if not self._fits(total):
                self.waiters += 1
                try:
                    fits = self._cond.wait_for(lambda: self._fits(total), max(0.0, wait_s))
                finally:
                    self.waiters -= 1
                if not fits:
                    raise Problem(503, f"server busy: detections running now hold {self.used_mb:.0f} of "
                                       f"{self.budget_mb:.0f} MiB and this request needs about {total:.0f}",
                                  retry_after=retry_after)
            self.used_mb += total
        return total

    def _fits(self, total: float) -> bool:
        return self.used_mb <= 0 or self.used_mb + total <= self.budget_mb

    def give(self, mb: float) -> None:
        """Give back what take() returned (and wake the requests waiting for memory)."""
        if mb:
            with self._cond:
                self.used_mb = max(0.0, self.used_mb - mb)
                self._cond.notify_all()

    def check_body(self, body_bytes: int, retry_after: float) -> None:
        """Before a body of body_bytes is read: 413 (field body) when even its least costly reading (the densest
        cloud, one sample) cannot fit the budget, 503 when it cannot fit now and other requests already wait for
        memory."""
        if self.budget_mb <= 0:
            return
        parts = request_cost(body_bytes // DENSEST_POINT_BYTES, 1)
        total = sum(parts.values())
        if total > self.budget_mb:
            raise Problem(413, f"a body of {body_bytes} bytes holds up to {body_bytes // DENSEST_POINT_BYTES} points, "
                               f"about {total:.0f} MiB of detection memory, more than the server's budget of "
                               f"{self.budget_mb:.0f} MiB (GRASPD_DETECT_MEMORY_MB)", "body")
        with self._cond:
            if self.waiters and not self._fits(total):  # requests already wait for memory: do not hold a body too
                raise Problem(503, f"server busy: detections running now hold {self.used_mb:.0f} of "
                                   f"{self.budget_mb:.0f} MiB and {self.waiters} more wait for memory",
                              retry_after=retry_after)
