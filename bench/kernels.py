"""The compiled point kernels against the numpy/scipy code they replaced, timed in the same run.

Rows: PCA normals (graspd.core.points.pca_normals: 1 cm radius, 30 nearest) on the 3 mm voxels of the real
table_mug.pcd and of a 1M-point synthetic scan; the voxel grid (graspd.gpd.preprocess.voxelize at 3 mm) and the
whole of graspd.gpd.preprocess.preprocess (selection, voxels, normals) on table_mug.pcd and on synthetic tabletop
scans of 1M and 5M points, with a workspace box and with the detector's default range window instead.  The old
implementations are copies kept in this script (old_*), as the service had them; each row also says whether the
outputs agree (voxels, cameras bit for bit; normals: the largest angle between old and new, up to sign).

Synthetic tabletop scans (tabletop_scan): two pinhole cameras 0.75 m above a 1.2 x 0.8 m table, 40 degrees
apart, ray-cast onto the table, two boxes, a sphere and an upright cylinder; 0.5 mm Gaussian noise on every
coordinate; points in each camera's pixel (raster) order as a depth camera streams them, and the same points
shuffled (a merged cloud: no locality).  The table top lies at z = 0, on a voxel boundary, as in a robot's frame.

Times are medians of --repeats runs after one warm-up (compiled kernels load from numba's cache).  Load on a
shared machine varies, so each row also gives its time divided by a fixed CPU workload (20 float64 256x256
matmuls + tanh on one thread) timed right before each run: the normalised figure is comparable between runs on a
machine whose load changed.  The header records the load average before and after.

    PYTHONPATH=service:client:lab .venv/bin/python bench/kernels.py [--repeats 7] [--sizes 1000000,5000000]
        [--out bench/results/kernels.md]
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # the reference workload on one thread (before numpy loads)
os.environ.setdefault("OMP_NUM_THREADS", "1")

import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "service"), str(ROOT / "client")]

from scipy.spatial import cKDTree  # noqa: E402

from graspd.core.cloud import ViewpointCloud  # noqa: E402
from graspd.core.parallel import THREADS  # noqa: E402
from graspd.core.points import pca_normals  # noqa: E402
from graspd.gpd.preprocess import (  # noqa: E402
    NEAR_QUANTILE,
    RANGE_SAMPLE,
    PreprocessParams,
    Workspace,
    crop_mask,
    orient_toward_cameras,
    preprocess,
    spans_window,
    voxelize,
)
from graspd.io.pcd import read_pcd  # noqa: E402

TABLE_MUG = ROOT.parent / "shared" / "data" / "real" / "table_mug.pcd"
VOXEL = 0.003
RADIUS = 0.01
MAX_NN = 30
NOISE = 0.0005


# --- the implementations the kernels replaced (numpy and scipy), kept here only to time them -----------------

OLD_DENSE_VOXEL_CELLS = 1 << 22


def old_voxel_groups(points: NDArray[np.floating], voxel: float) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """graspd.core.points.voxel_groups before the kernels: numpy keys, bincount or unique."""
    grid = np.floor(points / voxel).astype(np.int64)
    grid -= grid.min(axis=0)
    dims = grid.max(axis=0) + 1
    cells = int(dims[0]) * int(dims[1]) * int(dims[2])
    if cells >= 1 << 62:
        _, inverse, counts = np.unique(grid, axis=0, return_inverse=True, return_counts=True)
        return inverse.reshape(-1), counts
    keys = (grid[:, 0] * dims[1] + grid[:, 1]) * dims[2] + grid[:, 2]
    if cells <= OLD_DENSE_VOXEL_CELLS:
        dense = np.bincount(keys, minlength=cells)
        occupied = np.flatnonzero(dense)
        rank = np.empty(cells, np.intp)
        rank[occupied] = np.arange(len(occupied))
        return rank[keys], dense[occupied]
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    return inverse.reshape(-1), counts


def old_voxelize(points: NDArray[np.float32], camera_source: NDArray[np.int32], voxel_size: float,
                 normals: NDArray[np.float32] | None = None
                 ) -> tuple[NDArray[np.float32], NDArray[np.int32], NDArray[np.float32] | None]:
    """graspd.gpd.preprocess.voxelize before the kernels."""
    inverse, counts = old_voxel_groups(points, voxel_size)
    m = counts.shape[0]
    sums = np.stack([np.bincount(inverse, points[:, k], m) for k in range(3)], axis=1)
    out_pts: NDArray[np.float32] = (sums / counts[:, None]).astype(np.float32)
    ncam = int(camera_source.max()) + 1 if camera_source.size else 1
    votes = np.bincount(inverse * ncam + camera_source, minlength=m * ncam).reshape(m, ncam)
    out_src = np.argmax(votes, axis=1).astype(np.int32)
    out_nrm = None
    if normals is not None:
        nsum = np.stack([np.bincount(inverse, normals[:, k], m) for k in range(3)], axis=1)
        out_nrm = (nsum / np.maximum(np.linalg.norm(nsum, axis=1, keepdims=True), 1e-12)).astype(np.float32)
    return out_pts, out_src.astype(np.int32), out_nrm


OLD_NORMALS_CHUNK = 4096


def old_pca_normals(points: NDArray[np.floating], radius: float, max_nn: int, chunk: int = OLD_NORMALS_CHUNK
                    ) -> NDArray[np.float32]:
    """graspd.core.points.pca_normals before the kernels: a cKDTree query and numpy eigh per chunk."""
    pts = np.asarray(points, np.float64)
    out = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (len(pts), 1))
    if len(pts) < 3:
        return out
    tree = cKDTree(pts, balanced_tree=False)
    padded = np.vstack([pts, np.zeros((1, 3))])
    k = min(max_nn, len(pts))

    def normals_of(start: int) -> None:
        dist, idx = tree.query(pts[start:start + chunk], k=k, distance_upper_bound=radius * (1 + 1e-12))
        idx = idx.reshape(len(idx), k)
        count = np.isfinite(dist.reshape(len(idx), k)).sum(axis=1)
        nb = padded[idx]
        n = np.maximum(count, 1)[:, None]
        mean = nb.sum(axis=1) / n
        cov = np.matmul(nb.transpose(0, 2, 1), nb) / n[:, :, None] - mean[:, :, None] * mean[:, None, :]
        evals, evecs = np.linalg.eigh(cov)
        ok = (count >= 3) & (evals[:, 2] > 0.0)
        out[start:start + chunk][ok] = evecs[ok, :, 0].astype(np.float32)

    THREADS.map(normals_of, range(0, len(pts), chunk))
    return out


OLD_RANGE_CHUNK = 262_144


def old_range_limit(points: NDArray[np.floating], camera_source: NDArray[np.int32], viewpoints: NDArray[np.floating],
                    window: float) -> tuple[NDArray[np.floating], float]:
    """graspd.gpd.preprocess.range_limit before the kernels: einsum over blocks."""
    pts = np.asarray(points)
    cams = np.asarray(viewpoints, pts.dtype).reshape(-1, 3)
    ranges = np.empty(len(pts), pts.dtype if pts.dtype.kind == "f" else np.float64)
    for a in range(0, len(pts), OLD_RANGE_CHUNK):
        rel = pts[a:a + OLD_RANGE_CHUNK] - (cams[0] if len(cams) == 1 else cams[camera_source[a:a + OLD_RANGE_CHUNK]])
        ranges[a:a + OLD_RANGE_CHUNK] = np.sqrt(np.einsum("ij,ij->i", rel, rel))
    if len(ranges) == 0:
        return ranges, float("inf")
    sample = ranges[:: max(1, len(ranges) // RANGE_SAMPLE)]
    sample = sample[np.isfinite(sample)]
    if len(sample) == 0:
        return ranges, float("inf")
    return ranges, float(np.quantile(sample, NEAR_QUANTILE)) + window


def old_region_mask(cloud: ViewpointCloud, workspace: Workspace | None, range_window: float) -> NDArray[np.bool_]:
    """graspd.gpd.preprocess.region_mask before the kernels."""
    mask = np.asarray(np.isfinite(cloud.points).all(axis=1), bool)
    if workspace is not None:
        return mask & crop_mask(cloud.points, workspace)
    if range_window > 0.0 and mask.any() and spans_window(cloud.points, range_window):
        ranges, far = old_range_limit(cloud.points, cloud.camera_source, cloud.viewpoints, range_window)
        mask &= ranges <= far
    return mask


def old_preprocess(cloud: ViewpointCloud, p: PreprocessParams) -> ViewpointCloud:
    """graspd.gpd.preprocess.preprocess before the kernels (the selection copied, then voxelized; no outlier
    removal: these parameters have none)."""
    keep = old_region_mask(cloud, p.workspace, p.range_window)
    if cloud.normals is not None:
        keep &= np.asarray(np.isfinite(cloud.normals).all(axis=1), bool)
    c = cloud.select(keep) if not keep.all() else cloud
    if len(c) == 0:
        return c.__class__(points=np.zeros((0, 3), np.float32), viewpoints=c.viewpoints,
                           normals=np.zeros((0, 3), np.float32))
    pts, src, nrm = c.points, c.camera_source, c.normals
    if p.voxel_size > 0.0 and len(pts) > 1 and bool(np.all(np.ptp(pts, axis=0) < p.voxel_size)):
        pts, src = pts[:1], src[:1]
        nrm = None if nrm is None else nrm[:1]
    elif p.voxel_size > 0.0:
        pts, src, nrm = old_voxelize(pts, src, p.voxel_size, nrm)
    if nrm is None or p.recompute_normals:
        nrm = old_pca_normals(pts, p.normal_radius, p.normal_max_nn) if len(pts) >= 3 else np.zeros_like(pts)
    nrm = orient_toward_cameras(pts, nrm, src, c.viewpoints)
    return ViewpointCloud(points=pts, viewpoints=c.viewpoints, camera_source=src, normals=nrm)


# --- inputs -----------------------------------------------------------------------------------------------------


def _look_at(eye: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    """Camera-to-world rotation (columns: image right, image down, optical axis) looking from eye at target."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _cast(origin: NDArray[np.float64], rays: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance along each unit ray (R,3) from origin to the nearest surface of the scene (inf: none)."""
    t = np.full(len(rays), np.inf)

    def take(hit: NDArray[np.float64]) -> None:
        np.minimum(t, np.where(hit > 1e-9, hit, np.inf), out=t)

    with np.errstate(divide="ignore", invalid="ignore"):
        tz = -origin[2] / rays[:, 2]  # the table top, z = 0, 1.2 x 0.8 m
        p = origin + tz[:, None] * rays
        take(np.where((np.abs(p[:, 0]) <= 0.6) & (np.abs(p[:, 1]) <= 0.4), tz, np.inf))
        for lo, hi in (((-0.35, -0.15, 0.0), (-0.15, 0.05, 0.12)), ((0.1, 0.1, 0.0), (0.3, 0.18, 0.25))):
            t0 = (np.asarray(lo) - origin) / rays
            t1 = (np.asarray(hi) - origin) / rays
            near = np.minimum(t0, t1).max(axis=1)
            far = np.maximum(t0, t1).min(axis=1)
            take(np.where(near <= far, near, np.inf))
        centre, r = np.array([0.0, -0.2, 0.07]), 0.07  # a sphere resting on the table
        oc = origin - centre
        b = rays @ oc
        disc = b * b - (oc @ oc - r * r)
        take(np.where(disc >= 0.0, -b - np.sqrt(disc), np.inf))
        axis, r, h = np.array([0.0, 0.2]), 0.04, 0.18  # an upright cylinder (a can), side and top
        o2, d2 = origin[:2] - axis, rays[:, :2]
        a = (d2 * d2).sum(axis=1)
        b = d2 @ o2
        disc = b * b - a * (o2 @ o2 - r * r)
        ts = (-b - np.sqrt(disc)) / a
        zs = origin[2] + ts * rays[:, 2]
        take(np.where((disc >= 0.0) & (zs >= 0.0) & (zs <= h), ts, np.inf))
        tt = (h - origin[2]) / rays[:, 2]
        pt = origin[:2] + tt[:, None] * d2 - axis
        take(np.where((pt * pt).sum(axis=1) <= r * r, tt, np.inf))
    return t


def tabletop_scan(num_points: int, seed: int = 0, shuffled: bool = False
                  ) -> tuple[NDArray[np.float32], NDArray[np.int32], NDArray[np.float32]]:
    """A synthetic two-camera tabletop scan of about num_points points (m, table frame: z up, table top at 0),
    each camera's points in pixel order; its camera index per point and the two camera positions (2,3)."""
    rng = np.random.default_rng(seed)
    eyes = [np.array([-0.27, -0.35, 0.75]), np.array([0.27, -0.35, 0.75])]
    per_camera = num_points // 2
    side = int(np.sqrt(per_camera / 0.55)) + 1  # the scene fills ~55% of a 70-degree square image
    points, sources = [], []
    for c, eye in enumerate(eyes):
        rot = _look_at(eye, np.array([0.0, 0.0, 0.05]))
        f = side / 2 / np.tan(np.radians(35.0))
        v, u = np.mgrid[0:side, 0:side]
        rays = np.stack([(u.ravel() - side / 2) / f, (v.ravel() - side / 2) / f, np.ones(side * side)], axis=1)
        rays = rays @ rot.T
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        hits = []
        for a in range(0, len(rays), 1 << 20):
            t = _cast(eye, rays[a:a + (1 << 20)])
            ok = np.isfinite(t)
            hits.append(eye + t[ok, None] * rays[a:a + (1 << 20)][ok])
        pts = np.concatenate(hits)
        keep = np.linspace(0, len(pts) - 1, min(per_camera, len(pts))).astype(np.int64)  # pixel order kept
        points.append(pts[keep])
        sources.append(np.full(len(keep), c, np.int32))
    pts = np.concatenate(points)
    pts += rng.normal(0.0, NOISE, pts.shape)
    src = np.concatenate(sources)
    if shuffled:
        order = rng.permutation(len(pts))
        pts, src = pts[order], src[order]
    return pts.astype(np.float32), src, np.array(eyes, np.float32)


def table_mug() -> NDArray[np.float32]:
    """The finite points of the real Kinect capture table_mug.pcd (m, camera frame)."""
    points = read_pcd(TABLE_MUG.read_bytes()).points
    return points[np.isfinite(points).all(axis=1)]


# --- timing -----------------------------------------------------------------------------------------------------

_A = np.random.default_rng(1).standard_normal((256, 256))


def reference_workload() -> float:
    """Seconds of a fixed single-thread CPU workload (20 float64 256x256 matmuls, numpy's BLAS on one thread)."""
    t = time.perf_counter()
    x = _A
    for _ in range(20):
        x = np.tanh(x @ _A)
    return time.perf_counter() - t


def timed(fn: Callable[[], Any], repeats: int) -> tuple[float, float, float]:
    """Median wall seconds of fn() over repeats runs after one warm-up, the median CPU seconds (all the process's
    threads) and the median of the reference workload timed before each run."""
    fn()
    times, cpus, refs = [], [], []
    for _ in range(repeats):
        refs.append(reference_workload())
        t, c = time.perf_counter(), time.process_time()
        fn()
        times.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    return statistics.median(times), statistics.median(cpus), statistics.median(refs)


def _cpu() -> str:
    """The processor's model name (Linux), else the platform's word for it."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


#: The service code this benchmark times.
_BENCHED = ("service/graspd/core", "service/graspd/gpd/preprocess.py")


def _commit() -> str:
    """The checkout's commit, "+ local changes" when the code benchmarked here differs from it."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", *_BENCHED], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "?"
    return head + (" + local changes" if dirty else "")


def normal_angle(a: NDArray[np.floating], b: NDArray[np.floating], signed: bool = False) -> float:
    """Largest angle (rad) between corresponding unit vectors, up to sign unless signed (from the chord: accurate
    near 0)."""
    a64, b64 = np.asarray(a, np.float64), np.asarray(b, np.float64)
    chord = np.linalg.norm(a64 - b64, axis=1)
    if not signed:
        chord = np.minimum(chord, np.linalg.norm(a64 + b64, axis=1))
    return float(2.0 * np.arcsin(min(1.0, float(chord.max(initial=0.0)) / 2.0)))


def agreement(old: Any, new: Any) -> str:
    """How the old and new outputs compare: voxels and cameras bit for bit, normals by angle (unoriented ones up to
    sign; preprocess's, oriented toward the cameras, as they are)."""
    oriented = isinstance(old, ViewpointCloud)
    if isinstance(old, ViewpointCloud):
        old, new = (old.points, old.camera_source, old.normals), (new.points, new.camera_source, new.normals)
    if isinstance(old, np.ndarray):  # normals alone
        return f"normals max angle {normal_angle(old, new):.1e} rad (up to sign)"
    same = all(np.array_equal(a, b) for a, b in zip(old[:2], new[:2], strict=True))
    text = "same voxels, cameras" if same else "DIFFERENT voxels or cameras"
    if old[2] is not None and new[2] is not None:
        text += f"; oriented normals max angle {normal_angle(old[2], new[2], signed=oriented):.1e} rad"
    return text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--sizes", default="1000000,5000000", help="synthetic scan sizes (points), comma-separated")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "kernels.md"))
    args = ap.parse_args()

    load_before = _load()
    # case, stage, old s, new s, old CPU s, new CPU s, reference s, agreement
    rows: list[tuple[str, str, float, float, float, float, float, str]] = []

    def row(case: str, stage: str, old: Callable[[], Any], new: Callable[[], Any]) -> None:
        t_old, c_old, r_old = timed(old, args.repeats)
        t_new, c_new, r_new = timed(new, args.repeats)
        ref = statistics.median([r_old, r_new])
        agree = agreement(old(), new())
        rows.append((case, stage, t_old, t_new, c_old, c_new, ref, agree))
        print(f"{case:30s} {stage:26s} old {t_old * 1e3:8.1f} ms  new {t_new * 1e3:8.1f} ms  x{t_old / t_new:5.1f}  "
              f"CPU {c_old * 1e3:.0f} -> {c_new * 1e3:.0f} ms  (reference workload {ref * 1e3:.1f} ms)  {agree}",
              flush=True)

    workspace = PreprocessParams(voxel_size=VOXEL, workspace=(-0.65, 0.65, -0.45, 0.45, -0.01, 0.3))
    window = PreprocessParams(voxel_size=VOXEL, range_window=1.0)  # the detector's default, no workspace

    mug = table_mug()
    zeros = np.zeros(len(mug), np.int32)
    mug_vox = voxelize(mug, zeros, VOXEL)[0]
    mug_cloud = ViewpointCloud(points=mug, viewpoints=np.zeros(3, np.float32))
    row(f"table_mug ({len(mug)} pts)", "voxelize", partial(old_voxelize, mug, zeros, VOXEL),
        partial(voxelize, mug, zeros, VOXEL))
    row(f"table_mug voxels ({len(mug_vox)} pts)", "pca_normals", partial(old_pca_normals, mug_vox, RADIUS, MAX_NN),
        partial(pca_normals, mug_vox, RADIUS, MAX_NN))
    row(f"table_mug ({len(mug)} pts)", "preprocess", partial(old_preprocess, mug_cloud, PreprocessParams()),
        partial(preprocess, mug_cloud, PreprocessParams()))
    for n in (int(x) for x in args.sizes.split(",")):
        for shuffled in (False, True):
            pts, src, eyes = tabletop_scan(n, shuffled=shuffled)
            name = f"tabletop {len(pts) / 1e6:g}M{' shuffled' if shuffled else ''}"
            row(name, "voxelize", partial(old_voxelize, pts, src, VOXEL), partial(voxelize, pts, src, VOXEL))
            if n == 1_000_000 and not shuffled:
                vox = voxelize(pts, src, VOXEL)[0]
                row(f"tabletop 1M voxels ({len(vox)} pts)", "pca_normals",
                    partial(old_pca_normals, vox, RADIUS, MAX_NN), partial(pca_normals, vox, RADIUS, MAX_NN))
            cloud = ViewpointCloud(points=pts, viewpoints=eyes, camera_source=src)
            for label, params in (("workspace", workspace), ("range window", window)):
                row(name, f"preprocess ({label})", partial(old_preprocess, cloud, params),
                    partial(preprocess, cloud, params))
            del pts, src, cloud
    load_after = _load()

    lines = [
        f"# Compiled point kernels against the numpy code they replaced (bench/kernels.py, commit {_commit()}, "
        f"{time.strftime('%Y-%m-%d')})",
        "",
        f"Command: `PYTHONPATH=service:client:lab .venv/bin/python bench/kernels.py --repeats {args.repeats}"
        f"{'' if args.sizes == '1000000,5000000' else ' --sizes ' + args.sizes}`",
        "",
        f"Machine: {_cpu()}, {os.cpu_count()} cores, "
        f"thread budget {THREADS.cores}; load average (1, 5, 15 min) before {load_before}, after {load_after}.",
        "",
        "Medians of the runs after one warm-up: wall ms, and CPU ms of all the process's threads (the work done, "
        "less sensitive to other load than the wall time); `ref` is a fixed one-thread CPU workload (20 float64 "
        "256x256 matmuls + tanh) timed before each run, and `/ref` each wall time divided by it (comparable between "
        "runs on a machine whose load changed).  preprocess rows: the whole of preprocess (selection, voxels, "
        "normals); workspace: a box around the table; range window: the detector's default 1 m, no workspace.  "
        "Outputs: whether old and new give the same voxels and cameras (bit for bit), and the largest angle between "
        "their normals.",
        "",
        "| cloud | stage | old ms | new ms | old / new | old CPU ms | new CPU ms | ref ms | old /ref | new /ref "
        "| outputs |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for case, stage, t_old, t_new, c_old, c_new, ref, agree in rows:
        lines.append(f"| {case} | {stage} | {t_old * 1e3:.1f} | {t_new * 1e3:.1f} | {t_old / t_new:.1f} | "
                     f"{c_old * 1e3:.0f} | {c_new * 1e3:.0f} | {ref * 1e3:.1f} | {t_old / ref:.2f} | {t_new / ref:.2f} "
                     f"| {agree} |")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
