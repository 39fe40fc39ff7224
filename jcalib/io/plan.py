"""Station plans: the flange poses a capture visits, in order (``jcalib.plan/1``, JSON or YAML).

```json
{"schema": "jcalib.plan/1",
 "stations": [{"id": "s000", "T_base_flange": [[1,0,0,0.5],[0,1,0,0],[0,0,1,0.8],[0,0,0,1]], "move": "joint"}]}
```
``T_base_flange`` is in metres (the flange in the robot base); ``move`` is "joint" (default) or "linear".
Optional ``joints_deg``: the joint values that reach the pose, in the controller's units (degrees;
prismatic axes in mm), as ``jcalib plan --kind kinematics`` writes them: the configuration the plan
was designed for (a capture may move there in joint space, or check that its inverse kinematics lands on
the same branch). Plans without it stay valid and keep their digest.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.geometry.se3 import check_pose
from jcalib.errors import BadInputError
from jcalib.io.atomic import write_json_atomic
from jcalib.io.goals import Goal, parse_goals
from jcalib.io.schema.plan import validate_plan_document
from jcalib.io.schema.reading import read_document

SCHEMA = "jcalib.plan/1"
_ID = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


@dataclass(frozen=True)
class Station:
    """One planned station: id, target ``T_base_flange`` (4, 4) in m, the move kind, and optionally the
    joints ``joints_deg`` (n,) that reach it (controller units: deg, mm for prismatic axes), and the lens
    settings ``lens`` (camera -> GenICam feature -> value) to set before grabbing."""

    id: str
    T_base_flange: np.ndarray
    move: str = "joint"
    joints_deg: tuple[float, ...] | None = None
    lens: Mapping[str, Mapping[str, float]] | None = None

    def to_json(self) -> dict:
        out = {"id": self.id, "T_base_flange": self.T_base_flange.tolist(), "move": self.move}
        if self.joints_deg is not None:
            out["joints_deg"] = list(self.joints_deg)
        if self.lens:
            out["lens"] = {c: dict(v) for c, v in self.lens.items()}
        return out


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


def make_plan(poses: list[np.ndarray] | np.ndarray, ids: list[str] | None = None, move: str = "joint",
              joints_deg: list | np.ndarray | None = None) -> Plan:
    """Plan from (n, 4, 4) flange poses in m; ids default to ``s000, s001, ...``; ``joints_deg``: optional
    (n, j) joint values reaching them (controller units)."""
    poses = list(poses)
    ids = ids if ids is not None else [f"s{i:03d}" for i in range(len(poses))]
    if len(ids) != len(poses):
        raise BadInputError(f"ids: expected {len(poses)} ids (one per pose), got {len(ids)}")
    if joints_deg is not None and len(joints_deg) != len(poses):
        raise BadInputError(f"joints_deg: expected {len(poses)} joint vectors (one per pose), got {len(joints_deg)}")
    stations = [{"id": i, "T_base_flange": np.asarray(T).tolist(), "move": move} for i, T in zip(ids, poses)]
    for s, j in zip(stations, joints_deg if joints_deg is not None else []):
        s["joints_deg"] = np.asarray(j, dtype=np.float64).tolist()
    return _validate(stations, "plan")


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
        out.append(Station(sid, T, move, _joints(s.get("joints_deg"), f"{at} ({sid})"), _lens(s.get("lens"), f"{at} ({sid})")))
    sizes = {len(st.joints_deg) for st in out if st.joints_deg is not None}
    if len(sizes) > 1:
        raise BadInputError(f"{where}: the stations' joints_deg have different lengths {sorted(sizes)}; one robot "
                            "has one number of joints")
    return Plan(tuple(out))


def _joints(value: object, at: str) -> tuple[float, ...] | None:
    """A station's optional ``joints_deg``: 1..32 finite joint values (controller units)."""
    if value is None:
        return None
    try:
        if not isinstance(value, (list, tuple)) or any(isinstance(v, bool) for v in value):
            raise ValueError
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.full(0, np.nan)
    if arr.ndim != 1 or not 1 <= arr.size <= 32 or not np.all(np.isfinite(arr)):
        raise BadInputError(f"{at}: joints_deg must be a list of 1..32 finite joint values (deg; mm for "
                            f"prismatic axes), got {value!r}")
    return tuple(float(v) for v in arr)


def _lens(value: object, at: str) -> dict[str, dict[str, float]] | None:
    """A station's optional ``lens``: camera -> GenICam feature -> finite number."""
    if value is None:
        return None
    ok = isinstance(value, dict) and all(
        isinstance(c, str) and isinstance(f, dict) and all(
            isinstance(k, str) and isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
            for k, v in f.items()) for c, f in value.items())
    if not ok:
        raise BadInputError(f"{at}: lens must map cameras to lens settings, e.g. {{cam0: {{Zoom: 350}}}}, got {value!r}")
    return {c: {k: float(v) for k, v in f.items()} for c, f in value.items()}


def with_lens_settings(plan: Plan, specs: list[str]) -> Plan:
    """The plan with every station visited at each lens setting of ``specs`` (``"cam0.Zoom=100,200,300"``;
    several specs: every combination), in order: each station's settings one after the other (the robot
    moves once per station). Ids become ``<id>-<setting><value>`` (e.g. ``s003-Zoom350``)."""
    import itertools

    axes = []
    for spec in specs:
        head, eq, values = str(spec).partition("=")
        cam, dot, name = head.partition(".")
        try:
            numbers = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            numbers = []
        if not eq or not dot or not cam or not name or not numbers or not all(np.isfinite(numbers)):
            raise BadInputError(f"--lens-settings: got {spec!r}; expected CAMERA.SETTING=V1,V2,..., e.g. "
                                "cam0.Zoom=100,200,300")
        axes.append([(cam, name, v) for v in numbers])
    stations = []
    for st in plan.stations:
        for combo in itertools.product(*axes):
            lens: dict[str, dict[str, float]] = {}
            for cam, name, v in combo:
                lens.setdefault(cam, {})[name] = v
            suffix = "-".join(f"{name}{v:g}" for _, name, v in combo)
            stations.append({**st.to_json(), "id": f"{st.id}-{suffix}"[:64], "lens": lens})
    return _validate(stations, "plan")


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


def plan_goals(plan: str | Path | Mapping) -> tuple[tuple[Goal, ...], dict[str, float]]:
    """``(goals, predicted σ per goal text)`` of a goal-driven plan (``jcalib plan --kind optimal``): its
    ``planner.goals`` and ``planner.predicted``. The whole plan is validated (a plan with a bad station is
    refused here too, not only when a capture reads it).

    Raises:
        BadInputError: unreadable or invalid plan, or a plan without goals (made by another planner kind).
    """
    where = "--plan"
    if isinstance(plan, Mapping):
        data: Any = plan
    else:
        where = f"--plan {plan}"
        data = read_document(plan, "plan file", fmt="json")
    plan_from_json(data, where)
    planner = data.get("planner") if isinstance(data, Mapping) else None
    texts = planner.get("goals") if isinstance(planner, Mapping) else None
    if not isinstance(texts, list) or not texts:
        kind = planner.get("kind") if isinstance(planner, Mapping) else None
        raise BadInputError(f"{where}: the plan has no goals (planner kind {kind!r}); the goals table needs a plan "
                            "made with `jcalib plan --kind optimal --goal ...`")
    goals = parse_goals(texts, f"{where}: planner.goals")
    predicted: dict[str, float] = {}
    given = planner.get("predicted") or {}
    if not isinstance(given, Mapping):
        raise BadInputError(f"{where}: planner.predicted: expected a mapping of goal -> predicted σ, got "
                            f"{type(given).__name__}; write the plan again with `jcalib plan --kind optimal`")
    for text, value in given.items():
        if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
            predicted[str(text)] = float(value)
    return goals, predicted
