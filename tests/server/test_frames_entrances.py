"""Frames, NaN rows and file inputs through every entrance of a real server (HTTP JSON and uploads through the
client SDK, Zenoh with a CDR PointCloud2 and the stream options, the CLI in-process): the same cloud gives the
same grasps, the same frame and the same warnings everywhere, and a bad pose or a cloud with nothing finite is
refused naming the field.

The frames test is the issue's: table_mug (camera at the origin: a camera-frame cloud) sent in its camera's
frame with a rotated, translated camera pose answers in the robot frame, on the mug there, exactly as the same
cloud sent already in the robot frame."""

from __future__ import annotations

import io
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from graspd.cli.main import main as cli_main
from graspd.core.camera import Camera, camera_intrinsics, camera_pose, depth_image
from graspd.io.cloud_files import read_input
from graspd.io.ros import Header, encode_pointcloud2
from graspd.server.runner import free_port, serve_in_thread
from graspd.server.settings import Settings
from graspd_client import GraspClient, Grasps, RequestRejected
from graspd_client.zenoh_client import ZenohGraspClient
from graspd_lab.world.meshes import pose_from, posed_box, posed_cylinder, rot_z, table_mesh
from graspd_lab.world.noise import DepthNoise
from graspd_lab.world.render import render_scene_with_ids

ROT = Rotation.from_euler("xyz", [120, 10, -35], degrees=True)
T = np.array([0.6, -0.3, 0.8])
SAMPLES = 80
CAMERA_FRAME = "camera_color_optical_frame"


def pose_4x4() -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = ROT.as_matrix()
    m[:3, 3] = T
    return m


def pose_7() -> list[float]:
    return [*T.tolist(), *ROT.as_quat().tolist()]


Server = tuple[str, str]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """(HTTP URL, Zenoh endpoint) of a real server without models (unscored: fast, and the CLI's
    --no-classifier runs the same detection)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(port=0, zenoh_enabled=True, zenoh_listen=[endpoint], zenoh_stream=False, deadline_s=300,
                        models_dir=tmp_path_factory.mktemp("no-models"), data_dir=tmp_path_factory.mktemp("data"),
                        allow_unscored=True, detect_workers=2)
    with serve_in_thread(settings) as url:
        yield url, endpoint


@pytest.fixture(scope="module")
def mug(real_data: Path) -> np.ndarray:
    """table_mug (camera frame: the camera at the origin), a third of its points."""
    return read_input(real_data / "table_mug.pcd").cloud.points[::3].copy()


def robot_frame(points: np.ndarray) -> np.ndarray:
    return (np.asarray(points, np.float64) @ ROT.as_matrix().T + T).astype(np.float32)


def run_cli(tmp_path: Path, *args: str) -> tuple[int, dict[str, Any] | None]:
    out = tmp_path / f"cli-{len(list(tmp_path.iterdir()))}.json"
    code = cli_main(["detect", *args, "--no-classifier", "--out", str(out)])
    return code, (json.loads(out.read_text()) if out.exists() else None)


def same_grasps(a: Grasps | dict[str, Any], b: Grasps) -> None:
    """The same grasps in the same order (a: Grasps, or a JSON answer of the Zenoh query or the CLI)."""
    pos = a.positions if isinstance(a, Grasps) else np.array([g["position"] for g in a["grasps"]]).reshape(-1, 3)
    assert len(pos) == len(b) > 0
    assert np.allclose(pos, b.positions, atol=1e-5)


def test_table_mug_in_a_camera_frame_answers_on_the_mug_in_the_robot_frame(server: Server, mug: np.ndarray) -> None:
    url, _ = server
    robot = robot_frame(mug)
    with GraspClient(url, timeout=120) as client:
        in_camera = client.detect(mug, camera_poses=[pose_4x4()], points_frame="camera", num_samples=SAMPLES)
        sent_in_robot = client.detect(robot, [T], num_samples=SAMPLES)
        robot_with_pose = client.detect(robot, camera_poses=[pose_7()], points_frame="robot", num_samples=SAMPLES)
    assert (in_camera.frame, sent_in_robot.frame, robot_with_pose.frame) == ("robot", "cloud", "robot")
    same_grasps(robot_with_pose, sent_in_robot)
    same_grasps(in_camera, sent_in_robot)
    # on the mug, in the robot frame: within 3 mm of a mug point (more than 1.5 cm above the support found)
    support = sent_in_robot.raw["environment"]["support"]
    height = robot @ np.asarray(support["normal"]) + support["offset"]
    on_mug = cKDTree(robot[height > 0.015]).query(in_camera.samples)[0]
    assert on_mug.max() < 0.003, on_mug.max()
    assert cKDTree(mug).query(in_camera.positions)[0].min() > 0.2  # not left in the camera frame
    assert in_camera.raw["warnings"] == []


def test_every_entrance_answers_the_camera_frame_cloud_alike(server: Server, mug: np.ndarray, tmp_path: Path
                                                             ) -> None:
    url, endpoint = server
    npy = tmp_path / "mug.npy"
    np.save(npy, mug)
    with GraspClient(url, timeout=120) as client:
        json_answer = client.detect(mug, camera_poses=[pose_4x4()], points_frame="camera", num_samples=SAMPLES)
        upload = client.detect_file(npy, camera_pose=pose_7(), points_frame="camera", num_samples=SAMPLES)
    assert upload.frame == "robot"
    same_grasps(upload, json_answer)
    with ZenohGraspClient(connect=[endpoint], timeout=120) as zc:
        shown = zc.set_stream_options(camera_poses=[pose_4x4()], points_frame="camera", camera_frame_id=CAMERA_FRAME,
                                      num_samples=SAMPLES)
        assert np.allclose(shown["viewpoints"], [T]) and shown["points_frame"] == "camera"  # the camera, in base_link
        reply = zc.query(encode_pointcloud2(mug, Header(CAMERA_FRAME, (5, 6))))
        with pytest.raises(RequestRejected) as err:  # a cloud of another camera: its pose would be wrong
            zc.query(encode_pointcloud2(mug, Header("other_camera", (5, 6))))
        zc.set_stream_options()
    assert err.value.status == 422 and err.value.field == "header.frame_id"
    assert reply["frame"] == "robot" and reply["header"]["frame_id"] == "base_link"
    same_grasps(reply, json_answer)
    code, cli = run_cli(tmp_path, str(npy), "--camera-pose", *map(str, pose_4x4().reshape(-1)), "--points-frame",
                        "camera", "--samples", str(SAMPLES))
    assert code == 0 and cli is not None and cli["frame"] == "robot"
    same_grasps(cli, json_answer)


def test_a_bad_pose_is_refused_naming_it_on_every_entrance(server: Server, mug: np.ndarray, tmp_path: Path
                                                           ) -> None:
    url, endpoint = server
    mirror = np.diag([1.0, 1.0, -1.0, 1.0])
    with GraspClient(url, timeout=60) as client:
        with pytest.raises(RequestRejected) as err:
            client.detect(mug[:100], camera_poses=[mirror], points_frame="camera")
        assert err.value.status == 422 and err.value.field == "cloud.camera_poses[0]"
        with pytest.raises(RequestRejected) as err:
            client.detect(mug[:100], camera_poses=[np.eye(4)])
        assert err.value.status == 422 and err.value.field == "cloud.points_frame"
        with pytest.raises(RequestRejected) as err:  # two cameras' points: which pose moves which point?
            client.detect(mug[:100], camera_poses=[np.eye(4), pose_4x4()], points_frame="camera")
        assert err.value.status == 422 and err.value.field == "cloud.camera_source"
        with pytest.raises(RequestRejected) as err:
            client.detect_file(np.save(buf := io.BytesIO(), mug[:100]) or buf.getvalue(),
                               camera_pose=[0, 0, 0, 0, 0, 0, 2], points_frame="camera")
        assert err.value.status == 422 and err.value.field == "camera_pose"
    with ZenohGraspClient(connect=[endpoint], timeout=60) as zc:
        with pytest.raises(RequestRejected) as err:
            zc.set_stream_options(camera_poses=[mirror], points_frame="camera")
        assert err.value.status == 422 and err.value.field == "camera_poses[0]"
        zc.set_stream_options(camera_poses=[np.eye(4), pose_4x4()], points_frame="camera")
        with pytest.raises(RequestRejected) as err:  # a PointCloud2 cannot say which of two cameras saw a point
            zc.query(encode_pointcloud2(mug[:100], Header(CAMERA_FRAME, (5, 6))))
        zc.set_stream_options()
    assert err.value.status == 422 and err.value.field == "camera_poses"
    np.save(npy := tmp_path / "small.npy", mug[:100])
    assert run_cli(tmp_path, str(npy), "--camera-pose", *map(str, mirror.reshape(-1)), "--points-frame",
                   "camera")[0] == 2


def test_nan_rows_are_dropped_and_counted_alike_on_every_entrance(server: Server, mug: np.ndarray,
                                                                  tmp_path: Path) -> None:
    url, endpoint = server
    rng = np.random.default_rng(3)
    holes = mug[::2].copy()
    holes[rng.choice(len(holes), 400, replace=False)] = np.nan  # a depth camera's holes
    holes[7] = [np.inf, 0.0, 1.0]
    np.save(npy := tmp_path / "holes.npy", holes)
    with GraspClient(url, timeout=120) as client:
        json_answer = client.detect(holes, num_samples=SAMPLES)
        upload = client.detect_file(npy, num_samples=SAMPLES)
    with ZenohGraspClient(connect=[endpoint], timeout=120) as zc:
        zc.set_stream_options(num_samples=SAMPLES)
        ros = zc.query(encode_pointcloud2(holes, Header(CAMERA_FRAME, (1, 2))))
        zc.set_stream_options()
    code, cli = run_cli(tmp_path, str(npy), "--samples", str(SAMPLES))
    assert code == 0 and cli is not None
    warning = json_answer.raw["warnings"][0]
    assert warning["code"] == "non_finite_dropped" and "401 of " in warning["message"]
    for answer in (upload.raw, ros, cli):
        assert answer["warnings"] == json_answer.raw["warnings"]
        same_grasps(answer, json_answer)
    same_grasps(upload, json_answer)


def test_a_cloud_with_nothing_finite_is_a_422_naming_the_points(server: Server, tmp_path: Path) -> None:
    url, endpoint = server
    nothing = np.full((50, 3), np.nan, np.float32)
    np.save(npy := tmp_path / "nothing.npy", nothing)
    with GraspClient(url, timeout=60) as client:
        for call in (lambda: client.detect(nothing), lambda: client.detect_file(npy)):
            with pytest.raises(RequestRejected) as err:
                call()
            assert err.value.status == 422 and err.value.field == "cloud.points"
            assert "no finite point" in str(err.value)
    with ZenohGraspClient(connect=[endpoint], timeout=60) as zc, pytest.raises(RequestRejected) as err:
        zc.query(encode_pointcloud2(nothing, Header(CAMERA_FRAME, (1, 2))))
    assert err.value.status == 422 and err.value.field == "data" and "no finite point" in str(err.value)
    assert run_cli(tmp_path, str(npy))[0] == 2


# ---- files: .npy, .npz and depth images of a rendered scene ---------------------------------------------------


@pytest.fixture(scope="module")
def scene() -> tuple[Camera, np.ndarray, np.ndarray, np.ndarray]:
    """(camera, world points it sees, which of them are on an object, its depth image): a box and a cylinder on a
    table, one noise-free camera above and aside (world frame, z up, m)."""
    cam = Camera(position=(0.45, 0.15, 0.5), target=(0.0, 0.0, 0.04))
    meshes = [table_mesh(), posed_box((0.05, 0.1, 0.08), pose_from(rot_z(0.4), (0.0, -0.06, 0.04))),
              posed_cylinder(0.03, 0.12, pose_from(rot_z(0.0), (0.02, 0.09, 0.06)))]
    cloud, ids = render_scene_with_ids(meshes, [cam], DepthNoise.none())
    return cam, cloud.points, ids > 0, depth_image(cam, cloud.points)


def on_objects(samples: np.ndarray, points: np.ndarray, objects: np.ndarray) -> float:
    return float(cKDTree(points[objects]).query(samples)[0].max())


def png_mm(depth: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.round(depth * 1000).astype(np.uint16)).save(buf, format="PNG")
    return buf.getvalue()


def test_npy_npz_and_depth_images_of_a_rendered_scene_give_grasps_on_the_objects(
        server: Server, scene: tuple[Camera, np.ndarray, np.ndarray, np.ndarray], tmp_path: Path) -> None:
    url, _ = server
    cam, points, objects, depth = scene
    np.save(npy := tmp_path / "scene.npy", points)
    np.savez_compressed(npz := tmp_path / "scene.npz", points=points, viewpoints=np.array([cam.position]),
                        camera_source=np.zeros(len(points), np.int32), colours=np.zeros((len(points), 3)))
    (png := tmp_path / "depth.png").write_bytes(png_mm(depth))
    intrinsics = camera_intrinsics(cam)
    world = camera_pose(cam)
    with GraspClient(url, timeout=120) as client:
        from_npy = client.detect_file(npy, viewpoint=cam.position, num_samples=SAMPLES)
        from_npz = client.detect_file(npz, num_samples=SAMPLES)
        from_png = client.detect_depth(png.read_bytes(), intrinsics, camera_pose=world, num_samples=SAMPLES)
        in_camera = client.detect_depth(depth, intrinsics, num_samples=SAMPLES)  # float metres, no pose
    same_grasps(from_npz, from_npy)
    for answer in (from_npy, from_png):
        assert answer.frame == ("robot" if answer is from_png else "cloud")
        assert on_objects(answer.samples, points, objects) < 0.004
    back = in_camera.samples @ world[:3, :3].T + world[:3, 3]  # the camera frame's answer, in the world
    assert in_camera.frame == "cloud" and on_objects(back, points, objects) < 0.004
    code, cli = run_cli(tmp_path, str(png), "--intrinsics", *map(str, intrinsics), "--camera-pose",
                        *map(str, world.reshape(-1)), "--samples", str(SAMPLES))
    assert code == 0 and cli is not None and cli["frame"] == "robot"
    same_grasps(cli, from_png)


def test_a_depth_image_needs_intrinsics_and_depth(server: Server, scene: tuple[Camera, np.ndarray, np.ndarray,
                                                                                np.ndarray]) -> None:
    url, _ = server
    depth = scene[3]
    with GraspClient(url, timeout=60) as client:
        with pytest.raises(RequestRejected) as err:
            client.detect_file(png_mm(depth), content_type="image/png")
        assert err.value.status == 422 and err.value.field == "intrinsics"
        with pytest.raises(RequestRejected) as err:
            client.detect_depth(np.zeros((8, 8), np.float32), (500, 500, 4, 4))
        assert err.value.status == 422 and "no pixel with depth" in str(err.value)
        with pytest.raises(RequestRejected) as err:
            client.detect_depth(depth, (0, 500, 320, 240))
        assert err.value.status == 422 and err.value.field == "intrinsics"
        rgb = io.BytesIO()
        Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(rgb, format="PNG")
        with pytest.raises(RequestRejected) as err:
            client.detect_depth(rgb.getvalue(), (500, 500, 4, 4))
        assert err.value.status == 422 and "16-bit" in str(err.value)


def _request_of(parsed: Any) -> dict[str, Any]:
    """A Parsed's request, decoded cloud and target, as services.mapping.detection_inputs takes them."""
    return {"req": parsed.request, "given": parsed.given, "target": parsed.target}


def test_the_ros2_example_puts_a_camera_frame_cloud_into_its_base_link_workspace(mug: np.ndarray) -> None:
    """examples/ros2/graspd.env: a camera-frame PointCloud2 and a base_link workspace work together (the issue: the
    viewpoint at the origin with that workspace gave 0 candidates, with no word why)."""
    from graspd.gpd.detector import GraspDetector  # noqa: PLC0415
    from graspd.server.services.mapping import detection_inputs  # noqa: PLC0415
    from graspd.server.services.ros_stream import decode_input, parse_options, stream_request  # noqa: PLC0415

    env = (Path(__file__).resolve().parents[2] / "examples" / "ros2" / "graspd.env").read_text()
    found = re.search(r"^GRASPD_STREAM_OPTIONS='(.*)'$", env, re.M)
    assert found is not None
    example = json.loads(found.group(1))
    options = parse_options({"num_samples": SAMPLES}, example, ((0.0, 0.0, 0.0),))
    msg = decode_input(encode_pointcloud2(mug, Header(example["camera_frame_id"], (3, 4))), "pointcloud2", options)
    assert msg.header.frame_id == "base_link"
    req = detection_inputs(**_request_of(stream_request(msg, options)))
    det = GraspDetector().detect(req.given.cloud, req.params)
    lo, hi = np.array(example["workspace"][0::2]), np.array(example["workspace"][1::2])
    assert len(det.grasps) > 0 and ((det.grasps.positions >= lo) & (det.grasps.positions <= hi)).all()
    assert det.environment is not None and det.environment.up is not None and det.environment.up[2] > 0.99
    without = {k: v for k, v in example.items() if k not in ("camera_poses", "points_frame", "camera_frame_id")}
    old = parse_options({"num_samples": SAMPLES}, without, ((0.0, 0.0, 0.0),))
    old_req = detection_inputs(**_request_of(stream_request(
        decode_input(encode_pointcloud2(mug, Header("cam", (3, 4))), "pointcloud2", old), old)))
    assert len(GraspDetector().detect(old_req.given.cloud, old_req.params).grasps) == 0


def test_gpd_ros_clouds_of_two_cameras_move_with_each_cameras_pose(mug: np.ndarray) -> None:
    """A CloudSources / CloudSamples of two cameras, each point in its own camera's frame: with the stream's camera
    poses, camera_source picks the pose; the cloud, its viewpoints and the samples land where the JSON request's
    do (one rule: graspd.io.inputs.apply_frames)."""
    from graspd.io.ros import encode_cloud_samples, encode_cloud_sources  # noqa: PLC0415
    from graspd.server.problems import Problem  # noqa: PLC0415
    from graspd.server.requests import parse_request  # noqa: PLC0415
    from graspd.server.services.mapping import cloud_input  # noqa: PLC0415
    from graspd.server.services.ros_stream import decode_input, parse_options  # noqa: PLC0415

    second = np.eye(4)
    second[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    second[:3, 3] = [0.1, 0.2, 0.3]
    poses = [pose_4x4(), second]
    points = np.concatenate([mug[:300], mug[300:600]])
    source = np.repeat([0, 1], 300)
    options = parse_options({"camera_poses": [p.tolist() for p in poses], "points_frame": "camera"}, {},
                            ((0.0, 0.0, 0.0),))
    want_request = parse_request({"cloud": {"points": points.tolist(), "camera_source": source.tolist(),
                                    "camera_poses": [p.tolist() for p in poses], "points_frame": "camera"}})
    want = cloud_input(want_request.cloud).cloud
    got = decode_input(encode_cloud_sources(points, np.zeros((2, 3)), source, Header("cam", (1, 2))),
                       "cloud_sources", options)
    assert np.allclose(got.cloud.points, want.points, atol=1e-6)
    assert np.allclose(got.cloud.viewpoints, [T, [0.1, 0.2, 0.3]], atol=1e-6) and got.header.frame_id == "base_link"
    samples = decode_input(encode_cloud_samples(points, np.zeros((2, 3)), points[:5], source, Header("cam", (1, 2))),
                           "cloud_samples", options)
    assert samples.samples is not None and np.allclose(samples.samples, want.points[:5], atol=1e-6)
    with pytest.raises(Problem) as err:  # an index beyond the poses: the message's field is named
        decode_input(encode_cloud_sources(points, np.zeros((3, 3)), np.full(600, 2), Header("cam", (1, 2))),
                     "cloud_sources", options)
    assert err.value.status == 422 and err.value.field == "camera_source"
