"""Analytic scenes with known geometry: visible surfaces of a cylinder or box on a table, or a wall."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from graspd.core.cloud import ViewpointCloud


def _visible(points: np.ndarray, normals: np.ndarray, camera: np.ndarray,
             occluder: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Front-facing points whose line of sight to the camera does not pass through the occluder."""
    facing = np.einsum("ij,ij->i", normals, camera - points) > 0
    t = np.linspace(0.02, 1.0, 60)
    ray = points[:, None, :] + t[None, :, None] * (camera - points)[:, None, :]
    blocked = occluder(ray.reshape(-1, 3)).reshape(len(points), len(t)).any(axis=1)
    return facing & ~blocked


def cylinder_on_table(cameras: list[tuple[float, float, float]], radius: float = 0.03, height: float = 0.12,
                      spacing: float = 0.002) -> ViewpointCloud:
    """An upright cylinder (axis z, base on the table plane z = 0, centred at the origin) and a 40 cm
    table, sampled at `spacing` metres and seen from the given cameras."""
    th = np.arange(0, 2 * np.pi, spacing / radius)
    zz = np.arange(spacing / 2, height, spacing)
    T, Z = np.meshgrid(th, zz)
    side = np.stack([radius * np.cos(T), radius * np.sin(T), Z], -1).reshape(-1, 3)
    side_n = np.stack([np.cos(T), np.sin(T), np.zeros_like(T)], -1).reshape(-1, 3)
    g = np.arange(-radius, radius, spacing)
    X, Y = np.meshgrid(g, g)
    cap = np.stack([X, Y, np.full_like(X, height)], -1).reshape(-1, 3)
    cap = cap[np.hypot(cap[:, 0], cap[:, 1]) < radius]
    t = np.arange(-0.2, 0.2, spacing)
    X, Y = np.meshgrid(t, t)
    table = np.stack([X, Y, np.zeros_like(X)], -1).reshape(-1, 3)
    table = table[np.hypot(table[:, 0], table[:, 1]) > radius]
    pts = np.concatenate([side, cap, table])
    nrm = np.concatenate([side_n, np.tile([0, 0, 1.0], (len(cap), 1)), np.tile([0, 0, 1.0], (len(table), 1))])

    def inside(q: np.ndarray) -> np.ndarray:
        return (np.hypot(q[:, 0], q[:, 1]) < radius - 1e-4) & (q[:, 2] > 1e-4) & (q[:, 2] < height - 1e-4)

    out_p, out_s = [], []
    seen = np.zeros(len(pts), bool)
    for k, cam in enumerate(np.array(cameras, float)):
        vis = _visible(pts, nrm, cam, inside) & ~seen
        seen |= vis
        out_p.append(pts[vis])
        out_s.append(np.full(int(vis.sum()), k, np.int32))
    return ViewpointCloud(points=np.concatenate(out_p), viewpoints=np.array(cameras, np.float32),
                          camera_source=np.concatenate(out_s))


@pytest.fixture
def cylinder_scene() -> ViewpointCloud:
    return cylinder_on_table([(0.5, 0.0, 0.4)])


@pytest.fixture
def cylinder_two_cameras() -> ViewpointCloud:
    c = np.radians(53.0 / 2)
    return cylinder_on_table([(0.55 * np.cos(c), 0.55 * np.sin(c), 0.45), (0.55 * np.cos(c), -0.55 * np.sin(c), 0.45)])


@pytest.fixture
def wall() -> ViewpointCloud:
    """A 60 cm square flat wall at x = 0 facing a camera on +x: nothing on it can be grasped."""
    t = np.arange(-0.3, 0.3, 0.003)
    Y, Z = np.meshgrid(t, t)
    pts = np.stack([np.zeros_like(Y), Y, Z], -1).reshape(-1, 3)
    return ViewpointCloud(points=pts, viewpoints=np.array([[0.6, 0.0, 0.0]], np.float32))
