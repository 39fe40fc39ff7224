"""Station strategies: where the robots (and free targets) go in each trial, as blocks of stations.

A scenario's ``stations`` is one block or a list of blocks; every block adds stations:

- pair blocks (``camera``, ``target``: by default the first camera and target that move relative to
  each other) place the camera relative to the target (``T_target_cam``) and move whichever of them a
  robot carries (the camera when both are on robots; the other robot is held at ``hold: {robot:
  [[4x4]]}``, by default presenting its target where a fixed board would be), or the free target of a
  camera rig. ``measure: poses`` records 6-DOF pose measurements instead of corners.

  - ``random``: :func:`jcalib.sim.scene.random_calibration_views` (``count`` views, ``fill`` of the image,
    ``max_tilt_deg``, ``max_roll_deg``);
  - ``robocalib_handeye``: RoboCalib algorithm 5: a frontal view, then camera rotations about its Z, Y,
    X axes (``angles_*_deg``), re-centred on the board at ``distance_m``;
  - ``robocalib_viewsets``: RoboCalib eqs 4.1–4.4: frontal, four tilted, world-origin and height views;
  - ``file``: ``T_target_cam``, a list of 4x4 camera poses in the target frame (m), inline or in the
    YAML/JSON file ``path`` (relative to the scenario's folder).

- TCP blocks (``tool``, ``camera``: a fixed camera in the tool's ``observed_by``) move the tool's robot:

  - ``tcp_three_pose`` (the thesis' setting): the tip on the camera's optical axis at ``tip_depth_m``
    in a random orientation, then rotated by ``alpha_deg`` about the camera z axis and by ``beta_deg``
    about the camera x axis, each followed by a servo translation in the camera x-y plane back onto the
    pixel; the servo stops within ``servo_sigma_px`` (default: the tip noise) per image axis;
  - ``tcp_random``: ``count`` poses rotated by 50–100 % of ``rotation_deg`` about random axes, the tip
    servoed back onto the ray at its depth;
  - ``tcp_spread``: ``count`` tips spread in front of the camera (``lateral_m`` half-widths across,
    ``depth_m`` range along the optical axis), the tool pointing down tilted by up to ``tilt_deg``.

  ``axis_points``: points detected on the imaged tool axis (over ``axis_length_m``); 0: the tip alone.
- ``pivot`` blocks (``tool``, ``point``): ``count`` orientations tilted by up to ``rotation_deg`` from
  pointing down, the tip in the point (within the contact noise); records the contacts.
- ``explicit`` blocks: ``stations``, a list of ``{T_base_flange: [[4x4]]}`` (or ``flange_poses: {robot:
  [[4x4]]}``, ``free: {target: [[4x4]]}``, ``contacts: [{tool, point}]``), the true poses (m), inline or
  in the file ``path``.

No robot model: every station is taken as reachable. Every block draws its random numbers in the same
order whatever the values.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import exp_so3, invert, make_pose, rot_x
from jcalib.io.cell import CellSpec
from jcalib.sim.observe import CellTruth, SimStation
from jcalib.study.checks import check_keys, fail, integer, number, numbers, poses, read_file
from jcalib.study.truth import DEFAULTS

__all__ = ["STRATEGIES", "STRATEGY_OPTIONS", "Block", "BlockRecord", "holder", "parse_blocks", "plan_stations"]

PAIR_STRATEGIES = ("random", "robocalib_handeye", "robocalib_viewsets", "file")
TCP_STRATEGIES = ("tcp_three_pose", "tcp_random", "tcp_spread")
#: strategy -> {option: default}. Units in the names (m, deg, px); None: see the strategy.
STRATEGY_OPTIONS: dict[str, dict[str, Any]] = {
    "random": {"count": 15, "max_tilt_deg": 40.0, "max_roll_deg": 30.0, "fill": [0.35, 0.8]},
    "robocalib_handeye": {"distance_m": 0.5, "angles_z_deg": [-90.0, -45.0, 45.0, 90.0],
                          "angles_y_deg": [-30.0, -15.0, 15.0, 30.0], "angles_x_deg": [-30.0, -15.0, 15.0, 30.0]},
    "robocalib_viewsets": {"distance_m": 0.5, "tilt_deg": 30.0, "heights": [0.8, 1.25], "rolls_deg": [0.0, 45.0]},
    "file": {"path": None, "T_target_cam": None},
    "tcp_three_pose": {"alpha_deg": 30.0, "beta_deg": 30.0, "tip_depth_m": 0.4, "servo_sigma_px": None},
    "tcp_random": {"count": 5, "rotation_deg": 30.0, "tip_depth_m": 0.4, "servo_sigma_px": None},
    "tcp_spread": {"count": 20, "depth_m": [0.5, 0.7], "lateral_m": [0.08, 0.06], "tilt_deg": 40.0},
    "pivot": {"count": 8, "rotation_deg": 30.0},
    "explicit": {"stations": None, "path": None},
}
STRATEGIES = tuple(STRATEGY_OPTIONS)
#: Keys every block of a kind takes besides its strategy's options.
BLOCK_KEYS = {
    "pair": ("camera", "target", "measure", "hold"),
    "tcp": ("tool", "camera", "axis_points", "axis_length_m"),
    "pivot": ("tool", "point"),
    "explicit": (),
}

@dataclass(frozen=True)
class Block:
    """One station block: a strategy, the things it involves and its options (defaults filled in).

    Attributes:
        strategy: a key of :data:`STRATEGY_OPTIONS`.
        kind: ``"pair"``, ``"tcp"``, ``"pivot"`` or ``"explicit"``.
        options: the strategy's options.
        camera, target, tool, point: what the block is about (None where it does not apply).
        measure: pair blocks: ``"corners"`` or ``"poses"`` (6-DOF pose measurements).
        hold: robot -> flange pose (4, 4) the robot keeps during the block.
        T_target_cam: ``file`` strategy: (N, 4, 4) camera poses in the target frame, m.
        stations: ``explicit`` strategy: station records (``T_base_flange`` or ``flange_poses``,
            ``free``, ``contacts``; true poses, m).
    """

    strategy: str
    kind: str
    options: dict = field(default_factory=dict)
    camera: str | None = None
    target: str | None = None
    tool: str | None = None
    point: str | None = None
    measure: str = "corners"
    hold: dict = field(default_factory=dict)
    T_target_cam: np.ndarray | None = None
    stations: tuple = ()

    def to_dict(self) -> dict:
        out: dict[str, Any] = {"strategy": self.strategy}
        for k in ("camera", "target", "tool", "point"):
            if getattr(self, k) is not None:
                out[k] = getattr(self, k)
        if self.kind == "pair":
            out["measure"] = self.measure
            if self.hold:
                out["hold"] = {r: np.asarray(T).tolist() for r, T in self.hold.items()}
        out.update({k: v for k, v in self.options.items() if k not in ("path", "T_target_cam", "stations")})
        if self.strategy == "file":
            out["T_target_cam"] = np.asarray(self.T_target_cam).tolist()
        if self.strategy == "explicit":
            out["stations"] = list(self.stations)
        return out




def holder(cell: CellSpec, name: str) -> str | None:
    """A robot name (on its flange), None (fixed in the cell's frame) or ``"free"`` (a free target)."""
    spec = cell.cameras.get(name) or cell.targets.get(name) or cell.tools.get(name)
    mount = getattr(spec, "mount", "flange")
    if mount == "flange":
        return spec.robot or (list(cell.robots) or [(cell.robot.name if cell.robot else None) or "robot"])[0]
    if mount == "free" and name in cell.targets:
        return "free"
    return None


def _kind(strategy: str) -> str:
    if strategy in PAIR_STRATEGIES:
        return "pair"
    if strategy in TCP_STRATEGIES:
        return "tcp"
    return strategy  # pivot, explicit


# ------------------------------------------------------------------------------------ parsing


def _default_pair(cell: CellSpec) -> tuple[str | None, str | None]:
    for c in cell.cameras:
        for t in cell.targets:
            hc, ht = holder(cell, c), holder(cell, t)
            if ht == "free" or hc != ht:
                return c, t
    return None, None


def _default_tool(cell: CellSpec) -> tuple[str | None, str | None]:
    for k, tool in cell.tools.items():
        for c in tool.observed_by:
            if holder(cell, c) is None:
                return k, c
    return None, None


def _pair_options(opts: dict, strategy: str, where: str, base: Path | None) -> tuple[dict, np.ndarray | None]:
    T_tc = None
    if strategy == "random":
        opts["count"] = integer(opts["count"], f"{where}.count", 3)
        opts["max_tilt_deg"] = number(opts["max_tilt_deg"], f"{where}.max_tilt_deg", 0.0, 80.0, hi_open=True)
        opts["max_roll_deg"] = number(opts["max_roll_deg"], f"{where}.max_roll_deg", 0.0, 90.0, hi_open=True)
        fill = numbers(opts["fill"], f"{where}.fill", 2)
        if not 0 < fill[0] <= fill[1] <= 1.5:
            raise fail(f"{where}.fill", opts["fill"], "[min, max] with 0 < min <= max <= 1.5")
        opts["fill"] = fill
    elif strategy == "robocalib_handeye":
        opts["distance_m"] = number(opts["distance_m"], f"{where}.distance_m", 0.0, lo_open=True)
        for k in ("angles_z_deg", "angles_y_deg", "angles_x_deg"):
            vals = numbers(opts[k], f"{where}.{k}")
            if any(v == 0.0 or abs(v) > 180.0 for v in vals):
                raise fail(f"{where}.{k}", opts[k], "non-zero angles within +-180 deg")
            opts[k] = vals
    elif strategy == "robocalib_viewsets":
        opts["distance_m"] = number(opts["distance_m"], f"{where}.distance_m", 0.0, lo_open=True)
        opts["tilt_deg"] = number(opts["tilt_deg"], f"{where}.tilt_deg", 0.0, 90.0, lo_open=True, hi_open=True)
        opts["heights"] = numbers(opts["heights"], f"{where}.heights")
        if any(not 0.0 < h <= 10.0 for h in opts["heights"]):
            raise fail(f"{where}.heights", opts["heights"], "scale factors in (0, 10]")
        opts["rolls_deg"] = numbers(opts["rolls_deg"], f"{where}.rolls_deg")
    else:  # file
        if opts.get("T_target_cam") is not None:
            T_tc = poses(opts["T_target_cam"], f"{where}.T_target_cam", 3)
        else:
            if not isinstance(opts.get("path"), (str, os.PathLike)):
                raise fail(f"{where}.path", opts.get("path"), "a YAML/JSON file with T_target_cam (list of 4x4, m)")
            p = Path(opts["path"])
            p = base / p if not p.is_absolute() and base is not None else p
            content = read_file(p, f"{where}.path")
            if not isinstance(content, dict) or "T_target_cam" not in content:
                raise fail(f"{where}.path", str(p), "a file with a T_target_cam key (list of 4x4 poses, m)")
            T_tc = poses(content["T_target_cam"], f"{where}.path ({p}): T_target_cam", 3)
        opts = {}
    return opts, T_tc


def _tcp_options(opts: dict, strategy: str, where: str) -> dict:
    if strategy == "tcp_three_pose":
        for k in ("alpha_deg", "beta_deg"):
            opts[k] = number(opts[k], f"{where}.{k}", 0.0, 180.0, lo_open=True, hi_open=True)
    if strategy == "tcp_random":
        opts["count"] = integer(opts["count"], f"{where}.count", 3)
        opts["rotation_deg"] = number(opts["rotation_deg"], f"{where}.rotation_deg", 0.0, 180.0, lo_open=True)
    if strategy in ("tcp_three_pose", "tcp_random"):
        opts["tip_depth_m"] = number(opts["tip_depth_m"], f"{where}.tip_depth_m", 0.0, lo_open=True)
        if opts["servo_sigma_px"] is not None:
            opts["servo_sigma_px"] = number(opts["servo_sigma_px"], f"{where}.servo_sigma_px", 0.0)
    if strategy == "tcp_spread":
        opts["count"] = integer(opts["count"], f"{where}.count", 3)
        d = numbers(opts["depth_m"], f"{where}.depth_m", 2)
        if not 0 < d[0] <= d[1]:
            raise fail(f"{where}.depth_m", opts["depth_m"], "[near, far] with 0 < near <= far (m)")
        opts["depth_m"] = d
        opts["lateral_m"] = [number(v, f"{where}.lateral_m[{i}]", 0.0)
                             for i, v in enumerate(numbers(opts["lateral_m"], f"{where}.lateral_m", 2))]
        opts["tilt_deg"] = number(opts["tilt_deg"], f"{where}.tilt_deg", 0.0, 90.0)
    return opts


def _explicit(opts: dict, where: str, base: Path | None, cell: CellSpec) -> tuple:
    records = opts.get("stations")
    if records is None:
        if not isinstance(opts.get("path"), (str, os.PathLike)):
            raise fail(f"{where}.stations", None, "a list of stations, or path: a YAML/JSON file with stations")
        p = Path(opts["path"])
        p = base / p if not p.is_absolute() and base is not None else p
        content = read_file(p, f"{where}.path")
        records = content.get("stations") if isinstance(content, dict) else None
    if not isinstance(records, list) or not records:
        raise fail(f"{where}.stations", type(records).__name__, "a non-empty list of stations")
    out = []
    for i, r in enumerate(records):
        w = f"{where}.stations[{i}]"
        if not isinstance(r, dict):
            raise fail(w, r, "{T_base_flange | flange_poses, free, contacts}")
        check_keys(r, ("T_base_flange", "flange_poses", "free", "contacts"), w)
        rec: dict[str, Any] = {}
        if r.get("T_base_flange") is not None:
            rec["T_base_flange"] = poses(r["T_base_flange"], f"{w}.T_base_flange")[0].tolist()
        if r.get("flange_poses") is not None:
            if not isinstance(r["flange_poses"], dict):
                raise fail(f"{w}.flange_poses", r["flange_poses"], "{robot: [[4x4]]}")
            rec["flange_poses"] = {k: poses(v, f"{w}.flange_poses.{k}")[0].tolist() for k, v in r["flange_poses"].items()}
        if r.get("free") is not None:
            if not isinstance(r["free"], dict) or any(t not in cell.targets for t in r["free"]):
                raise fail(f"{w}.free", r["free"], "{free target: [[4x4]]}")
            rec["free"] = {k: poses(v, f"{w}.free.{k}")[0].tolist() for k, v in r["free"].items()}
        contacts = r.get("contacts") or []
        if not isinstance(contacts, list) or not all(isinstance(c, dict) and c.get("tool") in cell.tools
                                                     and c.get("point") in cell.points for c in contacts):
            raise fail(f"{w}.contacts", contacts, "[{tool: <cell tool>, point: <cell point>}]")
        if contacts:
            rec["contacts"] = [{"tool": c["tool"], "point": c["point"]} for c in contacts]
        out.append(rec)
    return tuple(out)


def _block(sec: Any, where: str, cell: CellSpec, base: Path | None) -> Block:
    if not isinstance(sec, dict):
        raise fail(where, sec, "a mapping {strategy: ..., ...}")
    default = "random" if _default_pair(cell)[0] else "tcp_spread" if _default_tool(cell)[0] else "pivot"
    strategy = sec.get("strategy", default)
    if strategy not in STRATEGY_OPTIONS:
        raise fail(f"{where}.strategy", strategy, f"one of {list(STRATEGY_OPTIONS)}")
    kind = _kind(strategy)
    check_keys(sec, {"strategy", *BLOCK_KEYS[kind], *STRATEGY_OPTIONS[strategy]}, where)
    opts = {**STRATEGY_OPTIONS[strategy], **{k: v for k, v in sec.items()
                                             if k in STRATEGY_OPTIONS[strategy]}}
    if kind == "pair":
        c0, t0 = _default_pair(cell)
        camera, target = sec.get("camera", c0), sec.get("target", t0)
        if camera not in cell.cameras:
            raise fail(f"{where}.camera", camera, f"a camera of the cell ({', '.join(cell.cameras)})")
        if target not in cell.targets:
            raise fail(f"{where}.target", target, f"a target of the cell ({', '.join(cell.targets) or 'none'})")
        hc, ht = holder(cell, camera), holder(cell, target)
        if hc == ht and ht != "free":
            raise fail(f"{where}.target", target, f"a target that moves relative to camera '{camera}' (both are "
                                                 f"{'fixed' if hc is None else 'on robot ' + repr(hc)})")
        measure = sec.get("measure", "corners")
        if measure not in ("corners", "poses"):
            raise fail(f"{where}.measure", measure, "'corners' or 'poses' (6-DOF pose measurements)")
        hold = sec.get("hold") or {}
        robots = set(cell.robots) or {holder(cell, camera), holder(cell, target)} - {None, "free"}
        if not isinstance(hold, dict) or any(r not in robots for r in hold):
            raise fail(f"{where}.hold", hold, f"{{robot: [[4x4]]}} for robots of the cell ({', '.join(sorted(robots))})")
        hold = {r: poses(T, f"{where}.hold.{r}")[0] for r, T in hold.items()}
        if ht == "free" and hc not in (None, "free") and hc not in hold:
            raise fail(f"{where}.hold.{hc}", None, f"the flange pose robot '{hc}' keeps while the free target "
                                                  f"'{target}' moves in front of camera '{camera}'")
        opts, T_tc = _pair_options(opts, strategy, where, base)
        return Block(strategy, kind, opts, camera=camera, target=target, measure=measure, hold=hold,
                     T_target_cam=T_tc)
    if kind == "tcp":
        k0, c0 = _default_tool(cell)
        tool, camera = sec.get("tool", k0), sec.get("camera", c0)
        if tool not in cell.tools:
            raise fail(f"{where}.tool", tool, f"a tool of the cell ({', '.join(cell.tools) or 'none'})")
        if camera not in cell.tools[tool].observed_by or holder(cell, camera) is not None:
            raise fail(f"{where}.camera", camera, f"a fixed camera in tools.{tool}.observed_by "
                                                  f"({', '.join(cell.tools[tool].observed_by) or 'none'})")
        opts = _tcp_options(opts, strategy, where)
        opts["axis_points"] = integer(sec.get("axis_points", 0), f"{where}.axis_points", 0)
        opts["axis_length_m"] = number(sec.get("axis_length_m", 0.08), f"{where}.axis_length_m", 0.0, lo_open=True)
        return Block(strategy, kind, opts, camera=camera, tool=tool)
    if kind == "pivot":
        tool = sec.get("tool", next(iter(cell.tools), None))
        point = sec.get("point", next(iter(cell.points), None))
        if tool not in cell.tools:
            raise fail(f"{where}.tool", tool, f"a tool of the cell ({', '.join(cell.tools) or 'none'})")
        if point not in cell.points:
            raise fail(f"{where}.point", point, f"a point of the cell ({', '.join(cell.points) or 'none'})")
        opts["count"] = integer(opts["count"], f"{where}.count", 3)
        opts["rotation_deg"] = number(opts["rotation_deg"], f"{where}.rotation_deg", 0.0, 90.0, lo_open=True)
        return Block(strategy, kind, opts, tool=tool, point=point)
    return Block(strategy, kind, {}, stations=_explicit(opts, where, base, cell))


def parse_blocks(value: Any, cell: CellSpec, base: Path | None) -> tuple[Block, ...]:
    """The validated station blocks of a scenario (``stations``: one mapping or a list of them)."""
    if value is None:
        value = {}
    if isinstance(value, dict):
        return (_block(value, "scenario.stations", cell, base),)
    if not isinstance(value, list) or not value:
        raise fail("scenario.stations", value, "a station block {strategy: ...} or a non-empty list of them")
    return tuple(_block(b, f"scenario.stations[{i}]", cell, base) for i, b in enumerate(value))


# ------------------------------------------------------------------------------------ planning


@dataclass
class BlockRecord:
    """What a block planned: its station ids (in order) and what closed forms need to know.

    Attributes:
        block: the :class:`~jcalib.study.scenario.Block`.
        ids: the ids of its stations.
        servo_sigma_m: TCP blocks: σ of the servo residual per image axis at the tip depth (m).
        goal_pixel: TCP servo blocks: the pixel the tip is held at (the principal point).
    """

    block: Block
    ids: list[str] = field(default_factory=list)
    servo_sigma_m: float = 0.0
    goal_pixel: np.ndarray | None = None


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    from jcalib.geometry.se3 import matrix_from_quat

    q = rng.normal(size=4)
    return matrix_from_quat(q / np.linalg.norm(q))


def _rot(axis: str, deg: float) -> np.ndarray:
    return exp_so3(np.radians(deg) * {"X": np.array([1.0, 0, 0]), "Y": np.array([0, 1.0, 0]),
                                      "Z": np.array([0, 0, 1.0])}[axis])


def _views(block: Block, truth: CellTruth, rng: np.random.Generator) -> np.ndarray:
    """(N, 4, 4) ``T_target_cam`` of a pair block."""
    from jcalib.geometry import views as rc
    from jcalib.sim.scene import random_calibration_views

    o = block.options
    points = np.asarray(truth.target_points[block.target], np.float64)
    centre = points.mean(axis=0)
    if block.strategy == "random":
        T_ct = random_calibration_views(truth.cameras[block.camera], points, int(o["count"]), rng,
                                        fill=tuple(o["fill"]), max_tilt_deg=float(o["max_tilt_deg"]),
                                        max_roll_deg=float(o["max_roll_deg"]))
        return np.stack([invert(T) for T in T_ct])
    if block.strategy == "robocalib_handeye":
        D = float(o["distance_m"])
        T0 = rc.frontal_view(centre, D)
        views = [T0]
        for axis in ("Z", "Y", "X"):
            for a in o[f"angles_{axis.lower()}_deg"]:
                views.append(rc.recentre(rc.rotate_camera(T0, axis, np.radians(a)), centre, D))
        return np.stack(views)
    if block.strategy == "robocalib_viewsets":
        D, t = float(o["distance_m"]), float(o["tilt_deg"])
        views = [rc.frontal_view(centre, D)]
        views += [rc.tilted_view(centre, D, ax, np.radians(s * t)) for ax in ("X", "Y") for s in (1.0, -1.0)]
        views.append(rc.origin_view(D))
        views += [rc.height_view(centre, D, float(h), np.radians(float(r))) for h in o["heights"]
                  for r in o["rolls_deg"]]
        return np.stack(views)
    return np.asarray(block.T_target_cam, np.float64).copy()


def _world(cell: CellSpec, truth: CellTruth, name: str, flange: dict) -> np.ndarray:
    """World pose of a fixed thing, or of a thing on a robot at the flange pose in ``flange``."""
    h = holder(cell, name)
    mount = np.asarray(truth.poses[name], np.float64)
    if h is None:
        return mount
    return np.asarray(truth.bases.get(h, np.eye(4)), np.float64) @ flange[h] @ mount


def _flange_for(cell: CellSpec, truth: CellTruth, name: str, W: np.ndarray) -> np.ndarray:
    """The flange pose (in its robot's base) that puts ``name`` at world pose ``W``."""
    h = holder(cell, name)
    B = np.asarray(truth.bases.get(h, np.eye(4)), np.float64)
    return invert(B) @ W @ invert(np.asarray(truth.poses[name], np.float64))


def _pair_stations(cell: CellSpec, truth: CellTruth, block: Block, rng, ids) -> list[SimStation]:
    T_tc = _views(block, truth, rng)
    c, t = block.camera, block.target
    hc, ht = holder(cell, c), holder(cell, t)
    hold = {r: np.asarray(T, np.float64) for r, T in block.hold.items()}
    move_camera = hc not in (None, "free") and ht != "free"
    if move_camera and ht is not None and ht not in hold:  # the target's robot presents it like a fixed board
        hold[ht] = _flange_for(cell, truth, t, DEFAULTS["fixed_target"][0])
    out = []
    for k in range(len(T_tc)):
        flange = dict(hold)
        free = {}
        if move_camera:
            W_c = _world(cell, truth, t, hold) @ T_tc[k]
            flange[hc] = _flange_for(cell, truth, c, W_c)
        else:
            W_t = _world(cell, truth, c, hold) @ invert(T_tc[k])
            if ht == "free":
                free[t] = W_t
            else:
                flange[ht] = _flange_for(cell, truth, t, W_t)
        pose_pairs = ((c, t),) if block.measure == "poses" else ()
        out.append(SimStation(next(ids), flange=flange, free=free, pose_pairs=pose_pairs))
    return out


def _tcp_stations(cell: CellSpec, truth: CellTruth, block: Block, noise, rng, ids, rec: BlockRecord):
    o = block.options
    r = holder(cell, block.tool)
    B = np.asarray(truth.bases.get(r, np.eye(4)), np.float64)
    W_c = np.asarray(truth.poses[block.camera], np.float64)
    Rc, centre = W_c[:3, :3], W_c[:3, 3]
    x = np.asarray(truth.poses[block.tool], np.float64)[:3, 3]
    model = truth.cameras[block.camera]
    axis = dict(axis_points=int(o["axis_points"]), axis_length_m=float(o["axis_length_m"]))
    worlds = []
    if block.strategy == "tcp_spread":
        lx, ly = o["lateral_m"]
        for _ in range(int(o["count"])):
            u = rng.random(3)
            a = rng.normal(size=3)
            tilt = np.radians(o["tilt_deg"]) * rng.random()
            p_cam = np.array([lx * (2 * u[0] - 1), ly * (2 * u[1] - 1), o["depth_m"][0] + u[2] * (o["depth_m"][1]
                                                                                               - o["depth_m"][0])])
            R = rot_x(np.pi) @ exp_so3(tilt * a / np.linalg.norm(a))
            worlds.append(make_pose(R, Rc @ p_cam + centre - R @ x))
    else:
        depth = float(o["tip_depth_m"])
        f = float(np.mean(np.asarray(model.params)[:2]))
        servo_px = noise.tip_px if o["servo_sigma_px"] is None else float(o["servo_sigma_px"])
        rec.servo_sigma_m = servo_px * depth / f
        rec.goal_pixel = np.asarray(model.params, np.float64)[2:4].copy()
        p0 = centre + depth * Rc[:, 2]
        R0 = _random_rotation(rng)
        t0 = p0 - R0 @ x
        if block.strategy == "tcp_three_pose":
            rel = [Rc @ _rot("Z", o["alpha_deg"]) @ Rc.T, Rc @ _rot("X", o["beta_deg"]) @ Rc.T]
        else:
            k = int(o["count"]) - 1
            axes = rng.normal(size=(k, 3))
            axes /= np.linalg.norm(axes, axis=1, keepdims=True)
            ang = np.radians(o["rotation_deg"]) * rng.uniform(0.5, 1.0, k)
            rel = [exp_so3(a * g) for a, g in zip(axes, ang)]
        servo = rec.servo_sigma_m * rng.normal(size=(len(rel), 2))
        worlds.append(make_pose(R0, t0))
        for j, Rrel in enumerate(rel):
            R = Rrel @ R0
            tip = R @ x + t0  # rotated about the flange origin, before the servo
            if block.strategy == "tcp_three_pose":  # servo in the camera x-y plane only (depth may change)
                shift = -Rc[:, :2] @ (Rc.T @ (tip - p0))[:2]
            else:  # back onto the ray at the initial depth
                shift = -(tip - p0)
            worlds.append(make_pose(R, t0 + shift + Rc[:, :2] @ servo[j]))
    return [SimStation(next(ids), flange={r: invert(B) @ W}, **axis) for W in worlds]


def _pivot_stations(cell: CellSpec, truth: CellTruth, block: Block, noise, rng, ids):
    o = block.options
    r = holder(cell, block.tool)
    B = np.asarray(truth.bases.get(r, np.eye(4)), np.float64)
    x = np.asarray(truth.poses[block.tool], np.float64)[:3, 3]
    p = np.asarray(truth.points[block.point], np.float64)
    out = []
    for _ in range(int(o["count"])):
        a, u, e = rng.normal(size=3), rng.random(), rng.normal(size=3)
        R = rot_x(np.pi) @ exp_so3(np.radians(o["rotation_deg"]) * u * a / np.linalg.norm(a))
        W = make_pose(R, p + noise.contact_sigma_m * e - R @ x)
        out.append(SimStation(next(ids), flange={r: invert(B) @ W}, contacts=((block.tool, block.point),)))
    return out


def _explicit_stations(block: Block, ids) -> list[SimStation]:
    out = []
    for rec in block.stations:
        flange = {k: np.asarray(v) for k, v in rec.get("flange_poses", {}).items()}
        if "T_base_flange" in rec:
            flange["robot"] = np.asarray(rec["T_base_flange"])
        out.append(SimStation(next(ids), flange=flange, free={k: np.asarray(v) for k, v in rec.get("free", {}).items()},
                              contacts=tuple((c["tool"], c["point"]) for c in rec.get("contacts", ()))))
    return out


def plan_stations(cell: CellSpec, truth: CellTruth, blocks, noise, rng: np.random.Generator
                  ) -> tuple[list[SimStation], list[BlockRecord]]:
    """The stations of every block in order (ids ``s000``, ``s001``, ...) and what each block planned.

    Raises:
        BadInputError: a strategy cannot place its views (e.g. a target too large for the image).
    """
    counter = iter(f"s{i:03d}" for i in range(10**6))
    stations: list[SimStation] = []
    records = []
    for block in blocks:
        rec = BlockRecord(block)
        if block.kind == "pair":
            new = _pair_stations(cell, truth, block, rng, counter)
        elif block.kind == "tcp":
            new = _tcp_stations(cell, truth, block, noise, rng, counter, rec)
        elif block.kind == "pivot":
            new = _pivot_stations(cell, truth, block, noise, rng, counter)
        else:
            new = _explicit_stations(block, counter)
        rec.ids = [s.id for s in new]
        stations += new
        records.append(rec)
    if not math.isfinite(sum(float(np.sum(T)) for s in stations for T in s.flange.values())):
        raise BadInputError("stations: a planned flange pose is not finite")
    return stations, records
