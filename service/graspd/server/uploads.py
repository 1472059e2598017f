"""Raw PCD/PLY uploads to POST /detect: the file's points plus options from query parameters, turned
into the same request object as the JSON body."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import UnionType
from typing import Any, Literal, Union, get_args, get_origin

import numpy as np
from pydantic import BaseModel
from pydantic.fields import FieldInfo

from graspd.cloud import CloudError
from graspd.cloud_io import nearest_camera, parse_pcd, parse_ply

from .problems import Problem, from_error
from .schemas import DetectRequest

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


@dataclass(frozen=True)
class QueryParam:
    """One upload query parameter: a DetectRequest field (or viewpoint) and how its text is read.  kind: "bool"
    (true/false/1/0), "vector" (n comma-separated numbers), "text" (the string itself; pydantic converts numbers
    and checks it as it checks the JSON field)."""

    name: str
    kind: Literal["bool", "vector", "text"]
    schema: dict[str, Any]
    description: str
    length: int = 0


def _unwrap(annotation: Any) -> Any:
    """T from T | None."""
    args = [a for a in get_args(annotation) if a is not type(None)]
    return args[0] if get_origin(annotation) in (Union, UnionType) and len(args) == 1 else annotation


def _query_param(name: str, info: FieldInfo, schema: dict[str, Any]) -> QueryParam | None:
    """The query form of a DetectRequest field, None when it has none (objects: cloud, approach, crops)."""
    kind = _unwrap(info.annotation)
    description = info.description or ""
    if isinstance(kind, type) and issubclass(kind, BaseModel):  # a model with a string shorthand (hand, environment)
        form = getattr(kind, "STRING_FORM", None)
        if form is None:
            return None
        inner = kind.model_json_schema()["properties"][form]
        sub = {k: v for k, v in inner.items() if k in ("type", "enum")} or {"type": "string"}
        sub["type"] = "string"
        return QueryParam(name, "text", sub, f"the {form} (a plain string of the JSON field): "
                          f"{inner.get('description', description)}")
    if get_origin(kind) is list:
        n = next((m.min_length for m in info.metadata if getattr(m, "min_length", None)), 0)
        return QueryParam(name, "vector", {"type": "string"}, f"{n} comma-separated numbers: {description}", n)
    sub = {k: v for k, v in schema.items() if k not in ("anyOf", "default", "title", "description")}
    if "anyOf" in schema:  # T | None: the query form is T
        sub.update(next(s for s in schema["anyOf"] if s.get("type") != "null"))
    return QueryParam(name, "bool" if sub.get("type") == "boolean" else "text", sub, description)


def _query_params() -> dict[str, QueryParam]:
    """The upload query parameters: viewpoint, then every DetectRequest field that has a query form."""
    props = DetectRequest.model_json_schema()["properties"]
    out = {"viewpoint": QueryParam(
        "viewpoint", "vector", {"type": "string"}, "camera position 'x,y,z' (m) for PCD/PLY uploads; may repeat; "
        "default: the PCD VIEWPOINT header, else the origin", 3)}
    for name, info in DetectRequest.model_fields.items():
        param = _query_param(name, info, props[name])
        if param is not None:
            out[name] = param
    return out


#: Query parameters of a raw PCD/PLY upload to POST /detect, generated from DetectRequest.
QUERY_PARAMS: dict[str, QueryParam] = _query_params()


def openapi_parameters() -> list[dict[str, Any]]:
    """The OpenAPI parameter objects of QUERY_PARAMS."""
    return [{"name": p.name, "in": "query", "required": False, "schema": p.schema, "description": p.description}
            for p in QUERY_PARAMS.values()]


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
    unknown = sorted(set(query) - set(QUERY_PARAMS))
    file_vp = None
    try:
        if kind == "pcd":
            points, file_vp = parse_pcd(data)
        else:
            points = parse_ply(data)
    except CloudError as exc:
        raise from_error(exc, ("cloud",)) from None
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
        body["cloud"]["camera_source"] = nearest_camera(points, np.asarray(vps))
    for name, param in QUERY_PARAMS.items():
        if name not in query or name == "viewpoint":
            continue
        text = query[name]
        if param.kind == "bool":
            if text.lower() not in ("true", "false", "1", "0"):
                raise Problem(422, f"true or false expected, got {text!r}", name)
            body[name] = text.lower() in ("true", "1")
        elif param.kind == "vector":
            body[name] = _floats(text, param.length, name)
        else:
            body[name] = text
    if unknown:
        raise Problem(422, f"unknown query parameter(s) {unknown}", unknown[0])
    return body
