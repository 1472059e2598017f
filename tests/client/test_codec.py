"""The array codec round-trips every wire dtype and names the field when the input is malformed."""

from __future__ import annotations

import base64

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from graspd_client import codec
from graspd_client.codec import WIRE_DTYPES, WireError, decode_array, encode_array


@pytest.mark.parametrize("dtype", WIRE_DTYPES)
def test_round_trip_every_dtype(dtype: str) -> None:
    a = (np.arange(12).reshape(4, 3) % 7).astype(dtype)
    wire = encode_array(a)
    assert wire["dtype"] == dtype and wire["shape"] == [4, 3]
    b = decode_array(wire, "x")
    assert b.dtype == a.dtype and np.array_equal(a, b)


def test_bytes_are_little_endian_c_order() -> None:
    a = np.array([[1.0, 2.0]], dtype=">f4")  # big-endian input
    wire = encode_array(a)
    assert base64.b64decode(wire["data"]) == np.array([1.0, 2.0], "<f4").tobytes()
    f = np.asfortranarray(np.arange(6, dtype=np.int32).reshape(2, 3))
    assert base64.b64decode(encode_array(f)["data"]) == np.arange(6, dtype="<i4").tobytes()


def test_nested_lists_accepted() -> None:
    b = decode_array([[0, 1, 2], [3, 4, 5.5]], "cloud.points", shape=(None, 3))
    assert b.shape == (2, 3) and b[1, 2] == 5.5


@pytest.mark.parametrize(
    ("obj", "kwargs", "message"),
    [
        ({"dtype": "float32", "shape": [10, 2], "data": base64.b64encode(bytes(80)).decode()},
         {"shape": (None, 3)}, "cloud.points: shape (N,3) expected, got (10,2)"),
        ({"dtype": "float32", "shape": [10, 3], "data": base64.b64encode(bytes(100)).decode()},
         {}, "cloud.points.data: 100 bytes decoded, 120 expected"),
        ({"dtype": "float32", "shape": [1, 3], "data": "AAAA*AAA"}, {}, "cloud.points.data: invalid base64"),
        ({"dtype": "complex64", "shape": [1], "data": ""}, {}, "cloud.points.dtype: must be one of"),
        ({"dtype": "float32", "shape": [-1, 3], "data": ""}, {}, "cloud.points.shape"),
        ({"dtype": "float32", "shape": [1, 3]}, {}, "missing data"),
        ([[1, 2, 3], [4, 5]], {}, "rectangular"),
        ([["a", "b", "c"]], {}, "only numbers"),
        ([[np.nan, 0, 0]], {"finite": True}, "non-finite"),
        ([[0.5, 1, 2]], {"kind": "i"}, "integer values expected"),
        ("abc", {}, "got str"),
    ],
)
def test_errors_name_the_field(obj: object, kwargs: dict, message: str) -> None:
    with pytest.raises(WireError) as info:
        decode_array(obj, "cloud.points", **kwargs)
    assert message in str(info.value)
    assert info.value.field.startswith("cloud.points")


def test_size_limit_before_decoding() -> None:
    with pytest.raises(WireError, match="exceeds the limit"):
        decode_array({"dtype": "float64", "shape": [10**9, 3], "data": ""}, "p", max_bytes=1 << 20)
    with pytest.raises(WireError, match="exceeds the limit"):  # beyond int64: refused, no OverflowError
        decode_array({"dtype": "float64", "shape": [10**30, 4], "data": ""}, "hand_pose")


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(st.sampled_from([np.float32, np.float64, np.int32, np.uint8, np.int64]),
                  hnp.array_shapes(min_dims=0, max_dims=3, max_side=5)))
def test_round_trip_property(a: np.ndarray) -> None:
    b = decode_array(encode_array(a))
    assert b.shape == a.shape and b.dtype == a.dtype
    assert np.array_equal(a, b, equal_nan=True)


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=40), st.lists(st.integers(-3, 40), max_size=4), st.sampled_from(WIRE_DTYPES))
def test_garbage_raises_wire_error_only(data: str, shape: list[int], dtype: str) -> None:
    try:
        decode_array({"dtype": dtype, "shape": shape, "data": data}, "f", shape=(None, 3))
    except WireError as exc:
        assert exc.field.startswith("f")


@settings(max_examples=200, deadline=None)
@given(st.one_of(st.binary(max_size=64).map(lambda b: base64.b64encode(b).decode()),
                 st.text(alphabet="AB+/=a\n é*", max_size=16)))
def test_fast_and_standard_base64_agree(text: str) -> None:
    """With pybase64 (the server's) and without it (a robot with numpy + httpx only) the codec accepts the same
    well-formed data with the same bytes, and refuses anything outside the alphabet either way; pybase64 is
    only stricter about '=' after a complete quartet."""

    assert codec._fast_b64 is not None, "pybase64 is a dependency of the server and installed with it"
    obj = {"dtype": "uint8", "shape": [len(base64.b64decode(text)) if _valid(text) else 0], "data": text}
    results = []
    for fast in (codec._fast_b64, None):
        saved, codec._fast_b64 = codec._fast_b64, fast
        try:
            results.append(("ok", decode_array(obj, "x").tobytes()))
        except WireError as exc:
            results.append(("error", exc.field))
        finally:
            codec._fast_b64 = saved
    fast_result, standard = results
    if fast_result[0] == "ok" or standard[0] == "error":
        assert fast_result == standard
    else:
        assert text.rstrip("=") != text and len(text.rstrip("=")) % 4 == 0, text
    assert codec._b64encode(text.encode()) == base64.b64encode(text.encode()).decode()


def _valid(text: str) -> bool:
    try:
        base64.b64decode(text, validate=True)
    except ValueError:
        return False
    return True
