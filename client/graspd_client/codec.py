"""The array codec of the wire contract: {"dtype", "shape", "data": base64 of little-endian C-order bytes},
or plain nested lists for small inputs.  Pure numpy + stdlib so robots need nothing else."""

from __future__ import annotations

import base64
import binascii
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

try:  # SIMD base64, ~50x faster on megabyte clouds; optional here, a dependency of the server
    import pybase64 as _fast_b64
except ImportError:  # pragma: no cover - depends on the environment
    _fast_b64 = None  # type: ignore[assignment]

#: dtypes accepted on the wire (names as numpy spells them; bytes are always little-endian).
WIRE_DTYPES: tuple[str, ...] = (
    "float32", "float64", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64",
)

#: Shape spec: one entry per axis, an int for a fixed length or None (any length).
ShapeSpec = Sequence[int | None]


class WireError(ValueError):
    """A value on the wire is malformed; `field` is its dotted path (e.g. "cloud.points")."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}" if field else message)


def _shape_text(spec: ShapeSpec) -> str:
    names = iter("NMKLJ")
    parts = [str(s) if s is not None else next(names, "?") for s in spec]
    return "(" + ",".join(parts) + ("," if len(parts) == 1 else "") + ")"


def _got_text(shape: tuple[int, ...]) -> str:
    return "(" + ",".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def encode_array(array: Any, dtype: str | None = None) -> dict[str, Any]:
    """The wire form of an array: dtype name, shape list and base64 of its little-endian C-order bytes."""
    arr = np.asarray(array)
    if dtype is not None:
        arr = arr.astype(dtype, copy=False)
    if arr.dtype.name not in WIRE_DTYPES:
        raise WireError("", f"dtype {arr.dtype.name} cannot go on the wire; use one of {', '.join(WIRE_DTYPES)}")
    le = np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<"))
    return {"dtype": arr.dtype.name, "shape": list(arr.shape), "data": _b64encode(le.tobytes())}


def _b64encode(raw: bytes) -> str:
    """Standard base64 text of raw bytes (no newlines)."""
    if _fast_b64 is not None:
        return str(_fast_b64.b64encode_as_string(raw))
    return base64.b64encode(raw).decode("ascii")


def _b64decode(text: str) -> bytes:
    """Bytes of standard base64 text; binascii.Error or ValueError on a character outside the alphabet or bad
    padding (pybase64 also refuses '=' after a complete quartet, which binascii's strict mode lets through)."""
    if _fast_b64 is not None:
        return bytes(_fast_b64.b64decode(text, validate=True))
    return binascii.a2b_base64(text.encode("ascii"), strict_mode=True)


def _from_encoded(obj: dict[str, Any], field: str, max_bytes: int) -> NDArray[Any]:
    missing = [k for k in ("dtype", "shape", "data") if k not in obj]
    if missing:
        raise WireError(field, f"encoded array needs keys dtype, shape, data (missing {', '.join(missing)})")
    extra = sorted(set(obj) - {"dtype", "shape", "data"})
    if extra:
        raise WireError(field, f"unexpected keys in encoded array: {', '.join(extra)}")
    dtype, shape, data = obj["dtype"], obj["shape"], obj["data"]
    if not isinstance(dtype, str) or dtype not in WIRE_DTYPES:
        raise WireError(f"{field}.dtype", f"must be one of {', '.join(WIRE_DTYPES)}, got {dtype!r}")
    if (not isinstance(shape, list) or len(shape) > 8
            or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in shape)):
        raise WireError(f"{field}.shape", f"must be a list of non-negative integers, got {shape!r}")
    if not isinstance(data, str):
        raise WireError(f"{field}.data", "must be a base64 string")
    dt = np.dtype(dtype).newbyteorder("<")
    count = math.prod(shape)  # Python ints: a huge shape is refused below, never overflows
    expected = count * dt.itemsize
    if expected > max_bytes:
        raise WireError(field, f"{expected} bytes for shape {shape} exceeds the limit of {max_bytes}")
    try:  # strict: any character outside the base64 alphabet or bad padding is an error
        raw = _b64decode(data)
    except (binascii.Error, ValueError) as exc:
        raise WireError(f"{field}.data", f"invalid base64 ({exc})") from None
    if len(raw) != expected:
        raise WireError(
            f"{field}.data",
            f"{len(raw)} bytes decoded, {expected} expected for shape {shape} {dtype} (truncated?)",
        )
    return np.frombuffer(raw, dtype=dt).reshape(shape).astype(dt.newbyteorder("="), copy=False)


def _from_lists(obj: list[Any], field: str) -> NDArray[Any]:
    try:
        arr = np.array(obj)
    except (ValueError, TypeError) as exc:
        raise WireError(field, f"nested lists must be rectangular ({exc})") from None
    if arr.dtype == np.bool_ or arr.dtype.kind not in "iuf":
        if arr.size == 0:
            return arr.astype(np.float64)
        raise WireError(field, "nested lists must hold only numbers")
    return arr


def decode_array(
    obj: Any,
    field: str = "",
    *,
    shape: ShapeSpec | None = None,
    kind: str = "f",
    dtype: str | None = None,
    finite: bool = False,
    max_bytes: int = 1 << 30,
) -> NDArray[Any]:
    """A numpy array from its wire form (encoded dict or nested lists), checked against a shape spec.

    kind: "f" accepts any number (cast to dtype if given), "i" only integers; finite rejects NaN/inf.
    Raises WireError naming `field` and what was expected.
    """
    if isinstance(obj, np.ndarray):
        arr = obj
    elif isinstance(obj, dict):
        arr = _from_encoded(obj, field, max_bytes)
    elif isinstance(obj, list):
        arr = _from_lists(obj, field)
    else:
        raise WireError(field, "expected an encoded array {dtype, shape, data} or nested lists, "
                               f"got {type(obj).__name__}")
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, arr.shape, strict=False))
        if not ok:
            raise WireError(field, f"shape {_shape_text(shape)} expected, got {_got_text(arr.shape)}")
    if kind == "i":
        if arr.dtype.kind == "f":
            if arr.size and not (np.isfinite(arr).all() and (arr == np.round(arr)).all()):
                raise WireError(field, f"integer values expected, got dtype {arr.dtype.name} with fractions")
        elif arr.dtype.kind not in "iu":
            raise WireError(field, f"integer dtype expected, got {arr.dtype.name}")
    if dtype is not None:
        arr = arr.astype(dtype, copy=False)
    if finite and arr.dtype.kind == "f" and arr.size and not np.isfinite(arr).all():
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise WireError(field, f"{bad} non-finite value(s) (NaN or inf); send finite numbers only")
    return arr
