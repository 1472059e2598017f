"""HTTP clients for graspd: GraspClient (blocking) and AsyncGraspClient (asyncio), both over httpx.

numpy in (points, viewpoints, camera indices, optional image), Grasps out.  503 answers are retried
after the server's Retry-After (capped); 4xx raise RequestRejected naming the field.
"""

from __future__ import annotations

import asyncio
import io
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from numpy.typing import ArrayLike

from .codec import WireError
from .errors import RequestRejected, ServerBusy, ServerError, TransportError
from .grasps import Grasps
from .wire import build_demonstration_request, build_detect_request, build_feedback_request, upload_params

DEFAULT_URL = "http://127.0.0.1:8000"


def retry_delay(response: httpx.Response, attempt: int, max_delay: float) -> float:
    """Seconds to wait before retrying a 503: the Retry-After header if given, else exponential backoff."""
    header = response.headers.get("retry-after")
    try:
        delay = float(header) if header is not None else 0.1 * 2**attempt
    except ValueError:
        delay = 0.1 * 2**attempt
    return max(0.0, min(delay, max_delay))


def interpret(response: httpx.Response) -> Any:
    """The JSON body of a 2xx answer; RequestRejected / ServerError otherwise."""
    try:
        body = response.json()
    except ValueError:
        body = None
    if response.is_success:
        if body is None:
            raise ServerError(f"HTTP {response.status_code}: answer is not JSON")
        return body
    message = (body or {}).get("error") if isinstance(body, dict) else None
    field = (body or {}).get("field") if isinstance(body, dict) else None
    text = str(message or response.text[:300] or response.reason_phrase)
    if 400 <= response.status_code < 500:
        raise RequestRejected(response.status_code, text, field=field, body=body)
    raise ServerError(f"HTTP {response.status_code}: {text}")


def parse_grasps(body: Any) -> Grasps:
    try:
        return Grasps.from_response(body)
    except WireError as exc:
        raise ServerError(f"malformed detect response: {exc}") from None


def instance_upload(mesh_path: str | Path, name: str, category: str | None, hand: str | None) -> dict[str, Any]:
    """httpx arguments of a POST /models upload (multipart: the mesh file, name, category, hand)."""
    path = Path(mesh_path)
    fields = {"name": name, **({"category": category} if category else {}), **({"hand": hand} if hand else {})}
    return {"files": {"mesh": (path.name, path.read_bytes(), "application/octet-stream")}, "data": fields}


#: Content types of the files POST /detect takes, by suffix (the server also recognises them by their bytes).
FILE_TYPES = {".pcd": "application/x-pcd", ".ply": "application/ply", ".npy": "application/x-npy",
              ".npz": "application/x-npz", ".png": "image/png", ".mcap": "application/x-mcap",
              ".bag": "application/x-rosbag"}


def file_upload(data: bytes | str | Path, content_type: str | None, params: Mapping[str, Any]
                ) -> dict[str, Any]:
    """httpx arguments of a file upload to POST /detect: the bytes (or a path's), their content type (from the
    suffix when not given) and the options as query parameters (wire.upload_params)."""
    if isinstance(data, str | Path):
        path = Path(data)
        content_type = content_type or FILE_TYPES.get(path.suffix.lower(), "application/octet-stream")
        data = path.read_bytes()
    return {"content": data, "headers": {"Content-Type": content_type or "application/octet-stream"},
            "params": upload_params(params)}


def depth_upload(depth: ArrayLike | bytes, intrinsics: Mapping[str, float] | Sequence[float],
                 camera_pose: Any = None, depth_scale: float | None = None, **params: Any) -> dict[str, Any]:
    """httpx arguments of a depth image upload: PNG bytes (16-bit, depth_scale m a unit, default mm) or an array
    (H,W) (float: metres; integer: depth_scale units) sent as .npy; intrinsics fx, fy, cx, cy (pixels); an
    optional camera-to-robot pose (then the grasps come back in the robot frame)."""
    if isinstance(depth, bytes | bytearray):
        data, content_type = bytes(depth), "image/png"
    else:
        buf = io.BytesIO()
        np.save(buf, np.ascontiguousarray(np.asarray(depth)), allow_pickle=False)
        data, content_type = buf.getvalue(), "application/x-npy"
    options = {**params, "intrinsics": intrinsics, "camera_pose": camera_pose, "depth_scale": depth_scale}
    return file_upload(data, content_type, options)


def find_job(models: Any, job_id: str) -> Any:
    """The job job_id in a GET /models answer; ServerError when the server no longer lists it."""
    for job in models.get("jobs", []) if isinstance(models, dict) else []:
        if isinstance(job, dict) and job.get("id") == job_id:
            return job
    raise ServerError(f"the server lists no instance job {job_id!r} (restarted?)")


class GraspClient:
    """Blocking client.  `GraspClient("http://host:8000").detect(points, viewpoints)` → Grasps."""

    def __init__(self, url: str = DEFAULT_URL, *, timeout: float = 30.0, retries: int = 3,
                 max_retry_delay: float = 5.0, token: str | None = None) -> None:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.retries = retries
        self.max_retry_delay = max_retry_delay
        self._http = httpx.Client(base_url=url, timeout=timeout, headers=headers)

    def __enter__(self) -> GraspClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _request(self, method: str, path: str, **kwargs: Any) -> Any:
        for attempt in range(self.retries + 1):
            try:
                response = self._http.request(method, path, **kwargs)
            except httpx.TimeoutException as exc:
                raise TransportError(f"{method} {path}: no answer within the timeout ({exc!r})") from None
            except httpx.HTTPError as exc:
                raise TransportError(f"{method} {path}: {exc!r}") from None
            if response.status_code == 503 and attempt < self.retries:
                time.sleep(retry_delay(response, attempt, self.max_retry_delay))
                continue
            if response.status_code == 503:
                raise ServerBusy(f"{method} {path}: server busy after {self.retries + 1} attempts")
            return interpret(response)
        raise AssertionError("unreachable")

    def detect(self, points: ArrayLike, viewpoints: ArrayLike = ((0.0, 0.0, 0.0),),
               camera_source: ArrayLike | None = None, **options: Any) -> Grasps:
        """Grasps for a cloud; options are those of build_detect_request (model, hand, num_samples, ...,
        method="templates" for the grasp-template detector)."""
        return self.detect_request(build_detect_request(points, viewpoints, camera_source, **options))

    def add_demonstration(self, points: ArrayLike, hand_pose: ArrayLike,
                          viewpoints: ArrayLike = ((0.0, 0.0, 0.0),), camera_source: ArrayLike | None = None,
                          **options: Any) -> Any:
        """Teach the template library a grasp (hand_pose 4x4 in the cloud frame); options label, hand,
        workspace.  Answers {"entry_id", "library": counts}."""
        body = build_demonstration_request(points, hand_pose, viewpoints, camera_source, **options)
        return self._request("POST", "/demonstrations", json=body)

    def feedback(self, grasp_id: str, success: bool) -> Any:
        """Report the outcome of executing a returned grasp (Grasps.ids); answers what was stored."""
        return self._request("POST", "/feedback", json=build_feedback_request(grasp_id, success))

    def library(self) -> Any:
        """The template library: counts, hand, and entries (id, label, created_at, failures, ...)."""
        return self._request("GET", "/library")

    def detect_request(self, body: dict[str, Any]) -> Grasps:
        """Grasps for an already-built request body."""
        return parse_grasps(self._request("POST", "/detect", json=body))

    def detect_file(self, data: bytes | str | Path, *, content_type: str | None = None, **params: Any) -> Grasps:
        """Grasps for a file (its bytes or its path): .pcd, .ply, .npy ((N,3) points or (H,W,3) organised), .npz
        (points, optional viewpoints, camera_source, normals, camera_poses), a ROS bag (.mcap, ROS 1 .bag; with
        topic, index, info_topic, frame).  params are the upload's query parameters: viewpoint, camera_pose (one or
        a list; with points_frame "camera" or "robot"), num_samples, model, ... (Python values: wire.upload_params
        writes them)."""
        return parse_grasps(self._request("POST", "/detect", **file_upload(data, content_type, params)))

    def detect_depth(self, depth: ArrayLike | bytes, intrinsics: Mapping[str, float] | Sequence[float], *,
                     camera_pose: Any = None, depth_scale: float | None = None, **params: Any) -> Grasps:
        """Grasps for a depth image: 16-bit PNG bytes (millimetres unless depth_scale says otherwise) or an (H,W)
        array (float metres); intrinsics fx, fy, cx, cy (pixels, ROS CameraInfo K); camera_pose (camera-to-robot:
        4x4, 7 numbers x, y, z, qx, qy, qz, qw, or {position, quat_xyzw}) puts the answer in the robot frame.
        params: other query parameters (num_samples, workspace, ...)."""
        return parse_grasps(self._request("POST", "/detect", **depth_upload(depth, intrinsics, camera_pose,
                                                                            depth_scale, **params)))

    def models(self) -> Any:
        """{"default", "models": [{name, representation, default, card}], "jobs": [instance jobs]}."""
        return self._request("GET", "/models")

    def train_instance(self, mesh_path: str | Path, name: str, category: str | None = None,
                       hand: str | None = None) -> Any:
        """Ask the server for an instance model of one object (POST /models): its mesh (.obj, .stl or .ply,
        metres), the new model's name, optionally its category ("box" or "cylinder": fine-tune the category
        model) and hand preset.  Answers the queued job ({"id", "name", "state", ...}); wait_instance waits
        for it, and then detect(..., model=name) uses the new model."""
        return self._request("POST", "/models", **instance_upload(mesh_path, name, category, hand))

    def wait_instance(self, job_id: str, timeout: float = 1800.0, poll: float = 2.0) -> Any:
        """The instance job once it is done or failed (its "state" says which); TransportError after timeout s."""
        end = time.monotonic() + timeout
        while True:
            job = find_job(self.models(), job_id)
            if job["state"] in ("done", "failed") or time.monotonic() > end:
                break
            time.sleep(poll)
        if job["state"] not in ("done", "failed"):
            raise TransportError(f"instance job {job_id} still {job['state']} after {timeout:g} s")
        return job

    def ready(self) -> bool:
        try:
            self._request("GET", "/readyz")
        except (RequestRejected, ServerBusy, ServerError, TransportError):
            return False
        return True


class AsyncGraspClient:
    """asyncio client with the same methods as GraspClient (awaitable)."""

    def __init__(self, url: str = DEFAULT_URL, *, timeout: float = 30.0, retries: int = 3,
                 max_retry_delay: float = 5.0, token: str | None = None) -> None:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.retries = retries
        self.max_retry_delay = max_retry_delay
        self._http = httpx.AsyncClient(base_url=url, timeout=timeout, headers=headers)

    async def __aenter__(self) -> AsyncGraspClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        await self._http.aclose()

    async def _request(self, method: str, path: str, **kwargs: Any) -> Any:
        for attempt in range(self.retries + 1):
            try:
                response = await self._http.request(method, path, **kwargs)
            except httpx.TimeoutException as exc:
                raise TransportError(f"{method} {path}: no answer within the timeout ({exc!r})") from None
            except httpx.HTTPError as exc:
                raise TransportError(f"{method} {path}: {exc!r}") from None
            if response.status_code == 503 and attempt < self.retries:
                await asyncio.sleep(retry_delay(response, attempt, self.max_retry_delay))
                continue
            if response.status_code == 503:
                raise ServerBusy(f"{method} {path}: server busy after {self.retries + 1} attempts")
            return interpret(response)
        raise AssertionError("unreachable")

    async def detect(self, points: ArrayLike, viewpoints: ArrayLike = ((0.0, 0.0, 0.0),),
                     camera_source: ArrayLike | None = None, **options: Any) -> Grasps:
        return await self.detect_request(build_detect_request(points, viewpoints, camera_source, **options))

    async def detect_request(self, body: dict[str, Any]) -> Grasps:
        return parse_grasps(await self._request("POST", "/detect", json=body))

    async def detect_file(self, data: bytes | str | Path, *, content_type: str | None = None,
                          **params: Any) -> Grasps:
        return parse_grasps(await self._request("POST", "/detect", **file_upload(data, content_type, params)))

    async def detect_depth(self, depth: ArrayLike | bytes, intrinsics: Mapping[str, float] | Sequence[float], *,
                           camera_pose: Any = None, depth_scale: float | None = None, **params: Any) -> Grasps:
        return parse_grasps(await self._request("POST", "/detect", **depth_upload(depth, intrinsics, camera_pose,
                                                                                  depth_scale, **params)))

    async def add_demonstration(self, points: ArrayLike, hand_pose: ArrayLike,
                                viewpoints: ArrayLike = ((0.0, 0.0, 0.0),), camera_source: ArrayLike | None = None,
                                **options: Any) -> Any:
        body = build_demonstration_request(points, hand_pose, viewpoints, camera_source, **options)
        return await self._request("POST", "/demonstrations", json=body)

    async def feedback(self, grasp_id: str, success: bool) -> Any:
        return await self._request("POST", "/feedback", json=build_feedback_request(grasp_id, success))

    async def library(self) -> Any:
        return await self._request("GET", "/library")

    async def models(self) -> Any:
        return await self._request("GET", "/models")

    async def train_instance(self, mesh_path: str | Path, name: str, category: str | None = None,
                             hand: str | None = None) -> Any:
        return await self._request("POST", "/models", **instance_upload(mesh_path, name, category, hand))

    async def wait_instance(self, job_id: str, timeout: float = 1800.0, poll: float = 2.0) -> Any:
        end = time.monotonic() + timeout
        while True:
            job = find_job(await self.models(), job_id)
            if job["state"] in ("done", "failed") or time.monotonic() > end:
                break
            await asyncio.sleep(poll)
        if job["state"] not in ("done", "failed"):
            raise TransportError(f"instance job {job_id} still {job['state']} after {timeout:g} s")
        return job
