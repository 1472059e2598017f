"""Every entrance's parsing, in one place: JSON text, a file upload (PCD, PLY, NPY, NPZ, depth PNG with its
query options) or a decoded object becomes one validated request model (DetectRequest, ...), or a Problem
(400/422) naming the field.  HTTP routes, the Zenoh queryables and the ROS streams call these; the engine only
ever sees the typed request."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any, TypeVar

import orjson
from pydantic import BaseModel, ValidationError

from graspd.server.problems import CALLER_ERRORS, Problem, from_validation, from_wire
from graspd.server.uploads import sniff, upload_request
from graspd.server.wire.detect import DetectRequest

M = TypeVar("M", bound=BaseModel)


#: Deepest JSON nesting a request may have: orjson's own limit (the deepest valid request has ~6 levels).
MAX_JSON_DEPTH = 1024


class JsonTooDeep(ValueError):
    """Valid JSON nested beyond MAX_JSON_DEPTH: a 422 naming the body, not a parse error."""


def json_depth(obj: Any, limit: int = MAX_JSON_DEPTH) -> int:
    """Nesting depth of decoded JSON, counted iteratively (no recursion) and only up to limit + 1."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(obj, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            item = list(item.values())
        elif not isinstance(item, list):
            continue
        deepest = max(deepest, depth)
        if deepest > limit:
            return deepest
        stack.extend((v, depth + 1) for v in item if isinstance(v, list | dict))
    return deepest


def loads(payload: bytes | str) -> Any:
    """JSON text -> Python objects: orjson (~2x faster on megabyte bodies), else the standard library, which
    also reads NaN and Infinity (orjson refuses them) so that they reach validation and get a 422 naming the
    field.  orjson reads integers beyond 64 bits as floats; every integer field is bounded far below.
    ValueError when the text is not JSON or nests deeper than MAX_JSON_DEPTH (no RecursionError escapes)."""
    too_deep = f"JSON nested too deeply (at most about {MAX_JSON_DEPTH} levels)"
    try:
        return orjson.loads(payload)
    except orjson.JSONDecodeError as exc:
        if any(word in str(exc).lower() for word in ("depth limit", "recursion")):  # orjson 3.x wordings
            raise JsonTooDeep(too_deep) from None
    try:
        value = json.loads(payload)
    except RecursionError:
        raise JsonTooDeep(too_deep) from None
    if isinstance(value, list | dict) and json_depth(value) > MAX_JSON_DEPTH:
        raise JsonTooDeep(too_deep)
    return value


def dumps(body: Any) -> bytes:
    """Compact JSON bytes of a response body (orjson, ~10x faster than json.dumps on a 100-grasp answer)."""
    try:
        return orjson.dumps(body, option=orjson.OPT_SERIALIZE_NUMPY)
    except TypeError:  # a type orjson does not know: the standard library's rules
        return json.dumps(body, separators=(",", ":")).encode()


def parse_request(payload: bytes | str | dict[str, Any]) -> DetectRequest:
    """A validated DetectRequest from JSON text or a decoded object; Problem (400/422) names the field."""
    return parse_model(DetectRequest, payload)


def json_object(payload: bytes | str | dict[str, Any]) -> dict[str, Any]:
    """A JSON object from JSON text (or one already decoded); Problem 400 (not JSON) or 422 (too deep, not
    an object) naming the body."""
    if isinstance(payload, bytes | str):
        try:
            payload = loads(payload)
        except JsonTooDeep as exc:
            raise Problem(422, str(exc), "body") from None
        except (ValueError, UnicodeDecodeError) as exc:
            raise Problem(400, f"invalid JSON ({exc})", "body") from None
    if not isinstance(payload, dict):
        raise Problem(422, f"a JSON object is expected, got {type(payload).__name__}", "body")
    return payload


def parse_model(model: type[M], payload: bytes | str | dict[str, Any]) -> M:
    """A validated request model from JSON text or a decoded object; Problem (400/422) names the field."""
    payload = json_object(payload)
    try:
        return model.model_validate(payload)
    except ValidationError as exc:
        raise from_validation(exc) from None
    except CALLER_ERRORS as exc:
        raise from_wire(exc) from None


def parse_body(data: bytes, content_type: str, query: Mapping[str, str], viewpoints: list[str],
               camera_poses: list[str] | None = None) -> DetectRequest:
    """A validated DetectRequest from the body (JSON, PCD, PLY, NPY, NPZ or a depth PNG; options of a file in the
    query, viewpoint and camera_pose repeatable); runs on a worker thread: file decoding takes tens of milliseconds
    to seconds."""
    kind = sniff(data, content_type)
    if kind == "json":
        return parse_request(data)
    return parse_request(upload_request(data, kind, query, viewpoints, camera_poses))
