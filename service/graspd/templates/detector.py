"""Template detection (Herzog et al. 2012, Fig. 2): candidate templates on the object, matched against the
library with eq. 2, ranked by their best match; each candidate's best library grasp is set into the
candidate's template frame and returned in the common grasp convention (graspd.core.grasp)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudError, ViewpointCloud
from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd.core.types import F64
from graspd.gpd.preprocess import voxelize
from graspd.templates.collision import closing_widths, hand_collisions
from graspd.templates.geometry import TemplateError, candidate_templates, prepare_scene
from graspd.templates.library import TemplateLibrary
from graspd.templates.matching import match

Workspace = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class TemplateParams:
    """rotations r about each height axis; hull triangles merged into one axis within merge_angle_deg;
    reject_collisions drops grasps whose open hand would hold a cloud point in a finger or the palm, or
    reach below the table (the paper leaves this "feasible" test to the planner); record stores the
    returned grasps so feedback can name them, keep_cloud also stores the cloud (so feedback can encode
    the GPD grasp image); table segments the dominant plane out."""

    rotations: int = 16
    merge_angle_deg: float = 20.0
    reject_collisions: bool = True
    record: bool = True
    keep_cloud: bool = True
    table: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.rotations, (int, np.integer)) or not 1 <= self.rotations <= 360:
            raise TemplateError("rotations", f"must be an integer in [1, 360], got {self.rotations!r}")
        if not 0.0 <= self.merge_angle_deg < 90.0:
            raise TemplateError("merge_angle_deg", f"must lie in [0, 90), got {self.merge_angle_deg!r}")


@dataclass(frozen=True)
class TemplateDetection:
    """Grasps best first (score = 1 / (1 + m), m the eq. 2 mismatch), the id of each for feedback, the
    library entry each came from, the candidate template frame (4x4, columns x, y, height axis; origin on
    the hull; grasps.samples is its origin), per-stage timings (s) and counts."""

    grasps: GraspSet
    grasp_ids: list[str]
    entry_ids: NDArray[np.int64]
    mismatch: F64
    frames: F64
    timings: dict[str, float]
    num_candidates: int
    num_points: int
    num_entries: int
    detection_id: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: {"method": "templates", "grasps": [GRASP + id, template_entry, mismatch], ...}."""
        grasps = self.grasps.to_dicts()
        for g, gid, e, m in zip(grasps, self.grasp_ids, self.entry_ids, self.mismatch, strict=True):
            g["id"] = gid
            g["template_entry"] = int(e)
            g["mismatch"] = float(m) if np.isfinite(m) else None
        return {"method": "templates", "grasps": grasps, "timings": dict(self.timings),
                "num_candidates": self.num_candidates, "num_points": self.num_points,
                "num_entries": self.num_entries, "detection_id": self.detection_id}


def cloud_arrays(cloud: ViewpointCloud, voxel: float = 0.003) -> dict[str, NDArray[Any]]:
    """The cloud to keep with a detection, small: voxelized at GPD's default 3 mm (graspd.gpd.preprocess, which
    GPD's grasp images start from anyway), stored as float16 offsets (~0.1 mm steps) from its centre."""
    pts, src, _ = voxelize(cloud.points, cloud.camera_source, voxel)
    centre = pts.astype(np.float64).mean(axis=0) if len(pts) else np.zeros(3)
    return {"centre": centre, "offsets": (pts - centre).astype(np.float16), "viewpoints": cloud.viewpoints,
            "camera_source": src.astype(np.int16)}


class TemplateDetector:
    """Detects grasps by template matching against a TemplateLibrary (whose hand it uses)."""

    def __init__(self, library: TemplateLibrary, params: TemplateParams | None = None) -> None:
        self.library = library
        self.params = params or TemplateParams()

    @property
    def hand(self) -> HandGeometry:
        """The library's hand."""
        return self.library.hand

    def detect(self, cloud: ViewpointCloud, max_grasps: int = 100, workspace: Workspace | None = None,
               params: TemplateParams | None = None) -> TemplateDetection:
        """Grasps for the object in cloud (table + one object, cloud frame), best first, at most max_grasps.
        An empty library gives no grasps.  TemplateError / CloudError name the offending field."""
        p = params or self.params
        if not isinstance(max_grasps, (int, np.integer)) or max_grasps < 1:
            raise TemplateError("max_grasps", f"must be a positive integer, got {max_grasps!r}")
        if len(cloud) == 0:
            raise CloudError("cloud.points", "is empty")
        hand, geom = self.library.hand, self.library.geometry
        times: dict[str, float] = {}
        t0 = time.perf_counter()
        scene = prepare_scene(cloud, geom, workspace, table=p.table, seed=p.seed)
        t1 = time.perf_counter()
        times["segment"] = t1 - t0
        origins, frames, heights, types = candidate_templates(scene, p.rotations, p.merge_angle_deg)
        t2 = time.perf_counter()
        times["templates"] = t2 - t1
        snap = self.library.snapshot()
        t3 = time.perf_counter()
        times["library"] = t3 - t2
        empty = TemplateDetection(GraspSet(), [], np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 4, 4)), times,
                                  len(heights), len(cloud), len(snap))
        if len(snap) == 0:
            times["total"] = time.perf_counter() - t0
            return empty
        m, _ = match(heights, types, snap.heights, snap.types, snap.f_heights, snap.f_types, snap.f_owner,
                     snap.gamma)
        best = np.argmin(m, axis=1)
        best_m = m[np.arange(len(m)), best]
        order = np.argsort(best_m, kind="stable")
        order = order[np.isfinite(best_m[order])]
        t4 = time.perf_counter()
        times["match"] = t4 - t3
        cand_pose = np.zeros((len(order), 4, 4))
        cand_pose[:, :3, :3] = frames[order]
        cand_pose[:, :3, 3] = origins[order]
        cand_pose[:, 3, 3] = 1.0
        poses = cand_pose @ snap.grasps[best[order]]
        keep = np.ones(len(order), bool)
        if p.reject_collisions:  # in rank order, a chunk at a time, until max_grasps are collision-free
            step, done = max(2 * int(max_grasps), 32), 0
            while done < len(order) and keep[:done].sum() < max_grasps:
                end = min(done + step, len(order))
                keep[done:end] = ~hand_collisions(scene, poses[done:end, :3, 3], poses[done:end, :3, :3], hand)
                done = end
            keep[done:] = False
        sel = np.flatnonzero(keep)[:max_grasps]
        rows, poses, cand_pose = order[sel], poses[sel], cand_pose[sel]
        widths = closing_widths(scene, poses[:, :3, 3], poses[:, :3, :3], hand, snap.widths[best[rows]])
        mism = best_m[rows]
        grasps = GraspSet(positions=poses[:, :3, 3].copy(), rotations=poses[:, :3, :3].copy(), widths=widths,
                          scores=1.0 / (1.0 + mism), samples=origins[rows].copy())
        entry_ids = snap.entry_ids[best[rows]]
        t5 = time.perf_counter()
        times["grasps"] = t5 - t4
        det_id, ids = None, [""] * len(rows)
        if p.record and len(rows):
            det_id = self.library.record_detection(heights[rows], types[rows], entry_ids, poses, widths, mism,
                                                   cloud_arrays(cloud) if p.keep_cloud else None)
            ids = [f"{det_id}.{k}" for k in range(len(rows))]
        t6 = time.perf_counter()
        times["record"] = t6 - t5
        times["total"] = t6 - t0
        return TemplateDetection(grasps, ids, entry_ids, mism, cand_pose, times, len(heights), len(cloud), len(snap),
                                 det_id)
