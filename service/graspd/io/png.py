"""PNG in and out for object-proposal crops and request images (Pillow)."""

from __future__ import annotations

import base64
import io

import numpy as np
from numpy.typing import NDArray
from PIL import Image


def encode_png_b64(image: NDArray[np.uint8]) -> str:
    """Base64 text of a PNG of an (H,W,3) uint8 image (fast compression: crops are small)."""

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image), "RGB").save(buf, format="PNG", compress_level=1)
    return base64.b64encode(buf.getvalue()).decode("ascii")


#: Largest request image (pixels): 8 MP, above 4K UHD (3840 x 2160).  Decoding takes ~7 bytes a pixel at
#: its peak (Pillow's 4-byte RGBX buffer, then the 3-byte array), so ~60 MB at the cap.
MAX_IMAGE_PIXELS = 1 << 23
#: Smallest request image side (pixels): a 1-pixel image holds no object to crop.
MIN_IMAGE_SIDE = 2


def png_size(raw: bytes) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR chunk without decoding anything; ValueError if there is none."""
    if len(raw) < 24 or raw[:8] != b"\x89PNG\r\n\x1a\n" or raw[12:16] != b"IHDR":
        raise ValueError("not a PNG (no IHDR chunk after the signature)")
    return int.from_bytes(raw[16:20], "big"), int.from_bytes(raw[20:24], "big")


def check_image_size(width: int, height: int, max_pixels: int = MAX_IMAGE_PIXELS) -> None:
    """ValueError unless both sides are at least MIN_IMAGE_SIDE and the image has at most max_pixels."""
    if width < MIN_IMAGE_SIDE or height < MIN_IMAGE_SIDE:
        raise ValueError(f"image of {width}x{height} pixels is smaller than {MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE}")
    if width * height > max_pixels:
        raise ValueError(f"image of {width}x{height} pixels exceeds the limit of {max_pixels} pixels")


def decode_png_rgb(b64: str, max_pixels: int = MAX_IMAGE_PIXELS) -> NDArray[np.uint8]:
    """(H,W,3) uint8 from base64 PNG text; ValueError says why it cannot be read.  The size declared in the
    IHDR chunk is checked against max_pixels before any pixel is decoded."""

    raw = base64.b64decode(b64)
    width, height = png_size(raw)
    check_image_size(width, height, max_pixels)
    try:
        with Image.open(io.BytesIO(raw), formats=["PNG"]) as img:
            if img.size != (width, height):
                raise ValueError(f"IHDR says {width}x{height}, Pillow reads {img.width}x{img.height}")
            img.load()
            rgb = img if img.mode == "RGB" else img.convert("RGB")
            return np.asarray(rgb, np.uint8)  # read-only view of Pillow's bytes: nothing writes to it
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as exc:
        raise ValueError(f"unreadable PNG ({exc})") from None
