"""Raw PCD/PLY uploads to POST /detect: the file's points plus options from query parameters, turned
into the same request object as the JSON body."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from graspd.cloud import CloudError
from graspd_client.wire import UPLOAD_QUERY_PARAMS

from .problems import Problem

PCD_TYPES = ("application/x-pcd", "application/pcd", "image/x-pcd")
PLY_TYPES = ("application/ply", "application/x-ply", "model/ply", "text/ply")


def sniff(data: bytes, content_type: str) -> str:
    """'json', 'pcd' or 'ply' from the content type, else from the first bytes."""
    ct = content_type.split(";")[0].strip().lower()
    if ct == "application/json" or ct.endswith("+json"):
        return "json"
    if ct in PCD_TYPES:
        return "pcd"
    if ct in PLY_TYPES:
        return "ply"
    head = data[:512].lstrip()
    if head.startswith(b"ply"):
        return "ply"
    if head.startswith((b"# .PCD", b"VERSION", b"FIELDS")) or b"\nFIELDS " in head:
        return "pcd"
    if head.startswith(b"{"):
        return "json"
    raise Problem(415, "not JSON, PCD or PLY; send a DetectRequest as application/json or a .pcd/.ply file",
                  "body")


def _floats(text: str, n: int, field: str) -> list[float]:
    try:
        values = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise Problem(422, f"{n} comma-separated numbers expected, got {text!r}", field) from None
    if len(values) != n or not np.isfinite(values).all():
        raise Problem(422, f"{n} comma-separated finite numbers expected, got {text!r}", field)
    return values


def upload_request(data: bytes, kind: str, query: Mapping[str, str], viewpoints: list[str]) -> dict[str, Any]:
    """A DetectRequest-shaped dict from file bytes and query parameters (viewpoint may repeat)."""
    from graspd.cloud_io import parse_pcd, parse_ply

    file_vp = None
    try:
        if kind == "pcd":
            points, file_vp = parse_pcd(data)
        else:
            points = parse_ply(data)
    except CloudError as exc:
        message = str(exc)
        field = message.split(":", 1)[0] if message.startswith("cloud.") else "body"
        raise Problem(422, message, field) from None
    except (ValueError, KeyError, IndexError, UnicodeDecodeError) as exc:
        raise Problem(422, f"unreadable {kind.upper()} file ({type(exc).__name__}: {exc})", "body") from None
    if viewpoints:
        vps = [_floats(v, 3, "viewpoint") for v in viewpoints]
    elif file_vp is not None:
        vps = [np.asarray(file_vp, np.float64).tolist()]
    else:
        vps = [[0.0, 0.0, 0.0]]
    body: dict[str, Any] = {"cloud": {"points": np.asarray(points), "viewpoints": vps}}
    if len(vps) > 1:
        from graspd.cloud_io import nearest_camera

        body["cloud"]["camera_source"] = nearest_camera(points, np.asarray(vps))
    for key in ("model", "hand", "method", "environment"):
        if key in query:
            body[key] = query[key]
    for key in ("num_samples", "max_grasps", "seed"):
        if key in query:
            body[key] = query[key]
    for key in ("min_score", "min_aperture", "max_aperture", "approach_distance"):
        if key in query:
            body[key] = query[key]
    for key in ("selection", "clustering", "use_classifier", "exclude_support_plane"):
        if key in query:
            value = query[key].lower()
            if value not in ("true", "false", "1", "0"):
                raise Problem(422, f"true or false expected, got {query[key]!r}", key)
            body[key] = value in ("true", "1")
    if "workspace" in query:
        body["workspace"] = _floats(query["workspace"], 6, "workspace")
    if "gravity" in query:
        body["gravity"] = _floats(query["gravity"], 3, "gravity")
    unknown = sorted(set(query) - set(UPLOAD_QUERY_PARAMS))
    if unknown:
        raise Problem(422, f"unknown query parameter(s) {unknown}", unknown[0])
    return body
