"""Organised captures, preprocessed with and without their image grid: time and what changes.

For each organised capture in ../shared/data/real (and --folder), the detector's preprocessing
(graspd.gpd.preprocess.preprocess, the detector's defaults: 3 mm voxels, the range window; and once more inside
the workspace of bench/real_captures.json) runs on the cloud as read (with its grid: mixed pixels dropped,
normals from image neighbours averaged per voxel) and on the same points without the grid (what the service did
before: PCA normals of the voxels, 1 cm radius, 30 neighbours).  Times are the median and the least of --repeat
runs after a warm-up run (compiled kernels loaded), the runs with and without the grid taken in turn.  Also: the
mixed pixels dropped, the angle between the two normals of the voxels both keep (same voxel grid), and how far
each one's normals on the table (the dominant plane's voxels) stray from the plane's normal: median and 90th
percentile.

  PYTHONPATH=service:client .venv/bin/python bench/grid_normals.py [--repeat 5] [--out bench/results/grid-normals.md]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "service"), str(ROOT / "client")]

from graspd.core.cloud import ViewpointCloud  # noqa: E402
from graspd.core.grid import veil_points  # noqa: E402
from graspd.core.points import ransac_plane  # noqa: E402
from graspd.gpd.preprocess import DEFAULT_RANGE_WINDOW, PreprocessParams, preprocess, region  # noqa: E402
from graspd.io.cloud_files import read_input  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"
CAPTURES = ROOT / "bench" / "real_captures.json"


def timed(clouds: list[ViewpointCloud], params: PreprocessParams, repeat: int
          ) -> list[tuple[float, float, ViewpointCloud]]:
    """Per cloud (least seconds, median seconds, the result) of repeat runs after one warm-up, the clouds' runs
    taken in turn (a load that comes and goes falls on both alike)."""
    outs = [preprocess(c, params) for c in clouds]
    times: list[list[float]] = [[] for _ in clouds]
    for _ in range(repeat):
        for k, c in enumerate(clouds):
            t = time.perf_counter()
            outs[k] = preprocess(c, params)
            times[k].append(time.perf_counter() - t)
    return [(float(np.min(t)), float(np.median(t)), o) for t, o in zip(times, outs, strict=True)]


def agreement(a: ViewpointCloud, b: ViewpointCloud, voxel: float) -> tuple[float, float, int]:
    """Median and 90th-percentile angle (degrees) between the normals of the voxels both clouds hold (matched by
    voxel cell), and how many."""
    def cells(c: ViewpointCloud) -> dict[tuple[int, int, int], int]:
        keys = np.floor(c.points / voxel).astype(np.int64)
        return {tuple(k): i for i, k in enumerate(keys.tolist())}

    ca, cb = cells(a), cells(b)
    both = [(i, cb[k]) for k, i in ca.items() if k in cb]
    if not both:
        return float("nan"), float("nan"), 0
    ia, ib = np.array(both).T
    assert a.normals is not None and b.normals is not None
    cos = np.clip(np.einsum("ij,ij->i", a.normals[ia], b.normals[ib]), -1.0, 1.0)
    deg = np.degrees(np.arccos(cos))
    return float(np.median(deg)), float(np.percentile(deg, 90)), len(both)


def table_spread(cloud: ViewpointCloud) -> tuple[float, float]:
    """Median and 90th-percentile angle (degrees) between the normals of the dominant plane's voxels (within
    5 mm of it: the table) and the plane's normal: how flat a flat surface's normals come out (real data has no
    other truth)."""
    pts = cloud.points.astype(np.float64)
    plane, _ = ransac_plane(pts, 0.005, iterations=300, seed=0)
    on = np.abs(pts @ plane[:3] + plane[3]) <= 0.005
    assert cloud.normals is not None
    cos = np.clip(np.abs(cloud.normals[on] @ plane[:3]), 0.0, 1.0)
    deg = np.degrees(np.arccos(cos))
    return float(np.median(deg)), float(np.percentile(deg, 90))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--folder", type=Path, action="append", default=[], help="more captures (.pcd)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "grid-normals.md")
    args = ap.parse_args(argv)
    known: dict[str, dict[str, Any]] = json.loads(CAPTURES.read_text())
    rows: list[dict[str, Any]] = []
    for path in sorted(p for d in [REAL, *args.folder] for p in d.iterdir() if p.suffix == ".pcd"):
        cloud = read_input(path).cloud
        if cloud.grid is None:
            continue
        box = known.get(path.name, {}).get("workspace")
        for name, params in (("range window", PreprocessParams(range_window=DEFAULT_RANGE_WINDOW)),
                             ("workspace", PreprocessParams(workspace=None if box is None else tuple(box)))):
            (grid_min, grid_s, with_grid), (flat_min, flat_s, without) = timed(
                [cloud, replace(cloud, grid=None)], params, args.repeat)
            kept = region(cloud, params.workspace, params.range_window, finite_normals=True)
            assert cloud.grid is not None
            mixed = int(veil_points(cloud.points, cloud.camera_source, cloud.viewpoints, cloud.grid, kept.mask).sum())
            med, p90, matched = agreement(with_grid, without, params.voxel_size)
            table_grid, table_pca = table_spread(with_grid), table_spread(without)
            rows.append({"capture": path.name, "region": name, "points": int(kept.count), "mixed": mixed,
                         "voxels_grid": len(with_grid), "voxels_pca": len(without), "seconds_grid": grid_s,
                         "seconds_pca": flat_s, "least_grid": grid_min, "least_pca": flat_min, "angle_median": med,
                         "angle_p90": p90, "matched": matched, "table_grid": table_grid, "table_pca": table_pca})
            print(rows[-1], flush=True)
    load = os.getloadavg()
    lines = ["# Organised captures: preprocessing with the image grid (mixed pixels out, grid normals) and without",
             "", "Command: `PYTHONPATH=service:client .venv/bin/python bench/grid_normals.py --repeat "
             f"{args.repeat}`", "",
             f"Machine: {os.cpu_count()} cores, load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at the "
             f"end; median and least of {args.repeat} runs each after a warm-up, the two taken in turn.  'without' "
             "is the same points as an "
             "unorganised cloud (PCA normals of the 3 mm voxels).", "",
             "| capture | region | points | mixed pixels dropped | voxels (grid / without) | preprocess ms, median "
             "(grid / without) | least | grid vs PCA normals, median / p90 (deg) | table normals off its plane, "
             "median / p90 (deg; grid, PCA) |", "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['capture']} | {r['region']} | {r['points']:,} | {r['mixed']:,} | "
                     f"{r['voxels_grid']:,} / {r['voxels_pca']:,} | {1e3 * r['seconds_grid']:.0f} / "
                     f"{1e3 * r['seconds_pca']:.0f} | {1e3 * r['least_grid']:.0f} / {1e3 * r['least_pca']:.0f} | "
                     f"{r['angle_median']:.1f} / {r['angle_p90']:.1f} | {r['table_grid'][0]:.1f} / "
                     f"{r['table_grid'][1]:.1f}; {r['table_pca'][0]:.1f} / {r['table_pca'][1]:.1f} |")
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines[-len(rows) - 2:]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
