"""graspd.core.frames and graspd.io.inputs: camera poses in every accepted form mean the same transform, bad ones are
refused naming the field, camera-frame points move into the robot frame with their own camera's pose, and
non-finite rows are dropped and counted one way."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graspd.core.cloud import CloudError
from graspd.core.errors import FieldError
from graspd.core.frames import check_pose, pose_matrices, pose_matrix, to_robot
from graspd.io.cloud_files import read_input
from graspd.io.inputs import cloud_input, non_finite_warning

ROT = Rotation.from_euler("xyz", [30, -50, 120], degrees=True)
T = np.array([0.4, -0.25, 0.9])


def pose() -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = ROT.as_matrix()
    m[:3, 3] = T
    return m


def test_every_pose_form_is_the_same_transform() -> None:
    m = pose()
    q = ROT.as_quat()  # x, y, z, w
    forms = [m, m.tolist(), m.reshape(-1).tolist(), {"position": T.tolist(), "quat_xyzw": q.tolist()},
             [*T.tolist(), *q.tolist()], m.astype(np.float32)]
    for form in forms:
        assert np.allclose(pose_matrix(form), m, atol=1e-6), form
    assert pose_matrices([m, {"position": [0, 0, 0], "quat_xyzw": [0, 0, 0, 1]}]).shape == (2, 4, 4)


@pytest.mark.parametrize(("value", "field", "words"), [
    (np.diag([1.0, 1.0, -1.0, 1.0]), "camera_poses", "determinant -1"),
    (np.diag([2.0, 1.0, 1.0, 1.0]), "camera_poses", "not orthonormal"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "camera_poses", "last row"),
    ([[1, 0, 0, np.nan], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "camera_poses", "finite"),
    ({"position": [0, 0, 0], "quat_xyzw": [0, 0, 0, 3]}, "camera_poses.quat_xyzw", "unit quaternion"),
    ({"position": [0, 0], "quat_xyzw": [0, 0, 0, 1]}, "camera_poses.position", "3 numbers"),
    ({"pos": [0, 0, 0]}, "camera_poses", "position"),
    ([1, 2, 3], "camera_poses", "expected"),
    ([2e4, 0, 0, 0, 0, 0, 1], "camera_poses", "translation"),
])
def test_bad_poses_are_refused_naming_the_field(value: object, field: str, words: str) -> None:
    with pytest.raises(FieldError) as err:
        pose_matrix(value)
    assert err.value.field == field and words in err.value.message


def test_rotation_is_snapped_to_an_exact_one() -> None:
    m = pose().astype(np.float32).astype(np.float64)
    r = check_pose(m)[:3, :3]
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(r), 1.0)


def test_camera_frame_points_move_with_their_own_camera() -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3)).astype(np.float32)
    src = rng.integers(0, 2, 50)
    second = np.eye(4)
    second[:3, 3] = [1.0, 2.0, 3.0]
    poses = np.stack([pose(), second])
    moved, _ = to_robot(pts, src, poses)
    want = np.where((src == 0)[:, None], pts @ ROT.as_matrix().T + T, pts + [1.0, 2.0, 3.0])
    assert np.allclose(moved, want, atol=1e-5)
    inp = cloud_input(pts, camera_source=src, camera_poses=poses, points_frame="camera")
    assert inp.frame == "robot" and np.allclose(inp.cloud.points, want, atol=1e-5)
    assert np.allclose(inp.cloud.viewpoints, [T, [1.0, 2.0, 3.0]], atol=1e-6)
    kept = cloud_input(pts, camera_source=src, camera_poses=poses, points_frame="robot")
    assert np.array_equal(kept.cloud.points, pts) and kept.frame == "robot"


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"camera_poses": [np.eye(4)]}, "points_frame"),
    ({"points_frame": "camera"}, "points_frame"),
    ({"camera_poses": [np.eye(4)], "points_frame": "camera", "viewpoints": [[0, 0, 0]]}, "cloud.viewpoints"),
    ({"camera_poses": [np.eye(4)], "points_frame": "camera", "camera_source": [0, 1, 0]}, "cloud.camera_source"),
    ({"camera_poses": [np.eye(4), np.eye(4)], "points_frame": "camera"}, "cloud.camera_source"),
])
def test_frames_must_be_said_consistently(kwargs: dict[str, object], field: str) -> None:
    with pytest.raises(FieldError) as err:
        cloud_input(np.zeros((3, 3)) + [0, 0, 1], **kwargs)  # type: ignore[arg-type]
    assert err.value.field == field


def test_non_finite_rows_are_dropped_and_counted() -> None:
    pts = np.array([[0, 0, 1], [np.nan, 0, 1], [0, np.inf, 1], [0.1, 0, 1]], np.float32)
    normals = np.array([[0, 0, -1], [0, 0, -1], [0, 0, -1], [np.nan, 0, 0]], np.float32)
    inp = cloud_input(pts, normals=normals)
    assert inp.dropped == 3 and inp.received == 4 and len(inp.cloud) == 1
    assert inp.warnings == (non_finite_warning(3, 4),) and inp.warnings[0].code == "non_finite_dropped"
    assert "3 of 4" in inp.warnings[0].message
    assert cloud_input(pts[:1]).warnings == ()


def test_an_organised_clouds_pixels_without_depth_warn_only_when_almost_none_has_depth() -> None:
    pixels = np.zeros((20, 3), np.float32) + [0, 0, 1]
    pixels[:15] = np.nan  # a quarter of the pixels with depth, as a depth camera marks the rest
    inp = cloud_input(pixels, shape=(4, 5))
    assert (inp.dropped, inp.received, inp.warnings) == (15, 20, ())
    pixels[15:19] = np.nan  # one pixel in twenty with depth: a covered lens, a scene out of range
    warned = cloud_input(pixels, shape=(4, 5)).warnings
    assert [w.code for w in warned] == ["non_finite_dropped"] and "only 1 of the organised cloud's 20" in \
        warned[0].message
    with pytest.raises(CloudError) as err:
        cloud_input(np.full((5, 3), np.nan))
    assert err.value.field == "cloud.points" and "no finite point" in err.value.message


def test_an_organised_pcd_keeps_nothing_but_counts_its_holes(real_data: Path, tmp_path: Path) -> None:
    """An organised PCD (WIDTH x HEIGHT, NaN where the camera saw nothing) reads with its holes counted."""
    mug = read_input(real_data / "table_mug.pcd").cloud.points[:600]
    grid = np.full((20, 40, 3), np.nan, np.float32)
    grid.reshape(-1, 3)[::4][: len(mug[:200])] = mug[:200]
    head = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 40\nHEIGHT 20\n"
            "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 800\nDATA binary\n")
    path = tmp_path / "organised.pcd"
    path.write_bytes(head.encode() + grid.tobytes())
    inp = read_input(path)
    assert inp.received == 800 and inp.dropped == 600 and np.allclose(inp.cloud.points, mug[:200])
