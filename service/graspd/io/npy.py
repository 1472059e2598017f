"""The .npy format (numpy's one-array file), read by hand so that every refusal names the field in plain words:
the header (magic, version 1.0/2.0/3.0, a dict literal of descr, fortran_order and shape) is parsed and checked
before any data is read, and the data is then read in chunks from any stream (bytes, a zip member), never more
than the header declares.  numpy's own reader would raise texts holding Python object reprs on a garbage header."""

from __future__ import annotations

import ast
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudError

NPY_MAGIC = b"\x93NUMPY"
#: Longest header read (bytes): numpy's own default limit; the headers it writes are 128 bytes or a little more.
MAX_NPY_HEADER = 10_000
#: Most dimensions a header may declare (numpy's own limit is 64; a cloud has 2 or 3).
MAX_NPY_DIMS = 32
#: Bytes read from a stream at a time while the data is copied into the array.
READ_CHUNK = 1 << 20
_VERSIONS = {(1, 0): (2, "latin1"), (2, 0): (4, "latin1"), (3, 0): (4, "utf8")}  # header-length bytes, encoding

#: Reads up to n bytes (fewer only at the end): BytesIO.read, a zip member's read.
Read = Callable[[int], bytes]


@dataclass(frozen=True)
class NpyHeader:
    """A checked .npy header: the array's shape, its dtype (numbers only), its order, and the bytes the header
    and the data take."""

    shape: tuple[int, ...]
    dtype: np.dtype[Any]
    fortran_order: bool
    header_bytes: int

    @property
    def values(self) -> int:
        """How many numbers the array holds."""
        return math.prod(self.shape)

    @property
    def data_bytes(self) -> int:
        """Bytes of data that follow the header."""
        return self.values * self.dtype.itemsize


def _read_exact(read: Read, n: int, field: str, what: str) -> bytes:
    """Exactly n bytes from read (n is small: header parts); CloudError naming field when the stream ends."""
    out = read(n)
    while len(out) < n:
        more = read(n - len(out))
        if not more:
            raise CloudError(field, f"npy: the file ends inside its {what}")
        out += more
    return out


def _literal(text: str, field: str) -> dict[Any, Any]:
    """The header's dict literal; CloudError in plain words when it is not one (ast's own messages name node
    objects)."""
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
        value = None
    if not isinstance(value, dict):
        raise CloudError(field, "npy: unreadable header: a dictionary of 'descr', 'fortran_order' and 'shape' "
                         "(as numpy writes it) expected")
    return value


def _dtype(descr: object, field: str) -> np.dtype[Any]:
    """The dtype of a header's descr: a plain number type of at most 8 bytes (no objects, records, strings)."""
    if not isinstance(descr, str):
        raise CloudError(field, "npy: numbers expected (float or integer); the header describes a record type")
    try:
        dtype = np.dtype(descr)
    except (TypeError, ValueError, SyntaxError):
        raise CloudError(field, f"npy: the header's type {descr[:40]!r} is not a numpy type") from None
    if dtype.hasobject or dtype.kind not in "fiu" or dtype.fields is not None or dtype.itemsize > 8:
        raise CloudError(field, f"npy: numbers expected (float or integer of at most 8 bytes), got dtype {dtype}")
    return dtype


def read_npy_header(read: Read, field: str = "body") -> NpyHeader:
    """The header of an .npy stream, checked before any data is read: a version numpy writes, a header of at
    most MAX_NPY_HEADER bytes, numbers only, a shape of non-negative integers.  CloudError naming field, in plain
    words, otherwise.  The caller bounds the shape (it knows what the array is for)."""
    magic = _read_exact(read, 8, field, "signature")
    if magic[:6] != NPY_MAGIC:
        raise CloudError(field, "npy: not an .npy file (it does not start with \\x93NUMPY)")
    version = (magic[6], magic[7])
    if version not in _VERSIONS:
        raise CloudError(field, f"npy: format version {version[0]}.{version[1]} is not one numpy writes "
                         "(1.0, 2.0 or 3.0)")
    width, encoding = _VERSIONS[version]
    length = int.from_bytes(_read_exact(read, width, field, "header length"), "little")
    if length > MAX_NPY_HEADER:
        raise CloudError(field, f"npy: a header of {length} bytes exceeds the limit of {MAX_NPY_HEADER}")
    raw = _read_exact(read, length, field, "header")
    try:
        text = raw.decode(encoding)
    except UnicodeDecodeError:
        raise CloudError(field, f"npy: the header is not {encoding} text") from None
    header = _literal(text, field)
    if set(header) != {"descr", "fortran_order", "shape"}:
        raise CloudError(field, "npy: the header must hold exactly the keys 'descr', 'fortran_order' and 'shape'")
    shape, order = header["shape"], header["fortran_order"]
    if (not isinstance(shape, tuple) or len(shape) > MAX_NPY_DIMS
            or not all(type(d) is int and d >= 0 for d in shape)):
        raise CloudError(field, f"npy: the header's shape must be a tuple of at most {MAX_NPY_DIMS} non-negative "
                         "integers")
    if not isinstance(order, bool):
        raise CloudError(field, "npy: the header's fortran_order must be True or False")
    return NpyHeader(shape, _dtype(header["descr"], field), order, 8 + width + length)


def check_npy_values(header: NpyHeader, limit: int, field: str = "body") -> None:
    """CloudError naming field when the declared array holds more than limit numbers (decided from the header:
    nothing is allocated)."""
    if header.values > limit:
        shape = header.shape if len(str(header.shape)) <= 80 else f"of {len(header.shape)} dimensions"
        raise CloudError(field, f"npy: shape {shape} exceeds the limit of {limit} values")


def read_npy_data(read: Read, header: NpyHeader, field: str = "body") -> NDArray[Any]:
    """The array the header declares, its data read in chunks of at most READ_CHUNK bytes and never beyond
    header.data_bytes (the caller has bounded them); CloudError naming field when the data ends early."""
    out = np.empty(header.values, header.dtype)
    buf = out.view(np.uint8)
    need, pos = header.data_bytes, 0
    while pos < need:
        chunk = read(min(READ_CHUNK, need - pos))
        if not chunk:
            raise CloudError(field, f"npy: header declares {header.shape} {header.dtype} ({need} bytes); the data "
                             f"ends after {pos}")
        buf[pos:pos + len(chunk)] = np.frombuffer(chunk, np.uint8)
        pos += len(chunk)
    if header.fortran_order:
        return out.reshape(header.shape[::-1]).transpose()
    return out.reshape(header.shape)


def parse_npy_bytes(data: bytes, limit: int, field: str = "body") -> NDArray[Any]:
    """The array of whole .npy bytes: the header checked (read_npy_header, at most limit values), then the data
    length must be exactly what it declares, then the array is a view of the data (no copy)."""
    pos = 0

    def read(n: int) -> bytes:
        nonlocal pos
        chunk = data[pos:pos + n]
        pos += len(chunk)
        return chunk

    header = read_npy_header(read, field)
    check_npy_values(header, limit, field)
    held = len(data) - header.header_bytes
    if held != header.data_bytes:
        raise CloudError(field, f"npy: header declares {header.shape} {header.dtype} ({header.data_bytes} bytes); "
                         f"the file holds {held}")
    # the data read in place, not copied: a 60 MB upload of 5M points is not held twice (read-only: nothing
    # downstream writes into a request's points)
    out = np.frombuffer(data, header.dtype, count=header.values, offset=header.header_bytes)
    if header.fortran_order:
        return out.reshape(header.shape[::-1]).transpose()
    return out.reshape(header.shape)
