"""Pictures from users' files, refused by their header's size before they are decoded.

A PNG of a few kilobytes can decode to gigabytes (20000 x 20000 pixels of one colour
compress to almost nothing). The size is read from the file's header with Pillow's lazy
``Image.open``, which decodes no pixels, and checked before OpenCV decodes anything.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from factory.core.errors import VisionError

#: Most pixels a picture may have: a 64-megapixel camera, 64 MB as 8-bit grey.
MAX_PIXELS = 64_000_000


def image_size(data: bytes, source: str | Path) -> tuple[int, int]:
    """Width and height [px] from the image file's header, without decoding it.

    Raises
    ------
    VisionError
        Not a picture format Pillow knows (PNG, JPEG, BMP, TIFF, PGM/PPM, WebP, ...).
    """
    try:
        with warnings.catch_warnings():
            # Pillow warns (DecompressionBombWarning) or raises past its own limit; ours decides.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as im:
                return int(im.size[0]), int(im.size[1])
    except Image.DecompressionBombError:
        # Pillow's own refusal (past twice its MAX_IMAGE_PIXELS) comes before it tells the size.
        raise VisionError(f"picture of more than {2 * (Image.MAX_IMAGE_PIXELS or 0) / 1e6:.0f} megapixels is larger "
                          f"than {MAX_PIXELS / 1e6:g} megapixels", source=source) from None
    except Exception:  # Pillow raises many kinds for a file that is not a picture
        raise VisionError("cannot read image: not a picture (PNG, JPEG, BMP, TIFF, PGM, WebP)",
                          source=source) from None


def decode_grey(data: bytes, source: str | Path, max_pixels: int = MAX_PIXELS) -> np.ndarray:
    """An image file's bytes as an 8-bit grey image, refused before decoding when its header
    says it has more than ``max_pixels`` pixels.

    Raises
    ------
    VisionError
        Not a picture, larger than ``max_pixels``, or not decodable (truncated, corrupt).
    """
    w, h = image_size(data, source)
    if w * h > max_pixels:
        raise VisionError(f"picture of {w} x {h} px is larger than {max_pixels / 1e6:g} megapixels",
                          source=source)
    # OpenCV logs its own warning for a truncated file on stderr; the error below says it once.
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    finally:
        cv2.utils.logging.setLogLevel(level)
    if image is None:
        raise VisionError("cannot read image: truncated or corrupt picture", source=source)
    return image
