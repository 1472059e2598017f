"""The pictures of docs/robot/index.md ("On your robot"): table_mug.pcd (a Kinect cloud in the camera's optical
frame) sent to graspd the right way and with a common mistake, through the service's HTTP app in this process.

- correct.png: the points as the camera driver gives them (camera frame), with the camera's pose in base_link
  (what TF says) as camera_poses and points_frame "camera"; workspace and gravity in base_link.  The grasps
  come back in base_link; no warning.
- warned.png: the robot moved the cloud into base_link itself and left the viewpoint at the default
  [0, 0, 0] (the robot's base, on the table's plane): the normals face the wrong way, and the answer says so
  (viewpoint_flipped).

Each picture draws what the service answered (its grasps, best first, and its warnings) over the cloud in
base_link, the environment labelled as the detector labels it.  The camera pose is the one of docs/robot/index.md.

    PYTHONPATH=service:client .venv/bin/python examples/robot/pictures.py [--data ../shared/data/real]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from fastapi.testclient import TestClient

from graspd.core.cloud import ViewpointCloud
from graspd.io.cloud_files import read_cloud
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.core.frames import pose_matrix
from graspd.core.grasp import GraspSet, Ranking
from graspd.core.hand import HandGeometry
from graspd.viz.plot import plot_grasps
from graspd.server.app import create_app
from graspd.server.settings import Settings
from graspd_client import build_detect_request

HERE = Path(__file__).resolve().parent
#: The Kinect's pose in base_link (camera optical frame -> base_link, as `ros2 run tf2_ros tf2_echo base_link
#: camera_depth_optical_frame` prints it): 0.53 m above the table, 0.25 m behind the base, looking down 33 deg.
CAMERA_POSE = {"position": [-0.25, 0.0, 0.529], "quat_xyzw": [0.6283, -0.6154, 0.3401, -0.3331]}
#: The request's options, all in base_link (z up, the table top at z = 0).
OPTIONS: dict[str, Any] = {"num_samples": 300, "max_grasps": 20, "gravity": [0.0, 0.0, -1.0],
                           "workspace": [0.2, 0.65, -0.35, 0.25, -0.02, 0.3]}
TOP = 8


def grasps_of(answer: dict[str, Any]) -> GraspSet:
    """The answer's grasps (best first) as a GraspSet, with their ranking terms."""
    g = answer["grasps"]
    if not g:
        return GraspSet()
    pose = np.array([x["pose"] for x in g], np.float64)
    ranking = None
    if all("ranking" in x for x in g):
        cols = {k: np.array([np.nan if x["ranking"][k] is None else x["ranking"][k] for x in g])
                for k in ("classifier", "utility", "width", "unknown", "key")}
        ranking = Ranking(**cols)
    return GraspSet(positions=pose[:, :3, 3], rotations=pose[:, :3, :3],
                    widths=np.array([x["width"] for x in g], np.float64),
                    scores=np.array([np.nan if x["score"] is None else x["score"] for x in g], np.float64),
                    samples=np.array([x["sample"] for x in g], np.float64), ranking=ranking)


def draw(answer: dict[str, Any], cloud: ViewpointCloud, path: Path, what: str) -> None:
    """The picture of one answer: the cloud in base_link with the viewpoints the request gave, preprocessed and
    labelled as the detector does it, the best TOP grasps and the warnings."""
    params = DetectionParams(workspace=tuple(OPTIONS["workspace"]), gravity=tuple(OPTIONS["gravity"]))
    prep = GraspDetector(None).prepare(cloud, params, HandGeometry())
    n = len(answer["grasps"])
    title = (f"{what}: the best {min(TOP, n)} of the {n} grasps returned in frame {answer.get('frame', 'cloud')!r} "
             f"({answer['num_candidates']} candidates, model {answer['model']})")
    plot_grasps(prep.cloud, grasps_of(answer), HandGeometry(), path, top=TOP, title=title,
                gravity=params.gravity, environment=prep.environment, warnings=answer["warnings"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=HERE.parents[2] / "shared" / "data" / "real",
                    help="folder with table_mug.pcd (default ../shared/data/real beside the repository)")
    ap.add_argument("--out", type=Path, default=HERE, help="where correct.png and warned.png go")
    args = ap.parse_args(argv)
    camera = read_cloud(args.data / "table_mug.pcd")  # camera optical frame, metres
    pose = pose_matrix(CAMERA_POSE)
    in_base = (camera.points.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]).astype(np.float32)
    requests = {
        "correct": (build_detect_request(camera.points, camera_poses=[CAMERA_POSE], points_frame="camera",
                                         **OPTIONS),
                    ViewpointCloud(points=in_base, viewpoints=pose[None, :3, 3]),
                    "camera-frame cloud + camera_poses (TF), points_frame 'camera'"),
        "warned": (build_detect_request(in_base, viewpoints=[[0.0, 0.0, 0.0]], **OPTIONS),
                   ViewpointCloud(points=in_base, viewpoints=np.zeros((1, 3), np.float32)),
                   "base_link cloud, viewpoint left at [0, 0, 0]"),
    }
    with tempfile.TemporaryDirectory() as tmp, \
            TestClient(create_app(Settings(zenoh_enabled=False, warmup=False, data_dir=Path(tmp)))) as http:
        for name, (body, shown, what) in requests.items():
            r = http.post("/detect", json=body)
            r.raise_for_status()
            answer = r.json()
            draw(answer, shown, args.out / f"{name}.png", what)
            best = answer["grasps"][0]["position"] if answer["grasps"] else None
            print(f"{name}: frame {answer.get('frame')!r}, {len(answer['grasps'])} grasps, best at "
                  f"{np.round(best, 3).tolist() if best else None} m, warnings "
                  f"{[w['code'] for w in answer['warnings']]} -> {args.out / (name + '.png')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
