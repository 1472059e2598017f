"""Bundled scenes the project renders itself: a cluttered tabletop of procedural objects seen by two
depth cameras 53 degrees apart (the IJRR paper's passive setup), for the demo and the benchmarks."""

from __future__ import annotations

import numpy as np

from .cloud import ViewpointCloud
from .training.objects import PROCEDURAL_KINDS, procedural_object
from .training.render import render_scene, tabletop_cameras, tabletop_scene

#: Table-top frame: the table's top face is z = 0, gravity is -z, cameras look down from ~0.7 m.
GRAVITY = (0.0, 0.0, -1.0)


def cluttered_tabletop(num_objects: int = 6, seed: int = 7, num_cameras: int = 2, resolution_scale: float = 1.0,
                       table_size: tuple[float, float] = (0.5, 0.5)) -> ViewpointCloud:
    """A deterministic cluttered tabletop (procedural boxes, cylinders, spheres, cones, capsules,
    composites on a table), rendered with depth noise; camera resolution 640x480 x resolution_scale."""
    rng = np.random.default_rng(seed)
    kinds = [PROCEDURAL_KINDS[int(k)] for k in rng.integers(0, len(PROCEDURAL_KINDS), num_objects)]
    meshes = [procedural_object(kind, 1000 + i, seed=seed).mesh for i, kind in enumerate(kinds)]
    scene = tabletop_scene(meshes, seed=seed, table_size=table_size)
    w, h = int(round(640 * resolution_scale)), int(round(480 * resolution_scale))
    cams = tabletop_cameras(num_cameras, distance=0.75, elevation_deg=55.0, width=w, height=h)
    return render_scene(scene, cams, seed=seed)


def subsample(cloud: ViewpointCloud, num_points: int, seed: int = 0) -> ViewpointCloud:
    """At most num_points of the cloud, uniformly at random (camera indices kept)."""
    if len(cloud) <= num_points:
        return cloud
    idx = np.sort(np.random.default_rng(seed).choice(len(cloud), num_points, replace=False))
    return cloud.select(idx)
