"""The .npz format (a zip of .npy members, as numpy's savez and savez_compressed write it), read with every
decompression bounded: a member is read only when it is stored or deflated (bzip2 and LZMA are refused: one read
of theirs may inflate without limit), its npy header is read first and its declared shape checked against what
the member may hold, its zip entry must declare exactly that size, and the data is then read in chunks never past
it; the total across members is capped too.  A small archive cannot make the server inflate gigabytes."""

from __future__ import annotations

import io
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from numpy.typing import NDArray

from graspd.core.cloud import CloudError
from graspd.core.limits import MAX_POINTS, MAX_VIEWPOINTS
from graspd.io.npy import MAX_NPY_HEADER, NpyHeader, check_npy_values, read_npy_data, read_npy_header

ZIP_MAGIC = b"PK\x03\x04"
#: Bytes all members of one .npz may inflate to together: 5M float64 points (120 MB) with float32 normals
#: (60 MB) and int64 camera indices (40 MB) fit.
MAX_NPZ_BYTES = 256 << 20
#: Most entries the zip's central directory may list (numpy writes one per array; a cloud has up to five).
MAX_NPZ_ENTRIES = 1024
_CENTRAL_ENTRY = b"PK\x01\x02"  # every central-directory entry starts so: their count bounds what zipfile parses
_COMPRESSIONS = {zipfile.ZIP_BZIP2: "bzip2", zipfile.ZIP_LZMA: "LZMA"}
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, RuntimeError, NotImplementedError)


@dataclass(frozen=True)
class NpzMember:
    """An array an .npz cloud may hold: how many values it may have at most, and in what shapes (by the size of
    the last dimension and the count of dimensions; None: any)."""

    name: str
    max_values: int
    last: int | None = None
    ndims: tuple[int, ...] = ()
    shape_text: str = ""


#: The arrays an .npz cloud may hold, in the order they are read (others, such as colours, are never read).
NPZ_MEMBERS = (
    NpzMember("points", 3 * MAX_POINTS),
    NpzMember("viewpoints", 3 * MAX_VIEWPOINTS, 3, (1, 2), f"(K, 3): at most {MAX_VIEWPOINTS} camera positions"),
    NpzMember("camera_source", MAX_POINTS),
    NpzMember("normals", 3 * MAX_POINTS),
    NpzMember("camera_poses", 16 * MAX_VIEWPOINTS, 4, (2, 3), f"(K, 4, 4): at most {MAX_VIEWPOINTS} camera poses"),
    NpzMember("shape", 2, 2, (1,), "(2,): an organised cloud's [height, width], points being its pixels row-major"),
)
NPZ_ARRAYS = tuple(m.name for m in NPZ_MEMBERS)


def _check_shape(member: NpzMember, header: NpyHeader, field: str) -> None:
    """The declared shape fits the member: its count of values (and for cameras, their shape), from the header
    alone."""
    if member.last is not None and (len(header.shape) not in member.ndims or header.shape[-1] != member.last
                                    or header.values > member.max_values):
        raise CloudError(field, f"npz: {member.name} declares shape {_shape_text(header)}; {member.shape_text} "
                         "expected")
    check_npy_values(header, member.max_values, field)


def _shape_text(header: NpyHeader) -> str:
    """The declared shape, shortened when it is long."""
    text = str(header.shape)
    return text if len(text) <= 80 else f"of {len(header.shape)} dimensions"


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, member: NpzMember, budget: int, max_bytes: int
                 ) -> NDArray[Any]:
    """One member's array, inflated under budget bytes (what is left of max_bytes): compression and declared
    sizes checked before any data is inflated, the header before the data, the data read in chunks up to its
    declared size."""
    name, field = member.name, f"cloud.{member.name}"
    if info.compress_type in _COMPRESSIONS:
        raise CloudError(field, f"npz: {name} is compressed with {_COMPRESSIONS[info.compress_type]}; only stored "
                         "or deflate members are read (what numpy's savez and savez_compressed write)")
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise CloudError(field, f"npz: {name} uses zip compression method {info.compress_type}; only stored or "
                         "deflate members are read")
    if info.flag_bits & 0x1:
        raise CloudError(field, f"npz: {name} is encrypted")
    cap = member.max_values * 8 + MAX_NPY_HEADER + 12
    if info.file_size > cap:
        what = f" for {member.shape_text}" if member.shape_text else ""
        raise CloudError(field, f"npz: {name} declares {info.file_size} bytes uncompressed, beyond the limit of "
                         f"{cap}{what}")
    if info.file_size > budget:
        raise CloudError(field, f"npz: {name} declares {info.file_size} bytes uncompressed, beyond the limit of "
                         f"{max_bytes} for all arrays together ({budget} left)")
    try:
        with archive.open(info) as stream:
            header = read_npy_header(stream.read, field)
            _check_shape(member, header, field)
            total = header.header_bytes + header.data_bytes
            if info.file_size != total:
                raise CloudError(field, f"npz: {name} is {info.file_size} bytes in the zip directory but its npy "
                                 f"header declares {total}")
            array = read_npy_data(stream.read, header, field)
            if stream.read(1):  # nothing past the declared size (zipfile stops there; a last check)
                raise CloudError(field, f"npz: {name} holds more than its declared {total} bytes")
    except CloudError:
        raise
    except _ZIP_ERRORS as exc:
        why = str(exc) if isinstance(exc, zipfile.BadZipFile | zlib.error) else type(exc).__name__
        raise CloudError(field, f"npz: {name} is corrupt ({why})") from None
    return array


def _archive(data: bytes, field: str) -> zipfile.ZipFile:
    """The zip of data, its central directory bounded (MAX_NPZ_ENTRIES) before zipfile parses it."""
    if data.count(_CENTRAL_ENTRY) > MAX_NPZ_ENTRIES:
        raise CloudError(field, f"npz: the archive lists more than {MAX_NPZ_ENTRIES} entries")
    try:
        return zipfile.ZipFile(io.BytesIO(data))
    except _ZIP_ERRORS:
        raise CloudError(field, "npz: not a zip archive (no readable central directory)") from None


def parse_npz(data: bytes, field: str = "body", max_bytes: int = MAX_NPZ_BYTES) -> dict[str, NDArray[Any]]:
    """The NPZ_ARRAYS an .npz holds, all of them inflating to at most max_bytes together (each member bounded as
    _read_member says); 'points' is required.  CloudError naming the member (cloud.<name>) or field."""
    out: dict[str, NDArray[Any]] = {}
    with _archive(data, field) as archive:
        members = {Path(info.filename).stem: info for info in archive.infolist() if info.filename.endswith(".npy")}
        if "points" not in members:
            raise CloudError("cloud.points", f"npz: needs an array named 'points' (has {sorted(members)[:16]})")
        budget = max_bytes
        for member in NPZ_MEMBERS:
            info = members.get(member.name)
            if info is not None:
                out[member.name] = _read_member(archive, info, member, budget, max_bytes)
                budget -= info.file_size
    return out
