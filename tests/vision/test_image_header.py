"""Image headers read without decoding agree with what OpenCV decodes, for every format it writes here."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from jcalib.errors import DetectionError
from jcalib.vision.image import check_image_header, detection_memory_bytes, read_image
from jcalib.vision.image_header import read_image_header

RNG = np.random.default_rng(0)
SHAPES = {"g8": ((37, 53), np.uint8), "c8": ((37, 53, 3), np.uint8), "a8": ((37, 53, 4), np.uint8),
          "g16": ((37, 53), np.uint16), "c16": ((37, 53, 3), np.uint16), "cf": ((37, 53, 3), np.float32),
          "gf": ((37, 53), np.float32)}
FILES = ["g8.png", "c8.png", "a8.png", "g16.png", "c16.png", "g8.jpg", "c8.jpg", "g8.tif", "c16.tif", "cf.tif",
         "g8.bmp", "c8.bmp", "a8.bmp", "c8.webp", "a8.webp", "g8.pgm", "g16.pgm", "c8.ppm", "c8.pam", "cf.pfm",
         "gf.pfm", "cf.hdr", "c8.sr", "c8.jp2", "g16.jp2", "c8.avif", "c8.gif"]


@pytest.mark.parametrize("name", FILES)
def test_header_bounds_the_decoded_array(name, tmp_path):
    shape, dtype = SHAPES[name.split(".")[0]]
    img = RNG.random(shape).astype(dtype) if dtype == np.float32 else RNG.integers(0, np.iinfo(dtype).max, shape, dtype)
    path = tmp_path / name
    if not cv2.imwrite(str(path), img):
        pytest.skip(f"this OpenCV does not write {path.suffix}")
    image, header = read_image(path)
    assert (header.width, header.height) == (image.shape[1], image.shape[0])
    assert header.channels >= (1 if image.ndim == 2 else image.shape[2])
    assert header.bytes_per_sample >= image.itemsize
    assert detection_memory_bytes(header) >= 2 * image.nbytes


def test_unknown_and_damaged_headers_are_refused_by_name(tmp_path):
    (tmp_path / "a.png").write_bytes(b"hello, not an image")
    with pytest.raises(DetectionError, match="not an image format"):
        check_image_header(tmp_path / "a.png")
    assert read_image_header(tmp_path / "a.png") is None
    (tmp_path / "b.png").write_bytes(b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR\0\0")
    with pytest.raises(DetectionError, match="b.png: the image header is damaged"):
        check_image_header(tmp_path / "b.png")


def test_memory_budget_is_configurable(tmp_path, monkeypatch):
    path = tmp_path / "c.hdr"
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4000 +X 4000\n")
    assert read_image_header(path).pixels == 16_000_000
    monkeypatch.setenv("JCALIB_MAX_IMAGE_MB", "100")
    with pytest.raises(DetectionError, match="JCALIB_MAX_IMAGE_MB"):
        check_image_header(path)
