"""``jcalib demo``: a whole simulated cell, from plan to robot-controller exports, on loopback only.

The chain is the one a cell integrator runs on hardware, with simulators standing in for it:

1. plan stations for the cell (:func:`jcalib.planning.stations.plan_cell`): hand-eye stations
   (``cam_hand`` over the board), then tool stations (``tcp``: the tip of the tool ``torch`` held in
   front of ``cam_fixed``, the tool turned about two axes), appended to one plan (ids ``s…``, ``t…``);
2. serve a simulated robot controller (KUKAVARPROXY, ABB line protocol, or UR's RTDE + URScript) and two fake GigE Vision
   cameras — ``cam_hand`` on the flange, ``cam_fixed`` on the base — rendering the scene at the
   robot's *true* pose (repeatability noise included); ``cam_fixed`` shows the tool's silhouette on a
   backlight while the tip is in its tool zone (:mod:`jcalib.app.simcell`), the board otherwise;
3. capture the session through the real drivers (Aravis over GVCP/GVSP, the robot protocol over TCP);
4. detect the board in every image, and the tool tip in ``cam_fixed`` images without a board
   (:mod:`jcalib.pipeline.session`); 5. calibrate the cell jointly (:func:`jcalib.calibrate`): both
   cameras, both poses, the board and the TCP ``T_flange_torch`` in one least-squares problem;
6. write ``result.json``, the HTML report and the RAPID / KRL / OpenCV exports, and print every
   estimate next to the simulator's ground truth and its σ.

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
#: Tool stations appended to the hand-eye plan (``tcp`` planner).
TOOL_STATIONS = 7
#: The robot the demo cell has on each simulated protocol (a preset of :mod:`jcalib.geometry.robots`).
DEMO_ROBOTS = {"kuka": "kuka_kr10_r1100_sixx", "abb": "abb_irb4600_45_205", "ur": "ur5e"}


def run_cell_demo(
    out_dir: Path,
    *,
    stations: int = 16,
    tool_stations: int = TOOL_STATIONS,
    protocol: str = "kuka",
    image_size: str = "640x480",
    seed: int = 0,
    kinematic_errors: bool = False,
    console: Console | None = None,
) -> dict:
    """Run the whole-cell demo (inside a private network namespace); returns the comparison rows.

    Args:
        out_dir: folder for the plan, session, observations, result, report and exports.
        stations: hand-eye stations to plan (unreachable ones are dropped).
        tool_stations: tool (``tcp``) stations appended to them.
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
    num_handeye, num_tool, num_kin = plan_demo(
        calib_cell, out_dir / "plan.json", robot=robot, stations=stations, tool_stations=tool_stations,
        image_size=size, kinematic_stations=KINEMATIC_STATIONS if kinematic_errors else 0)  # fmt: skip
    timings["plan"] = time.perf_counter() - t0
    kin_text = f" + {num_kin} kinematic" if kinematic_errors else ""
    console.print(f"planned {num_handeye} hand-eye{kin_text} + {num_tool} tool stations for {robot}", highlight=False)

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
    if failures:
        console.print(f"[yellow]{len(failures)} image(s) without a usable board or tool-tip view (skipped)[/]")
    num_tips = sum(d.tool is not None for st in obs.stations for d in st.detections)
    console.print(f"tool tip found in {num_tips} of {num_tool} tool stations", highlight=False)

    t0 = time.perf_counter()
    with console.status("calibrating the whole cell (closed forms, then one joint least-squares problem)"):
        result = calibrate(calib_cell, out_dir / "observations.json")
    timings["calibrate"] = time.perf_counter() - t0
    result.to_json(out_dir / "result.json")
    nominal = None
    if kinematic_errors:
        t0 = time.perf_counter()
        with console.status("calibrating the same observations with the nominal kinematics, for comparison"):
            nominal = calibrate(cell_path, out_dir / "observations.json")
        timings["calibrate (nominal kinematics)"] = time.perf_counter() - t0
        nominal.to_json(out_dir / "result_nominal.json")

    t0 = time.perf_counter()
    write_report(out_dir / "result.json", out_dir / "report.html", observations=out_dir / "observations.json")
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
    console.print("timings: " + ", ".join(f"{k} {v:.1f} s" for k, v in timings.items()), highlight=False)
    console.print(escape(f"wrote {out_dir}/: " + ", ".join(written)), highlight=False)
    return rows


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
    table.add_row("rms reprojection", *(f"{r.stats.get('rms_px', float('nan')):.3f} px" for r in (result, nominal)))
    return table


def plan_demo(
    cell_path: Path,
    out: Path,
    *,
    robot: str,
    stations: int,
    tool_stations: int,
    image_size: tuple[int, int] | None,
    kinematic_stations: int = 0,
) -> tuple[int, int, int]:
    """Plan the demo: ``handeye`` stations (ids ``s000…``), ``kinematics`` stations (ids ``k000…``, when
    ``kinematic_stations`` > 0: joint configurations spread over the arm's range, D-optimal for its
    kinematic parameters; the cell must name ``kinematics:`` and ``calibrate_kinematics:``), then ``tcp``
    stations (ids ``t000…``), one plan.

    Writes ``out`` (``jcalib.plan/1`` with a ``planner`` key per part). Returns the number of
    hand-eye, tool and kinematic stations kept (reachable, in view).
    """
    from jcalib.planning.layout import cell_layout
    from jcalib.io.plan import make_plan
    from jcalib.planning.stations import plan_cell
    from jcalib.io.atomic import write_json_atomic

    layout = cell_layout(cell_path, robot=robot, image_size=image_size)
    parts = [("s", plan_cell(layout, "handeye", num_stations=stations))]
    if kinematic_stations > 0:
        parts.append(("k", plan_cell(layout, "kinematics", num_stations=kinematic_stations)))
    parts.append(("t", plan_cell(layout, "tcp", num_stations=tool_stations)))
    poses = [s.T_base_flange for _, p in parts for s in p.plan.stations]
    ids = [f"{prefix}{k:03d}" for prefix, p in parts for k in range(len(p.plan))]
    plan = make_plan(poses, ids)
    write_json_atomic(out, {**plan.to_json(), "planner": [p.to_json(layout)["planner"] for _, p in parts]})
    counts = {prefix: len(p.plan) for prefix, p in parts}
    return counts["s"], counts["t"], counts.get("k", 0)


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


def demo(out_dir: Path, *, stations: int = 16, protocol: str = "kuka", image_size: str = "640x480",
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
