"""Pictures every stage writes (deviation maps, toolpath previews, calibration reports)."""

from __future__ import annotations

import io

import numpy as np


def png_bytes(image: np.ndarray) -> bytes:
    """Encode an ``(H, W, 3)`` uint8 RGB picture as PNG."""
    from PIL import Image  # only the stages that draw pay for the import

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()
