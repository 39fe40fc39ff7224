"""Image file headers read without decoding: size, channels, sample depth, pages and EXIF orientation.

Every format OpenCV's ``imread`` decodes in jcalib's build is parsed here, by its own small reader (no
decoder runs, and nothing the header claims is allocated): PNG (and APNG), JPEG, TIFF and BigTIFF, BMP,
WebP, GIF, JPEG 2000 (JP2 and J2K), AVIF, PBM/PGM/PPM, PAM, PFM, Radiance HDR, Sun raster and OpenEXR.
A file whose first bytes match none of them is not an image OpenCV reads; a header that is cut short or
contradicts itself is damaged. :func:`jcalib.vision.image.load_image` checks the decode budget from
this header before decoding.

``channels`` and ``bytes_per_sample`` describe the array ``cv2.imread(..., IMREAD_UNCHANGED)`` returns,
or bound it from above where the header leaves it open (a palette expands to three or four channels).
"""

from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass
from typing import BinaryIO

from jcalib.errors import DetectionError

__all__ = ["FORMATS", "ImageHeader", "read_image_header"]

#: The formats :func:`read_image_header` knows (every one OpenCV's ``imread`` decodes here).
FORMATS = ("PNG", "JPEG", "TIFF", "BMP", "WebP", "GIF", "JPEG 2000", "AVIF", "PBM/PGM/PPM", "PAM", "PFM",
           "Radiance HDR", "Sun raster", "OpenEXR")
#: The most header bytes read from a text header (PxM, PAM, PFM, HDR) or an EXR attribute list.
TEXT_HEADER_BYTES = 65536
#: The most chunks, segments, boxes, IFDs or GIF blocks walked (a looping or endless header is damaged).
MAX_STEPS = 100_000


@dataclass(frozen=True)
class ImageHeader:
    """What an image file's header says.

    Attributes:
        format: one of :data:`FORMATS`.
        width, height: px.
        channels: channels of the decoded array (an upper bound where the header leaves it open).
        bytes_per_sample: 1 (8-bit), 2 (16-bit) or 4 (float / 32-bit).
        pages: pages (TIFF), frames (GIF, APNG, animated WebP, AVIF sequence); ``None``: several, not
            counted. OpenCV's ``imread`` reads the first.
        orientation: the EXIF orientation tag (1: pixels as stored; 2-8: a viewer flips or turns them).
    """

    format: str
    width: int
    height: int
    channels: int
    bytes_per_sample: int
    pages: int | None = 1
    orientation: int = 1

    @property
    def pixels(self) -> int:
        return self.width * self.height

    @property
    def decoded_bytes(self) -> int:
        """Bytes of the array the decoder returns."""
        return self.pixels * self.channels * self.bytes_per_sample


class _Damaged(Exception):
    pass


def _read(f: BinaryIO, offset: int, n: int) -> bytes:
    f.seek(offset)
    b = f.read(n)
    if len(b) < n:
        raise _Damaged(f"cut short at byte {offset + len(b)}")
    return b


def _unpack(fmt: str, f: BinaryIO, offset: int) -> tuple:
    return struct.unpack(fmt, _read(f, offset, struct.calcsize(fmt)))


def read_image_header(path: str | os.PathLike) -> ImageHeader | None:
    """The header of an image file, or None when its first bytes match no format OpenCV reads.

    Raises:
        DetectionError: reason ``"unreadable"``: the file cannot be opened, or its header is damaged
            (cut short, looping, or a size of zero).
        """
    name = os.fspath(path)
    try:
        with open(name, "rb") as f:
            head = f.read(64)
            parse = _sniff(head)
            if parse is None:
                return None
            header = parse(f, head)
    except _Damaged as e:
        raise DetectionError(f"{name}: the image header is damaged ({e})", "unreadable") from None
    except (struct.error, ValueError, IndexError, OverflowError) as e:
        raise DetectionError(f"{name}: the image header is damaged ({e})", "unreadable") from None
    except OSError as e:
        raise DetectionError(f"{name}: cannot read the file ({e.strerror or e})", "unreadable") from None
    if header.width <= 0 or header.height <= 0 or header.channels <= 0:
        raise DetectionError(f"{name}: the {header.format} header gives a size of {header.width}x{header.height} px "
                             f"with {header.channels} channels", "unreadable")
    return header


def _sniff(head: bytes):
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return _png
    if head.startswith(b"\xff\xd8\xff"):
        return _jpeg
    if head[:4] in (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+"):
        return _tiff_file
    if head.startswith(b"BM"):
        return _bmp
    if head.startswith(b"RIFF") and head[8:12] == b"WEBP":
        return _webp
    if head[:6] in (b"GIF87a", b"GIF89a"):
        return _gif
    if head.startswith((b"\x00\x00\x00\x0cjP  \r\n\x87\n", b"\xff\x4f\xff\x51")):
        return _jp2
    if head[4:8] == b"ftyp" and (b"avif" in head[8:64] or b"avis" in head[8:64]):
        return _avif
    if re.match(rb"P[1-6][\s#]", head):
        return _pxm
    if re.match(rb"P7\s", head):
        return _pam
    if re.match(rb"P[Ff]\s", head):
        return _pfm
    if head.startswith((b"#?RADIANCE", b"#?RGBE")):
        return _hdr
    if head.startswith(b"\x59\xa6\x6a\x95"):
        return _sun
    if head.startswith(b"\x76\x2f\x31\x01"):
        return _exr
    return None


# --- PNG ---------------------------------------------------------------------------------------------

def _png(f: BinaryIO, head: bytes) -> ImageHeader:
    off, ihdr, frames, orientation, alpha = 8, None, 1, 1, False
    for _ in range(MAX_STEPS):
        length, kind = _unpack(">I4s", f, off)
        if kind == b"IHDR":
            ihdr = _unpack(">IIBB", f, off + 8)
        elif kind == b"acTL":
            frames = max(1, _unpack(">I", f, off + 8)[0])
        elif kind == b"tRNS":
            alpha = True
        elif kind == b"eXIf":
            orientation = _exif_orientation(f, off + 8)
        elif kind in (b"IDAT", b"IEND"):
            break
        if ihdr is None:
            raise _Damaged("no IHDR chunk first")
        off += 12 + length
    else:
        raise _Damaged("too many chunks before the pixels")
    w, h, depth, colour = ihdr
    channels = {0: 1, 2: 3, 3: 3, 4: 4, 6: 4}.get(colour)
    if channels is None:
        raise _Damaged(f"PNG colour type {colour}")
    return ImageHeader("PNG", w, h, 4 if alpha and channels == 3 else channels, 2 if depth == 16 else 1,
                       frames, orientation)


# --- JPEG --------------------------------------------------------------------------------------------

_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _jpeg(f: BinaryIO, head: bytes) -> ImageHeader:
    off, orientation = 2, 1
    for _ in range(MAX_STEPS):
        b = _read(f, off, 2)
        if b[0] != 0xFF:
            raise _Damaged(f"no marker at byte {off}")
        marker = b[1]
        if marker == 0xFF:  # fill byte
            off += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):
            off += 2
            continue
        if marker in (0xD9, 0xDA):
            raise _Damaged("no frame header (SOF) before the scan")
        (length,) = _unpack(">H", f, off + 2)
        if length < 2:
            raise _Damaged(f"segment length {length}")
        if marker in _SOF:
            precision, h, w, components = _unpack(">BHHB", f, off + 4)
            channels = 1 if components == 1 else (3 if components == 3 else max(components, 3))
            return ImageHeader("JPEG", w, h, channels, 2 if precision > 8 else 1, 1, orientation)
        if marker == 0xE1 and length >= 16 and _read(f, off + 4, 6) == b"Exif\0\0":
            orientation = _exif_orientation(f, off + 10)
        off += 2 + length
    raise _Damaged("too many segments")


# --- TIFF (and the EXIF blocks of JPEG, PNG and WebP) ------------------------------------------------

_TYPE_SIZES = {1: 1, 3: 2, 4: 4, 6: 1, 8: 2, 9: 4, 16: 8, 17: 8, 18: 8}
_TYPE_CODES = {1: "B", 3: "H", 4: "I", 6: "b", 8: "h", 9: "i", 16: "Q", 17: "q", 18: "Q"}


def _tiff(f: BinaryIO, base: int, count_pages: bool = True) -> tuple[dict[int, list[int]], int]:
    """The first IFD's integer tags (tag -> values) and the number of IFDs, of a TIFF structure at ``base``."""
    order = _read(f, base, 2)
    if order not in (b"II", b"MM"):
        raise _Damaged("no TIFF byte order mark")
    e = "<" if order == b"II" else ">"
    (magic,) = _unpack(e + "H", f, base + 2)
    big = magic == 43
    if magic not in (42, 43):
        raise _Damaged(f"TIFF version {magic}")
    off = _unpack(e + "Q", f, base + 8)[0] if big else _unpack(e + "I", f, base + 4)[0]
    count_fmt, entry, word = (e + "Q", 20, "Q") if big else (e + "H", 12, "I")
    tags: dict[int, list[int]] = {}
    pages, seen = 0, set()
    while off and pages < MAX_STEPS:
        if off in seen:
            raise _Damaged("the IFD chain loops")
        seen.add(off)
        (n,) = _unpack(count_fmt, f, base + off)
        if n > 65535:
            raise _Damaged(f"an IFD of {n} entries")
        start = base + off + (8 if big else 2)
        if pages == 0:
            for i in range(n):
                tag, typ = _unpack(e + "HH", f, start + i * entry)
                (count,) = _unpack(e + word, f, start + i * entry + 4)
                if typ not in _TYPE_SIZES or count == 0 or count > 16:
                    continue
                size = _TYPE_SIZES[typ] * count
                at = start + i * entry + (12 if big else 8)
                if size > (8 if big else 4):
                    at = base + _unpack(e + word, f, at)[0]
                tags[tag] = list(struct.unpack(e + _TYPE_CODES[typ] * count, _read(f, at, size)))
            if not count_pages:
                break
        pages += 1
        (off,) = _unpack(e + word, f, start + n * entry)
    return tags, pages


def _exif_orientation(f: BinaryIO, base: int) -> int:
    """The orientation tag (274) of an EXIF block (a TIFF structure at ``base``); 1 when it has none."""
    if _read(f, base, 6) == b"Exif\0\0":
        base += 6
    tags, _ = _tiff(f, base, count_pages=False)
    return int(tags.get(274, [1])[0])


def _tiff_file(f: BinaryIO, head: bytes) -> ImageHeader:
    tags, pages = _tiff(f, 0)
    if 256 not in tags or 257 not in tags:
        raise _Damaged("no ImageWidth / ImageLength in the first IFD")
    bits = max(tags.get(258, [1]))
    spp = tags.get(277, [1])[0]
    channels = 3 if tags.get(262, [1])[0] == 3 else spp  # a palette decodes to BGR
    return ImageHeader("TIFF", tags[256][0], tags[257][0], channels, max(1, -(-bits // 8)), pages,
                       int(tags.get(274, [1])[0]))


# --- BMP, Sun raster, GIF, WebP ----------------------------------------------------------------------

def _bmp(f: BinaryIO, head: bytes) -> ImageHeader:
    (size,) = _unpack("<I", f, 14)
    if size == 12:
        w, h, _, bpp = _unpack("<HHHH", f, 18)
    else:
        w, h, _, bpp = _unpack("<iiHH", f, 18)
    return ImageHeader("BMP", w, abs(h), 4 if bpp == 32 else 3, 1)


def _sun(f: BinaryIO, head: bytes) -> ImageHeader:
    w, h, depth = _unpack(">iii", f, 4)
    return ImageHeader("Sun raster", w, h, 4 if depth == 32 else 3, 1)


def _gif(f: BinaryIO, head: bytes) -> ImageHeader:
    w, h, flags = _unpack("<HHB", f, 6)
    off = 13 + (3 << ((flags & 7) + 1) if flags & 0x80 else 0)
    frames = 0

    def skip_sub_blocks(at: int) -> int:
        for _ in range(1 << 24):
            (n,) = _unpack("B", f, at)
            if n == 0:
                return at + 1
            at += 1 + n
        raise _Damaged("endless data sub-blocks")

    for _ in range(MAX_STEPS):
        f.seek(off)
        b = f.read(1)
        if not b or b == b";":  # trailer, or a file cut after a frame (decoders stop there too)
            break
        if b == b"!":
            off = skip_sub_blocks(off + 2)
        elif b == b",":
            (lflags,) = _unpack("B", f, off + 9)
            off += 10 + (3 << ((lflags & 7) + 1) if lflags & 0x80 else 0)
            off = skip_sub_blocks(off + 1)
            frames += 1
        else:
            break
    return ImageHeader("GIF", w, h, 4, 1, max(frames, 1))


def _webp(f: BinaryIO, head: bytes) -> ImageHeader:
    (riff_size,) = _unpack("<I", f, 4)
    end, off = 8 + riff_size, 12
    size, frames, orientation = None, 0, 1
    for _ in range(MAX_STEPS):
        if off + 8 > end:
            break
        try:
            kind, length = _unpack("<4sI", f, off)
        except _Damaged:
            break
        data = off + 8
        if kind == b"VP8X":
            b = _read(f, data + 4, 6)
            size = (1 + int.from_bytes(b[:3], "little"), 1 + int.from_bytes(b[3:], "little"))
        elif kind == b"VP8 " and size is None:
            if _read(f, data + 3, 3) != b"\x9d\x01\x2a":
                raise _Damaged("no VP8 start code")
            w, h = _unpack("<HH", f, data + 6)
            size = (w & 0x3FFF, h & 0x3FFF)
        elif kind == b"VP8L" and size is None:
            sig, bits = _unpack("<BI", f, data)
            if sig != 0x2F:
                raise _Damaged("no VP8L signature")
            size = ((bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1)
        elif kind == b"ANMF":
            frames += 1
        elif kind == b"EXIF":
            orientation = _exif_orientation(f, data)
        off = data + length + (length & 1)
    if size is None:
        raise _Damaged("no VP8, VP8L or VP8X chunk")
    return ImageHeader("WebP", size[0], size[1], 4, 1, max(frames, 1), orientation)


# --- ISO boxes: JPEG 2000, AVIF ----------------------------------------------------------------------

def _boxes(f: BinaryIO, start: int, end: int | None):
    """(type, payload start, payload end) of the boxes between ``start`` and ``end`` (None: the file end)."""
    off = start
    for _ in range(MAX_STEPS):
        if end is not None and off + 8 > end:
            return
        f.seek(off)
        b = f.read(8)
        if len(b) < 8:
            return
        size, kind = struct.unpack(">I4s", b)
        data = off + 8
        if size == 1:
            (size,) = _unpack(">Q", f, data)
            data += 8
        elif size == 0:
            size = (end if end is not None else f.seek(0, 2)) - off
        if size < data - off:
            raise _Damaged(f"a {kind!r} box of {size} bytes")
        yield kind, data, off + size
        off += size
    raise _Damaged("too many boxes")


def _jp2(f: BinaryIO, head: bytes) -> ImageHeader:
    if head.startswith(b"\xff\x4f\xff\x51"):
        return _j2k_siz(f, 4)
    for kind, data, end in _boxes(f, 0, None):
        if kind == b"jp2h":
            for sub, sdata, _ in _boxes(f, data, end):
                if sub == b"ihdr":
                    h, w, nc, bpc = _unpack(">IIHB", f, sdata)
                    return ImageHeader("JPEG 2000", w, h, nc, 2 if (bpc & 0x7F) + 1 > 8 else 1)
        if kind == b"jp2c":
            return _j2k_siz(f, data + 4)
    raise _Damaged("no ihdr box")


def _j2k_siz(f: BinaryIO, siz: int) -> ImageHeader:
    _, _, xs, ys, xo, yo, _, _, _, _, comps = _unpack(">HHIIIIIIIIH", f, siz)
    bits = max((b & 0x7F) + 1 for b in _read(f, siz + 38, 3 * comps)[::3]) if comps else 8
    return ImageHeader("JPEG 2000", xs - xo, ys - yo, comps, 2 if bits > 8 else 1)


def _avif(f: BinaryIO, head: bytes) -> ImageHeader:
    sizes, bits, sequence = [], [], False
    containers = {b"meta": 4, b"iprp": 0, b"ipco": 0}

    def walk(start: int, end: int | None, depth: int) -> None:
        nonlocal sequence
        for kind, data, stop in _boxes(f, start, end):
            if kind == b"ftyp":
                sequence = b"avis" in _read(f, data, min(stop - data, 64))
            elif kind in containers and depth < 4:
                walk(data + containers[kind], stop, depth + 1)
            elif kind == b"ispe":
                sizes.append(_unpack(">II", f, data + 4))
            elif kind == b"pixi":
                (n,) = _unpack("B", f, data + 4)
                bits.extend(_read(f, data + 5, n))
            if kind == b"mdat":
                return

    walk(0, None, 0)
    if not sizes:
        raise _Damaged("no ispe (image size) property")
    w, h = max(sizes, key=lambda s: s[0] * s[1])
    return ImageHeader("AVIF", w, h, 4, 1 if bits and max(bits) <= 8 else 2, None if sequence else 1)


# --- text headers: PxM, PAM, PFM, Radiance HDR; OpenEXR ----------------------------------------------

def _tokens(f: BinaryIO, n: int) -> list[bytes]:
    """The first ``n`` whitespace-separated tokens after the two magic bytes (comments skipped)."""
    text = re.sub(rb"#[^\n\r]*", b" ", _text(f))
    tokens = text[2:].split(None, n)[:n]
    if len(tokens) < n:
        raise _Damaged("the header ends early")
    return tokens


def _text(f: BinaryIO) -> bytes:
    f.seek(0)
    return f.read(TEXT_HEADER_BYTES)


def _pxm(f: BinaryIO, head: bytes) -> ImageHeader:
    kind = head[1:2]
    bitmap = kind in (b"1", b"4")
    t = [int(x) for x in _tokens(f, 2 if bitmap else 3)]
    maxval = 1 if bitmap else t[2]
    if not 0 < maxval < 65536:
        raise _Damaged(f"maximum value {maxval}")
    return ImageHeader("PBM/PGM/PPM", t[0], t[1], 3 if kind in (b"3", b"6") else 1, 2 if maxval > 255 else 1)


def _pam(f: BinaryIO, head: bytes) -> ImageHeader:
    text = _text(f)
    end = text.find(b"ENDHDR")
    if end < 0:
        raise _Damaged("no ENDHDR")
    fields = dict(re.findall(rb"^\s*(WIDTH|HEIGHT|DEPTH|MAXVAL)\s+(\d+)", text[:end], re.MULTILINE))
    if not {b"WIDTH", b"HEIGHT", b"DEPTH", b"MAXVAL"} <= fields.keys():
        raise _Damaged("WIDTH, HEIGHT, DEPTH or MAXVAL missing")
    maxval = int(fields[b"MAXVAL"])
    return ImageHeader("PAM", int(fields[b"WIDTH"]), int(fields[b"HEIGHT"]), int(fields[b"DEPTH"]),
                       2 if maxval > 255 else 1)


def _pfm(f: BinaryIO, head: bytes) -> ImageHeader:
    t = _tokens(f, 3)
    float(t[2])  # the scale (its sign: the byte order)
    return ImageHeader("PFM", int(t[0]), int(t[1]), 3 if head[1:2] == b"F" else 1, 4)


def _hdr(f: BinaryIO, head: bytes) -> ImageHeader:
    text = _text(f)
    blank = re.search(rb"\r?\n\r?\n", text)
    if blank is None:
        raise _Damaged("no end of the header lines")
    m = re.match(rb"\s*([-+])([XY])\s+(\d+)\s+([-+])([XY])\s+(\d+)", text[blank.end():])
    if m is None or m.group(2) == m.group(5):
        raise _Damaged("no resolution line such as '-Y 480 +X 640'")
    n = {m.group(2): int(m.group(3)), m.group(5): int(m.group(6))}
    return ImageHeader("Radiance HDR", n[b"X"], n[b"Y"], 3, 4)


def _exr(f: BinaryIO, head: bytes) -> ImageHeader:
    text = _text(f)
    off, window, channels = 8, None, 0
    for _ in range(MAX_STEPS):
        end = text.index(b"\0", off)
        if end == off:
            break
        tend = text.index(b"\0", end + 1)
        name, kind = text[off:end], text[end + 1:tend]
        (size,) = struct.unpack_from("<i", text, tend + 1)
        value = tend + 5
        if size < 0 or value + size > len(text):
            raise _Damaged(f"attribute {name!r} of {size} bytes")
        if name == b"dataWindow" and kind == b"box2i":
            window = struct.unpack_from("<iiii", text, value)
        elif name == b"channels" and kind == b"chlist":
            at = value
            while at < value + size - 1 and text[at] != 0 and channels < MAX_STEPS:  # name, 16 bytes, ...
                at = text.index(b"\0", at) + 17
                channels += 1
        off = value + size
    if window is None:
        raise _Damaged("no dataWindow")
    x0, y0, x1, y1 = window
    return ImageHeader("OpenEXR", x1 - x0 + 1, y1 - y0 + 1, max(1, min(channels, 4)), 4)
