"""Saved request/answer pairs every transport must keep giving (tests/server/data/transport_cases/): the requests
(table_mug's points every 4th, sent as a flat list, so unorganised; a rendered box for the templates), how to
build each on a transport, and the answer's comparison (ids and timings left out, floats to 1e-6 relative).

Set GRASPD_RECORD_TRANSPORT_CASES=1 to write the answers the code gives now instead of comparing with them."""

from __future__ import annotations

import io
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from graspd.io.cloud_files import read_input
from graspd.io.png import encode_png_b64
from graspd_client import build_detect_request

CASES_DIR = Path(__file__).resolve().parent / "data" / "transport_cases"
RECORD = os.environ.get("GRASPD_RECORD_TRANSPORT_CASES") == "1"
#: Keys an answer may differ in from run to run or transport to transport (ids made per request, times).
VOLATILE = frozenset({"request_id", "timings", "id", "template_entry"})
#: Relative and absolute float tolerance of a replayed answer against the saved one.
RTOL, ATOL = 1e-6, 1e-7


def mug_points(real_data: Path) -> np.ndarray:
    """table_mug.pcd (camera frame, the camera at the origin), every 4th point (26k) as one flat (N, 3) array."""
    return read_input(real_data / "table_mug.pcd").cloud.points[::4].reshape(-1, 3).copy()


#: The options of the small default detection (the ROS 2 tests' node options).
SMALL = {"num_samples": 30, "max_grasps": 6}


def crops_options(points: np.ndarray) -> dict[str, Any]:
    """Crops of a 64 x 48 gradient image seen by a pinhole camera at the cloud's origin (table_mug's camera)."""
    h, w = 48, 64
    yy, xx = np.mgrid[0:h, 0:w]
    image = np.stack([xx * 4, yy * 5, (xx + yy) * 2], axis=-1).astype(np.uint8)
    return {"crops": {"image_png": encode_png_b64(image), "intrinsics": {"fx": 55.0, "fy": 55.0, "cx": 32.0,
                                                                          "cy": 24.0},
                      "camera_pose": np.eye(4).tolist(), "size": 16}}


def options_case(points: np.ndarray) -> dict[str, Any]:
    """A mix of options: a workspace, an approach cone, a seed, max_per_object and crops."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    mid = (lo + hi) / 2
    workspace = [float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]), float(mid[2] - 0.4), float(mid[2] + 0.4)]
    return {"num_samples": 40, "max_grasps": 5, "seed": 3, "workspace": workspace, "max_per_object": 2,
            "approach": {"direction": [0.0, 0.0, 1.0], "max_angle_deg": 80.0}, **crops_options(points)}


def json_body(points: np.ndarray, **options: Any) -> dict[str, Any]:
    """A DetectRequest body: the points (one viewpoint, the origin) and options as the request names them."""
    return {**build_detect_request(points, [[0.0, 0.0, 0.0]]), **options}


#: table_mug's support plane as the GPD answer of json_small found it (unit normal toward the camera, offset m):
#: the templates case's demonstration is placed from it, not from a detection
MUG_SUPPORT = (np.array([0.017108801510903687, -0.8370736805811262, -0.5468225874899713]), 0.5293914407402468)


def mug_top_grasp(points: np.ndarray, hand_depth: float = 0.06, reach: float = 0.03) -> np.ndarray:
    """A top-down hand pose (4x4, cloud frame, rotation columns [approach, binormal, axis]) over the mug: the
    points more than 1.5 cm above the support, approached against the support's normal, fingertips `reach` m
    below the mug's top, centred on its points' mean."""
    normal, offset = MUG_SUPPORT
    height = points @ normal + offset
    mug = points[height > 0.015]
    centre = mug.mean(axis=0)
    approach = -normal
    binormal = np.cross(approach, [1.0, 0.0, 0.0])
    binormal /= np.linalg.norm(binormal)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([approach, binormal, np.cross(approach, binormal)], axis=1)
    pose[:3, 3] = centre + normal * (height.max() - (centre @ normal + offset) + hand_depth - reach)
    return pose


def npy_bytes(points: np.ndarray) -> bytes:
    """The points as an NPY file body (float32, N x 3)."""
    buf = io.BytesIO()
    np.save(buf, np.asarray(points, np.float32))
    return buf.getvalue()


def stable(answer: Any) -> Any:
    """The answer without what changes between runs (VOLATILE keys, at any depth)."""
    if isinstance(answer, dict):
        return {k: stable(v) for k, v in answer.items() if k not in VOLATILE}
    if isinstance(answer, list):
        return [stable(v) for v in answer]
    return answer


def differences(got: Any, want: Any, path: str = "") -> list[str]:
    """Where got differs from want (floats beyond RTOL/ATOL, anything else exactly), as dotted paths."""
    if isinstance(want, dict) and isinstance(got, dict):
        out = [f"{path}.{k}: missing" for k in want.keys() - got.keys()]
        out += [f"{path}.{k}: unexpected" for k in got.keys() - want.keys()]
        for k in want.keys() & got.keys():
            out += differences(got[k], want[k], f"{path}.{k}")
        return out
    if isinstance(want, list) and isinstance(got, list):
        if len(want) != len(got):
            return [f"{path}: {len(got)} items, want {len(want)}"]
        return [d for i, (g, w) in enumerate(zip(got, want, strict=True)) for d in differences(g, w, f"{path}[{i}]")]
    if isinstance(want, float) or isinstance(got, float):
        if isinstance(got, int | float) and isinstance(want, int | float) and not isinstance(got, bool) and (
                math.isclose(got, want, rel_tol=RTOL, abs_tol=ATOL)):
            return []
        return [f"{path}: {got!r} != {want!r}"]
    return [] if got == want else [f"{path}: {got!r} != {want!r}"]


def check(name: str, answer: dict[str, Any]) -> None:
    """Compare an answer with the saved case `name` (or save it when recording); AssertionError lists the
    differences."""
    path = CASES_DIR / f"{name}.json"
    got = stable(answer)
    if RECORD:
        CASES_DIR.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
        return
    want = json.loads(path.read_text())
    diff = differences(got, want)
    assert not diff, f"{name}: {len(diff)} differences from the saved answer, first: {diff[:5]}"


def agree(got: dict[str, Any], reference: dict[str, Any], what: str) -> None:
    """got (another transport's answer) is the JSON route's reference answer, but for the ids and times."""
    diff = differences(stable(got), stable(reference))
    assert not diff, f"{what}: {len(diff)} differences from the JSON route's answer, first: {diff[:5]}"
