"""PNG in and out for object-proposal crops and request images (Pillow)."""

from __future__ import annotations

import base64
import io

import numpy as np
from numpy.typing import NDArray


def encode_png_b64(image: NDArray[np.uint8]) -> str:
    """Base64 text of a PNG of an (H,W,3) uint8 image (fast compression: crops are small)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image), "RGB").save(buf, format="PNG", compress_level=1)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def decode_png_rgb(b64: str, max_pixels: int = 50_000_000) -> NDArray[np.uint8]:
    """(H,W,3) uint8 from base64 PNG text; ValueError says why it cannot be read."""
    from PIL import Image

    raw = base64.b64decode(b64)
    try:
        with Image.open(io.BytesIO(raw)) as img:
            if img.width * img.height > max_pixels:
                raise ValueError(f"image of {img.width}x{img.height} pixels exceeds {max_pixels}")
            return np.array(img.convert("RGB"), np.uint8)
    except (OSError, SyntaxError, ValueError) as exc:
        raise ValueError(f"unreadable PNG ({exc})") from None
