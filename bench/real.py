"""Real captures as a user sends them: every .pcd/.ply in ../shared/data/real/ (and --folder), uploaded as the
file is to a real server (the shipped models, default settings) through the robot-side client, once with the
workspace committed for it in bench/real_captures.json (a box around the table, in the capture's frame) and
once with no workspace (the whole frame).  Defaults only: no option but the workspace (and a viewpoint where the
file's own is not the camera's: krylon.pcd, a scan centred on the can), no filtering here.

Judged by the benchmark's own segmentation, not the service's: inside the capture's workspace box, the table is
the dominant RANSAC plane, object points lie 12 mm to 40 cm above it (toward the camera), in clusters of at
least MIN_CLUSTER 5 mm voxels (1.2 cm apart; smaller ones are speckle).  A grasp is on an object when its
closing region (between the fingers: hand depth along approach, the opening along binormal, the hand's height
along axis) holds at least MIN_POINTS object points; its object is the cluster holding most of them.  A capture
with no workspace entry (krylon.pcd: a lone can, no table) counts every point as the object.

Per capture and row: of the top 10 grasps, how many are on objects and how many objects they cover, the top 5's
share, the warnings' codes, and the request's time (warm: the second of two identical requests).  A picture of
the top grasps over the region the service worked on per row goes to bench/results/real/ (graspd.viz.plot; the
bench's objects blue, the rest as support).

  PYTHONPATH=service:client .venv/bin/python bench/real.py [--folder DIR] [--out bench/results/real.md]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "service"), str(ROOT / "client")]

from scipy.spatial import cKDTree  # noqa: E402

from graspd.core.cloud import ViewpointCloud  # noqa: E402
from graspd.core.grasp import GraspSet  # noqa: E402
from graspd.core.hand import HandGeometry  # noqa: E402
from graspd.core.points import eps_clusters, ransac_plane, voxel_groups  # noqa: E402
from graspd.gpd.environment import Label  # noqa: E402
from graspd.gpd.preprocess import DEFAULT_RANGE_WINDOW, region_mask  # noqa: E402
from graspd.gpd.scene import closing_region_points  # noqa: E402
from graspd.io.cloud_files import read_input  # noqa: E402
from graspd_client import Grasps  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"
CAPTURES = ROOT / "bench" / "real_captures.json"
MIN_CLUSTER = 40  # 5 mm voxels: a cluster smaller than ~1 cm^2 of surface is speckle, not an object
MIN_POINTS = 20  # object points in a closing region for the grasp to hold something
TOP = 10


def object_labels(points: NDArray[np.float32], box: list[float] | None) -> NDArray[np.int64]:
    """An object id per point (-1: table, background or speckle) by the benchmark's own segmentation."""
    labels = np.full(len(points), -1, np.int64)
    finite = np.isfinite(points).all(axis=1)
    if box is None:
        labels[finite] = 0
        return labels
    lo, hi = np.array(box[0::2]), np.array(box[1::2])
    inside = finite & np.all((points >= lo) & (points <= hi), axis=1)
    idx = np.flatnonzero(inside)
    p = points[idx].astype(np.float64)
    plane, _ = ransac_plane(p[:: max(1, len(p) // 50_000)], 0.01, iterations=300, seed=0)
    if plane[:3] @ -p.mean(axis=0) < 0:  # the normal toward the camera (at the origin of every capture here)
        plane = -plane
    height = p @ plane[:3] + plane[3]
    above = (height > 0.012) & (height < 0.4)
    q = p[above]
    vox, counts = voxel_groups(q, 0.005)
    centres = np.stack([np.bincount(vox, q[:, k]) for k in range(3)], axis=1) / counts[:, None]
    cluster = eps_clusters(centres, 0.012)
    sizes = np.bincount(cluster)
    keep = sizes[cluster] >= MIN_CLUSTER
    # renumber the kept clusters by size, largest first, so ids read the same on every run
    order = np.argsort(-sizes, kind="stable")
    rank = np.full(len(sizes), -1)
    rank[order[sizes[order] >= MIN_CLUSTER]] = np.arange(int((sizes >= MIN_CLUSTER).sum()))
    voxel_label = np.where(keep, rank[cluster], -1)
    labels[idx[above]] = voxel_label[vox]
    return labels


def grasp_objects(grasps: GraspSet, hand: HandGeometry, points: NDArray[np.float32],
                  labels: NDArray[np.int64]) -> NDArray[np.int64]:
    """The object (label) each grasp's closing region (graspd.gpd.scene.closing_region_points) holds most of,
    -1 when it holds under MIN_POINTS object points."""
    out = np.full(len(grasps), -1, np.int64)
    obj = np.flatnonzero(labels >= 0)
    if len(obj) == 0 or len(grasps) == 0:
        return out
    p = points[obj]
    region = closing_region_points(cKDTree(np.asarray(p, np.float64)), p, grasps.positions, grasps.rotations, hand)
    for i in range(len(grasps)):
        held = labels[obj[region.index[region.grasp == i]]]
        if len(held) >= MIN_POINTS:
            out[i] = int(np.bincount(held).argmax())
    return out


def grasp_set(answer: Grasps) -> GraspSet:
    """The client's parsed answer as a GraspSet (cloud frame)."""
    return GraspSet(positions=answer.poses[:, :3, 3], rotations=answer.rotations, widths=answer.widths,
                    scores=answer.scores, samples=answer.samples)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--folder", type=Path, action="append", default=[], help="more captures (.pcd, .ply)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "real.md")
    args = ap.parse_args(argv)

    from graspd.server.runner import serve_in_thread  # noqa: PLC0415
    from graspd.server.settings import Settings  # noqa: PLC0415
    from graspd.viz.plot import plot_grasps  # noqa: PLC0415
    from graspd_client import GraspClient  # noqa: PLC0415

    known: dict[str, dict[str, Any]] = json.loads(CAPTURES.read_text())
    captures = sorted(p for d in [REAL, *args.folder] for p in d.iterdir() if p.suffix in (".pcd", ".ply"))
    pictures = args.out.parent / "real"
    pictures.mkdir(parents=True, exist_ok=True)
    hand = HandGeometry()
    rows: list[dict[str, Any]] = []
    with serve_in_thread(Settings(port=0, zenoh_enabled=False)) as url, GraspClient(url, timeout=120) as client:
        for path in captures:
            entry = known.get(path.name, {})
            box, viewpoint = entry.get("workspace"), entry.get("viewpoint")
            given = None if viewpoint is None else np.asarray([viewpoint], np.float32)
            cloud = read_input(path, given).cloud
            labels = object_labels(cloud.points, box)
            for row, workspace in (("workspace", box), ("whole frame", None)):
                if row == "workspace" and box is None:
                    continue
                params: dict[str, Any] = {} if viewpoint is None else {"viewpoint": viewpoint}
                if workspace is not None:
                    params["workspace"] = ",".join(f"{v:g}" for v in workspace)
                client.detect_file(path, **params)  # the first request of a kind: warm
                t0 = time.perf_counter()
                answer = client.detect_file(path, **params)
                seconds = time.perf_counter() - t0
                body = answer.raw
                grasps = grasp_set(answer)
                on = grasp_objects(grasps[:TOP], hand, cloud.points, labels)
                codes = [w["code"] for w in body["warnings"]]
                rows.append({"capture": path.name, "row": row, "grasps": len(grasps), "top10_on": int((on >= 0).sum()),
                             "top10_n": int(min(TOP, len(grasps))), "top5_on": int((on[:5] >= 0).sum()),
                             "objects": int(len(set(on[on >= 0].tolist()))),
                             "objects_in_scene": int(labels.max() + 1), "warnings": codes, "seconds": seconds,
                             "points": int(np.isfinite(cloud.points).all(axis=1).sum())})
                picture = pictures / f"{path.stem}-{row.replace(' ', '-')}.png"
                # the region the service worked on (the workspace, else its range window), the bench's objects
                # drawn as objects and the rest as support
                shown_rows = np.flatnonzero(region_mask(cloud, None if workspace is None else tuple(workspace),
                                                        DEFAULT_RANGE_WINDOW))[::2]
                shown = ViewpointCloud(points=cloud.points[shown_rows], viewpoints=cloud.viewpoints)
                drawn = np.where(labels[shown_rows] >= 0, int(Label.OBJECT), int(Label.SUPPORT))
                plot_grasps(shown, grasps, hand, picture, top=TOP, title=f"{path.name}: {row}",
                            labels=drawn, warnings=body["warnings"])
                print(rows[-1], flush=True)
    load = os.getloadavg()
    lines = ["# Real captures: where the top grasps go", "",
             "Command: `PYTHONPATH=service:client .venv/bin/python bench/real.py`", "",
             f"Machine: {os.cpu_count()} cores, load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at the end. "
             "Server: the shipped models, default settings; each capture uploaded as the file is (the client's "
             "`detect_file`), with the workspace in `bench/real_captures.json` or none.  On an object: the "
             f"closing region holds >= {MIN_POINTS} points of the benchmark's own object segmentation (RANSAC "
             "table inside the workspace box, clusters 1.2 cm apart above it).  Pictures: `bench/results/real/`.",
             "", "| capture | request | points | top 10 on objects | top 5 on objects | objects covered (of) | "
             "warnings | time (s) |", "|---|---|---:|---:|---:|---:|---|---:|"]
    for r in rows:
        lines.append(f"| {r['capture']} | {r['row']} | {r['points']:,} | {r['top10_on']} / {r['top10_n']} | "
                     f"{r['top5_on']} / {min(5, r['top10_n'])} | {r['objects']} ({r['objects_in_scene']}) | "
                     f"{', '.join(r['warnings']) or 'none'} | {r['seconds']:.2f} |")
    args.out.write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")
    print("\n".join(lines[-len(rows) - 2:]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
