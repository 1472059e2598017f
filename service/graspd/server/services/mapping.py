"""The mapping between the wire models (graspd.server.wire) and the detector's types, both ways: a request's cloud
as the detector's input (cloud_input: non-finite rows dropped and counted, an organised cloud's grid, frames
applied), its target, parameters and crop image (detection_inputs), and an Outcome (services.outcome) as the JSON
answer every transport sends (response, response_json: the one encoder of an answer).  The errors a request's
values cause here are the caller's (FieldError / WireError naming the field: a 422)."""

from __future__ import annotations

import base64
import binascii
from dataclasses import dataclass
from typing import Any

import numpy as np

from graspd.core.cloud import CloudGrid, ViewpointCloud
from graspd.core.limits import MAX_POINTS
from graspd.gpd.detector import DetectionParams
from graspd.gpd.environment import Box, EnvironmentParams, Plane
from graspd.gpd.target import OrientedBox, Target, TargetKind
from graspd.io.inputs import CloudInput, apply_frames, check_shape, keep_finite, point_counts
from graspd.io.png import check_image_size, decode_png_rgb, png_size
from graspd.server.services.outcome import GraspResult, Outcome
from graspd.server.wire.detect import Cloud, CropsRequest, DetectRequest, EnvironmentSpec, TargetSpec
from graspd.server.wire.response import DetectResponse
from graspd_client.codec import WireError


# ---- wire -> domain -----------------------------------------------------------------------------------------
def cloud_input(cloud: Cloud, field: str = "cloud") -> CloudInput:
    """The detector's cloud of a wire cloud, in the frame detection runs in (graspd.io.inputs.apply_frames): the
    rows with a NaN or infinite coordinate (or normal) dropped and counted (none left: a CloudError naming
    <field>.points), an organised cloud's grid (its shape checked against the rows sent: <field>.shape)."""
    points = np.asarray(cloud.points)
    received = len(points)
    if cloud.pixels is None:  # every pixel sent, row-major (with pixels, the wire model checked them)
        check_shape(cloud.shape, received, f"{field}.shape")
    keep, dropped = keep_finite(points, cloud.normals, f"{field}.points")
    source, normals = cloud.camera_source, cloud.normals
    if keep is not None:
        points = points[keep]
        source = None if source is None else source[keep]
        normals = None if normals is None else normals[keep]
    poses = cloud.poses()
    viewpoints = (np.zeros((len(poses), 3), np.float32) if poses is not None
                  else np.asarray(cloud.viewpoints, np.float32))
    grid = None
    if cloud.shape is not None:
        pixels = cloud.pixels
        grid = (CloudGrid.of_rows(cloud.shape[0], cloud.shape[1], keep) if pixels is None
                else CloudGrid(cloud.shape[0], cloud.shape[1], pixels if keep is None else pixels[keep]))
    detector_cloud = ViewpointCloud(points=points, viewpoints=viewpoints, normals=normals, grid=grid,
                                    camera_source=np.zeros(0, np.int32) if source is None else source)
    moved, frame = apply_frames(detector_cloud, poses, cloud.points_frame)
    return CloudInput(moved, frame, dropped, received, keep)


def _png_mask_size(b64: str, field: str) -> tuple[int, int]:
    """(width, height) a base64 PNG mask declares, checked against the PNG limits before anything is decoded."""
    try:
        raw = base64.b64decode(b64[:64] + "=" * (-len(b64[:64]) % 4), validate=True)  # the IHDR is in 33 bytes
    except (binascii.Error, ValueError) as exc:
        raise WireError(field, f"invalid base64 ({exc})") from None
    try:
        width, height = png_size(raw)
        check_image_size(width, height, MAX_POINTS)
    except ValueError as exc:
        raise WireError(field, str(exc)) from None
    return width, height


def _target_rows(spec: TargetSpec, received: int) -> np.ndarray | None:
    """One flag per row of the cloud as sent (received rows) for indices and masks, else None; WireError naming
    target.<field> when an index lies outside the cloud or the mask is not the cloud's size."""
    if spec.indices is not None:
        idx = spec.indices
        if idx.min() < 0 or idx.max() >= received:
            raise WireError("target.indices", f"rows must lie in [0, {received - 1}] (the cloud has {received} "
                            f"rows), got values in [{idx.min()}, {idx.max()}]")
        rows = np.zeros(received, bool)
        rows[idx] = True
        return rows
    if spec.mask is None:
        return None
    if isinstance(spec.mask, str):
        width, height = _png_mask_size(spec.mask, "target.mask")
    else:
        height, width = spec.mask.size
    if width * height != received:
        raise WireError("target.mask", f"a {width}x{height} mask has {width * height} pixels, the cloud {received} "
                        "rows; send the mask of the organised cloud's (or depth image's) own image")
    if isinstance(spec.mask, str):
        try:
            return np.asarray(decode_png_rgb(spec.mask, MAX_POINTS).any(axis=2)).reshape(-1)
        except ValueError as exc:
            raise WireError("target.mask", str(exc)) from None
    try:
        return spec.mask.decode()
    except WireError as exc:
        raise WireError("target.mask" + exc.field, exc.message) from None


def detection_target(spec: TargetSpec | None, given: CloudInput) -> Target | None:
    """The detector's target of a request's target on its input: rows of the cloud as sent are mapped onto the
    rows kept (given.kept); WireError naming target.<field> when it does not fit the cloud."""
    if spec is None:
        return None
    if spec.box is not None:
        pose = spec.box.pose()
        return Target("box", box=OrientedBox(centre=pose[:3, 3].copy(), rotation=pose[:3, :3].copy(),
                                             half_extents=np.asarray(spec.box.half_extents, np.float64)))
    if spec.points is not None:
        return Target("points", points=np.asarray(spec.points, np.float64))
    if spec.object is not None:
        return Target("object", object_id=spec.object)
    received = given.received or len(given.cloud)
    rows = _target_rows(spec, received)
    assert rows is not None
    kind: TargetKind = "indices" if spec.indices is not None else "mask"
    if given.kept is not None:
        rows = rows[given.kept]
    if not rows.any():
        raise WireError(f"target.{kind}", "selects no row of the cloud with finite coordinates"
                        if given.kept is not None else "selects no row of the cloud")
    return Target(kind, rows=rows)


def environment_params(spec: EnvironmentSpec | None) -> EnvironmentParams:
    """The environment stage's parameters of a request's environment (default: auto)."""
    if spec is None:
        return EnvironmentParams()
    plane = None if spec.support_plane is None else np.asarray(spec.support_plane, np.float64)
    return EnvironmentParams(mode=spec.mode, support=None if plane is None else Plane.from_coefficients(plane),
                             boxes=tuple(Box.from_bounds(b) for b in spec.boxes))


def detection_params(req: DetectRequest, target: Target | None = None) -> DetectionParams:
    """The detector's knobs (metres, degrees, cloud frame) with target.  Every limit was checked by validation
    (the bounds in graspd_client.wire); WireError naming the body if DetectionParams still refuses."""
    approach, gravity = req.approach, req.gravity
    try:
        return DetectionParams(
            num_samples=req.num_samples,
            workspace=req.workspace_bounds(),
            range_window=req.range_window,
            max_grasps=req.max_grasps,
            min_score=req.min_score,
            approach_direction=None if approach is None else (approach.direction[0], approach.direction[1],
                                                              approach.direction[2]),
            approach_max_angle_deg=None if approach is None else approach.max_angle_deg,
            min_aperture=req.min_aperture,
            max_aperture=req.max_aperture,
            use_selection=req.selection,
            use_clustering=req.clustering,
            use_classifier=req.use_classifier,
            gravity=None if gravity is None else (gravity[0], gravity[1], gravity[2]),
            exclude_support_plane=req.exclude_support_plane,
            environment=environment_params(req.environment),
            approach_distance=req.approach_distance,
            early_stop=req.early_stop,
            cascade=req.cascade,
            unknown_space=req.unknown_space,
            flat_objects=req.flat_objects,
            robust_copies=req.robust_copies,
            seed=req.seed,
            target=target,
            max_per_object=req.max_per_object,
        )
    except ValueError as exc:
        raise WireError("body", str(exc)) from None


def crops_image(crops: CropsRequest) -> np.ndarray:
    """The RGB image (H,W,3) uint8 of a crops request, its PNG decoded, its size checked (at least 2x2, at most
    8 MP) and the intrinsics' principal point inside it; WireError naming crops.<field>."""
    if crops.image_png is not None:
        try:
            image = decode_png_rgb(crops.image_png)
        except ValueError as exc:
            raise WireError("crops.image_png", str(exc)) from None
    else:
        assert crops.image is not None
        image = crops.image
        try:
            check_image_size(image.shape[1], image.shape[0])
        except ValueError as exc:
            raise WireError("crops.image", str(exc)) from None
    h, w = image.shape[:2]
    intr = crops.intrinsics
    if not (0 <= intr.cx <= w and 0 <= intr.cy <= h):
        raise WireError("crops.intrinsics", f"principal point ({intr.cx:g}, {intr.cy:g}) lies outside the {w}x{h} "
                        "image; intrinsics and image do not match")
    return image


@dataclass(frozen=True)
class DetectionInputs:
    """What a detection runs on: the input cloud (in the frame detection runs in, with its drop counts), the
    parameters (target included) and the crops' image (None: no crops asked)."""

    given: CloudInput
    params: DetectionParams
    crops_image: np.ndarray | None = None


def detection_inputs(req: DetectRequest, given: CloudInput | None = None, target: Target | None = None
                     ) -> DetectionInputs:
    """A request's detection inputs: given (a ROS message's cloud, already decoded) or the request's cloud, the
    request's target (or a ROS message's own), the crops' image.  FieldError / WireError naming the field."""
    given = given if given is not None else cloud_input(req.cloud)
    if target is None:
        target = detection_target(req.target, given)
    image = None if req.crops is None else crops_image(req.crops)
    return DetectionInputs(given, detection_params(req, target), image)


# ---- domain -> wire -----------------------------------------------------------------------------------------


def result_body(result: GraspResult, *, request_id: str, detection_id: str, timings: dict[str, float],
                frame: str = "cloud", crops: list[dict[str, Any]] | None = None, header: dict[str, Any] | None = None,
                model_fits_hand: bool | None = None, received: int | None = None, dropped: int = 0,
                out_of_range: int | None = None) -> dict[str, Any]:
    """The answer's JSON object for a result (the keys DetectResponse documents; those that do not apply to the
    method left out).  Grasp ids: result.grasp_ids(detection_id); crops: one CropOut-shaped dict per grasp;
    header: a ROS input's header; frame: the frame the grasps are in (graspd.core.frames); received, dropped: the
    rows the request's cloud had and those dropped for a NaN or infinite value (None: not a request's cloud);
    out_of_range: the finite rows the range window left out (None: not known, the templates)."""
    g = result.grasps
    cols = (result.grasp_ids(detection_id), g.positions.tolist(), g.approach.tolist(), g.binormal.tolist(),
            g.axis.tolist(), g.widths.tolist(), g.scores.tolist(), g.samples.tolist(), g.poses.tolist(),
            g.quat_xyzw.tolist(), result.grasp_fields())
    grasps: list[dict[str, Any]] = [
        {"id": gid, "position": pos, "approach": app, "binormal": bn, "axis": axis, "width": width,
         "score": None if score != score else score, "sample": sample, "pose": pose, "quat_xyzw": quat, **own}
        for gid, pos, app, bn, axis, width, score, sample, pose, quat, own in zip(*cols, strict=True)]
    if crops is not None:
        for grasp, crop in zip(grasps, crops, strict=True):
            grasp["crop"] = crop
    out: dict[str, Any] = {"request_id": request_id, "method": result.method, "frame": frame, "grasps": grasps,
                           "timings": timings, "num_candidates": result.num_candidates,
                           "num_points": result.num_points, "hand": result.hand.to_dict(),
                           "warnings": [w.to_dict() for w in result.warnings],
                           "model": result.model, "scored": result.scored, **result.answer_fields()}
    if received is not None:
        out.update(point_counts(received, dropped, out_of_range))
    if header is not None:
        out["header"] = header
    if model_fits_hand is not None:
        out["model_fits_hand"] = model_fits_hand
    return out


def response(outcome: Outcome) -> DetectResponse:
    """The answer to an Outcome, validated against DetectResponse (what is sent cannot drift from what is
    documented).  Cost at 100 grasps: ~1.2 ms to build, validate (pydantic-core) and serialise."""
    return DetectResponse.model_validate(result_body(
        outcome.result, request_id=outcome.request_id, detection_id=outcome.detection_id, timings=outcome.timings,
        frame=outcome.frame, crops=outcome.crops, header=outcome.header, model_fits_hand=outcome.model_fits_hand,
        received=outcome.received, dropped=outcome.dropped, out_of_range=outcome.out_of_range))


def response_json(outcome: Outcome) -> bytes:
    """The JSON bytes of an Outcome's answer, as every transport sends it: compact, with only the keys that apply
    (DetectResponse.to_json)."""
    return response(outcome).to_json()
