"""Pictures are refused by their header's size before they are decoded."""

from __future__ import annotations

import resource

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from factory.core.errors import VisionError
from tests.cli.hostile import png_header_only
from vision.imagefile import MAX_PIXELS, decode_grey, image_size


@pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp", ".tiff", ".webp", ".pgm"])
def test_size_from_the_header_of_every_format_calibrate_lists(ext):
    ok, buf = cv2.imencode(ext, np.full((48, 64), 90, np.uint8))
    assert ok
    assert image_size(buf.tobytes(), "x" + ext) == (64, 48)
    assert decode_grey(buf.tobytes(), "x" + ext).shape == (48, 64)


def test_huge_png_is_refused_before_decoding():
    data = png_header_only(20000, 20000)  # a few hundred kB that decode to 400 MB
    assert len(data) < 1_000_000
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(VisionError, match="is larger than 64 megapixels") as e:
        decode_grey(data, "big.png")
    assert e.value.source == "big.png"
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 100_000  # [kB]: nothing decoded


def test_limit_is_the_pixel_count():
    data = png_header_only(300, 200)
    assert decode_grey(data, "a.png", max_pixels=60_000).shape == (200, 300)
    with pytest.raises(VisionError, match="larger than"):
        decode_grey(data, "a.png", max_pixels=59_999)
    assert MAX_PIXELS >= 8192 * 6000
    with pytest.raises(VisionError, match="10000 x 8000 px is larger than 64 megapixels"):
        decode_grey(png_header_only(10000, 8000), "b.png")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cut=st.integers(0, 400), flips=st.lists(st.tuples(st.integers(0, 399), st.integers(0, 255)), max_size=8))
def test_truncated_or_corrupt_pictures_are_one_error(cut, flips):
    ok, buf = cv2.imencode(".png", (np.arange(64 * 48) % 251).astype(np.uint8).reshape(48, 64))
    data = bytearray(buf.tobytes()[:cut])
    for i, b in flips:
        if i < len(data):
            data[i] = b
    try:
        image = decode_grey(bytes(data), "p.png")
    except VisionError as e:
        assert e.source == "p.png" and "\n" not in e.message
    else:
        assert image.ndim == 2 and image.size <= MAX_PIXELS
