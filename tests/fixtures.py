"""Scripted hand poses on the synthetic box scenes of the template tests (tests/conftest.py renders them with
box_scene): a top-down and a side grasp on a box, and the angle between two hand orientations.
Metres, world frame, z up; hand rotation columns [approach, binormal, axis].

Importable as `fixtures` (pyproject.toml: [tool.pytest.ini_options] pythonpath = ["tests"])."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import urlparse

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from box_scene import pose_from

F64 = NDArray[np.float64]


def box_top_grasp(box_pose: F64, extents: tuple[float, float, float], hand_depth: float = 0.06,
                  bite: float = 0.02) -> F64:
    """A vertical hand pose on a box (pose 4x4, extents m) closing across its local x side, fingertips
    bite (m) below the top face; rotation columns [approach, binormal, axis]."""
    approach = np.array([0.0, 0.0, -1.0])
    binormal = box_pose[:3, :3] @ np.array([1.0, 0.0, 0.0])
    rot = np.column_stack([approach, binormal, np.cross(approach, binormal)])
    top = box_pose[:3, 3] + box_pose[:3, :3] @ np.array([0.0, 0.0, extents[2] / 2])
    return pose_from(rot, top - approach * (hand_depth - bite))


def box_side_grasp(box_pose: F64, extents: tuple[float, float, float], hand_depth: float = 0.06,
                   bite: float = 0.03, height: float = 0.2) -> F64:
    """A horizontal hand pose approaching a box's local +x face along -x, closing along its local y,
    at `height` (fraction of the box height) above its centre."""
    approach = box_pose[:3, :3] @ np.array([-1.0, 0.0, 0.0])
    binormal = box_pose[:3, :3] @ np.array([0.0, 1.0, 0.0])
    rot = np.column_stack([approach, binormal, np.cross(approach, binormal)])
    face = box_pose[:3, 3] + box_pose[:3, :3] @ np.array([extents[0] / 2, 0.0, extents[2] * height])
    return pose_from(rot, face - approach * (hand_depth - bite))


def grasp_angle_deg(rot_a: F64, rot_b: F64) -> float:
    """Angle (deg) between two hand orientations, counting a half turn about the approach as no change
    (a parallel-jaw hand is symmetric under it)."""
    flip = np.diag([1.0, -1.0, -1.0])
    best = 180.0
    for b in (rot_b, rot_b @ flip):
        c = (np.trace(rot_a.T @ b) - 1.0) / 2.0
        best = min(best, float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))))
    return best


def write_mesh(path: Path, mesh: o3d.geometry.TriangleMesh) -> Path:
    """The mesh written to path (.ply, .stl, .obj by suffix), as a user's mesh file for instance models."""
    assert o3d.io.write_triangle_mesh(str(path), mesh)
    return path


#: Where a camera that saw krylon.pcd could stand, in the cloud's frame.  The cloud is a 360-degree scan centred on
#: the can: a viewpoint at its origin puts the camera inside the can, and every hand would reach into space the
#: camera did not see.  One viewpoint outside it still leaves the far side unseen (the response says so).
KRYLON_VIEWPOINT = (0.5, 0.0, 0.3)


def krylon_camera_frame(points: np.ndarray) -> np.ndarray:
    """krylon.pcd's points in the frame of a camera at KRYLON_VIEWPOINT (axes kept): what a PointCloud2 or an
    upload without a viewpoint sends, the camera at the origin."""
    return points - np.asarray(KRYLON_VIEWPOINT, points.dtype)


@contextmanager
def connect(url: str, timeout: float = 10) -> Iterator[socket.socket]:
    """A raw TCP connection to an http://host:port URL (for tests that speak HTTP/1.1 byte by byte)."""
    u = urlparse(url)
    with socket.create_connection((u.hostname, u.port), timeout=timeout) as s:
        yield s


def read_response(s: socket.socket) -> tuple[int, dict[str, str], bytes]:
    """One HTTP/1.1 response (Content-Length framed) from a raw socket: status, headers (lower-case), body."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = s.recv(65536)
        assert chunk, f"connection closed after {data!r}"
        data += chunk
    head, _, rest = data.partition(b"\r\n\r\n")
    lines = head.decode().split("\r\n")
    headers = {k.lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
    while len(rest) < int(headers.get("content-length", 0)):
        rest += s.recv(65536)
    return int(lines[0].split()[1]), headers, rest
