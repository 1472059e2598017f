"""Ground-truth grasp labels against full meshes: collision-free frictionless antipodal grasps.

IJRR paper, "A Grasp Dataset for Training the CNN": a candidate is a grasp when closing the fingers
from its pose forms a frictionless antipodal grasp, allowing every mesh vertex a position error of
1 mm; for a parallel-jaw hand this reduces to small contact regions on each finger and asking whether
any pair of contacts in them is antipodal.  Implementation, vectorised over candidates with open3d
raycasting (hand frame: x approach from the palm, y closing direction, z hand axis):

* Closing rays on a grid (x, z) over each finger's inner face, cast from the finger's outer face
  toward the other finger.  A hit closer than finger_width, or a back face first (the finger starts
  inside the object; grazing hits excepted), is a finger collision; otherwise the hit is a contact candidate at distance
  s = t - finger_width from the inner face.
* Palm/finger rays along +x on a grid (y, z) from palm_depth behind the palm: a hit before the palm
  (closing gap) or before the fingertips (finger columns), or a back face first, is a collision.
* Each finger's contact region: its rays with s within 2 * tolerance of its first contact (a 1 mm
  vertex error can move either surface by 1 mm).
* A pair of contacts on the same (x, z) ray line, one in each region, is antipodal when both surface
  normals lie within a slack angle of the closing line: frictionless, the slack is the tilt the
  tolerance allows the hit triangle, atan(2 tol / its smallest altitude), capped at max_slack_deg;
  with friction (mu given), the friction cone half-angle atan(mu) (Nguyen's two-contact force closure).
A candidate is positive when it is collision-free and has an antipodal pair.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from ..grasp import GraspSet
from ..hand import HandGeometry
from .render import MeshScene


@dataclass(frozen=True)
class LabelParams:
    """tolerance (m, the paper's 1 mm vertex error); mu None = frictionless antipodal, else the friction
    coefficient; ray spacing (m) over finger faces and the palm; palm_depth (m) the palm's thickness
    behind the hand base; max_slack_deg caps the frictionless normal slack of small triangles."""

    tolerance: float = 0.001
    mu: float | None = None
    max_slack_deg: float = 15.0
    ray_spacing: float = 0.002
    palm_ray_spacing: float = 0.004
    rows: int = 5
    palm_depth: float = 0.01
    chunk: int = 1024
    nthreads: int = 0

    def to_dict(self) -> dict[str, float | int | None]:
        return asdict(self)


@dataclass(frozen=True)
class Labels:
    """Per candidate (M,): grasp (the label), collision, antipodal (ignoring collision), first-contact
    distances of the left/right finger from its open inner face (m, inf = no contact), and the width
    between the first contacts (m)."""

    grasp: NDArray[np.bool_]
    collision: NDArray[np.bool_]
    antipodal: NDArray[np.bool_]
    left_contact: NDArray[np.float32]
    right_contact: NDArray[np.float32]
    width: NDArray[np.float32]


# A first hit on a back face means the ray starts inside the object; below this cosine the hit is a
# graze along a silhouette (a ray through a vertex of a tessellated curve), not an exit.
_BACK_FACE_COS = 0.2


def triangle_slack(mesh: o3d.geometry.TriangleMesh, tolerance: float, max_slack_deg: float) -> NDArray[np.float32]:
    """Cosine (T,) of the largest tilt (rad) of each triangle's normal reachable by moving its vertices by
    at most tolerance: atan(2 tol / smallest altitude), at most max_slack_deg."""
    v = np.asarray(mesh.vertices)
    t = np.asarray(mesh.triangles)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    longest = np.max(np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                               np.linalg.norm(a - c, axis=1)]), axis=0)
    altitude = area2 / np.maximum(longest, 1e-12)
    slack = np.minimum(np.arctan(2.0 * tolerance / np.maximum(altitude, 1e-9)), np.deg2rad(max_slack_deg))
    return np.cos(slack).astype(np.float32)


def _grid(lo: float, hi: float, spacing: float) -> NDArray[np.float64]:
    n = max(int(np.ceil((hi - lo) / spacing)), 1)
    return lo + (np.arange(n) + 0.5) * (hi - lo) / n


def label_grasps(meshes: list[o3d.geometry.TriangleMesh] | MeshScene, grasps: GraspSet, hand: HandGeometry,
                 params: LabelParams | None = None) -> Labels:
    """Labels of every candidate against the full meshes (world frame of the grasps, m)."""
    p = params or LabelParams()
    scene = meshes if isinstance(meshes, MeshScene) else MeshScene(list(meshes))
    if p.mu is None:
        cos_slack = [triangle_slack(m, p.tolerance, p.max_slack_deg) for m in scene.meshes]
    else:
        if p.mu <= 0:
            raise ValueError(f"label mu must be positive (or None for frictionless), got {p.mu}")
        cone = np.float32(np.cos(np.arctan(p.mu)))
        cos_slack = [np.full(len(m.triangles), cone, np.float32) for m in scene.meshes]
    slack_all = np.concatenate(cos_slack + [np.ones(1, np.float32)])
    offsets = np.cumsum([0] + [len(s) for s in cos_slack])

    od, fw, hd, hh = hand.hand_outer_diameter, hand.finger_width, hand.hand_depth, hand.hand_height
    gap = od / 2.0 - fw
    xs = _grid(0.0, hd, p.ray_spacing)
    zs = _grid(-hh / 2, hh / 2, hh / p.rows)
    ys = _grid(-od / 2, od / 2, p.palm_ray_spacing)
    gx, gz = (a.reshape(-1) for a in np.meshgrid(xs, zs, indexing="ij"))
    py, pz = (a.reshape(-1) for a in np.meshgrid(ys, zs, indexing="ij"))
    in_gap = np.abs(py) < gap
    palm_limit = np.where(in_gap, p.palm_depth, p.palm_depth + hd)

    m = len(grasps)
    out_grasp = np.zeros(m, bool)
    out_coll = np.zeros(m, bool)
    out_anti = np.zeros(m, bool)
    out_left = np.full(m, np.inf, np.float32)
    out_right = np.full(m, np.inf, np.float32)
    for a in range(0, m, p.chunk):
        sl = slice(a, min(a + p.chunk, m))
        pos = grasps.positions[sl]
        rot = grasps.rotations[sl]
        ax_, bn, hz = rot[:, :, 0], rot[:, :, 1], rot[:, :, 2]
        n = len(pos)
        base = pos[:, None, :] + gx[None, :, None] * ax_[:, None, :] + gz[None, :, None] * hz[:, None, :]
        left_o = base - (od / 2) * bn[:, None, :]
        right_o = base + (od / 2) * bn[:, None, :]
        dirs_l = np.broadcast_to(bn[:, None, :], left_o.shape)
        palm_o = (pos[:, None, :] - p.palm_depth * ax_[:, None, :] + py[None, :, None] * bn[:, None, :]
                  + pz[None, :, None] * hz[:, None, :])
        dirs_p = np.broadcast_to(ax_[:, None, :], palm_o.shape)
        origins = np.concatenate([left_o, right_o, palm_o], axis=1).astype(np.float32)
        dirs = np.concatenate([dirs_l, -dirs_l, dirs_p], axis=1).astype(np.float32)
        rays = np.concatenate([origins, dirs], axis=2).reshape(-1, 6)
        hit = scene.cast_rays(rays, p.nthreads)
        r = origins.shape[1]
        t = hit["t_hit"].numpy().reshape(n, r)
        nrm = hit["primitive_normals"].numpy().reshape(n, r, 3)
        gid = hit["geometry_ids"].numpy().astype(np.int64).reshape(n, r)
        pid = hit["primitive_ids"].numpy().astype(np.int64).reshape(n, r)
        hit_ok = np.isfinite(t)
        facing = np.einsum("nrk,nrk->nr", nrm, dirs)
        back = hit_ok & (facing > _BACK_FACE_COS)
        g = len(gx)
        tl, tr, tp = t[:, :g], t[:, g : 2 * g], t[:, 2 * g :]
        coll = (
            np.any((tl < fw) | back[:, :g], axis=1)
            | np.any((tr < fw) | back[:, g : 2 * g], axis=1)
            | np.any((tp < palm_limit[None, :]) | back[:, 2 * g :], axis=1)
        )
        sl_ = np.where((tl <= fw + 2 * gap) & ~back[:, :g], tl - fw, np.inf)
        sr_ = np.where((tr <= fw + 2 * gap) & ~back[:, g : 2 * g], tr - fw, np.inf)
        first_l = sl_.min(axis=1)
        first_r = sr_.min(axis=1)
        region_l = sl_ <= first_l[:, None] + 2 * p.tolerance
        region_r = sr_ <= first_r[:, None] + 2 * p.tolerance
        tri = np.where(hit_ok, offsets[np.minimum(gid, len(cos_slack) - 1)] + pid, len(slack_all) - 1)
        tri = np.where(gid < len(cos_slack), tri, len(slack_all) - 1)
        cos_ok = -facing >= slack_all[tri]  # outward normal within the slack of the closing line
        pair = region_l & region_r & cos_ok[:, :g] & cos_ok[:, g : 2 * g]
        anti = np.any(pair, axis=1) & np.isfinite(first_l) & np.isfinite(first_r)
        out_coll[sl] = coll
        out_anti[sl] = anti
        out_grasp[sl] = anti & ~coll
        out_left[sl] = first_l
        out_right[sl] = first_r
    width = np.where(np.isfinite(out_left) & np.isfinite(out_right), 2 * gap - out_left - out_right, np.nan)
    return Labels(grasp=out_grasp, collision=out_coll, antipodal=out_anti, left_contact=out_left,
                  right_contact=out_right, width=width.astype(np.float32))
