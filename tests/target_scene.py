"""A rendered table of graspable objects seen by one depth camera as an organised cloud (one row per pixel, NaN
where no surface was hit) with the mesh each pixel saw: the ground truth of targets (indices, masks, boxes)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from graspd.core.cloud import ViewpointCloud
from graspd_lab.world.meshes import box_mesh, cylinder_mesh, pose_from, rot_z

CAMERA = (0.0, -0.45, 0.6)
LOOK_AT = (0.0, 0.02, 0.0)
WIDTH, HEIGHT = 320, 240

#: Six objects a hand of 8 cm opening grasps: (kind, sizes (m), centre x, y on the table (m), yaw (rad)).
SIX = (
    ("box", (0.05, 0.04, 0.09), -0.12, -0.06, 0.2),
    ("cylinder", (0.025, 0.10), 0.0, -0.06, 0.0),
    ("box", (0.04, 0.06, 0.07), 0.12, -0.06, -0.4),
    ("cylinder", (0.02, 0.08), -0.12, 0.08, 0.0),
    ("box", (0.045, 0.045, 0.10), 0.0, 0.08, 0.7),
    ("box", (0.035, 0.07, 0.06), 0.12, 0.08, 0.1),
)

#: Nine objects on a 3 x 3 grid of 10 cm (boxes and cylinders of different heights: some rank far above others).
NINE = tuple(
    ("box", (0.04 + 0.005 * (k % 3), 0.05, 0.06 + 0.01 * k), (k % 3 - 1) * 0.11, (k // 3 - 1) * 0.11, 0.3 * k)
    if k % 2 == 0 else
    ("cylinder", (0.02 + 0.002 * k, 0.07 + 0.005 * k), (k % 3 - 1) * 0.11, (k // 3 - 1) * 0.11, 0.0)
    for k in range(9))
#: Object 2 of SIX with a box standing 5 mm beside it: the grasp across it along x is blocked.
NEIGHBOUR = ("box", (0.03, 0.08, 0.09), 0.045, -0.06, 0.0)


@dataclass(frozen=True)
class OrganisedScene:
    """cloud: HEIGHT x WIDTH rows (row-major, NaN where nothing was hit); ids: the mesh index of each row (-1
    none, 0 the table, k the k-th object); boxes: each object's (centre, rotation, half extents)."""

    cloud: ViewpointCloud
    ids: np.ndarray
    boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray]]
    meshes: list[o3d.geometry.TriangleMesh]

    def rows(self, k: int) -> np.ndarray:
        """The rows of object k (1-based, as in ids)."""
        return np.flatnonzero(self.ids == k)

    def mask(self, k: int) -> np.ndarray:
        """Object k's boolean image (HEIGHT, WIDTH)."""
        return (self.ids == k).reshape(HEIGHT, WIDTH)


def _object(kind: str, sizes: tuple[float, ...], x: float, y: float, yaw: float
            ) -> tuple[o3d.geometry.TriangleMesh, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    if kind == "box":
        half = np.array(sizes) / 2
        mesh = box_mesh(*sizes)
    else:
        radius, height = sizes
        half = np.array([radius, radius, height / 2])
        mesh = cylinder_mesh(radius, height)
    mesh.translate(-mesh.get_axis_aligned_bounding_box().get_center())
    pose = pose_from(rot_z(yaw), (x, y, half[2]))
    mesh.transform(pose)
    mesh.compute_triangle_normals()
    return mesh, (pose[:3, 3].copy(), pose[:3, :3].copy(), half)


def render_table(objects: tuple[tuple[str, tuple[float, ...], float, float, float], ...] = SIX
                 ) -> OrganisedScene:
    """The objects on a 60 x 60 cm table (top at z = 0), seen from CAMERA as an organised cloud."""
    table = box_mesh(0.6, 0.6, 0.02)
    table.translate(-table.get_axis_aligned_bounding_box().get_center() + np.array([0.0, 0.0, -0.01]))
    table.compute_triangle_normals()
    meshes, boxes = [table], []
    for spec in objects:
        mesh, box = _object(*spec)
        meshes.append(mesh)
        boxes.append(box)
    scene = o3d.t.geometry.RaycastingScene()
    for m in meshes:
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
    rays = scene.create_rays_pinhole(fov_deg=50.0, center=list(LOOK_AT), eye=list(CAMERA),  # type: ignore[call-overload]
                                     up=[0.0, 0.0, 1.0], width_px=WIDTH, height_px=HEIGHT)
    hit = scene.cast_rays(rays)
    t = hit["t_hit"].numpy().reshape(-1)
    ids = hit["geometry_ids"].numpy().astype(np.int64).reshape(-1)
    d = rays.numpy().reshape(-1, 6)[:, 3:]
    ok = np.isfinite(t)
    points = np.full((len(t), 3), np.nan, np.float32)
    points[ok] = (np.asarray(CAMERA) + d[ok] * t[ok, None]).astype(np.float32)
    ids = np.where(ok, ids, -1)
    cloud = ViewpointCloud(points=points, viewpoints=np.array([CAMERA], np.float32))
    return OrganisedScene(cloud=cloud, ids=ids, boxes=boxes, meshes=meshes)


def finite(scene: OrganisedScene) -> tuple[ViewpointCloud, np.ndarray]:
    """The cloud without its NaN rows (what the detector receives) and the mesh id of each kept row."""
    keep = np.isfinite(scene.cloud.points).all(axis=1)
    return scene.cloud.select(keep), scene.ids[keep]
