"""``jcalib demo``: a whole simulated cell, from plan to robot-controller exports, on loopback only.

The chain is the one a cell integrator runs on hardware, with simulators standing in for it:

1. plan stations toward the cell's goals (``goals:`` of :data:`DEMO_CELL`: hand-eye, fixed camera, TCP
   position and axis, the flange camera's projection over the whole image; :func:`plan_demo`, the
   goal-driven selection of ``jcalib plan --kind optimal``): views of the board by ``cam_hand`` (ids
   ``s…``), then tool stations (ids ``t…``: the tip of the tool ``torch`` held in front of ``cam_fixed``,
   the tool tilted and turned), as few as meet every goal by prediction;
2. serve a simulated robot controller (KUKAVARPROXY, ABB line protocol, or UR's RTDE + URScript) and
   two fake GigE Vision cameras — ``cam_hand`` on the flange, ``cam_fixed`` on the base — rendering the scene at the
   robot's *true* pose (repeatability noise included); ``cam_fixed`` shows the tool's silhouette on a
   backlight while the tip is in its tool zone (:mod:`jcalib.app.simcell`), the board otherwise;
3. capture the session through the real drivers (Aravis over GVCP/GVSP, the robot protocol over TCP);
4. detect the board in every image, and the tool tip in ``cam_fixed`` images without a board
   (:mod:`jcalib.pipeline.session`); 5. calibrate the cell jointly (:func:`jcalib.calibrate`): both
   cameras, both poses, the board and the TCP ``T_flange_torch`` in one least-squares problem;
6. write ``result.json``, the HTML report (from the in-memory result: every section, the goals table
   included) and the RAPID / KRL / OpenCV exports, print every estimate next to the simulator's ground
   truth and its σ, and each goal's achieved σ against its limit and the plan's prediction (met, or by how
   much not and why).

With ``kinematic_errors`` (``jcalib demo --kinematic-errors``) the simulated arm hides seeded realistic
kinematic errors (joint zeros, link lengths, twists; ``jcalib simulate --kinematic-errors``): its
controller plans and reports with the nominal preset, as a real one does, while the cameras see the true
arm. The cell that is calibrated (``cell_kinematics.yaml``) then names ``kinematics: <preset>`` and
``calibrate_kinematics: [joint_offsets, link_lengths, twists]``, so the identifiable kinematic
parameters are estimated with everything else from the stations' joint values; the demo prints them
against the truth, and calibrates the same observations once more with the nominal kinematics
(``result_nominal.json``) to show how far off the hand-eye, fixed-camera and TCP estimates are then.

The second camera needs its own loopback address (GigE Vision's control port is fixed at 3956), so
the demo runs in a private network namespace (``unshare -n``; ``unshare -rn`` when not root) where
``lo`` is up with 127.0.0.1 and 127.0.0.2: nothing is broadcast on real interfaces.

A real cell: run the same steps with ``jcalib plan``, ``jcalib capture --robot kuka://IP:7000
--camera cam_hand=gige://IP ...``, ``jcalib detect --session``, ``jcalib calibrate``,
``jcalib report`` and ``jcalib export`` (see the README).
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from jcalib.errors import BadInputError, DeviceError
from jcalib.workflow.simulate import DEMO_ADDRESSES as ADDRESSES
from jcalib.workflow.simulate import DEMO_CELL, start_simulator

#: What the demo with kinematic errors calibrates of the arm (the identifiable subset is kept).
KINEMATIC_GROUPS = ("joint_offsets", "link_lengths", "twists")
#: Stations planned for the arm's kinematics (``kinematics`` planner) with ``--kinematic-errors``.
KINEMATIC_STATIONS = 20
#: The most views and tool stations the goal-driven plan may take (``jcalib demo --stations``).
MAX_STATIONS = 30
#: The plan aims at this fraction of each goal's limit, so that the noise of one capture (the achieved σ
#: scatter about the predicted ones) does not tip over a goal that the plan would meet only just.
PLAN_MARGIN = 0.8
#: Candidate stations the plan chooses from: views of the board by the flange camera, and tool stations
#: generated (those the simulated fixed camera would not show as its tip detector needs are dropped: about 9 in
#: 10, :func:`_tool_shown`).
VIEW_CANDIDATES = 120
TOOL_CANDIDATES = 320
#: A tool candidate's tip lies within this fraction of the simulated tool zone's radius, and its flange end
#: projects at least this far outside the image, px.
TOOL_ZONE_MARGIN = 0.9
SHAFT_OUT_PX = 20.0
#: The simulated cameras' detection noise ("realistic" sensor noise at 640x480), px, measured as the
#: a-posteriori σ of the demo's calibrations: corners 0.12, tool tips 0.5-0.6. The demo states it to its
#: calibration, as an integrator states a detector's noise: a kind of measurement with too little redundancy
#: for its own variance component (a tip at each of a few tool stations) keeps its stated σ, and the default
#: (0.25 px) would make the TCP's σ half its error.
SIM_NOISE = {"sigma_px": 0.12, "tip_sigma_px": 0.55}
#: The noise the plan assumes, px. The tool's silhouette gives one point of its axis, about 50 px from the
#: tip, where the prediction places four, 1-4 cm from it (:data:`jcalib.geometry.se3.SHAFT_POINTS_M`, 20-80
#: px here): the stated 0.5 px on that one point tells as much about the axis as 1.1 px on the four (the sums
#: of squared distances from the tip differ 5x).
PLAN_NOISE = {**SIM_NOISE, "axis_sigma_px": 1.1}
#: The robot the demo cell has on each simulated protocol (a preset of :mod:`jcalib.geometry.robots`).
DEMO_ROBOTS = {"kuka": "kuka_kr10_r1100_sixx", "abb": "abb_irb4600_45_205", "ur": "ur5e"}


def run_cell_demo(
    out_dir: Path,
    *,
    stations: int = MAX_STATIONS,
    protocol: str = "kuka",
    image_size: str = "640x480",
    seed: int = 0,
    kinematic_errors: bool = False,
    console: Console | None = None,
) -> dict:
    """Run the whole-cell demo (inside a private network namespace); returns the comparison rows.

    Args:
        out_dir: folder for the plan, session, observations, result, report and exports.
        stations: the most views and tool stations the goal-driven plan may take (:func:`plan_demo`; it stops
            when the cell's goals are predicted met).
        protocol: simulated controller, "kuka" (a KUKA KR 10 R1100 sixx), "abb" (an ABB IRB 4600-45/2.05) or "ur" (a
            Universal Robots UR5e over RTDE and URScript, on UR's fixed ports).  image_size: "WIDTHxHEIGHT", px.
        seed: noise seed of the simulated cell (and of its kinematic errors).
        kinematic_errors: the arm hides kinematic errors, which the calibration estimates (module
            docstring); the rows then include the kinematic parameters (deg, mm; truth = true minus nominal).

    Returns:
        ``{quantity: (truth, estimate, σ)}`` in the units printed (px, mm, deg).
    """
    from jcalib.workflow.capture import run_capture
    from jcalib.workflow.devices import parse_image_size
    from jcalib.problems.api import calibrate
    from jcalib.io.atomic import write_text_atomic
    from jcalib.io.export import export_result
    from jcalib.report.html import write_report
    from jcalib.pipeline.session import detect_session_to_file

    console = console or Console()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if protocol not in DEMO_ROBOTS:
        raise BadInputError(f"--protocol: expected kuka, abb or ur, got {protocol!r}")
    cell_path = out_dir / "cell.yaml"
    write_text_atomic(cell_path, DEMO_CELL)
    size = parse_image_size(image_size)
    robot = DEMO_ROBOTS[protocol]
    calib_cell = cell_path
    if kinematic_errors:
        calib_cell = out_dir / "cell_kinematics.yaml"
        write_text_atomic(calib_cell, kinematic_cell(robot))
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    with console.status("planning stations toward the cell's goals (candidates, predicted σ, selection)"):
        planned = plan_demo(calib_cell, out_dir / "plan.json", robot=robot, max_stations=stations, image_size=size,
                            kinematic_stations=KINEMATIC_STATIONS if kinematic_errors else 0)
    timings["plan"] = time.perf_counter() - t0
    num_tool = planned.num_tool
    kin_text = f" + {planned.num_kinematic} kinematic" if kinematic_errors else ""
    console.print(f"planned {planned.num_views} board views{kin_text} + {num_tool} tool stations for {robot} toward "
                  f"the cell's {len(planned.goals)} goals ({'met' if planned.met else 'NOT all met'} by prediction"
                  f"{'' if planned.met else f' within {stations} stations'}):", highlight=False)
    for line in planned.lines():
        console.print(line, highlight=False, markup=False)

    # The simulator runs as its own process (`jcalib simulate`), like the real controller and cameras; its
    # sensor noise is a real camera's ("realistic"): a fair table of errors in σ.
    t0 = time.perf_counter()
    sim = start_simulator(cell_path, addresses=ADDRESSES, log_path=out_dir / "simulate.log", protocol=protocol,
                          robot=robot, image_size=image_size, seed=seed, time_scale=0.0, noise="realistic",
                          truth=out_dir / "truth.json", kinematic_errors=seed if kinematic_errors else None)
    try:
        run_capture(robot_url=sim.robot_url, camera_urls=sim.camera_urls, plan_path=out_dir / "plan.json",
                    out=out_dir / "session", cell=cell_path, packet_size=1400)  # fmt: skip
    finally:
        sim.stop()
    timings["capture"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    obs, failures = detect_session_to_file(out_dir / "session", cell_path, out_dir / "observations.json")
    timings["detect"] = time.perf_counter() - t0
    # at a tool station (ids t…) the flange camera looks away from the board: nothing to detect there
    expected = [f for f in failures if f.station.startswith("t") and f.station in planned.pairs
                and f.camera != planned.pairs[f.station][0]]
    if expected:
        console.print(f"{len(expected)} image(s) without a board, as planned (the flange camera at the tool stations)",
                      highlight=False)
    if len(failures) > len(expected):
        console.print(f"[yellow]{len(failures) - len(expected)} image(s) without a usable board or tool-tip view "
                      "(skipped)[/]")
    num_tips = sum(d.tool is not None for st in obs.stations for d in st.detections)
    console.print(f"tool tip found in {num_tips} of {num_tool} tool stations", highlight=False)

    from jcalib.problems.options import CalibrationOptions

    options = CalibrationOptions(**SIM_NOISE)  # the stated noise; a-posteriori where the data tell
    t0 = time.perf_counter()
    with console.status("calibrating the whole cell (closed forms, then one joint least-squares problem)"):
        result = calibrate(calib_cell, out_dir / "observations.json", options)
    timings["calibrate"] = time.perf_counter() - t0
    result.to_json(out_dir / "result.json")
    nominal = None
    if kinematic_errors:
        t0 = time.perf_counter()
        with console.status("calibrating the same observations with the nominal kinematics, for comparison"):
            nominal = calibrate(cell_path, out_dir / "observations.json", options)
        timings["calibrate (nominal kinematics)"] = time.perf_counter() - t0
        nominal.to_json(out_dir / "result_nominal.json")

    from jcalib.problems.goals import goal_rows

    rows_goals = goal_rows(planned.goals, result, planned.predicted)
    t0 = time.perf_counter()
    with console.status("writing the report (with the solve: task-space σ, hints, residuals, cross-validation)"):
        write_report(result, out_dir / "report.html", observations=obs, cell=calib_cell, goals=rows_goals)
    written = ["result.json", "report.html"]
    # one OpenCV file per camera: the flange camera moves relative to the fixed one (no stereo pair)
    exports = [("opencv", f"{cam}_opencv.yaml", {"cameras": cam}) for cam in result.file.cameras]
    exports += [("rapid", "jcalib_cell.mod", {}), ("krl", "jcalib_cell.dat", {})]
    for fmt, name, names in exports:
        try:
            export_result(out_dir / "result.json", fmt, out_dir / name, **names)
            written.append(name)
        except BadInputError as e:
            console.print(f"[yellow]no {fmt} export:[/] {escape(str(e))}", highlight=False)
    timings["report+export"] = time.perf_counter() - t0

    if nominal is not None:
        written += ["cell_kinematics.yaml", "result_nominal.json"]
    truth = json.loads((out_dir / "truth.json").read_text())
    rows = compare_with_truth(result.file, truth)
    table = Table(title=f"jcalib demo: whole cell from {len(obs.stations)} stations ({protocol} robot, 2 GigE "
                        "cameras, 1 tool)")  # fmt: skip
    for col in ("unknown", "truth", "estimate", "σ", "error", "error / σ"):
        table.add_column(col, justify="left" if col == "unknown" else "right")
    for name, (t, e, s) in rows.items():
        z = (e - t) / s if s > 0 else float("nan")
        table.add_row(name, f"{t:.5g}", f"{e:.5g}", f"{s:.2g}", f"{e - t:+.2g}", f"{z:+.2f}")
    console.print(table)
    if nominal is not None:
        kin_rows = compare_kinematics(result.file, truth)
        console.print(kinematics_table(kin_rows, robot))
        rows.update({f"kinematics {k}": v for k, v in kin_rows.items()})
    z = np.array([(e - t) / s for t, e, s in rows.values() if s > 0])
    console.print(
        f"max |error/σ| = {np.max(np.abs(z)):.2f} over {z.size} unknowns (consistent with the reported σ when "
        "most are below 2 and none far beyond 3)",
        highlight=False,
    )
    if nominal is not None:
        console.print(pose_error_table(result.file, nominal.file, truth))
    from jcalib.report.console import prediction_line

    line = prediction_line(result.file.stats.get("prediction"))
    if line:
        console.print(line, highlight=False, markup=False)
    from jcalib.report.goals import goals_table

    console.print(goals_table(rows_goals))
    for line in goal_verdicts(rows_goals, planned, result.file.stats, lost_stations(planned, obs)):
        console.print(line, highlight=False, markup=False)
    console.print("timings: " + ", ".join(f"{k} {v:.1f} s" for k, v in timings.items()), highlight=False)
    console.print(escape(f"wrote {out_dir}/: " + ", ".join(written)), highlight=False)
    return rows


def lost_stations(planned: DemoPlan, obs) -> list[str]:
    """Planned views without a detected board and tool stations without a detected tool tip (ids)."""
    seen = {st.id: st for st in obs.stations}
    lost = []
    for sid, (camera, thing) in planned.pairs.items():
        st = seen.get(sid)
        if st is None or not any(d.camera == camera and thing in (d.target, d.tool) for d in st.detections):
            lost.append(sid)
    return lost


def goal_verdicts(rows, planned: DemoPlan, stats: dict, lost: list[str]) -> list[str]:
    """What the goals table means: every goal met, or for each one not met by how much and why (the plan
    could not meet it within its stations, stations lost, noisier images than the plan assumed, or the
    scatter of one capture about the prediction)."""
    met = [r for r in rows if r.met]
    out = []
    if len(met) == len(rows):
        worst = max(r.achieved / r.goal.limit for r in rows)
        out.append(f"every goal met: the largest σ is {worst:.0%} of its limit (planned for {PLAN_MARGIN:.0%}, "
                   "predicted at the simulated cameras' noise)")
        return out
    corner = float(stats.get("sigma_px", float("nan")))
    tip = SIM_NOISE["tip_sigma_px"] * float((stats.get("variance_components") or {}).get("tip", 1.0)) ** 0.5
    out.append(f"{len(met)} of {len(rows)} goals met; not met:")
    for r in rows:
        if r.met:
            continue
        g, a, p = r.goal, r.achieved, r.predicted
        head = f"  {g.text}: σ {a:.3g} {g.unit}, {a - g.limit:.3g} {g.unit} ({a / g.limit - 1:.0%}) over the limit"
        if p is not None and p > g.limit:
            why = (f"the plan predicted {p:.3g} {g.unit}: {planned.max_stations} stations cannot meet it "
                   "(jcalib demo --stations N allows more)")
        elif lost:
            why = (f"predicted {p:.3g} {g.unit}, but {len(lost)} planned station(s) gave no detection "
                   f"({', '.join(lost[:5])}{'…' if len(lost) > 5 else ''})")
        else:
            ratio = a / p if p else float("nan")
            why = (f"predicted {p:.3g} {g.unit} (achieved / predicted {ratio:.2f}); the images gave {corner:.3g} px "
                   f"corner and {tip:.3g} px tip noise, the plan assumed {PLAN_NOISE['sigma_px']:g} and "
                   f"{PLAN_NOISE['tip_sigma_px']:g} px")
        out.append(f"{head}: {why}")
    return out


def kinematic_cell(robot: str) -> str:
    """The demo cell with the arm's kinematics calibrated: ``kinematics: <robot>`` and
    ``calibrate_kinematics:`` :data:`KINEMATIC_GROUPS` under ``robot:``."""
    head = "robot:\n  model: kuka_kr10_r1100_sixx\n"
    return DEMO_CELL.replace(head, f"robot:\n  model: {robot}\n  kinematics: {robot}  # nominal model (controller)\n"
                                   f"  calibrate_kinematics: [{', '.join(KINEMATIC_GROUPS)}]\n")


def _is_length(name: str) -> bool:
    return name.rsplit(".", 1)[-1] in ("a", "d", "tx", "ty", "tz")


def compare_kinematics(result, truth: dict) -> dict[str, tuple[float, float, float]]:
    """``{parameter (unit): (true - nominal, estimate - nominal, σ)}`` of the calibrated kinematic
    parameters (mm for lengths, deg for angles); empty when the result or the truth has none."""
    true = (truth.get("robot") or {}).get("kinematics")
    if not true or not result.kinematics:
        return {}
    k = next(iter(result.kinematics.values()))
    true_value = dict(zip(true["names"], true["values"]))
    std = k.std
    rows = {}
    for name in k.calibrated:
        i = k.names.index(name)
        f, unit = (1e3, "mm") if _is_length(name) else (float(np.degrees(1.0)), "deg")
        nominal = float(k.nominal[i])
        rows[f"{name} ({unit})"] = ((true_value[name] - nominal) * f, (float(k.values[i]) - nominal) * f,
                                    std.get(name, 0.0) * f)  # fmt: skip
    return rows


def kinematics_table(rows: dict[str, tuple[float, float, float]], robot: str) -> Table:
    """The kinematic parameters against the truth (deviations from the nominal model)."""
    table = Table(title=f"{robot}: calibrated kinematic parameters (deviation from the nominal model)")
    for col in ("parameter", "true error", "estimate", "σ", "error", "error / σ"):
        table.add_column(col, justify="left" if col == "parameter" else "right")
    for name, (t, e, s) in rows.items():
        z = (e - t) / s if s > 0 else float("nan")
        table.add_row(name, f"{t:+.4f}", f"{e:+.4f}", f"{s:.2g}", f"{e - t:+.2g}", f"{z:+.2f}")
    return table


def pose_error_table(result, nominal, truth: dict) -> Table:
    """Position (mm) and rotation (deg) errors of every calibrated pose with the kinematics calibrated
    and with the nominal kinematics, each with its error / σ (the largest per axis), and the rms px."""
    table = Table(title="the same observations calibrated with and without the arm's kinematics")
    for col in ("transform", "kinematics calibrated", "nominal kinematics"):
        table.add_column(col, justify="left" if col == "transform" else "right")
    per = [compare_with_truth(r, truth) for r in (result, nominal)]
    keys = sorted({k.split(" ")[0] for k in per[0] if k.startswith("T_")})
    for key in keys:
        cells = []
        for rows in per:
            t = np.array([rows[f"{key} t{a} (mm, frame b)"] for a in "xyz" if f"{key} t{a} (mm, frame b)" in rows])
            r = np.array([rows[f"{key} r{a} (deg)"] for a in "xyz" if f"{key} r{a} (deg)" in rows])
            z = [abs(e - tr) / s for tr, e, s in (*t, *r) if s > 0]
            text = f"{np.linalg.norm(t[:, 1]):.3f} mm" if t.size else "-"
            if r.size:
                text += f", {np.linalg.norm(r[:, 1]):.4f} deg"
            cells.append(text + (f" (max {max(z):.1f} σ)" if z else ""))
        table.add_row(key, *cells)
    table.add_row("rms reprojection per point", *(f"{r.stats.get('rms_px', float('nan')):.3f} px" for r in (result, nominal)))
    return table


class _WithMargin:
    """A :class:`~jcalib.planning.predict.Predictor` as :func:`jcalib.planning.optimal.select` sees it, each
    goal's limit times :data:`PLAN_MARGIN`."""

    def __init__(self, pred):
        self._pred, self.goals = pred, pred.goals

    def goal_sigmas(self, cov: np.ndarray) -> np.ndarray:
        return self._pred.goal_sigmas(cov)

    def limits(self) -> np.ndarray:
        return self._pred.limits() * PLAN_MARGIN


@dataclass
class DemoPlan:
    """What :func:`plan_demo` planned.

    Attributes:
        num_views, num_tool, num_kinematic: stations of each part (ids ``s…``, ``t…``, ``k…``).
        goals: the cell's goals.  predicted: goal text -> predicted σ of the views and tool stations (goal's
            unit; kinematic parameters held at nominal).  met: every goal predicted met (at its limit).
        max_stations: the most views and tool stations the plan could take.
        pairs: station id -> what it shows: ``(camera, target)`` or ``(camera, tool)`` (views and tool stations).
    """

    num_views: int
    num_tool: int
    num_kinematic: int
    goals: tuple
    predicted: dict[str, float]
    met: bool
    max_stations: int
    pairs: dict[str, tuple[str, str]]

    def lines(self) -> list[str]:
        """One line per goal: predicted σ against the limit."""
        out = []
        for g in self.goals:
            p = self.predicted[g.text]
            verdict = "met" if p <= g.limit else f"NOT met ({p / g.limit - 1:.0%} over)"
            out.append(f"  {g.text}: predicted σ {p:.3g} {g.unit} ({verdict})")
        return out


def _goal_cell(data: dict) -> dict:
    """The cell the goals are planned for: with its robot's kinematics nominal (not calibrated), so that the
    prediction covers the cameras, board and tool; kinematic stations come from their own planner."""
    robot = data.get("robot")
    if not isinstance(robot, dict) or not robot.get("calibrate_kinematics"):
        return data
    return {**data, "robot": {k: v for k, v in robot.items() if k not in ("kinematics", "calibrate_kinematics")}}


def _tool_shown(layout, camera: str, tool: str, T_base_flange: np.ndarray) -> np.ndarray:
    """``(M,)`` whether the simulated ``camera`` shows ``tool`` as its tip detector needs, at flange poses
    ``(M, 4, 4)``: the tip well inside the camera's tool zone (the ball where the simulated backlight shows
    the tool, :mod:`jcalib.app.simcell`), and the shaft running out of the image (the simulated tool runs
    straight from the tip to the flange: with both of its ends in view, the tip can be taken at the wrong
    end)."""
    from jcalib.app.simcell import DEFAULT_TOOL_ZONE_RADIUS_M
    from jcalib.planning.stations import TOOL_VIEW_DISTANCE_M

    cam = layout.cameras[camera]
    T_cam_flange = np.linalg.inv(cam.pose)[None] @ np.asarray(T_base_flange)
    tip = T_cam_flange[:, :3, :3] @ layout.tools[tool][:3, 3] + T_cam_flange[:, :3, 3]
    in_zone = np.linalg.norm(tip - np.array([0.0, 0.0, TOOL_VIEW_DISTANCE_M]), axis=1) <= (
        TOOL_ZONE_MARGIN * DEFAULT_TOOL_ZONE_RADIUS_M)
    end = T_cam_flange[:, :3, 3]  # the flange origin, projected by the pinhole part of the camera
    z = np.where(end[:, 2] > 1e-6, end[:, 2], 1e-6)
    u = (end[:, :2] / z[:, None]) @ cam.K[:2, :2].T + cam.K[:2, 2]
    w, h = cam.image_size
    inside = (end[:, 2] > 1e-6) & np.all((u > -SHAFT_OUT_PX) & (u < np.array([w, h]) - 1 + SHAFT_OUT_PX), axis=1)
    return in_zone & ~inside


def plan_demo(
    cell_path: Path,
    out: Path,
    *,
    robot: str,
    max_stations: int = MAX_STATIONS,
    image_size: tuple[int, int] | None,
    kinematic_stations: int = 0,
    seed: int = 0,
) -> DemoPlan:
    """Plan the demo toward the cell's goals: views of the board by the flange camera (ids ``s000…``),
    ``kinematics`` stations (ids ``k000…``, when ``kinematic_stations`` > 0: joint configurations spread over
    the arm's range, D-optimal for its kinematic parameters; the cell must name ``kinematics:`` and
    ``calibrate_kinematics:``), then tool stations (ids ``t000…``), one plan.

    The views and tool stations are chosen as ``jcalib plan --kind optimal`` chooses them
    (:mod:`jcalib.planning.optimal`: candidates within reach, the predicted information of each from the one
    problem builder, greedy selection and exchanges), for the simulated cell: tool candidates only where the
    simulated fixed camera shows the tool as its tip detector needs (:func:`_tool_shown`), every view also
    gives the fixed camera its view of the board (it sees the board whenever no tool is in its zone), and the
    prediction assumes the simulated cameras' detection noise (:data:`PLAN_NOISE`). Selection stops when
    every goal is predicted at :data:`PLAN_MARGIN` of its limit, or at ``max_stations``. (``jcalib plan
    --kind optimal`` itself refuses this cell: its prediction has no view of the board by the fixed camera,
    whose pose the calibration then cannot start from.)

    Writes ``out`` (``jcalib.plan/1`` with a ``planner`` key: kind ``optimal``, goals, predicted σ, ...; read
    by ``jcalib report --plan``). Returns the :class:`DemoPlan`.

    Raises:
        BadInputError: a cell without goals, ``max_stations`` outside 2..200, or no usable candidates.
    """
    from jcalib.io.atomic import write_json_atomic
    from jcalib.io.plan import make_plan
    from jcalib.planning import candidates as cands
    from jcalib.planning.layout import cell_layout, load_cell_dict
    from jcalib.planning.optimal import select
    from jcalib.planning.predict import Predictor
    from jcalib.planning.stations import plan_cell, visit_order
    from jcalib.problems.options import CalibrationOptions

    if not 2 <= int(max_stations) <= 200:
        raise BadInputError(f"--stations: expected 2..200 stations (the most the goal-driven plan may take), got "
                            f"{max_stations}")
    data, _ = load_cell_dict(cell_path)
    layout = cell_layout(_goal_cell(data), robot=robot, image_size=image_size)
    goals = layout.cell.goals
    if not goals:
        raise BadInputError(f"{cell_path}: the demo plans toward the cell's goals; the cell has none (goals:)")
    rng = np.random.default_rng(seed)
    views, tips = cands.cell_pairs(layout)
    parts = [cands.view_candidates(layout, c, t, VIEW_CANDIDATES // max(1, len(views)), rng) for c, t in views]
    for c, tool in tips:
        found = cands.tool_candidates(layout, c, tool, TOOL_CANDIDATES // len(tips), rng)
        parts.append(found.subset(np.flatnonzero(_tool_shown(layout, c, tool, found.T_base_flange))))
    c = cands.merge(parts)
    if not len(c):
        raise BadInputError(f"plan: no candidate station of the demo cell is reachable by {robot} and in view")
    # fixed cameras see fixed targets at every view station: the same view, fresh noise each time
    fixed = [(cam, t) for cam, cl in layout.cameras.items() for t, tl in layout.targets.items()
             if cl.mount == "base" and tl.mount == "base" and layout.cell.targets[t].type != "points"]
    fixed_c = cands.Candidates(np.repeat(c.T_base_flange[:1], len(fixed), 0), np.repeat(c.joints_rad[:1], len(fixed), 0),
                               fixed)
    pred = Predictor(layout, goals, CalibrationOptions(**PLAN_NOISE))
    pred.setup(cands.merge([c, fixed_c]))
    infos = pred.informations(c)
    is_view = np.array([thing in layout.targets for _, thing in c.pair])
    if fixed:
        infos[is_view] += pred.informations(fixed_c).sum(axis=0)
    first = sorted({c.pair.index(p) for p in c.pair})  # one candidate of each pair: every unknown is in it
    prior = pred.prior_information(c.subset(first))
    d = select(_WithMargin(pred), infos, prior, int(max_stations))
    sigma = pred.goal_sigmas(np.linalg.inv(d.information))
    predicted = {g.text: float(s) for g, s in zip(goals, sigma)}

    def ordered(keep: np.ndarray) -> list[int]:
        chosen = [k for k in d.chosen if keep[k]]
        return [chosen[i] for i in visit_order(c.joints_rad[chosen], layout.home_rad)] if chosen else []

    view_k, tool_k = ordered(is_view), ordered(~is_view)
    poses = [c.T_base_flange[k] for k in view_k]
    ids = [f"s{k:03d}" for k in range(len(view_k))]
    details: dict = {}
    num_kin = 0
    if kinematic_stations > 0:
        kin = plan_cell(cell_layout(cell_path, robot=robot, image_size=image_size), "kinematics",
                        num_stations=kinematic_stations)
        poses += [s.T_base_flange for s in kin.plan.stations]
        num_kin = len(kin.plan)
        ids += [f"k{k:03d}" for k in range(num_kin)]
        details["kinematics"] = kin.to_json()["planner"]
    poses += [c.T_base_flange[k] for k in tool_k]
    ids += [f"t{k:03d}" for k in range(len(tool_k))]
    texts = [g.text for g in goals]
    planner = {
        "kind": "optimal", "robot": layout.robot, "goals": texts, "predicted": predicted,
        "met": bool(np.all(sigma <= np.array([g.limit for g in goals]))), "margin": PLAN_MARGIN,
        "after_each_station": [{t: float(s) for t, s in zip(texts, row)} for row in d.history],
        "pairs": {"s": [list(c.pair[k]) for k in view_k], "t": [list(c.pair[k]) for k in tool_k]},
        "candidates": len(c), "dropped": {k: int(v) for k, v in c.dropped.items()},
        "assumes": (f"{PLAN_NOISE['sigma_px']:g} px corner noise, {PLAN_NOISE['tip_sigma_px']:g} px tip noise, "
                    f"{PLAN_NOISE['axis_sigma_px']:g} px tool-axis noise (the simulated cameras'), the robot's pose "
                    "noise, the nominal cell geometry (first order), nominal kinematics"),
        **details,
    }  # fmt: skip
    write_json_atomic(out, {**make_plan(poses, ids).to_json(), "planner": planner})
    pairs = {f"s{i:03d}": c.pair[k] for i, k in enumerate(view_k)} | {f"t{i:03d}": c.pair[k] for i, k in enumerate(tool_k)}
    return DemoPlan(len(view_k), len(tool_k), num_kin, tuple(goals), predicted, planner["met"], int(max_stations), pairs)


def _rotation_error_deg(R_true: np.ndarray, R_est: np.ndarray) -> np.ndarray:
    """Small rotation ``R_true⁻¹ R_est`` as a rotation vector (deg) in the frame of the right perturbation."""
    from jcalib.geometry.conversions import matrix_to_rvec

    return np.degrees(np.asarray(matrix_to_rvec(R_true.T @ R_est)))


def compare_with_truth(result, truth: dict) -> dict[str, tuple[float, float, float]]:
    """``{quantity: (truth, estimate, σ)}``: intrinsics (px / -), transforms (mm, deg about the axes of *b*).

    Rotation rows give the error rotation ``Log(R_true⁻¹ R_est)`` per axis (truth 0), in the frame in
    which the covariance is stated (right perturbation), so error / σ is meaningful per axis. A tool's
    TCP ``T_flange_<tool>`` gives its translation rows and, when its orientation was calibrated (imaged
    tool axis), the tilt of its axis (rx, ry); the rotation about the axis is a convention (no row).
    """
    rows: dict[str, tuple[float, float, float]] = {}
    for name, cam in result.cameras.items():
        t = truth["cameras"].get(name)
        if t is None:
            continue
        K, dist = np.asarray(t["K"]), np.asarray(t["dist"])
        true = dict(zip(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"),
                        [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *dist]))  # fmt: skip
        for p, value in zip(cam.param_names, cam.params):
            if p in true and p in cam.std:
                rows[f"{name} {p}"] = (float(true[p]), float(value), float(cam.std[p]))
    wanted = {}
    for name, c in truth["cameras"].items():
        wanted[f"T_{c['mount']}_{name}"] = np.asarray(c[f"T_{c['mount']}_{name}"])
    for name, tg in truth["targets"].items():
        wanted[f"T_{tg['mount']}_{name}"] = np.asarray(tg[f"T_{tg['mount']}_{name}"])
    tcps = set()
    for name, tool in truth.get("tools", {}).items():
        wanted[f"T_flange_{name}"] = np.asarray(tool[f"T_flange_{name}"])
        tcps.add(f"T_flange_{name}")
    for key, T_true in wanted.items():
        entry = result.transforms.get(key)
        if entry is None:
            continue
        T = entry.matrix
        std = entry.std if entry.std is not None else np.zeros(6)
        # translation error expressed in frame b, like the covariance: R_true^T (t_est - t_true)
        d_t = T_true[:3, :3].T @ (T[:3, 3] - T_true[:3, 3])
        d_r = _rotation_error_deg(T_true[:3, :3], T[:3, :3])
        for i, ax in enumerate("xyz"):
            rows[f"{key} t{ax} (mm, frame b)"] = (0.0, float(d_t[i] * 1e3), float(std[3 + i] * 1e3))
        axes = "xyz"
        if key in tcps:
            if entry.extra.get("orientation") != "calibrated":
                continue
            axes = "xy"
        for i, ax in enumerate(axes):
            rows[f"{key} r{ax} (deg)"] = (0.0, float(d_r[i]), float(np.degrees(std[i])))
    return rows


def main(argv: list[str] | None = None) -> int:
    """Entry point inside the namespace: ``python -m jcalib.app.demo_cell OUT STATIONS PROTOCOL SIZE SEED
    [KINEMATIC_ERRORS (0/1)]``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    out, stations, protocol, size, seed, *rest = argv
    run_cell_demo(Path(out), stations=int(stations), protocol=protocol, image_size=size, seed=int(seed),
                  kinematic_errors=bool(int(rest[0])) if rest else False)  # fmt: skip
    return 0


def demo(out_dir: Path, *, stations: int = MAX_STATIONS, protocol: str = "kuka", image_size: str = "640x480",
         seed: int = 0, kinematic_errors: bool = False) -> None:
    """The ``jcalib demo`` command body: enter a private network namespace, then run the demo there."""
    from jcalib.acquisition.netns import in_private_namespace, run_in_private_namespace

    args = [str(out_dir), str(int(stations)), protocol, image_size, str(int(seed)), str(int(bool(kinematic_errors)))]
    if in_private_namespace():
        main(args)
        return
    code = run_in_private_namespace([sys.executable, "-m", "jcalib.app.demo_cell", *args],
                                    addresses=[a for a in ADDRESSES.values() if a != "127.0.0.1"],
                                    what="the demo's second fake camera")  # fmt: skip
    if code != 0:
        raise DeviceError(f"the demo failed (exit status {code}); see the messages above")


if __name__ == "__main__":
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    from jcalib.solve.cache import enable_compilation_cache

    enable_compilation_cache()
    try:
        sys.exit(main())
    except Exception as e:  # one paragraph, like the CLI
        from jcalib.errors import JcalibError

        if isinstance(e, JcalibError):
            Console(stderr=True, soft_wrap=True).print(f"[red]error:[/] {escape(str(e))}", highlight=False)
            sys.exit(getattr(e, "exit_code", 1))
        raise
