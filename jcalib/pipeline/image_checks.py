"""Checks of the image files ``jcalib detect`` is given, before and after detection: files of a session
stay inside it, one file is one station's, byte-identical images under two names, and image sizes that
contradict the cell (the intrinsics' principal point, GenICam ``Width``/``Height``) or the session's record.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from jcalib.errors import BadInputError

__all__ = ["file_key", "identical_images", "outside_session", "recorded_settings", "same_file_twice", "size_warnings"]

#: A principal point farther than this fraction of the image's width (height) from its centre: the
#: intrinsics were estimated for another resolution (a binned, cropped or resized image).
PRINCIPAL_POINT_OFF_CENTRE = 0.2


def outside_session(session_dir: Path, path: Path) -> str | None:
    """Why ``path`` (a file a session names) may not be read, or None: it must resolve inside the session
    folder, symlinks (to files or folders) followed."""
    try:
        real = path.resolve()
        real.relative_to(session_dir.resolve())
    except ValueError:
        return (f"{path} resolves to {real}, outside the session {session_dir} (a symlink): a session's images "
                "must lie inside it; copy the file into the session")
    except (OSError, RuntimeError) as e:  # a symlink loop
        return f"{path} cannot be resolved ({e})"
    return None


def file_key(path: Path) -> tuple[int, int] | str:
    """What identifies a file whatever its name (device and inode; the resolved path when stat fails)."""
    try:
        st = path.stat()
        return (st.st_dev, st.st_ino)
    except OSError:
        return str(path.resolve())


def same_file_twice(entries: Sequence[tuple[str, Path]], where: str) -> None:
    """Refuse one file named by two stations (names, hard links or symlinks to it).

    Args:
        entries: (station id, image path) pairs.
        where: the session or command, for the message.

    Raises:
        BadInputError: naming both stations and the file.
    """
    seen: dict[Any, tuple[str, Path]] = {}
    for sid, path in entries:
        first = seen.setdefault(file_key(path), (sid, path))
        if first[0] != sid:
            raise BadInputError(
                f"{where}: stations {first[0]} and {sid} both name the image file {first[1]}"
                + (f" (as {path})" if path != first[1] else "") + "; an image is one station's view: exclude one "
                "of the stations (the operator app, exclusions.json) or correct the station records")
        # one station naming one file for two cameras is caught by the size and detection checks


def identical_images(paths: Sequence[Path]) -> dict[Path, Path]:
    """``{path: the first earlier path with the same bytes}`` for byte-identical files under two names
    (files of equal size only are hashed: the normal case reads no file)."""
    by_size: dict[int, list[Path]] = {}
    for p in paths:
        try:
            by_size.setdefault(p.stat().st_size, []).append(p)
        except OSError:
            continue
    out: dict[Path, Path] = {}
    for group in by_size.values():
        if len(group) < 2:
            continue
        first: dict[str, Path] = {}
        for p in group:
            h = hashlib.sha256()
            try:
                with open(p, "rb") as f:
                    for block in iter(lambda: f.read(1 << 20), b""):
                        h.update(block)
            except OSError:
                continue
            earlier = first.setdefault(h.hexdigest(), p)
            if earlier != p:
                out[p] = earlier
    return out


def size_warnings(cam_spec: Any, size: tuple[int, int], recorded: Mapping[str, Any] | None = None,
                  recorded_where: str = "") -> list[str]:
    """What contradicts a camera's image size ``(width, height)``: the cell's intrinsics (principal point far
    off the image centre), the cell's GenICam ``Width``/``Height`` settings, the ``Width``/``Height`` the
    capture recorded (``recorded``: the session's camera settings; ``recorded_where`` names the file).
    Each sentence is said of the camera (the callers report it as ``camera <id>: ...``)."""
    w, h = size
    out = []
    K = getattr(cam_spec, "K", None)
    if K is not None:
        cx, cy = float(K[0][2]), float(K[1][2])
        if abs(cx - (w - 1) / 2) > PRINCIPAL_POINT_OFF_CENTRE * w or abs(cy - (h - 1) / 2) > PRINCIPAL_POINT_OFF_CENTRE * h:
            out.append(f"its images are {w}x{h} px but the cell's intrinsics put the principal point "
                       f"at ({cx:.0f}, {cy:.0f}), far from the image centre: intrinsics of another resolution "
                       "(binned, cropped or resized images)?")
    for source, settings in (("the cell's settings", getattr(cam_spec, "settings", None) or {}),
                             (f"{recorded_where} (recorded at capture)", recorded or {})):
        sw, sh = settings.get("Width"), settings.get("Height")
        if isinstance(sw, (int, float)) and isinstance(sh, (int, float)) and (int(sw), int(sh)) != (w, h):
            out.append(f"its images are {w}x{h} px but {source} give Width x Height "
                       f"{int(sw)}x{int(sh)}: resized or replaced images, or images of another camera?")
    return out


def recorded_settings(meta: Mapping[str, Any], camera: str) -> Mapping[str, Any] | None:
    """The GenICam settings a session's ``session.json`` recorded for a camera (None: none recorded)."""
    cams = (meta.get("devices") or {}).get("cameras") if isinstance(meta.get("devices"), dict) else None
    entry = cams.get(camera) if isinstance(cams, dict) else None
    settings = entry.get("settings") if isinstance(entry, dict) else None
    return settings if isinstance(settings, dict) else None

