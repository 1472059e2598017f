"""Ground-truth grasp labels against full meshes: collision-free frictionless antipodal grasps.

IJRR paper, "A Grasp Dataset for Training the CNN": a candidate is a grasp when closing the fingers
from its pose forms a frictionless antipodal grasp, allowing every mesh vertex a position error of
1 mm; for a parallel-jaw hand this reduces to small contact regions on each finger and asking whether
any pair of contacts in them is antipodal.  Implementation, vectorised over candidates with open3d
raycasting (hand frame: x approach from the palm, y closing direction, z hand axis):

* Closing rays on a grid (x, z) over each finger's inner face, cast from the finger's outer face
  toward the other finger.  A hit more than tolerance inside the finger's width, or a back face first
  (the finger starts inside the object; grazing hits excepted), is a finger collision; otherwise the
  hit is a contact candidate at distance s = t - finger_width from the inner face.
* Palm/finger rays along +x on a grid (y, z) from palm_depth behind the palm: a hit more than
  approach_tolerance before the palm (closing gap) or the fingertips (finger columns), or a back face
  first, is a collision (cast only for candidates that are otherwise grasps: elsewhere they cannot
  change the label).
* Each finger's contact region: its rays with s within 2 * tolerance of its first contact (a 1 mm
  vertex error can move either surface by 1 mm).
* A pair of contacts on the same (x, z) ray line, one in each region, is antipodal when both surface
  normals lie within a slack angle of the closing line.  Frictionless, the slack is the tilt the
  tolerance allows a surface patch the size of the finger pad: moving its edges by 1 mm each way
  tilts it by atan(2 tol / contact_patch), contact_patch = finger_width by default (11.3 deg for
  GPD's 1 cm fingers); independent of how finely the mesh is tessellated.  With friction (mu given),
  the slack is the friction cone half-angle atan(mu) (Nguyen's two-contact force closure).
A candidate is positive when it is collision-free and has an antipodal pair.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from graspd.core.grasp import GraspSet
from graspd.core.hand import HandGeometry
from graspd_lab.world.render import MeshScene


@dataclass(frozen=True)
class LabelParams:
    """tolerance (m, the paper's 1 mm vertex error); mu None = frictionless antipodal, else the friction
    coefficient; approach_tolerance (m) how far the object may reach past the palm or fingertip plane
    (the hand then stops that much short: it was placed against a noisy cloud, about 2 sigma of the
    sensor noise); contact_patch (m, None = the hand's finger_width) sets the frictionless normal slack;
    ray spacing (m) over finger faces and the palm; palm_depth (m) how far behind the hand base the palm
    rays start (None = the hand's own palm model, HandGeometry.palm_depth).  The default 0.01 is what the
    shipped datasets and models were labelled with; HandGeometry's default palm is 0.02 m deep, so None
    would change the labels of the default hand (kept, not silently changed).  approach_path (m): the
    palm and finger columns must also be free this far back along the approach, the path the open hand
    travels to the grasp (scene data: the service's approach_distance; 0 for the single-object data)."""

    tolerance: float = 0.001
    approach_tolerance: float = 0.003
    mu: float | None = None
    contact_patch: float | None = None
    ray_spacing: float = 0.002
    palm_ray_spacing: float = 0.004
    rows: int = 5
    palm_depth: float | None = 0.01
    approach_path: float = 0.0
    chunk: int = 1024
    nthreads: int = 0

    def to_dict(self) -> dict[str, float | int | None]:
        return asdict(self)


@dataclass(frozen=True)
class Labels:
    """Per candidate (M,): grasp (the label), collision (fingers always; palm only where antipodal and
    the fingers are free), antipodal (ignoring collision), first-contact
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


def normal_slack_deg(hand: HandGeometry, params: LabelParams) -> float:
    """Largest angle (deg) between a contact normal and the closing line for the contact to count."""
    if params.mu is not None:
        if params.mu <= 0:
            raise ValueError(f"label mu must be positive (or None for frictionless), got {params.mu}")
        return float(np.rad2deg(np.arctan(params.mu)))
    patch = hand.finger_width if params.contact_patch is None else params.contact_patch
    if patch <= 0 or params.tolerance < 0:
        raise ValueError("label contact_patch must be positive and tolerance non-negative")
    return float(np.rad2deg(np.arctan(2.0 * params.tolerance / patch)))


def _cone_pairs(cl: NDArray[np.floating], nl: NDArray[np.floating], ml: NDArray[np.bool_],
                cr: NDArray[np.floating], nr: NDArray[np.floating], mr: NDArray[np.bool_], cos_cone: float,
                gl: NDArray[np.int64] | None = None, gr: NDArray[np.int64] | None = None) -> NDArray[np.bool_]:
    """Whether some contact pair (one of each finger's region, masks ml/mr (n,g)) has the line between its
    contacts (n,g,3) inside both friction cones about the inward normals (outward normals nl/nr); with mesh
    ids gl/gr (n,g), only pairs on one mesh count."""
    u = cr[:, None, :, :] - cl[:, :, None, :]  # (n, g_left, g_right, 3)
    u /= np.maximum(np.linalg.norm(u, axis=3, keepdims=True), 1e-9)
    ok_l = -np.einsum("nlk,nlrk->nlr", nl, u) >= cos_cone
    ok_r = np.einsum("nrk,nlrk->nlr", nr, u) >= cos_cone
    ok = ok_l & ok_r & ml[:, :, None] & mr[:, None, :]
    if gl is not None and gr is not None:
        ok &= gl[:, :, None] == gr[:, None, :]
    return np.any(ok, axis=(1, 2))


def _cast(scene: MeshScene, pos: NDArray[np.float32], rot: NDArray[np.float32], local: NDArray[np.float32],
          axis: int, nthreads: int, sign: tuple[int, float] | None = None
          ) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.int64]]:
    """Cast rays from hand-frame origins local (R,3) of every hand (n) along hand axis `axis` (the last
    R - sign[0] rays reversed by sign[1]); returns t_hit (n,R) (m, inf = miss), hit normals (n,R,3) and the
    hit meshes' indices (n,R; -1 = miss)."""
    n, r = len(pos), len(local)
    rays = np.empty((n, r, 6), np.float32)
    rays[:, :, :3] = pos[:, None, :] + np.matmul(local[None], rot.transpose(0, 2, 1))
    rays[:, :, 3:] = rot[:, None, :, axis]
    if sign is not None:
        rays[:, sign[0]:, 3:] *= sign[1]
    hit = scene.cast_rays(rays.reshape(-1, 6), nthreads)
    t = hit["t_hit"].numpy().reshape(n, r)
    gid = np.where(np.isfinite(t), hit["geometry_ids"].numpy().astype(np.int64).reshape(n, r), -1)
    return t, hit["primitive_normals"].numpy().reshape(n, r, 3), gid


def _grid(lo: float, hi: float, spacing: float) -> NDArray[np.float64]:
    n = max(int(np.ceil((hi - lo) / spacing)), 1)
    return lo + (np.arange(n) + 0.5) * (hi - lo) / n


def label_grasps(meshes: list[o3d.geometry.TriangleMesh] | MeshScene, grasps: GraspSet, hand: HandGeometry,
                 params: LabelParams | None = None, graspable: NDArray[np.bool_] | None = None) -> Labels:
    """Labels of every candidate against the full meshes (world frame of the grasps, m).  graspable (one
    flag per mesh; None = all): an antipodal pair counts only with both contacts on one graspable mesh, so a
    scene's table, tray walls and two touching objects are never a grasp (they still collide)."""
    p = params or LabelParams()
    if p.approach_path < 0:
        raise ValueError(f"label approach_path must be >= 0 m, got {p.approach_path}")
    scene = meshes if isinstance(meshes, MeshScene) else MeshScene(list(meshes))
    cos_slack = float(np.cos(np.deg2rad(normal_slack_deg(hand, p))))

    od, fw, hd, hh = hand.hand_outer_diameter, hand.finger_width, hand.hand_depth, hand.hand_height
    gap = od / 2.0 - fw
    xs = _grid(0.0, hd, p.ray_spacing)
    zs = _grid(-hh / 2, hh / 2, hh / p.rows)
    ys = _grid(-od / 2, od / 2, p.palm_ray_spacing)
    gx, gz = (a.reshape(-1) for a in np.meshgrid(xs, zs, indexing="ij"))
    py, pz = (a.reshape(-1) for a in np.meshgrid(ys, zs, indexing="ij"))
    in_gap = np.abs(py) < gap
    palm_depth = hand.palm_depth if p.palm_depth is None else p.palm_depth
    palm_limit = np.where(in_gap, palm_depth, palm_depth + hd) + p.approach_path

    left_local = np.stack([gx, np.full_like(gx, -od / 2), gz], axis=1).astype(np.float32)
    right_local = left_local * np.array([1.0, -1.0, 1.0], np.float32)
    palm_local = np.stack([np.full_like(py, -palm_depth - p.approach_path), py, pz], axis=1).astype(np.float32)
    g = len(gx)

    m = len(grasps)
    out_grasp = np.zeros(m, bool)
    out_coll = np.zeros(m, bool)
    out_anti = np.zeros(m, bool)
    out_left = np.full(m, np.inf, np.float32)
    out_right = np.full(m, np.inf, np.float32)
    for a in range(0, m, p.chunk):
        sl = slice(a, min(a + p.chunk, m))
        pos = grasps.positions[sl].astype(np.float32)
        rot = grasps.rotations[sl].astype(np.float32)
        bn = rot[:, :, 1]
        # Closing rays: from each finger's outer face toward the other finger.
        t, nrm, gid = _cast(scene, pos, rot, np.concatenate([left_local, right_local]), 1, p.nthreads,
                            sign=(g, -1.0))
        dirs = np.concatenate([np.broadcast_to(bn[:, None, :], (len(pos), g, 3)),
                               np.broadcast_to(-bn[:, None, :], (len(pos), g, 3))], axis=1)
        hit_ok = np.isfinite(t)
        facing = np.einsum("nrk,nrk->nr", nrm, dirs)
        back = hit_ok & (facing > _BACK_FACE_COS)
        tl, tr = t[:, :g], t[:, g:]
        coll = np.any((t < fw - p.tolerance) | back, axis=1)
        sl_ = np.where((tl <= fw + 2 * gap) & ~back[:, :g], tl - fw, np.inf)
        sr_ = np.where((tr <= fw + 2 * gap) & ~back[:, g:], tr - fw, np.inf)
        first_l = sl_.min(axis=1)
        first_r = sr_.min(axis=1)
        region_l = sl_ <= first_l[:, None] + 2 * p.tolerance
        region_r = sr_ <= first_r[:, None] + 2 * p.tolerance
        cos_ok = hit_ok & (-facing >= cos_slack)  # outward normal within the slack of the closing line
        pair = region_l & region_r & cos_ok[:, :g] & cos_ok[:, g:]
        if graspable is not None:  # both contacts of a pair on one graspable mesh
            gl, gr = gid[:, :g], gid[:, g:]
            one = (gl == gr) & (gl >= 0) & graspable[np.maximum(gl, 0)]
            pair &= one
            region_l &= (gl < 0) | graspable[np.maximum(gl, 0)]
            region_r &= (gr < 0) | graspable[np.maximum(gr, 0)]
        both = np.isfinite(first_l) & np.isfinite(first_r)
        anti = np.any(pair, axis=1) & both
        if p.mu is not None:  # with friction the contacts need not face each other along y
            todo = np.nonzero(~anti & both)[0]
            nl = np.einsum("nrk,nkj->nrj", nrm[:, :g], rot)  # outward normals in the hand frame
            nr = np.einsum("nrk,nkj->nrj", nrm[:, g:], rot)
            gxb, gzb = np.broadcast_to(gx, sl_.shape), np.broadcast_to(gz, sl_.shape)
            cl = np.stack([gxb, -gap + np.where(region_l, sl_, 0.0), gzb], axis=2)
            cr = np.stack([gxb, gap - np.where(region_r, sr_, 0.0), gzb], axis=2)
            for b in range(0, len(todo), 64):
                i = todo[b : b + 64]
                anti[i] = _cone_pairs(cl[i], nl[i], region_l[i], cr[i], nr[i], region_r[i], cos_slack,
                                      None if graspable is None else gid[i, :g],
                                      None if graspable is None else gid[i, g:])
        # Palm and finger columns along the approach: only where they can still change the label.
        check = np.flatnonzero(anti & ~coll)
        if len(check):
            tp, nrm_p, _ = _cast(scene, pos[check], rot[check], palm_local, 0, p.nthreads)
            facing_p = np.einsum("nrk,nk->nr", nrm_p, rot[check, :, 0])
            back_p = np.isfinite(tp) & (facing_p > _BACK_FACE_COS)
            coll[check] |= np.any((tp < palm_limit[None, :] - p.approach_tolerance) | back_p, axis=1)
        out_coll[sl] = coll
        out_anti[sl] = anti
        out_grasp[sl] = anti & ~coll
        out_left[sl] = first_l
        out_right[sl] = first_r
    width = np.where(np.isfinite(out_left) & np.isfinite(out_right), 2 * gap - out_left - out_right, np.nan)
    return Labels(grasp=out_grasp, collision=out_coll, antipodal=out_anti, left_contact=out_left,
                  right_contact=out_right, width=width.astype(np.float32))
