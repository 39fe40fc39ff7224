"""Exclusions of a capture session (``exclusions.json``, schema ``jcalib.exclusions/1``).

An operator (the ``jcalib ui`` inspect page, or a text editor) can leave a view or a whole station out of
the calibration without deleting anything: the images and ``stations.jsonl`` stay as captured, and this
small file in the session folder lists what is left out::

    {"schema": "jcalib.exclusions/1",
     "excluded": [{"station": "s003"},                          # the whole station
                  {"station": "s007", "camera": "cam_hand"}],   # one camera's view of it
     "updated": "2026-11-29T10:00:00Z"}

Entries may carry a ``note`` (why). Every consumer honours the file the same way
(:func:`apply_exclusions`): ``jcalib detect --session`` does not detect excluded views, and
``jcalib calibrate`` / :func:`jcalib.calibrate` given the observations of a session folder
(``SESSION/observations.json``, what ``detect --session`` writes) leave them out too, so a command-line
user and the app get the same result. An excluded view drops that camera's detections and 6-DOF pose
measurements of the station; an excluded station drops the whole station.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from jcalib.errors import BadInputError
from jcalib.io.atomic import write_json_atomic

SCHEMA = "jcalib.exclusions/1"
FILENAME = "exclusions.json"
#: Largest exclusions file read, bytes (a session has at most thousands of views).
MAX_BYTES = 4 << 20

__all__ = ["SCHEMA", "FILENAME", "Exclusions", "load_exclusions", "save_exclusions", "apply_exclusions",
           "session_of_observations"]


@dataclass(frozen=True)
class Exclusions:
    """What is left out of a session's calibration.

    Attributes:
        stations: station ids left out entirely.
        views: ``(station, camera)`` pairs left out.
        notes: ``(station, camera or None)`` -> why (optional).
    """

    stations: frozenset[str] = frozenset()
    views: frozenset[tuple[str, str]] = frozenset()
    notes: tuple[tuple[tuple[str, str | None], str], ...] = ()

    def __bool__(self) -> bool:
        return bool(self.stations or self.views)

    def excludes(self, station: str, camera: str | None = None) -> bool:
        """Whether the station (camera None) or that camera's view of it is left out."""
        return station in self.stations or (camera is not None and (station, camera) in self.views)

    def with_station(self, station: str, excluded: bool) -> "Exclusions":
        """A copy with ``station`` left out (``excluded``) or taken back in (its views included)."""
        _check_id(station, "station")
        if excluded:
            return replace(self, stations=self.stations | {station})
        return replace(self, stations=self.stations - {station},
                       views=frozenset(v for v in self.views if v[0] != station))

    def with_view(self, station: str, camera: str, excluded: bool) -> "Exclusions":
        """A copy with one camera's view of ``station`` left out or taken back in."""
        _check_id(station, "station")
        _check_id(camera, "camera")
        if excluded:
            return replace(self, views=self.views | {(station, camera)})
        return replace(self, views=self.views - {(station, camera)})

    def entries(self) -> list[dict[str, str]]:
        """The ``excluded`` list of the file, sorted."""
        notes = dict(self.notes)
        out = [{"station": s} for s in sorted(self.stations)]
        out += [{"station": s, "camera": c} for s, c in sorted(self.views)]
        for e in out:
            note = notes.get((e["station"], e.get("camera")))
            if note:
                e["note"] = note
        return out

    def to_json(self) -> dict[str, Any]:
        from datetime import datetime, timezone

        now = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
        return {"schema": SCHEMA, "excluded": self.entries(), "updated": now}

    def describe(self) -> str:
        """``"station s003, view s007/cam_hand"``: what is left out, for messages."""
        parts = [f"station {s}" for s in sorted(self.stations)] + [f"view {s}/{c}" for s, c in sorted(self.views)]
        return ", ".join(parts) if parts else "nothing"


def _check_id(value: Any, what: str) -> None:
    if not isinstance(value, str) or not value or len(value) > 200 or any(ord(c) < 32 for c in value):
        raise BadInputError(f"exclusions: {what} id must be a non-empty printable string, got {value!r}")


def parse_exclusions(data: Any, source: str) -> Exclusions:
    """Validate an ``exclusions.json`` document."""
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        got = data.get("schema") if isinstance(data, dict) else type(data).__name__
        raise BadInputError(f"{source}: schema {got!r}, expected {SCHEMA!r} (a session's exclusions file)")
    unknown = set(data) - {"schema", "excluded", "updated"}
    if unknown:
        raise BadInputError(f"{source}: unknown key(s) {', '.join(sorted(map(str, unknown)))}; expected schema, "
                            "excluded, updated")
    entries = data.get("excluded", [])
    if not isinstance(entries, list):
        raise BadInputError(f"{source}: 'excluded' must be a list of {{station, camera?, note?}}")
    stations, views, notes = set(), set(), []
    for i, e in enumerate(entries):
        where = f"{source}: excluded[{i}]"
        if not isinstance(e, dict) or "station" not in e or set(e) - {"station", "camera", "note"}:
            raise BadInputError(f"{where}: expected {{station: ID}} or {{station: ID, camera: ID}} (optional note), "
                                f"got {str(e)[:120]}")
        try:
            _check_id(e["station"], "station")
            if "camera" in e:
                _check_id(e["camera"], "camera")
        except BadInputError as err:
            raise BadInputError(f"{where}: {err}") from None
        note = e.get("note")
        if note is not None and not isinstance(note, str):
            raise BadInputError(f"{where}: note must be text, got {type(note).__name__}")
        if "camera" in e:
            views.add((e["station"], e["camera"]))
        else:
            stations.add(e["station"])
        if note:
            notes.append(((e["station"], e.get("camera")), note[:500]))
    return Exclusions(frozenset(stations), frozenset(views), tuple(notes))


def load_exclusions(session_dir: str | os.PathLike) -> Exclusions:
    """The exclusions of a session folder (none when it has no ``exclusions.json``).

    Raises:
        BadInputError: the file is unreadable, too large or not a ``jcalib.exclusions/1`` document.
    """
    import json

    path = Path(session_dir) / FILENAME
    if not path.is_file():
        return Exclusions()
    try:
        if path.stat().st_size > MAX_BYTES:
            raise BadInputError(f"{path}: {path.stat().st_size} bytes, more than an exclusions file holds "
                                f"({MAX_BYTES} bytes); fix or remove it")
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        raise BadInputError(f"{path}: cannot read the session's exclusions ({e}); fix or remove the file") from None
    return parse_exclusions(data, str(path))


def save_exclusions(session_dir: str | os.PathLike, exclusions: Exclusions) -> Path:
    """Write the session's ``exclusions.json`` atomically (removes nothing else)."""
    return write_json_atomic(Path(session_dir) / FILENAME, exclusions.to_json())


def apply_exclusions(observations: Any, exclusions: Exclusions) -> tuple[Any, list[str]]:
    """Leave out what ``exclusions`` names.

    Args:
        observations: :class:`jcalib.io.observations.Observations`.
        exclusions: what to leave out.

    Returns:
        ``(observations, left_out)``: the observations without the excluded stations and views (a station
        whose every detection and pose measurement was excluded is dropped), and ``"s003"`` /
        ``"s007/cam_hand"`` for every station and view that was present and left out.
    """
    if not exclusions:
        return observations, []
    kept, left_out = [], []
    for st in observations.stations:
        if exclusions.excludes(st.id):
            left_out.append(st.id)
            continue
        cams = {d.camera for d in st.detections} | {m.camera for m in st.poses}
        gone = sorted(c for c in cams if exclusions.excludes(st.id, c))
        if not gone:
            kept.append(st)
            continue
        left_out += [f"{st.id}/{c}" for c in gone]
        dets = tuple(d for d in st.detections if d.camera not in gone)
        poses = tuple(m for m in st.poses if m.camera not in gone)
        if dets or poses or st.contacts:
            kept.append(replace(st, detections=dets, poses=poses))
    return replace(observations, stations=tuple(kept)), left_out


def session_of_observations(path: str | os.PathLike) -> Path | None:
    """The capture session folder an observations file belongs to: its folder when that holds a
    ``session.json`` (``jcalib detect --session`` writes ``SESSION/observations.json``), else None."""
    folder = Path(path).resolve().parent
    return folder if (folder / "session.json").is_file() else None
