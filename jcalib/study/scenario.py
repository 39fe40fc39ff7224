"""Study scenarios (``jcalib.study/1``): a cell spec, its truth, noise, station strategies and estimators.

A scenario is a dict (or a YAML / JSON file)::

    schema: jcalib.study/1
    name: eye-in-hand, 15 random stations   # free text
    cell:                                   # any jcalib.cell/1 spec, inline or a path (from this file's folder)
      schema: jcalib.cell/1
      cameras: {cam0: {model: opencv5, mount: flange, fix: [fx, fy, cx, cy, k1, k2, p1, p2, k3]}}
      targets: {board: {type: checkerboard, cols: 9, rows: 6, square: 0.025, mount: base}}
      robot: {pose_noise: {translation_m: 1.0e-4, rotation_deg: 0.01}}
    truth:                                  # optional: what is true in every trial (or how to draw it)
      cameras: {cam0: {image_size: [1600, 1200], params: [1400, 1395, 801.5, 598, -0.12, 0.08, 0.0005, -0.0003, -0.02]}}
      poses:                                # each thing's pose on its holder: a 4x4, or a draw
        cam0: {rotation_deg: 180, translation_m: 0.1}
        board: {pose: [[-1, 0, 0, 0.6], [0, 1, 0, 0.1], [0, 0, -1, 0], [0, 0, 0, 1]], rotation_deg: 180, axis: [0, 0, 1]}
    noise: {pixel_sigma_px: 0.2, robot_translation_m: 1.0e-4, robot_rotation_deg: 0.01, dropout_rate: 0.0}
    stations:                               # one block or a list of blocks
      - {strategy: random, camera: cam0, target: board, count: 15}
    estimators:                             # closed forms by name; the builder with options
      - park_martin
      - {name: joint, options: {pose_model: false}}
      - {name: joint_pose_model, options: {pose_model: true}}

The truth is described in :mod:`jcalib.study.truth` (defaults: a plausible layout for every mount),
the station strategies in :mod:`jcalib.study.stations` (:data:`STRATEGY_OPTIONS`), the estimators in
:mod:`jcalib.study.estimators`. ``given: [cam1, ...]`` writes the true value of those things into each
trial's cell spec (camera intrinsics, fixed poses, robot bases, point positions); a camera whose every
intrinsic is in ``fix`` and a thing listed in the cell's ``fixed`` without a value get it anyway (what a
cell holds fixed is known exactly).

The first form of this file (``cell: handeye | tcp | camera`` with ``camera``, ``target``,
``intrinsics`` keys) is still read: :func:`jcalib.study.legacy.convert` turns it into this form.
:func:`load_scenario` validates everything and raises :class:`jcalib.errors.BadInputError` naming the
offending key (``scenario.noise.pixel_sigma_px``, ``scenario.stations[1].count``, ...), the value
received and what was expected.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from jcalib.errors import BadInputError
from jcalib.io.cell import CellSpec, parse_cell
from jcalib.study.checks import check_keys, fail, integer, number, read_file, relative
from jcalib.study.legacy import convert, is_old_form
from jcalib.study.stations import STRATEGIES, STRATEGY_OPTIONS, Block, parse_blocks
from jcalib.study.truth import check_truth

__all__ = [
    "BUILDER_PRESETS",
    "CLOSED_FORMS",
    "STRATEGIES",
    "STRATEGY_OPTIONS",
    "Block",
    "Estimator",
    "Noise",
    "Scenario",
    "load_scenario",
]

SCHEMA = "jcalib.study/1"
HANDEYE_CLOSED_FORMS = ("tsai_lenz", "park_martin", "horaud", "andreff", "daniilidis")
ROBOT_WORLD_CLOSED_FORMS = ("shah", "li")
#: Closed-form estimators (:mod:`jcalib.init`, OpenCV) by name -> what they need.
CLOSED_FORMS: dict[str, str] = {
    **{m: "a hand-eye pair (a camera and a target a robot moves relative to each other)" for m in HANDEYE_CLOSED_FORMS},
    **{m: "a hand-eye pair (robot-world: AX = ZB)" for m in ROBOT_WORLD_CLOSED_FORMS},
    "three_pose": "a tcp_three_pose station block",
    "ray_lsq": "a tcp_three_pose or tcp_random station block",
    "pivot": "stations with contacts (a pivot or explicit station block)",
    "opencv": "cameras that see targets (cv2.calibrateCameraExtended per camera)",
}
#: Builder estimators by name without options: name -> CalibrationOptions fields.
BUILDER_PRESETS: dict[str, dict] = {"joint": {}, "joint_pose_model": {"pose_model": True}}
_NOISE = {"pixel_sigma_px": 0.2, "tip_sigma_px": None, "axis_sigma_px": 0.5, "robot_translation_m": None,
          "robot_rotation_deg": None, "contact_sigma_m": 5e-5, "pose_rotation_deg": 0.05,
          "pose_translation_m": 5e-4, "dropout_rate": 0.0, "min_points": 8}
_TOP_KEYS = ("schema", "name", "cell", "truth", "noise", "stations", "estimators", "given")
OLD_KEYS = ("camera", "target", "intrinsics")


@dataclass(frozen=True)
class Noise:
    """Noise of the simulated measurements (σ per coordinate).

    Attributes:
        pixel_sigma_px: target corners.  tip_sigma_px: tool tips (default: ``pixel_sigma_px``).
        axis_sigma_px: points on an imaged tool axis.
        robot_translation_m, robot_rotation_deg: recorded flange poses, per axis (flange frame);
            None: each robot's ``pose_noise`` in the cell spec (exact poses without one).
        contact_sigma_m: how far a tool tip sits from the point it touches, per axis (pivot blocks; the
            poses of explicit blocks are taken as true).
        pose_rotation_deg, pose_translation_m: 6-DOF pose measurements.
        dropout_rate: probability that a detection is lost, in [0, 1).
        min_points: fewest corners of a view that count as a detection (>= 6).
    """

    pixel_sigma_px: float = 0.2
    tip_sigma_px: float | None = None
    axis_sigma_px: float = 0.5
    robot_translation_m: float | None = None
    robot_rotation_deg: float | None = None
    contact_sigma_m: float = 5e-5
    pose_rotation_deg: float = 0.05
    pose_translation_m: float = 5e-4
    dropout_rate: float = 0.0
    min_points: int = 8

    @property
    def tip_px(self) -> float:
        return self.pixel_sigma_px if self.tip_sigma_px is None else self.tip_sigma_px


@dataclass(frozen=True)
class Estimator:
    """An estimator: the builder with options, or a closed form.

    Attributes:
        name: the table's name for it.
        closed_form: the closed form's name (a key of :data:`CLOSED_FORMS`), or None for the builder.
        options: :class:`~jcalib.problems.options.CalibrationOptions` fields (builder).
    """

    name: str
    closed_form: str | None = None
    options: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        if self.closed_form is not None:
            return {"name": self.name, "closed_form": self.closed_form}
        return {"name": self.name, "options": dict(self.options)}


@dataclass(frozen=True)
class Scenario:
    """A validated study scenario (see the module docstring for the file form).

    Attributes:
        cell: the cell spec as plain data; ``cell_spec``: parsed.
        truth: the ``truth`` section (validated plain data).
        noise: :class:`Noise`.  stations: the :class:`Block` s.  estimators: the :class:`Estimator` s.
        given: names whose true values each trial's cell spec states.
        name, source: free text; where the scenario came from.
    """

    cell: dict
    cell_spec: CellSpec
    truth: dict
    noise: Noise
    stations: tuple[Block, ...]
    estimators: tuple[Estimator, ...]
    given: tuple[str, ...] = ()
    name: str = ""
    source: str = "<dict>"

    def to_dict(self) -> dict:
        """The scenario as plain data (JSON-able, new form); ``load_scenario(s.to_dict())`` gives ``s`` back."""
        return {"schema": SCHEMA, "name": self.name, "cell": self.cell, "truth": self.truth,
                "noise": {k: getattr(self.noise, k) for k in _NOISE}, "stations": [b.to_dict() for b in self.stations],
                "estimators": [e.to_dict() for e in self.estimators], "given": list(self.given)}

    @property
    def estimator_names(self) -> list[str]:
        return [e.name for e in self.estimators]


# ------------------------------------------------------------------------------------ sections


def _noise(data: dict) -> Noise:
    sec = data.get("noise") or {}
    if not isinstance(sec, dict):
        raise fail("scenario.noise", sec, "a mapping")
    check_keys(sec, _NOISE, "scenario.noise")
    v = {**_NOISE, **sec}
    out = {}
    for k, d in _NOISE.items():
        key = f"scenario.noise.{k}"
        if k == "min_points":
            out[k] = integer(v[k], key, 6)
        elif k == "dropout_rate":
            out[k] = number(v[k], key, 0.0, 1.0, hi_open=True)
        elif v[k] is None and d is None:
            out[k] = None
        else:
            out[k] = number(v[k], key, 0.0)
    if (out["robot_translation_m"] is None) != (out["robot_rotation_deg"] is None):
        raise fail("scenario.noise.robot_translation_m", (out["robot_translation_m"], out["robot_rotation_deg"]),
                   "both robot_translation_m and robot_rotation_deg, or neither (then the cell's pose_noise)")
    return Noise(**out)


def _cell(data: dict, base: Path | None) -> tuple[dict, CellSpec]:
    raw = data.get("cell")
    if raw is None:
        raise fail("scenario.cell", None, "a jcalib.cell/1 spec (a mapping) or the path of one")
    source = "scenario.cell"
    if isinstance(raw, (str, os.PathLike)):
        p = relative(raw, base, "scenario.cell")
        raw, source = read_file(p, "scenario.cell"), str(p)
    if not isinstance(raw, dict):
        raise fail("scenario.cell", type(raw).__name__, "a jcalib.cell/1 spec (a mapping) or the path of one")
    raw = {"schema": "jcalib.cell/1", **raw}
    try:
        spec = parse_cell(raw, source=source)
    except BadInputError as err:
        msg = str(err)
        raise BadInputError(msg if msg.startswith(source) else f"{source}: {msg}") from None
    return json.loads(json.dumps(raw)), spec


def _estimators(data: dict, cell: CellSpec) -> tuple[Estimator, ...]:
    from jcalib.problems.options import CalibrationOptions

    est = data.get("estimators", ["joint"])
    if isinstance(est, (str, dict)):
        est = [est]
    if not isinstance(est, (list, tuple)) or not est:
        raise fail("scenario.estimators", est, "a non-empty list of closed forms and {name, options} entries")
    out = []
    for i, e in enumerate(est):
        key = f"scenario.estimators[{i}]"
        if isinstance(e, str):
            if e in CLOSED_FORMS:
                out.append(Estimator(e, closed_form=e))
            elif e in BUILDER_PRESETS:
                out.append(Estimator(e, options=dict(BUILDER_PRESETS[e])))
            else:
                raise fail(key, e, f"a closed form ({', '.join(CLOSED_FORMS)}), a builder preset "
                                   f"({', '.join(BUILDER_PRESETS)}) or {{name: ..., options: {{...}}}}")
            continue
        if not isinstance(e, dict):
            raise fail(key, e, "a name or a mapping {name, options} / {name, closed_form}")
        check_keys(e, ("name", "options", "closed_form"), key)
        name = e.get("name")
        if not isinstance(name, str) or not name:
            raise fail(f"{key}.name", name, "a non-empty string")
        if e.get("closed_form") is not None:
            if e["closed_form"] not in CLOSED_FORMS:
                raise fail(f"{key}.closed_form", e["closed_form"], f"one of {list(CLOSED_FORMS)}")
            if e.get("options"):
                raise fail(f"{key}.options", e["options"], "no options for a closed form")
            out.append(Estimator(name, closed_form=e["closed_form"]))
            continue
        opts = e.get("options") or {}
        if not isinstance(opts, dict):
            raise fail(f"{key}.options", opts, "a mapping of CalibrationOptions fields")
        if name in BUILDER_PRESETS:
            opts = {**BUILDER_PRESETS[name], **opts}
        try:
            CalibrationOptions().replace(**opts)
        except BadInputError as err:
            raise BadInputError(f"{key}.options: {err}") from None
        out.append(Estimator(name, options=dict(opts)))
    names = [e.name for e in out]
    if len(set(names)) != len(names):
        raise fail("scenario.estimators", names, "each estimator name once")
    return tuple(out)


def _given(data: dict, cell: CellSpec) -> tuple[str, ...]:
    given = data.get("given") or []
    if not isinstance(given, list) or not all(isinstance(g, str) for g in given):
        raise fail("scenario.given", given, "a list of camera, target, robot or point names")
    known = set(cell.cameras) | set(cell.targets) | set(cell.robots) | set(cell.points)
    for i, g in enumerate(given):
        if g not in known:
            raise fail(f"scenario.given[{i}]", g, f"one of the cell's names ({', '.join(sorted(known))})")
    return tuple(given)


def load_scenario(scenario: str | os.PathLike | dict | Scenario) -> Scenario:
    """Read and validate a study scenario.

    Args:
        scenario: a :class:`Scenario`, a dict, or a path to a YAML / JSON file (``jcalib.study/1``), in
            this form or the first one (``cell: handeye | tcp | camera``).

    Returns:
        The validated :class:`Scenario`, defaults filled in.

    Raises:
        BadInputError: unknown or malformed keys; the message names the key (e.g.
            ``scenario.noise.pixl_sigma_px: unknown key``), the value received and what was expected.
    """
    if isinstance(scenario, Scenario):
        return scenario
    base, source = None, "<dict>"
    if isinstance(scenario, (str, os.PathLike)):
        base, source = Path(scenario).resolve().parent, str(scenario)
        scenario = read_file(scenario)
    if not isinstance(scenario, dict):
        raise fail("scenario", type(scenario).__name__, "a mapping (YAML/JSON object)")
    data = scenario
    schema = data.get("schema", SCHEMA)
    if schema != SCHEMA:
        raise fail("scenario.schema", schema, repr(SCHEMA))
    if is_old_form(data):
        data = convert(data)
    for k in OLD_KEYS:
        if k in data:
            raise BadInputError(
                f"scenario.{k}: a key of the first scenario form (cell: handeye | tcp | camera); with a cell spec, "
                "write the camera into the cell (cameras.<id>: {model, mount, fix, intrinsics}), its true "
                "parameters into truth.cameras.<id>: {image_size, params}, a target into the cell's targets, and "
                "known intrinsics as fix: [all of them] (their true values are then given to the estimators)")
    check_keys(data, _TOP_KEYS, "scenario")
    name = data.get("name", "")
    if not isinstance(name, str):
        raise fail("scenario.name", name, "a string")
    raw_cell, cell = _cell(data, base)
    noise = _noise(data)
    truth = check_truth(data.get("truth") or {}, cell)
    stations = parse_blocks(data.get("stations"), cell, base)
    estimators = _estimators(data, cell)
    given = _given(data, cell)
    return Scenario(cell=raw_cell, cell_spec=cell, truth=truth, noise=noise, stations=stations,
                    estimators=estimators, given=given, name=name, source=source)
