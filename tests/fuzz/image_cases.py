"""Generated and mutated image inputs for ``jcalib detect`` (fixed seeds), shared by
``tests/fuzz/test_image_fuzz.py`` and ``benchmarks/bench_image_fuzz.py``.

Each case writes its files under a folder of its own and returns the CLI arguments and what must hold:
the exit statuses allowed and words the output must contain (the file named, the budget stated, ...).
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

CELL = """schema: jcalib.cell/1
cameras:
  cam0: {model: opencv4}
targets:
  board: {type: checkerboard, cols: 5, rows: 4, square: 0.03}
"""
CELL_INTRINSICS = CELL.replace("{model: opencv4}", "{model: opencv4, intrinsics: {K: [[500, 0, 320], [0, 500, 240], "
                                                   "[0, 0, 1]]}}")
CELL_DICT = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv4"}},
             "targets": {"board": {"type": "checkerboard", "cols": 5, "rows": 4, "square": 0.03}}}
SIZE = (320, 240)


def board(seed: int = 0) -> np.ndarray:
    """A 320x240 grey view of the 5x4-inner-corner board (squares of 30 px, a small seeded shift)."""
    rng = np.random.default_rng(seed)
    img = np.full((SIZE[1], SIZE[0]), 235, np.uint8)
    x0, y0 = 60 + int(rng.integers(0, 20)), 40 + int(rng.integers(0, 20))
    for r in range(5):
        for c in range(6):
            if (r + c) % 2 == 0:
                img[y0 + 30 * r:y0 + 30 * (r + 1), x0 + 30 * c:x0 + 30 * (c + 1)] = 20
    return cv2.GaussianBlur(img, (0, 0), 0.8)


@dataclass
class Case:
    """One input: ``make(folder) -> CLI arguments`` (after ``detect``), the exit statuses allowed, words the
    output must hold, and files that must not exist afterwards."""

    name: str
    kind: str
    make: Callable[[Path], list]
    exits: tuple[int, ...] = (0, 2, 3)
    says: tuple[str, ...] = ()
    env: dict[str, str] = field(default_factory=dict)


def _images(folder: Path, *paths: Path, extra: tuple = ()) -> list:
    (folder / "cell.yaml").write_text(CELL)
    return ["--cell", folder / "cell.yaml", "--camera", "cam0", *paths, "-o", folder / "obs.json", "-j", "1", *extra]


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _encode(ext: str, img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, img)
    assert ok, ext
    return buf.tobytes()


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _png_bomb(w: int, h: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IDAT", zlib.compress(b"\0" * 4096))
            + _png_chunk(b"IEND", b""))


def _tiff_bomb(w: int, h: int) -> bytes:
    entries = [(256, 4, 1, w), (257, 4, 1, h), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 1), (273, 4, 1, 8),
               (277, 3, 1, 1), (278, 4, 1, h), (279, 4, 1, w * h)]
    ifd = struct.pack("<H", len(entries)) + b"".join(
        struct.pack("<HHI", t, typ, n) + (struct.pack("<HH", v, 0) if typ == 3 else struct.pack("<I", v))
        for t, typ, n, v in entries) + struct.pack("<I", 0)
    return b"II*\0" + struct.pack("<I", 8) + ifd + b"\0" * 64


def _bmp_bomb(w: int, h: int) -> bytes:
    return b"BM" + struct.pack("<IHHI", 54 + 64, 0, 0, 54) + struct.pack("<IiiHHIIiiII", 40, w, h, 1, 24, 0, 0, 0, 0,
                                                                         0, 0) + b"\0" * 64


def _jpeg_bomb(w: int, h: int) -> bytes:
    sof = struct.pack(">BHHB", 8, h, w, 3) + b"\x01\x22\x00\x02\x11\x01\x03\x11\x01"
    return b"\xff\xd8" + b"\xff\xc0" + struct.pack(">H", 2 + len(sof)) + sof + b"\xff\xd9"


def _gif_bomb(w: int, h: int) -> bytes:
    return b"GIF89a" + struct.pack("<HHBBB", w, h, 0, 0, 0) + b"," + struct.pack("<HHHHB", 0, 0, w, h, 0) + b"\x02\x02\x4c\x01\x00;"


def _webp_bomb(w: int, h: int) -> bytes:
    vp8x = b"VP8X" + struct.pack("<I", 10) + b"\0\0\0\0" + (w - 1).to_bytes(3, "little") + (h - 1).to_bytes(3, "little")
    return b"RIFF" + struct.pack("<I", 4 + len(vp8x)) + b"WEBP" + vp8x


HEADER_BOMBS = {
    "png": lambda: _png_bomb(100_000, 100_000),
    "tif": lambda: _tiff_bomb(60_000, 60_000),
    "hdr": lambda: b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 20000 +X 20000\n" + b"\x02\x02\x4e\x20" * 16,
    "pfm": lambda: b"PF\n20000 20000\n-1.0\n" + b"\0" * 1024,
    "bmp": lambda: _bmp_bomb(50_000, 50_000),
    "pgm": lambda: b"P5\n# comment\n30000 30000\n255\n" + b"\0" * 1024,
    "jpg": lambda: _jpeg_bomb(65_000, 65_000),
    "gif": lambda: _gif_bomb(65_535, 65_535),
    "webp": lambda: _webp_bomb(16_384, 16_384),
}


def _valid(fmt: str, seed: int) -> bytes:
    img = board(seed)
    if fmt in ("hdr", "pfm", "exr"):
        return _encode("." + fmt, cv2.cvtColor(img, cv2.COLOR_GRAY2BGR).astype(np.float32) / 255.0)
    if fmt == "png16":
        return _encode(".png", img.astype(np.uint16) * 257)
    return _encode("." + fmt, cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if fmt in ("jpg", "webp") else img)


def _session(folder: Path, records: list[dict], settings: dict | None = None) -> Path:
    s = folder / "session"
    (s / "images" / "cam0").mkdir(parents=True, exist_ok=True)
    meta = {"schema": "jcalib.session/1", "cell": CELL_DICT}
    if settings:
        meta["devices"] = {"cameras": {"cam0": {"settings": settings}}}
    (s / "session.json").write_text(json.dumps(meta))
    (s / "stations.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return s


def _pose(x: float) -> list:
    return [[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, 0.5], [0, 0, 0, 1]]


def _station(sid: str, rel: str, x: float = 0.3) -> dict:
    return {"id": sid, "T_base_flange": _pose(x), "images": {"cam0": rel}}


def _session_args(folder: Path, session: Path, extra: tuple = ()) -> list:
    return ["--session", session, "-o", folder / "obs.json", "-j", "1", *extra]


def cases(seed: int = 0) -> list[Case]:
    """Every case, deterministic for a seed."""
    rng = np.random.default_rng(seed)
    out: list[Case] = []
    for fmt in ("png", "jpg", "tif", "bmp", "webp", "pgm", "hdr", "pfm", "png16", "jp2"):
        ext = "png" if fmt == "png16" else fmt
        out.append(Case(f"valid {fmt}", "generated", lambda d, fmt=fmt, ext=ext: _images(
            d, _write(d / f"view.{ext}", _valid(fmt, seed))), (0,)))
        data = _valid(fmt, seed)
        for cut in sorted(rng.uniform(0.0, 0.95, 2)):
            n = int(cut * len(data))
            out.append(Case(f"{fmt} truncated to {n} of {len(data)} B", "truncated",
                            lambda d, data=data, n=n, ext=ext: _images(d, _write(d / f"cut.{ext}", data[:n]))))
        positions = rng.integers(0, min(len(data), 256), 4)
        flipped = bytearray(data)
        for p in positions:
            flipped[p] ^= 0xFF
        out.append(Case(f"{fmt} header bytes {sorted(int(p) for p in positions)} flipped", "mutated",
                        lambda d, b=bytes(flipped), ext=ext: _images(d, _write(d / f"flip.{ext}", b))))
    for ext, make in HEADER_BOMBS.items():
        out.append(Case(f"{ext} header claiming a huge size", "header bomb",
                        lambda d, ext=ext, make=make: _images(d, _write(d / f"bomb.{ext}", make())), (2,),
                        ("bomb", "JCALIB_MAX_IMAGE")))
    out.append(Case("hdr 8000x8000 under the pixel budget, over a 256 MiB memory budget", "memory bomb",
                    lambda d: _images(d, _write(d / "big.hdr", b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8000 +X 8000\n")),
                    (2,), ("MiB", "JCALIB_MAX_IMAGE_MB"), {"JCALIB_MAX_IMAGE_MB": "256"}))
    out.append(Case("random bytes named .png", "generated", lambda d: _images(
        d, _write(d / "noise.png", np.random.default_rng(seed).bytes(2048))), (2,), ("not an image format",)))
    out.append(Case("empty file", "generated", lambda d: _images(d, _write(d / "empty.png", b"")), (2,)))

    def multipage(d: Path) -> list:
        cv2.imwritemulti(str(d / "pages.tif"), [board(seed), board(seed + 1), board(seed + 2)])
        return _images(d, d / "pages.tif")

    def animated(d: Path) -> list:
        from PIL import Image

        frames = [Image.fromarray(board(seed + k)) for k in range(3)]
        frames[0].save(d / "anim.gif", save_all=True, append_images=frames[1:])
        return _images(d, d / "anim.gif")

    def exif(d: Path) -> list:
        from PIL import Image

        ex = Image.Exif()
        ex[274] = 6
        Image.fromarray(board(seed)).save(d / "turned.jpg", exif=ex, quality=95)
        return _images(d, d / "turned.jpg")

    out.append(Case("multi-page TIFF (3 pages)", "multi-page", multipage, (0,), ("3 pages",)))
    out.append(Case("animated GIF (3 frames)", "multi-page", animated, (0,), ("only the first",)))
    out.append(Case("JPEG with EXIF orientation 6", "EXIF", exif, (0,), ("EXIF orientation 6",)))

    def twins(d: Path) -> list:
        data = _valid("png", seed)
        return _images(d, _write(d / "a.png", data), _write(d / "b.png", data))

    def hardlink(d: Path) -> list:
        a = _write(d / "a.png", _valid("png", seed))
        os.link(a, d / "b.png")
        return _images(d, a, d / "b.png")

    def overwrite(d: Path) -> list:
        _write(d / "photo.png", _valid("png", seed + 1))
        return [*_images(d, _write(d / "view.png", _valid("png", seed)))[:-4], "-o", d / "photo.png", "-j", "1"]

    def overwrite_force(d: Path) -> list:
        return [*overwrite(d), "--force"]

    def intrinsics(d: Path) -> list:
        args = _images(d, _write(d / "view.png", _valid("png", seed)))
        (d / "cell.yaml").write_text(CELL_INTRINSICS)
        return args

    out.append(Case("byte-identical images under two names", "duplicate", twins, (0,), ("byte-identical",)))
    out.append(Case("one file under two names (hard link)", "duplicate", hardlink, (2,), ("both name",)))
    out.append(Case("-o names an existing PNG", "overwrite", overwrite, (2,), ("--force",)))
    out.append(Case("-o names an existing PNG, --force", "overwrite", overwrite_force, (0,)))
    out.append(Case("cell intrinsics of a 640x480 camera, 320x240 images", "size", intrinsics, (0,),
                    ("principal point",)))

    def symlink_file(d: Path) -> list:
        outside = _write(d / "outside.png", _valid("png", seed))
        s = _session(d, [_station("s0", "images/cam0/s0.png"), _station("s1", "images/cam0/s1.png", 0.35)])
        _write(s / "images/cam0/s0.png", _valid("png", seed + 1))
        os.symlink(outside, s / "images/cam0/s1.png")
        return _session_args(d, s)

    def symlink_dir(d: Path) -> list:
        elsewhere = d / "elsewhere"
        elsewhere.mkdir()
        _write(elsewhere / "s0.png", _valid("png", seed))
        s = _session(d, [_station("s0", "images/link/s0.png")])
        os.symlink(elsewhere, s / "images/link")
        return _session_args(d, s)

    def symlink_loop(d: Path) -> list:
        s = _session(d, [_station("s0", "images/cam0/s0.png"), _station("s1", "images/cam0/s1.png", 0.35)])
        _write(s / "images/cam0/s0.png", _valid("png", seed))
        os.symlink("s1.png", s / "images/cam0/s1.png")
        return _session_args(d, s)

    def one_file_two_stations(d: Path) -> list:
        s = _session(d, [_station("s0", "images/cam0/s0.png"), _station("s1", "images/cam0/s0.png", 0.4)])
        _write(s / "images/cam0/s0.png", _valid("png", seed))
        return _session_args(d, s)

    def stale_frame(d: Path) -> list:
        s = _session(d, [_station("s0", "images/cam0/s0.png"), _station("s1", "images/cam0/s1.png", 0.4)])
        _write(s / "images/cam0/s0.png", _valid("png", seed))
        _write(s / "images/cam0/s1.png", _valid("png", seed))
        return _session_args(d, s)

    def recorded_size(d: Path) -> list:
        s = _session(d, [_station("s0", "images/cam0/s0.png")], settings={"Width": 640, "Height": 480})
        _write(s / "images/cam0/s0.png", _valid("png", seed))
        return _session_args(d, s)

    def session_overwrite(d: Path) -> list:
        s = _session(d, [_station("s0", "images/cam0/s0.png")])
        _write(s / "images/cam0/s0.png", _valid("png", seed))
        (s / "observations.json").write_text("my notes, not observations\n")
        return ["--session", s, "-j", "1"]

    out.append(Case("session image symlinked to a file outside", "symlink", symlink_file, (0,), ("outside_session",)))
    out.append(Case("session image folder symlinked outside", "symlink", symlink_dir, (2,), ("outside_session",)))
    out.append(Case("session image symlink loop", "symlink", symlink_loop, (0,), ("s1",)))
    out.append(Case("one image file named by two stations", "duplicate", one_file_two_stations, (2,), ("both name",)))
    out.append(Case("byte-identical images at two robot poses (stale frame)", "duplicate", stale_frame, (0,),
                    ("duplicate_image",)))
    out.append(Case("session records Width x Height 640x480, images 320x240", "size", recorded_size, (0,),
                    ("640x480",)))
    out.append(Case("session observations.json is not observations", "overwrite", session_overwrite, (2,),
                    ("--force",)))
    return out


def snapshot(folder: Path, skip: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (symlinks not followed) but ``skip``: path -> bytes."""
    out = {}
    for root, _, files in os.walk(folder):
        for f in files:
            p = Path(root) / f
            if p != skip and not p.is_symlink():
                out[str(p)] = p.read_bytes()
    return out
