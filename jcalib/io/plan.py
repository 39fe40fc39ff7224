"""Station plans: the flange poses a capture visits, in order (``jcalib.plan/1``, JSON or YAML).

```json
{"schema": "jcalib.plan/1",
 "stations": [{"id": "s000", "T_base_flange": [[1,0,0,0.5],[0,1,0,0],[0,0,1,0.8],[0,0,0,1]], "move": "joint"}]}
```
``T_base_flange`` is in metres (the flange in the robot base); ``move`` is "joint" (default) or "linear".
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jcalib.geometry.se3 import check_pose
from jcalib.errors import BadInputError
from jcalib.io.atomic import write_json_atomic
from jcalib.io.schema.plan import validate_plan_document
from jcalib.io.schema.reading import read_document

SCHEMA = "jcalib.plan/1"
_ID = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


@dataclass(frozen=True)
class Station:
    """One planned station: id, target ``T_base_flange`` (4, 4) in m, and the move kind."""

    id: str
    T_base_flange: np.ndarray
    move: str = "joint"

    def to_json(self) -> dict:
        return {"id": self.id, "T_base_flange": self.T_base_flange.tolist(), "move": self.move}


@dataclass(frozen=True)
class Plan:
    """An ordered list of stations with unique ids."""

    stations: tuple[Station, ...]

    def to_json(self) -> dict:
        return {"schema": SCHEMA, "stations": [s.to_json() for s in self.stations]}

    def digest(self) -> str:
        """sha256 of the canonical JSON: a resumed capture must run the same plan."""
        return hashlib.sha256(json.dumps(self.to_json(), sort_keys=True).encode()).hexdigest()

    def __len__(self) -> int:
        return len(self.stations)


def make_plan(poses: list[np.ndarray] | np.ndarray, ids: list[str] | None = None, move: str = "joint") -> Plan:
    """Plan from (n, 4, 4) flange poses in m; ids default to ``s000, s001, ...``."""
    poses = list(poses)
    ids = ids if ids is not None else [f"s{i:03d}" for i in range(len(poses))]
    if len(ids) != len(poses):
        raise BadInputError(f"ids: expected {len(poses)} ids (one per pose), got {len(ids)}")
    return _validate([{"id": i, "T_base_flange": np.asarray(T).tolist(), "move": move} for i, T in zip(ids, poses)], "plan")


def _validate(stations: object, where: str) -> Plan:
    if not isinstance(stations, list) or not stations:
        raise BadInputError(f"{where}: expected a non-empty list under 'stations'")
    out, seen = [], set()
    for k, s in enumerate(stations):
        at = f"{where}: station {k}"
        if not isinstance(s, dict):
            raise BadInputError(f"{at}: expected a mapping with 'id' and 'T_base_flange', got {s!r}")
        sid = s.get("id", f"s{k:03d}")
        if not isinstance(sid, str) or not _ID.match(sid):
            raise BadInputError(f"{at}: id must be 1-64 characters of [A-Za-z0-9_.-] (a file name), got {sid!r}")
        if sid in seen:
            raise BadInputError(f"{at}: duplicate station id {sid!r}")
        seen.add(sid)
        if "T_base_flange" not in s:
            raise BadInputError(f"{at} ({sid}): missing 'T_base_flange' (4x4 matrix, m)")
        try:
            T = check_pose(np.asarray(s["T_base_flange"], dtype=np.float64), f"{at} ({sid}) T_base_flange")
        except (TypeError, ValueError) as e:
            if isinstance(e, BadInputError):
                raise
            raise BadInputError(f"{at} ({sid}): T_base_flange is not a 4x4 numeric matrix: {e}") from e
        move = s.get("move", "joint")
        if move not in ("joint", "linear"):
            raise BadInputError(f"{at} ({sid}): move must be 'joint' or 'linear', got {move!r}")
        out.append(Station(sid, T, move))
    return Plan(tuple(out))


def plan_from_json(obj: dict, where: str = "plan") -> Plan:
    """Validate a loaded ``jcalib.plan/1`` document."""
    if not isinstance(obj, dict) or obj.get("schema") != SCHEMA:
        got = obj.get("schema") if isinstance(obj, dict) else type(obj).__name__
        raise BadInputError(f"{where}: expected schema {SCHEMA!r}, got {got!r}")
    validate_plan_document(obj, where)  # keys, shapes, poses within reach (jcalib.io.schema.plan)
    return _validate(obj.get("stations"), where)


def load_plan(path: str | Path) -> Plan:
    """Read a plan file (``.json``, ``.yaml`` or ``.yml``)."""
    path = Path(path)
    obj = read_document(path, "plan", fmt="yaml" if path.suffix.lower() in (".yaml", ".yml") else "json")
    return plan_from_json(obj, str(path))


def save_plan(plan: Plan, path: str | Path) -> Path:
    """Write a plan as JSON, atomically."""
    return write_json_atomic(path, plan.to_json())
