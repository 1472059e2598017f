"""Grasp templates (Herzog et al. 2012, Sec. II-A/B): height maps around a height axis, with region types.

A template frame has its origin on a convex-hull facet of the object, z = the facet's outward normal
(the height axis h), x/y = a rotation about h.  The n x n tiles cover [-size/2, size/2]^2 in x/y; each
tile stores the depth (m, >= 0) below the plane z = 0 along -h of the first thing met in the tile's
column, limited to the gripper box depth `depth`, and a region type (paper's Fig. 3):
  surface     an object point lies in the column (height of the highest one);
  occlusion   the column enters space no camera saw (height of the upper bound of that space);
  background  the column reaches the table (height of the table);
  void        nothing within the box (height = box depth).
The table is segmented out with a RANSAC plane (graspd.core.points.ransac_plane) and only the points above it are
the object.  All frames are the cloud's frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import minimum_filter
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from graspd.core.cloud import ViewpointCloud
from graspd.core.errors import FieldError
from graspd.core.hand import HandGeometry
from graspd.core.points import ransac_plane, voxel_downsample
from graspd.core.types import F32, F64

U8 = NDArray[np.uint8]

SURFACE, VOID, OCCLUSION, BACKGROUND = 0, 1, 2, 3
REGION_NAMES: tuple[str, ...] = ("surface", "void", "occlusion", "background")


class TemplateError(FieldError):
    """Input that no template can be made from; `field` names the offending one (e.g. "hand_pose")."""


@dataclass(frozen=True)
class TemplateGeometry:
    """n x n tiles over a size x size square (m) and the gripper box depth (m) along -h."""

    n: int = 30
    size: float = 0.15
    depth: float = 0.09

    def __post_init__(self) -> None:
        if not isinstance(self.n, (int, np.integer)) or self.n < 2:
            raise TemplateError("template.n", f"must be an integer >= 2, got {self.n!r}")
        for name in ("size", "depth"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise TemplateError(f"template.{name}", f"must be a positive number of metres, got {value!r}")

    @property
    def tile(self) -> float:
        """Tile side (m)."""
        return self.size / self.n

    @property
    def num_tiles(self) -> int:
        return self.n * self.n

    @staticmethod
    def for_hand(hand: HandGeometry, n: int = 30) -> TemplateGeometry:
        """Sized from the gripper, as the paper does (15 cm for the PR2): the square covers the open hand
        and its reach with a 25% margin; the box reaches 1.5 hand depths below the plane."""
        size = 1.25 * max(hand.hand_outer_diameter, 2.0 * hand.hand_depth)
        return TemplateGeometry(n=n, size=round(size, 6), depth=round(1.5 * hand.hand_depth, 6))

    def tile_centres(self) -> F64:
        """(n*n, 2) tile centres (u, v) in the template's x/y, row-major over (i along x, j along y)."""
        c = (np.arange(self.n) + 0.5) * self.tile - self.size / 2.0
        u, v = np.meshgrid(c, c, indexing="ij")
        return np.stack([u.ravel(), v.ravel()], axis=1)


@dataclass(frozen=True)
class TablePlane:
    """Plane normal . p + offset = 0, normal unit and pointing toward the cameras (up)."""

    normal: F64
    offset: float

    def height(self, points: NDArray[np.floating]) -> F64:
        """Signed height (m) above the table of points (...,3)."""
        return np.einsum("...j,j->...", np.asarray(points, np.float64), self.normal) + self.offset


def segment_table(points: F32, viewpoints: F32, distance: float = 0.005, min_fraction: float = 0.1,
                  seed: int = 0, max_fit_points: int = 20000) -> tuple[TablePlane | None, NDArray[np.bool_]]:
    """The dominant plane (graspd.core.points.ransac_plane on at most max_fit_points, seeded) as the table if it holds
    min_fraction of the points, and the mask of points within distance (m) of it; (None, all False)
    if there is no such plane."""
    mask = np.zeros(len(points), bool)
    if len(points) < 50:
        return None, mask
    fit = points
    if len(points) > max_fit_points:
        fit = points[np.random.default_rng(seed).choice(len(points), max_fit_points, replace=False)]
    model, inliers = ransac_plane(fit, distance, iterations=200, seed=seed)
    if inliers < min_fraction * len(fit):
        return None, mask
    normal = np.asarray(model[:3], np.float64)
    scale = float(np.linalg.norm(normal))
    normal, offset = normal / scale, float(model[3]) / scale
    if float(np.mean(viewpoints.astype(np.float64) @ normal + offset)) < 0.0:
        normal, offset = -normal, -offset
    plane = TablePlane(normal=normal, offset=offset)
    mask = np.abs(plane.height(points)) < distance
    return plane, mask


@dataclass(frozen=True)
class DepthMap:
    """What one camera saw: the least depth (m, along `forward`) per pixel of a pinhole image whose
    pixels are `pixel` wide in tangent units, covering pixel rows/cols from `origin`."""

    position: F64
    basis: F64  # rows: forward, right, down
    pixel: float
    origin: NDArray[np.int64]
    depth: F32

    def occluded(self, points: F64, tolerance: float) -> NDArray[np.bool_]:
        """Whether each point (P,3) lies more than tolerance (m) behind what this camera saw."""
        d = np.asarray(points, np.float64) - self.position
        f, r, w = (d[:, 0:1] * self.basis[:, 0] + d[:, 1:2] * self.basis[:, 1] + d[:, 2:3] * self.basis[:, 2]).T
        return self.occluded_local(f.astype(np.float32), r.astype(np.float32), w.astype(np.float32), tolerance)

    def occluded_local(self, z: F32, right: F32, down: F32, tolerance: float) -> NDArray[np.bool_]:
        """As occluded, for points given in this camera's basis (depth z, right, down; m), any shape."""
        inv = np.float32(1.0 / self.pixel) / np.maximum(z, np.float32(1e-6))
        h, w = self.depth.shape
        r = np.floor(right * inv).astype(np.int32) - np.int32(self.origin[0])
        c = np.floor(down * inv).astype(np.int32) - np.int32(self.origin[1])
        ok = (z > 1e-6) & (r >= 0) & (r < h) & (c >= 0) & (c < w)
        seen = self.depth.reshape(-1)[np.where(ok, r * np.int32(w) + c, 0)]
        return ok & (z > seen + np.float32(tolerance))


def depth_map(points: F64, camera: F64, look_at: F64, spacing: float) -> DepthMap | None:
    """The depth image of points seen from camera, pixels ~2 point spacings wide at the points' range,
    one-pixel holes closed; None without points in front of the camera."""
    forward = look_at - camera
    norm = float(np.linalg.norm(forward))
    if norm < 1e-9:
        return None
    forward = forward / norm
    helper = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    right = np.cross(forward, helper)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    basis = np.stack([forward, right, down])
    local = np.einsum("pj,kj->pk", points - camera, basis)  # not BLAS: its threads spin on a busy host
    local = local[local[:, 0] > 1e-6]
    if len(local) == 0:
        return None
    pixel = 2.0 * spacing / float(np.median(local[:, 0]))
    r = np.floor(local[:, 1] / local[:, 0] / pixel).astype(np.int64)
    c = np.floor(local[:, 2] / local[:, 0] / pixel).astype(np.int64)
    origin = np.array([r.min() - 1, c.min() - 1])
    shape = (int(r.max() - origin[0] + 2), int(c.max() - origin[1] + 2))
    depth = np.full(shape, np.inf)
    np.minimum.at(depth, (r - origin[0], c - origin[1]), local[:, 0])
    closed = minimum_filter(depth, size=3, mode="constant", cval=np.inf)
    depth = np.where(np.isinf(depth), closed, depth).astype(np.float32)
    return DepthMap(position=camera, basis=basis, pixel=pixel, origin=origin, depth=depth)


@dataclass(frozen=True)
class TemplateScene:
    """A cloud made ready for template extraction: object points (downsampled to a fraction of a tile),
    their kd-tree, the table plane, and one depth map per camera for the occlusion test."""

    object_points: F64
    segments: NDArray[np.int64]  # (N,) connected piece of each object point (0..S-1)
    tree: cKDTree
    table: TablePlane | None
    depth_maps: tuple[DepthMap, ...]
    viewpoints: F64
    geometry: TemplateGeometry
    num_points: int

    def unobserved(self, points: F64) -> NDArray[np.bool_]:
        """Whether each point (P,3) is hidden from every camera (occluded by what each camera saw)."""
        if not self.depth_maps:
            return np.zeros(len(points), bool)
        out = np.ones(len(points), bool)
        for dm in self.depth_maps:
            out &= dm.occluded(points, self.geometry.tile)
        return out


def prepare_scene(cloud: ViewpointCloud, geometry: TemplateGeometry, workspace: tuple[float, ...] | None = None,
                  table: bool = True, seed: int = 0) -> TemplateScene:
    """Crop to the workspace [xmin,xmax,ymin,ymax,zmin,zmax] (m), segment the table plane out (if table),
    and index the remaining object points.  Raises TemplateError naming the field when nothing is left."""
    pts = cloud.points.astype(np.float64)
    src = cloud.camera_source
    finite = np.isfinite(pts).all(axis=1)
    if workspace is not None:
        ws = np.asarray(workspace, np.float64)
        if ws.shape != (6,) or not np.isfinite(ws).all():
            raise TemplateError("workspace", "must be 6 finite numbers [xmin, xmax, ymin, ymax, zmin, zmax]")
        if np.any(ws[1::2] < ws[0::2]):
            raise TemplateError("workspace", "each max must be >= its min ([xmin, xmax, ymin, ymax, zmin, zmax])")
        finite &= np.all((pts >= ws[0::2]) & (pts <= ws[1::2]), axis=1)
    pts, src = pts[finite], src[finite]
    if len(pts) < 10:
        raise TemplateError("cloud.points", f"{len(pts)} finite points in the workspace, need at least 10")
    vps = cloud.viewpoints.astype(np.float64)
    plane, on_table = segment_table(pts.astype(np.float32), cloud.viewpoints, seed=seed) if table else (None, None)
    if plane is not None and on_table is not None:
        keep = ~on_table & (plane.height(pts) > 0.005)
    else:
        keep = np.ones(len(pts), bool)
    # keyed and averaged in float32, as the templates always were (graspd.gpd.preprocess.voxelize)
    obj = voxel_downsample(pts[keep].astype(np.float32), 0.6 * geometry.tile).astype(np.float64)
    obj, segments = connected_pieces(obj, 1.5 * geometry.tile)
    if len(obj) < 4:
        raise TemplateError("cloud.points", "fewer than 4 object points above the table")
    sub = pts[:: max(1, len(pts) // 4000)]
    spacing = float(np.median(cKDTree(sub).query(sub, k=2)[0][:, 1])) / np.sqrt(max(1, len(pts) // 4000))
    spacing = max(spacing, 1e-4)
    centre = obj.mean(axis=0)
    maps = []
    for k in range(len(vps)):
        seen = pts[src == k]
        if len(seen):
            dm = depth_map(seen, vps[k], centre, spacing)
            if dm is not None:
                maps.append(dm)
    return TemplateScene(object_points=obj, segments=segments, tree=cKDTree(obj), table=plane, depth_maps=tuple(maps),
                         viewpoints=vps, geometry=geometry, num_points=len(cloud))


def connected_pieces(points: F64, link: float, min_points: int = 20, min_fraction: float = 0.02
                     ) -> tuple[F64, NDArray[np.int64]]:
    """Points linked within link (m) grouped into pieces; pieces smaller than min_points or min_fraction of
    all points (sensor outliers) dropped.  The kept points and their piece labels 0..S-1."""
    if len(points) < 4:
        return points, np.zeros(len(points), np.int64)
    pairs = cKDTree(points).query_pairs(link, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points)))
    _, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    big = np.flatnonzero(sizes >= max(min_points, min_fraction * len(points)))
    if len(big) == 0:
        return points[:0], np.zeros(0, np.int64)
    relabel = np.full(len(sizes), -1, np.int64)
    relabel[big] = np.arange(len(big))
    lab = relabel[labels]
    keep = lab >= 0
    return points[keep], lab[keep]


def reference_x(normals: F64) -> F64:
    """A unit direction perpendicular to each height axis (A,3), the zero of its rotation: world z
    projected into the template plane, or world x where the axis is near vertical."""
    ref = np.tile(np.array([0.0, 0.0, 1.0]), (len(normals), 1))
    ref[np.abs(normals[:, 2]) > 0.9] = np.array([1.0, 0.0, 0.0])
    ref -= np.einsum("ij,ij->i", ref, normals)[:, None] * normals
    return ref / np.linalg.norm(ref, axis=1, keepdims=True)


def height_axes(scene: TemplateScene, merge_angle_deg: float = 20.0, merge_offset: float | None = None
                ) -> tuple[F64, F64]:
    """Height axes (centres (A,3), outward unit normals (A,3)) from the convex-hull polygons of each
    connected piece of the object that face at least one camera.  Hull triangles are merged into polygons,
    biggest first: a triangle joins when its normal is within merge_angle_deg and its centroid within
    merge_offset (default one tile) of the seed's plane.  Each axis starts at its polygon's area-weighted
    centroid, moved onto the piece's supporting plane so that none of its points lies above it."""
    centres, normals = [], []
    for piece in range(int(scene.segments.max()) + 1 if len(scene.segments) else 0):
        c, n = hull_axes(scene.object_points[scene.segments == piece], scene.viewpoints, merge_angle_deg,
                         scene.geometry.tile if merge_offset is None else merge_offset)
        centres.append(c)
        normals.append(n)
    if not centres or sum(len(c) for c in centres) == 0:
        raise TemplateError("cloud.points", "the object points span no volume facing a camera "
                                            "(cloud.viewpoints must see the object)")
    return np.concatenate(centres), np.concatenate(normals)


def hull_axes(pts: F64, viewpoints: F64, merge_angle_deg: float, tol: float) -> tuple[F64, F64]:
    """The height axes of one piece (see height_axes); none if its points span no volume."""
    empty = np.zeros((0, 3))
    try:
        hull = ConvexHull(pts)
    except (QhullError, ValueError):
        return empty, empty
    tri = pts[hull.simplices]
    normals = hull.equations[:, :3]
    cents = tri.mean(axis=1)
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    to_cam = viewpoints[None, :, :] - cents[:, None, :]
    front = (np.einsum("fkj,fj->fk", to_cam, normals) > 0.0).any(axis=1)
    normals, cents, areas = normals[front], cents[front], areas[front]
    if len(normals) == 0:
        return empty, empty
    cos_lim = np.cos(np.radians(merge_angle_deg))
    left = np.ones(len(normals), bool)
    out_c, out_n = [], []
    for f in np.argsort(-areas, kind="stable"):
        if not left[f]:
            continue
        grp = left & (normals @ normals[f] > cos_lim) & (np.abs((cents - cents[f]) @ normals[f]) < tol)
        grp[f] = True
        left &= ~grp
        w = areas[grp] + 1e-12
        n = (normals[grp] * w[:, None]).sum(axis=0)
        n /= np.linalg.norm(n)
        c = (cents[grp] * w[:, None]).sum(axis=0) / w.sum()
        out_c.append(c)
        out_n.append(n)
    centres, norms = np.array(out_c), np.array(out_n)
    support = (pts[hull.vertices] @ norms.T).max(axis=0)
    centres += (support - np.einsum("ij,ij->i", centres, norms))[:, None] * norms
    return centres, norms


def axis_frames(normals: F64, reference: F64) -> F64:
    """Base frames (A,3,3), columns [x0, y0, h]: reference x0, y0 = h x x0, the height axis h."""
    y0 = np.cross(normals, reference)
    return np.stack([reference, y0, normals], axis=2)


def rotated_frames(base: F64, angles: F64) -> F64:
    """Frames (A*R,3,3) rotated by each angle (R,) (rad) about the base frames' z (A,3,3), axis-major."""
    c, s = np.cos(angles), np.sin(angles)
    x = base[:, None, :, 0] * c[None, :, None] + base[:, None, :, 1] * s[None, :, None]
    y = -base[:, None, :, 0] * s[None, :, None] + base[:, None, :, 1] * c[None, :, None]
    z = np.broadcast_to(base[:, None, :, 2], x.shape)
    return np.stack([x, y, z], axis=3).reshape(-1, 3, 3)


def extract_templates(scene: TemplateScene, centres: F64, base: F64, angles: F64) -> tuple[F32, U8]:
    """Templates for every axis (centre (A,3), base frame (A,3,3)) at every rotation angle (R,) about it:
    heights (A*R, n*n) float32 depth below the plane (m) and types (A*R, n*n) uint8, axis-major."""
    g = scene.geometry
    n, t, big_d = g.n, g.tile, g.depth
    a_count, r_count = len(centres), len(angles)
    uv = g.tile_centres()
    cos, sin = np.cos(angles), np.sin(angles)
    # Surface: the highest object point in each tile column (np.minimum.at over flat tile keys; keys of
    # points outside the template go to one spare slot at the end).
    radius = float(np.sqrt(2.0 * (g.size / 2.0) ** 2 + big_d**2))
    near = scene.tree.query_ball_point(centres, radius)
    counts = np.array([len(x) for x in near], np.int64)
    spare = a_count * r_count * n * n
    surf_flat = np.full(spare + 1, np.inf, np.float32)
    if counts.sum():
        idx = np.concatenate([np.asarray(x, np.int64) for x in near])
        aid = np.repeat(np.arange(a_count), counts)
        local = np.einsum("pj,pjk->pk", scene.object_points[idx] - centres[aid], base[aid])
        depth = -local[:, 2]
        inside = depth < big_d
        xt = (local[inside, 0] / t).astype(np.float32)[:, None]  # tile units
        yt = (local[inside, 1] / t).astype(np.float32)[:, None]
        depth, aid = depth[inside].astype(np.float32), aid[inside].astype(np.int32)
        c32, s32, half = cos.astype(np.float32)[None, :], sin.astype(np.float32)[None, :], np.float32(n / 2)
        i = np.floor(xt * c32 + yt * s32 + half).astype(np.int32)
        j = np.floor(yt * c32 - xt * s32 + half).astype(np.int32)
        ok = (i >= 0) & (i < n) & (j >= 0) & (j < n)
        key = ((aid[:, None] * r_count + np.arange(r_count, dtype=np.int32)[None, :]) * n + i) * n + j
        np.minimum.at(surf_flat, np.where(ok, key, spare).ravel(), np.repeat(depth, r_count))
    surf = surf_flat[:spare].reshape(a_count, r_count, n * n)
    # Tile centres in the base frame's x/y for each rotation: (R, T).
    bx = uv[None, :, 0] * cos[:, None] - uv[None, :, 1] * sin[:, None]
    by = uv[None, :, 0] * sin[:, None] + uv[None, :, 1] * cos[:, None]
    # Background: where each tile column meets the table.
    table_d = np.full((a_count, r_count, n * n), np.inf, np.float32)
    if scene.table is not None:
        nt = scene.table.normal
        s0 = (scene.table.height(centres)[:, None, None] + (base[:, :, 0] @ nt)[:, None, None] * bx[None]
              + (base[:, :, 1] @ nt)[:, None, None] * by[None]).astype(np.float32)
        down = (base[:, :, 2] @ nt)[:, None, None].astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            table_d = np.where(s0 <= 0.0, np.float32(0.0), np.where(down > 1e-9, s0 / down, np.float32(np.inf)))
    occ_d = occlusion_depths(scene, centres, base, bx, by)
    return combine_tiles(surf, occ_d, table_d, big_d)


def occlusion_depths(scene: TemplateScene, centres: F64, base: F64, bx: F64, by: F64) -> F32:
    """Depth (m) at which each tile column (axis, rotation, tile) first enters unobserved space above
    the table, inf if it does not within the box.  Sampled once per axis on a tile-spaced grid of
    columns and depths, then looked up at each rotated tile centre."""
    g = scene.geometry
    t = g.tile
    half = int(np.ceil(g.size / np.sqrt(2.0) / t)) + 1
    grid = (np.arange(-half, half + 1)) * t
    gx_all, gy_all = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
    disc = np.flatnonzero(gx_all**2 + gy_all**2 <= (g.size / np.sqrt(2.0) + t) ** 2)  # rotated tiles stay inside
    gx, gy = gx_all[disc], gy_all[disc]
    depths = (np.arange(int(np.ceil(g.depth / t))) + 0.5) * t
    side = len(grid)

    def along(vec: F64) -> F32:
        """Coordinate (A, G, Z) of the column samples along a world direction vec (3,) (linear in q)."""
        o = (centres @ vec)[:, None, None]
        return (o + np.outer(base[:, :, 0] @ vec, gx).reshape(len(centres), -1, 1)
                + np.outer(base[:, :, 1] @ vec, gy).reshape(len(centres), -1, 1)
                - (base[:, :, 2] @ vec)[:, None, None] * depths[None, None, :]).astype(np.float32)

    hidden = np.ones((len(centres), len(disc), len(depths)), bool)
    if not scene.depth_maps:
        hidden[:] = False
    for dm in scene.depth_maps:
        coords = [along(dm.basis[k]) - np.float32(dm.basis[k] @ dm.position) for k in range(3)]
        hidden &= dm.occluded_local(coords[0], coords[1], coords[2], t)
    if scene.table is not None:
        hidden &= along(scene.table.normal) + np.float32(scene.table.offset) > 0.0
    first = np.full((len(centres), side * side), np.inf, np.float32)
    first[:, disc] = np.where(hidden.any(axis=2), depths[np.argmax(hidden, axis=2)] - 0.5 * t, np.inf)
    gi = np.clip(np.rint(bx / t).astype(np.int64) + half, 0, side - 1)
    gj = np.clip(np.rint(by / t).astype(np.int64) + half, 0, side - 1)
    return first[:, gi * side + gj]  # (A, R, T)


def combine_tiles(surf: F32, occ: F32, table: F32, box_depth: float) -> tuple[F32, U8]:
    """Region type and height per tile from the depths (m) of surface, occlusion and table in its column:
    surface if seen within the box, else whichever of occlusion/table comes first, else void."""
    types = np.full(surf.shape, VOID, np.uint8)
    heights = np.full(surf.shape, box_depth, np.float32)
    is_bg = table < box_depth
    heights = np.where(is_bg, table, heights)
    types[is_bg] = BACKGROUND
    is_occ = (occ < box_depth) & (occ < table)
    heights = np.where(is_occ, occ, heights)
    types[is_occ] = OCCLUSION
    is_surf = surf < box_depth
    heights = np.where(is_surf, np.maximum(surf, 0.0), heights)
    types[is_surf] = SURFACE
    k = surf.shape[-1]
    return heights.reshape(-1, k).astype(np.float32), types.reshape(-1, k)


def candidate_templates(scene: TemplateScene, rotations: int = 16, merge_angle_deg: float = 20.0
                        ) -> tuple[F64, F64, F32, U8]:
    """All candidate templates of a scene: frames origins (K,3), rotations (K,3,3) columns [x, y, h],
    heights (K, n*n), types (K, n*n); K = number of front-facing hull axes x rotations."""
    if rotations < 1:
        raise TemplateError("rotations", f"must be a positive integer, got {rotations!r}")
    centres, normals = height_axes(scene, merge_angle_deg)
    base = axis_frames(normals, reference_x(normals))
    angles = 2.0 * np.pi * np.arange(rotations) / rotations
    heights, types = extract_templates(scene, centres, base, angles)
    origins = np.repeat(centres, rotations, axis=0)
    return origins, rotated_frames(base, angles), heights, types
