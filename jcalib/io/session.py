"""Capture sessions on disk (``jcalib.session/1``): written as data arrives, never rewritten.

```
session/
  session.json          schema, cell spec, jcalib version, creation time, devices and settings, plan
  stations.jsonl        one line per finished station, appended and fsync'ed
  images/<camera>/<station>.png   written to a temporary name, fsync'ed, renamed
```

A station line is appended only after all its images are on disk, so a process killed at any instant
leaves a session whose listed stations are complete; resuming skips them and repeats at most the
station that was in flight. Resuming also removes temporary files of interrupted image writes and
cuts a torn last line (a write the kernel did not finish; possible only on power loss).
An advisory lock (``.lock``, ``flock``) stops two captures from writing one session at once; the
kernel releases it when the process dies, even by ``kill -9``.

A station whose images went missing after it was listed is captured again by a resumed capture and
appended once more with ``"retake": true``; readers keep the last record of each station, in the
order the stations were first listed (the file itself is never rewritten).
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

import jcalib
from jcalib.errors import BadInputError, DeviceError
from jcalib.io.atomic import append_line_durable, write_bytes_atomic, write_json_atomic
from jcalib.io.schema.reading import decode_utf8, parse_json, read_bytes_limited, read_document
from jcalib.io.schema.session import validate_session_meta, validate_station_record

SCHEMA = "jcalib.session/1"


def utc_now() -> str:
    """Current UTC time as ``2026-11-21T10:00:00.123Z``."""
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def encode_png(image: np.ndarray) -> bytes:
    """(H, W) uint8/uint16 or (H, W, 3) RGB uint8 -> PNG bytes (lossless)."""
    import cv2

    img = np.asarray(image)
    if img.dtype not in (np.uint8, np.uint16):
        raise BadInputError(f"image: expected uint8 or uint16 pixels, got {img.dtype}")
    if img.ndim == 3:
        img = img[:, :, ::-1]  # RGB -> BGR for OpenCV
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise BadInputError(f"image: PNG encoding failed for shape {img.shape}")
    return buf.tobytes()


def read_stations(directory: str | Path) -> list[dict]:
    """The station records of a session, in order (a torn last line is ignored; a ``"retake": true``
    record replaces the earlier record of its station, at that station's place).

    Raises:
        BadInputError: not a session, a corrupt line other than the last, or a station id repeated
            without ``"retake": true``.
    """
    path = Path(directory) / "stations.jsonl"
    if not (Path(directory) / "session.json").is_file():
        raise BadInputError(f"session: {directory} has no session.json; not a jcalib session")
    if not path.exists():
        return []
    raw = read_bytes_limited(path, "session stations file")
    lines = raw.split(b"\n")
    complete, tail = lines[:-1], lines[-1]  # tail is b"" when the file ends with a newline
    out, seen = [], {}
    for n, line in enumerate(complete, start=1):
        where = f"session: {path} line {n}"
        rec = parse_json(decode_utf8(line, where), where)
        if not isinstance(rec, dict) or "id" not in rec:
            raise BadInputError(f"session: {path} line {n} is not a station record (no 'id')")
        validate_station_record(rec, where)  # types, poses within reach, image paths inside the session
        if rec["id"] in seen:
            if rec.get("retake") is not True:
                raise BadInputError(f"session: {path} line {n} repeats station {rec['id']!r}")
            out[seen[rec["id"]]] = rec
            continue
        seen[rec["id"]] = len(out)
        out.append(rec)
    del tail  # an unterminated last line is a torn write: not a finished station
    return out


def read_session(directory: str | Path) -> tuple[dict, list[dict]]:
    """``(session.json contents, station records)`` of a session directory."""
    d = Path(directory)
    meta = read_document(d / "session.json", "session: session file", fmt="json")
    if not isinstance(meta, dict) or meta.get("schema") != SCHEMA:
        got = meta.get("schema") if isinstance(meta, dict) else type(meta).__name__
        raise BadInputError(f"session: {d / 'session.json'} has schema {got!r}, expected {SCHEMA!r}")
    validate_session_meta(meta, str(d / "session.json"))
    return meta, read_stations(d)


class SessionWriter:
    """Appends stations and images to a session directory. Create with :meth:`create` or :meth:`open`."""

    def __init__(self, directory: Path, meta: dict, stations: list[dict], lock_fd: int):
        self.directory = directory
        self.meta = meta
        self.stations = {r["id"]: r for r in stations}
        self._lock_fd = lock_fd

    @staticmethod
    def _lock(directory: Path) -> int:
        fd = os.open(directory / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError as e:
            os.close(fd)
            raise DeviceError(f"session {directory} is being written by another process (capture running?)") from e
        return fd

    @classmethod
    def create(
        cls,
        directory: str | Path,
        *,
        cell: dict | None = None,
        devices: dict | None = None,
        plan: dict | None = None,
        extra: dict | None = None,
    ) -> "SessionWriter":
        """Start a new session in ``directory`` (created; must not hold a session already).

        Args:
            cell: the cell spec as loaded from ``cell.yaml`` (plain mapping), or None.
            devices: device addresses and settings, e.g. ``{"robot": {...}, "cameras": {"cam0": {...}}}``.
            plan: the station plan (``jcalib.plan/1`` mapping) the capture runs.
            extra: further keys for session.json.
        """
        d = Path(directory)
        if (d / "session.json").exists():
            raise BadInputError(
                f"session: {d} already holds a session; resume it (--resume) or choose another --out folder"
            )
        d.mkdir(parents=True, exist_ok=True)
        fd = cls._lock(d)
        meta: dict[str, Any] = {
            "schema": SCHEMA,
            "jcalib_version": jcalib.__version__,
            "created": utc_now(),
            "cell": cell,
            "devices": devices or {},
            "plan": plan,
            **(extra or {}),
        }
        write_json_atomic(d / "session.json", meta)
        (d / "images").mkdir(exist_ok=True)
        fdd = os.open(d / "stations.jsonl", os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        os.fsync(fdd)
        os.close(fdd)
        return cls(d, meta, [], fd)

    @classmethod
    def open(cls, directory: str | Path) -> "SessionWriter":
        """Reopen an existing session to append to it (resume): repairs what a kill can leave behind."""
        d = Path(directory)
        if not (d / "session.json").is_file():
            raise BadInputError(f"session: {d} has no session.json; nothing to resume (start without --resume)")
        fd = cls._lock(d)
        path = d / "stations.jsonl"
        if path.exists():
            raw = path.read_bytes()
            if raw and not raw.endswith(b"\n"):  # torn last line: cut it, it is not a finished station
                with open(path, "r+b") as f:
                    f.truncate(raw.rfind(b"\n") + 1)
                    f.flush()
                    os.fsync(f.fileno())
        for tmp in (d / "images").glob("*/.*.tmp"):
            tmp.unlink()
        meta, stations = read_session(d)
        return cls(d, meta, stations, fd)

    def image_path(self, camera: str, station_id: str) -> str:
        """Session-relative path of an image, ``images/<camera>/<station>.png``."""
        return f"images/{camera}/{station_id}.png"

    def write_image(self, camera: str, station_id: str, image: np.ndarray) -> str:
        """Write one image atomically (temp file, fsync, rename); returns its session-relative path."""
        rel = self.image_path(camera, station_id)
        write_bytes_atomic(self.directory / rel, encode_png(image))
        return rel

    def append_station(self, record: dict) -> None:
        """Append one finished station (its images must already be written); fsync'ed.

        Raises:
            BadInputError: duplicate id (unless the record is a ``"retake": true``), or an image the
                record names is missing.
        """
        sid = record["id"]
        if sid in self.stations and record.get("retake") is not True:
            raise BadInputError(f"session: station {sid!r} is already recorded in {self.directory}")
        for cam, rel in record.get("images", {}).items():
            if not (self.directory / rel).is_file():
                raise BadInputError(f"session: station {sid!r} names image {rel} of {cam}, which is not on disk")
        append_line_durable(self.directory / "stations.jsonl", json.dumps(record, allow_nan=False, separators=(",", ":")))
        self.stations[sid] = record

    def close(self) -> None:
        """Release the session lock."""
        if self._lock_fd >= 0:
            os.close(self._lock_fd)
            self._lock_fd = -1

    def __enter__(self) -> "SessionWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
