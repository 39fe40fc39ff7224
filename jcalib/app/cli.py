"""The ``jcalib`` command. Thin: parse arguments, call one public function, print or write its result.

Heavy imports (JAX, OpenCV) happen inside the commands, so ``jcalib --help`` is instant.
Exit statuses: 0 success, 2 bad input, 3 data cannot determine the unknowns, 4 device error.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

import jcalib
from jcalib.app.checks import SEED, count, number
from jcalib.errors import JcalibError
from jcalib.io.outputs import check_output_dir, check_outputs


def enable_compilation_cache() -> None:
    """JAX's persistent compilation cache (imported here, not at the top: ``--help`` stays instant)."""
    from jcalib.solve.cache import enable_compilation_cache as enable

    enable()


app = typer.Typer(
    name="jcalib",
    help="Calibrate robot cells: cameras, hand-eye, TCP — one joint problem, honest uncertainty.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"jcalib {jcalib.__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(
    version: Annotated[
        bool, typer.Option("--version", help="Print the version and exit.", is_eager=True, callback=_print_version)
    ] = False,
) -> None:
    """Calibrate robot cells: cameras, hand-eye, TCP — one joint problem, honest uncertainty."""


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder for the session, results, report and exports.")] = Path(
        "demo-output"
    ),
    stations: Annotated[int, typer.Option(callback=count(1), help="The most robot stations (board views and tool stations) the plan "
                                          "may take; it stops when the cell's goals are predicted met.")] = 30,
    protocol: Annotated[str, typer.Option(help="Simulated robot controller: kuka (KUKAVARPROXY, a KR 10), abb (an IRB "
                                              "4600) or ur (RTDE + URScript, a UR5e).")] = "kuka",
    image_size: Annotated[str, typer.Option(help="Simulated camera resolution WIDTHxHEIGHT.")] = "640x480",
    seed: Annotated[int, typer.Option(callback=SEED, help="Random seed of the simulated cell.")] = 0,
    camera_only: Annotated[
        bool, typer.Option(help="Only the rendered single-camera calibration (no robot, no network).")
    ] = False,
    views: Annotated[int, typer.Option(callback=count(1), help="--camera-only: number of rendered views.")] = 20,
    kinematic_errors: Annotated[
        bool, typer.Option("--kinematic-errors", help="The simulated arm hides realistic kinematic errors (seeded by "
                           "--seed); calibrate its joint offsets, link lengths and twists with the cell, and compare "
                           "with a calibration that takes the nominal kinematics.")
    ] = False,
) -> None:
    """Run a whole simulated cell on loopback, calibrate it jointly, compare with the ground truth.

    A simulated robot, two fake GigE cameras (flange, fixed) and a torch the fixed camera sees: plan,
    capture, detect (board, tool tip), calibrate, report, export (RAPID, KRL, OpenCV), and a table of
    every estimate against the truth with its σ.

    The second camera needs its own loopback address, so the demo runs in a private network namespace
    (`unshare -n`, or `unshare -rn` when not root); nothing is broadcast on real interfaces.
    """
    check_output_dir("--out", out)
    enable_compilation_cache()
    if camera_only and kinematic_errors:
        from jcalib.errors import BadInputError

        raise BadInputError("--kinematic-errors needs the whole-cell demo (a robot); drop --camera-only")
    if camera_only:
        from jcalib.app.demo_camera import run_demo

        run_demo(out_dir=out, num_views=views, seed=seed)
        return
    from jcalib.app.demo_cell import demo as run_cell

    run_cell(out, stations=stations, protocol=protocol, image_size=image_size, seed=seed,
             kinematic_errors=kinematic_errors)


@app.command()
def detect(
    images: Annotated[Optional[list[Path]], typer.Argument(help="Image files, one station per image.")] = None,
    cell: Annotated[Optional[Path], typer.Option("--cell", help="Cell spec (jcalib.cell/1 YAML).")] = None,
    camera: Annotated[Optional[str], typer.Option("--camera", help="Camera id in the cell spec.")] = None,
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="Observations JSON to write.")] = None,
    target: Annotated[
        Optional[str], typer.Option("--target", help="Target id (default: the cell's only target).")
    ] = None,
    session: Annotated[
        Optional[Path],
        typer.Option("--session", help="Capture session: detect in all its images (cell, -o optional)."),
    ] = None,
    jobs: Annotated[
        Optional[int], typer.Option("--jobs", "-j", help="Worker processes (default: every core; 1: none).")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an -o file that is not observations.json.")] = False,
) -> None:
    """Detect the cell's calibration target in images (or a capture session) and write observations.json."""
    from jcalib.io.replace import check_replaceable

    if jobs is not None and jobs < 1:
        from jcalib.errors import BadInputError

        raise BadInputError(f"--jobs: got {jobs}, expected an integer >= 1 (or leave it out: every core)")
    if session is not None:
        from jcalib.errors import BadInputError
        from jcalib.pipeline.session import detect_session_to_file

        if not session.is_dir():
            raise BadInputError(f"--session {session}: no such folder (expected a jcalib capture session)")
        check_outputs({"-o": out if out is not None else session / "observations.json"}, [cell, *(images or [])],
                      input_dirs={session: ["observations.json"]})  # fmt: skip
        check_replaceable("-o", out if out is not None else session / "observations.json", "jcalib.observations/1", force)
        detect_session_to_file(session, cell, out, target=target, jobs=jobs)
        return
    if not images or cell is None or camera is None or out is None:
        from jcalib.errors import BadInputError

        raise BadInputError("detect: give IMAGES with --cell, --camera and -o, or --session SESSION")
    check_outputs({"-o": out}, [cell, *images])
    check_replaceable("-o", out, "jcalib.observations/1", force)
    from jcalib.pipeline.images import detect_images_to_file

    detect_images_to_file(cell_path=cell, camera=camera, image_paths=images, out_path=out, target=target, jobs=jobs)


def _opt(help_: str, *flags: str):
    return typer.Option(*flags, help=help_)


@app.command()
def calibrate(
    cell: Annotated[Path, typer.Argument(help="Cell spec (jcalib.cell/1 YAML).")],
    observations: Annotated[Path, typer.Argument(help="Observations (jcalib.observations/1 JSON).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Result JSON to write.")],
    sigma_px: Annotated[Optional[float], _opt("Target-corner noise σ, pixels [0.25].")] = None,
    tip_sigma_px: Annotated[Optional[float], _opt("Tool-tip detection noise σ, pixels [0.25].")] = None,
    axis_sigma_px: Annotated[Optional[float], _opt("Tool-axis point noise σ across the axis, pixels [0.5].")] = None,
    contact_sigma_m: Annotated[Optional[float], _opt("Tool-tip contact noise σ per axis, m [5e-5].")] = None,
    pose_sigma_deg: Annotated[Optional[float], _opt("6-DOF pose measurement σ per rotation axis, deg [0.1].")] = None,
    pose_sigma_m: Annotated[Optional[float], _opt("6-DOF pose measurement σ per translation axis, m [1e-3].")] = None,
    noise: Annotated[Optional[str], _opt("Covariance scale: a_posteriori (variance components from the residuals) "
                                         "or stated [a_posteriori].")] = None,
    loss: Annotated[Optional[str], _opt("Robust loss on corners, tips, axis points, contacts: none, huber or cauchy "
                                        "[none].")] = None,
    loss_scale: Annotated[Optional[float], _opt("Robust loss scale, in σ [3].")] = None,
    outlier_threshold: Annotated[Optional[float], _opt("Reject measurements beyond this many σ of their kind "
                                                       "(0 keeps every measurement) [5].")] = None,
    reseed_views: Annotated[Optional[bool], _opt("Re-start far-off views of free targets from their other PnP pose "
                                                 "[on].", "--reseed-views/--no-reseed-views")] = None,
    pose_model: Annotated[Optional[bool], _opt("Estimate per-station robot pose errors under the robot's pose_noise "
                                               "[as the cell says].", "--pose-model/--no-pose-model")] = None,
    method: Annotated[Optional[str], _opt("Closed-form hand-eye start: park_martin, tsai_lenz, horaud, andreff or "
                                          "daniilidis [park_martin].")] = None,
    max_iterations: Annotated[Optional[int], _opt("Levenberg–Marquardt iterations per solve [100].")] = None,
    reference_camera: Annotated[Optional[str], _opt("Camera whose frame is the rig frame (cells without robots) "
                                                    "[the first].")] = None,
    fix_unobservable: Annotated[Optional[bool], _opt("Hold a hand-eye translation one-axis motion cannot determine "
                                                     "at a prior instead of failing.", "--fix-unobservable")] = None,
    unobservable_prior_m: Annotated[Optional[float], _opt("Prior value of that translation, m [0].")] = None,
    unobservable_prior_sigma_m: Annotated[Optional[float], _opt("Prior σ of that translation, m [1e-6].")] = None,
    prediction: Annotated[Optional[bool], _opt("Held-out prediction from the robot's poses (robot cells) [on].",
                                               "--prediction/--no-prediction")] = None,
    prior: Annotated[Optional[Path], _opt("Previous result.json: re-optimise (reuse what still holds, flag what moved "
                                          "by a χ² test).")] = None,
) -> None:
    """Calibrate a cell from observations and write result.json.

    Every option applies to every kind of cell; one the cell cannot use (e.g. --pose-model without a robot)
    is refused with a message naming it.
    """
    check_outputs({"-o": out}, [cell, observations, prior])
    if prior is not None:
        from jcalib.io.result import load_result

        load_result(prior)  # every input checked before the solve (the cell and observations in calibrate)
    enable_compilation_cache()
    from jcalib.problems.api import calibrate as run
    from jcalib.report.console import print_result

    given = {k: v for k, v in dict(
        sigma_px=sigma_px, tip_sigma_px=tip_sigma_px, axis_sigma_px=axis_sigma_px, contact_sigma_m=contact_sigma_m,
        pose_sigma_deg=pose_sigma_deg, pose_sigma_m=pose_sigma_m, noise=noise, loss=loss, loss_scale=loss_scale,
        outlier_threshold=outlier_threshold, reseed_views=reseed_views, pose_model=pose_model, method=method,
        max_iterations=max_iterations, reference_camera=reference_camera, fix_unobservable=fix_unobservable,
        unobservable_prior_m=unobservable_prior_m, unobservable_prior_sigma_m=unobservable_prior_sigma_m,
        prediction=prediction,
    ).items() if v is not None}
    if given.get("outlier_threshold") == 0:
        given["outlier_threshold"] = None
    result = run(cell, observations, given, prior=prior)
    result.to_json(out)
    print_result(result.file)
    typer.echo(f"wrote {out}")


@app.command()
def export(
    result: Annotated[Path, typer.Argument(help="Result JSON (jcalib.result/1).")],
    format: Annotated[str, typer.Option("--format", "-f", help="opencv, ros, rapid, krl, kinematics, urdf or "
                                                             "ur-calibration.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="File to write.")],
    camera: Annotated[Optional[str], typer.Option(help="Camera id (opencv, ros).")] = None,
    module: Annotated[Optional[str], typer.Option(help="RAPID module name (rapid).")] = None,
    robot: Annotated[Optional[str], typer.Option(help="Robot whose calibrated kinematics to export (kinematics: "
                                                      "default all; urdf, ur-calibration: needed when several).")] = None,
    tool_orientation: Annotated[
        Optional[list[str]],
        typer.Option(help="rapid, krl: TOOL=flange or TOOL=X,Y,Z (tool axis in the flange frame) for a tool whose "
                          "orientation was not calibrated; such tools are refused without it."),
    ] = None,
    at: Annotated[Optional[str], typer.Option(help="CAMERA.SETTING=VALUE: a zoom camera at one lens setting.")] = None,
    extrapolate: Annotated[bool, typer.Option(help="--at outside the calibrated range.")] = False,
) -> None:
    """Export a result for the cell: OpenCV YAML, ROS camera_info, ABB RAPID, KUKA KRL, or the calibrated robot
    kinematics as a cell-spec table with σ and controller offsets (kinematics), a URDF (urdf), or a UR arm's
    delta DH in the form of its calibration.conf (ur-calibration: for comparison and records; a UR arm's
    calibration is applied only by UR's own procedure)."""
    check_outputs({"-o": out}, [result])
    from jcalib.io.export import export_result
    from jcalib.io.export.formats import export_options

    if at is not None:
        from jcalib.app.lens_at import result_at

        result, camera = result_at(result, at, extrapolate, camera)
    options = export_options(format, camera=camera, module=module, robot=robot, tool_orientation=tool_orientation)
    path = export_result(result, format, out, **options)
    typer.echo(f"wrote {path}")


@app.command()
def convert(
    result: Annotated[Path, typer.Argument(help="Result JSON (jcalib.result/1).")],
    to: Annotated[str, typer.Option("--to", help="Target lens model: pinhole, opencv4, opencv5, opencv8, opencv12, "
                                                 "opencv14 or fisheye.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Result JSON to write, with the camera converted.")],
    camera: Annotated[Optional[str], typer.Option(help="Camera id (needed when the result has several).")] = None,
    region: Annotated[
        Optional[str], typer.Option(help="x0,y0,x1,y1 pixels to fit over (default: the whole image).")] = None,
    fix: Annotated[
        Optional[str], typer.Option(help="Coefficients of the target held at 0, e.g. k4,k5,k6.")] = None,
) -> None:
    """Convert a calibrated camera into another lens model over an image region, e.g. a fisheye into
    OpenCV's opencv8 for software that reads only that; prints the approximation error (px) and writes
    the result with the converted camera (its σ propagated from the source's)."""
    check_outputs({"-o": out}, [result])
    enable_compilation_cache()
    from jcalib.app.convert import run_convert

    run_convert(result, to, out, camera, region, fix)


@app.command()
def report(
    result: Annotated[Path, typer.Argument(help="Result JSON (jcalib.result/1).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="HTML file to write.")],
    observations: Annotated[
        Optional[Path],
        typer.Option(help="Observations (jcalib.observations/1) for the residual / coverage plots."),
    ] = None,
    cell: Annotated[
        Optional[Path],
        typer.Option(help="Cell spec (jcalib.cell/1): with --observations, adds the cross-validation section."),
    ] = None,
    plan: Annotated[
        Optional[Path],
        typer.Option(help="Goal-driven plan (`jcalib plan --kind optimal --goal ...`): adds the Goals table (goal, "
                          "predicted σ, achieved σ, met), also printed here."),
    ] = None,
) -> None:
    """Write a one-page, self-contained HTML report of a result (tables, warnings, plots)."""
    check_outputs({"-o": out}, [result, observations, cell, plan])
    _check_report_inputs(result, observations, cell)
    rows = None
    if plan is not None:
        from rich.console import Console

        from jcalib.io.plan import plan_goals
        from jcalib.problems.goals import goal_rows
        from jcalib.report.goals import goals_table

        goals, predicted = plan_goals(plan)
        rows = goal_rows(goals, result, predicted)
        Console().print(goals_table(rows))
    enable_compilation_cache()
    from jcalib.report.html import write_report

    path = write_report(result, out, observations=observations, cell=cell, goals=rows)
    typer.echo(f"wrote {path}")


@app.command()
def triangulate(
    observations: Annotated[Path, typer.Argument(help="Pixels of named points (jcalib.pixels/1 JSON).")],
    cell: Annotated[Path, typer.Option("--cell", help="Cell spec (jcalib.cell/1 YAML).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Points JSON (jcalib.pipeline.points/1) to write.")],
    result: Annotated[Optional[Path], typer.Option("--result", help="Calibration result with the cameras.")] = None,
    frame: Annotated[str, typer.Option(help="Output frame: base, flange, a camera id or a target id.")] = "base",
    station: Annotated[Optional[str], typer.Option(help="Station the frame refers to (not for base).")] = None,
    sigma_px: Annotated[Optional[float], typer.Option(help="Pixel noise σ per coordinate (default: file, 0.5).")] = None,
) -> None:
    """Triangulate named points seen by calibrated cameras; write them with σ (m, m²).

    \b
    OBSERVATIONS (jcalib.pixels/1; OpenCV pixels, 4x4 poses in m):
      {"schema": "jcalib.pixels/1", "sigma_px": 0.3,
       "cameras": {"cam1": {"image_size": [1280, 1024]}},
       "stations": [{"id": "s0", "T_base_flange": [[...4x4...]],
                     "pixels": {"cam0": {"p1": [812.4, 600.1]},
                                "cam1": {"p1": [402.0, 511.3]}}}]}

    Cameras (intrinsics, T_base_<cam> / T_flange_<cam>, covariances) come from --result, else from
    the cell; the cell's robot.pose_noise is each station's pose covariance. The σ includes pixel
    noise, intrinsics, camera and robot poses, with their correlations. OUT (jcalib.pipeline.points/1) holds
    the points, their joint covariance and the pairwise distances with σ.
    """
    check_outputs({"-o": out}, [observations, cell, result])
    enable_compilation_cache()
    from jcalib.pipeline.points import triangulate_file

    summary = triangulate_file(observations, cell, out, result=result, frame=frame, station=station,
                               sigma_px=sigma_px)  # fmt: skip
    for name, p in zip(summary.points.names, summary.points.points, strict=True):
        std = " ".join(f"{s:.3f}" for s in p.std * 1e3)
        typer.echo(f"{name}: {' '.join(f'{v:.6f}' for v in p.p_base)} m ({summary.frame}), σ {std} mm, "
                   f"rms {p.rms_px:.2f} px, {p.num_views} views")  # fmt: skip
    typer.echo(f"wrote {summary.path}")


@app.command()
def frame(
    points: Annotated[Path, typer.Argument(help="Points JSON (jcalib.pipeline.points/1, as triangulate writes).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Frame as a result JSON (jcalib.result/1).")],
    method: Annotated[str, typer.Option(help="three-point (origin, +X, +Y side) or plane (N-point fit).")] = "three-point",
    use: Annotated[Optional[str], typer.Option("--points", help="Point names to use, comma separated, in order.")] = None,
    name: Annotated[str, typer.Option(help="Name of the work object / base.")] = "wobj",
    origin: Annotated[str, typer.Option(help="three-point origin: first or foot.")] = "first",
    sigma_mm: Annotated[Optional[float], typer.Option(callback=number(0, 1000, "mm"),
                                                      help="Point σ (mm) where the file has no covariance.")] = None,
    export: Annotated[Optional[str], typer.Option(help="Also write rapid (wobjdata) or krl (BASE_DATA).")] = None,
    export_out: Annotated[Optional[Path], typer.Option(help="Export file (default: OUT with .mod / .dat).")] = None,
) -> None:
    """Fit a work-object frame to points; write it with its 6x6 covariance as a result file.

    \b
    POINTS (jcalib.pipeline.points/1 as triangulate writes it; m, m²; covariances optional):
      {"points": {"p1": {"position": \\[x, y, z], "frame": "base",
                         "covariance": [[3x3]]}, ...},
       "joint_covariance": {"points": \\[names], "matrix": [[3M x 3M]]}}

    three-point: origin, a point on +X, a point on the +Y side (ABB / KUKA 3-point method).
    plane: least-squares plane through all the points; +X from the first to the second point,
    the third on the +Y side, origin the first projected onto the plane. OUT holds
    T_<frame>_<name>; --export writes ABB wobjdata or KUKA BASE_DATA. Collinear points: exit 3.
    """
    if export is not None and export_out is None:
        export_out = out.with_suffix(".mod" if export == "rapid" else ".dat")
    check_outputs({"-o": out, "--export-out": export_out if export is not None else None}, [points])
    enable_compilation_cache()
    import math

    from jcalib.pipeline.points import frame_file

    names = None if use is None else [s.strip() for s in use.split(",") if s.strip()]
    summary = frame_file(points, out, method=method, use=names, name=name, origin=origin, sigma_mm=sigma_mm,
                         export=export, export_out=export_out)  # fmt: skip
    std = summary.frame.std
    if std is not None:
        typer.echo(f"{summary.transform}: σ rotation {' '.join(f'{math.degrees(s):.4f}' for s in std[:3])} deg, "
                   f"translation {' '.join(f'{s * 1e3:.3f}' for s in std[3:])} mm")  # fmt: skip
    typer.echo(f"wrote {summary.path}" + (f" and {summary.export_path}" if summary.export_path else ""))


@app.command("import")
def import_(
    format: Annotated[str, typer.Argument(help="industrial-calibration, calibration-rs, easy-handeye, moveit, opencv-pairs or rosbag.")],
    source: Annotated[Path, typer.Argument(help="The data set: file or folder (see the format).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Session folder to create.")],
    mount: Annotated[
        Optional[str],
        typer.Option(help="Where the camera is: flange (eye-in-hand) or base (eye-to-hand), for sources that do not say."),
    ] = None,
    option: Annotated[
        Optional[list[str]], typer.Option("--option", help="Format option KEY=VALUE (repeat); a wrong key lists the valid ones.")
    ] = None,
) -> None:
    """Turn another tool's data set into a capture session (images + robot poses + cell spec).

    Then `jcalib detect --session OUT` and `jcalib calibrate OUT/cell.yaml OUT/observations.json -o RESULT`.
    Each format states the conventions it assumes (frames, units, quaternion order) and refuses
    ambiguous input instead of guessing. OUT must be a new or empty folder outside the source; a
    failed import leaves nothing there. Paths in a manifest must stay inside the source folder
    (--option allow_outside=true where the format takes it).
    """
    from jcalib.io.importers import import_session, parse_options

    options = parse_options(format, option)  # unknown, repeated or colliding keys refused before any work
    summary = import_session(format, source, out, mount=mount, **options)
    for note in summary.notes:
        typer.echo(f"note: {note}", err=True)
    typer.echo(f"wrote {summary.out}: {summary.num_stations} stations, cameras {', '.join(summary.cameras)}")
    for step in summary.next_steps:
        typer.echo(f"next: {step}")


def _check_cell(cell: Path) -> None:
    """Read and validate a cell spec before a command hands its path to code that reads it again."""
    from jcalib.io.cell import load_cell

    load_cell(cell)


def _check_report_inputs(result: Path, observations: Path | None, cell: Path | None) -> None:
    from jcalib.io.result import load_result

    load_result(result)
    if observations is not None:
        from jcalib.io.observations import load_observations

        obs = load_observations(observations)
        if cell is not None:
            from jcalib.io.cell import load_cell
            from jcalib.io.schema import check_cell_observations

            check_cell_observations(load_cell(cell), obs)
    elif cell is not None:
        _check_cell(cell)


# --- acquisition commands (simulate, plan, capture) live below this line ---


@app.command()
def plan(
    cell: Annotated[Path, typer.Option("--cell", help="Cell spec (jcalib.cell/1 YAML).")],
    kind: Annotated[str, typer.Option("--kind", help="viewsets, handeye, tcp, kinematics or optimal.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Plan JSON (jcalib.plan/1) to write.")],
    robot: Annotated[Optional[str], typer.Option(help="Robot preset (default: the cell's robot.model).")] = None,
    stations: Annotated[Optional[int], typer.Option(callback=count(1), help="Candidate stations (unreachable ones are dropped); "
                                                         "kinematics: stations to plan (default 30).")] = None,
    camera: Annotated[Optional[str], typer.Option(help="Camera to plan for (viewsets, handeye, kinematics).")] = None,
    target: Annotated[Optional[str], typer.Option(help="Target to plan for (viewsets, handeye, kinematics).")] = None,
    tool: Annotated[Optional[str], typer.Option(help="Tool to plan for (tcp).")] = None,
    amplitude_deg: Annotated[Optional[float], typer.Option(callback=number(0, 90, "deg"), help="Largest tilt / rotation, degrees (kinematics: "
                                                                "largest view angle from the target normal, 45).")] = None,
    image_size: Annotated[Optional[str], typer.Option(help="WxH of cameras without intrinsics.")] = None,
    candidates: Annotated[Optional[int], typer.Option(callback=count(1, 100_000), help="kinematics: candidate configurations to choose from "
                                                           "(default 20 per station); optimal: candidate stations "
                                                           "(default 400).")] = None,
    seed: Annotated[int, typer.Option(callback=SEED, help="kinematics, optimal: random seed of the candidates.")] = 0,
    sigma_px: Annotated[Optional[float], typer.Option(callback=number(0, 10, "px"), help="kinematics, optimal: corner noise (px) assumed for the "
                                                           "predicted σ (default 0.2 / the calibration's 0.25).")] = None,
    goal: Annotated[Optional[list[str]], typer.Option("--goal", help="optimal: what must be accurate, "
                                                      "NAME:QUANTITY<=VALUE, e.g. T_flange_cam0:translation_mm<=0.05, "
                                                      "T_flange_cam0:rotation_deg<=0.01, T_flange_torch:position_mm<=0.02, "
                                                      "cam0:projection_px<=0.1 (repeatable; default: the cell's goals:).")] = None,
    max_stations: Annotated[Optional[int], typer.Option(callback=count(1, 500), help="optimal: most stations to plan (default 20); the plan "
                                                             "stops earlier when the goals are met.")] = None,
    lens_settings: Annotated[Optional[list[str]], typer.Option("--lens-settings", help="CAMERA.SETTING=V1,V2,...: "
                             "visit every station at each lens setting (a zoom lens, e.g. cam0.Zoom=100,300,500).")] = None,
) -> None:
    """Plan robot stations (flange poses) for camera, hand-eye, TCP or kinematic calibration, or for goals.

    kinematics: joint configurations that determine the kinematic parameters the cell calibrates
    (robot kinematics: and calibrate_kinematics:), chosen D-optimally from random candidates within the
    joint limits (and, with a flange camera or a flange target, with the target in view); the plan
    records each station's joints_deg and the predicted σ per parameter group.

    optimal: stations chosen to meet accuracy goals (--goal, or the cell's goals:): candidates within reach
    and joint limits that show a target or a tool tip, the predicted σ of every goal from the calibration's own
    builder, greedy selection with exchanges and a local refinement; prints the predicted σ after each station
    and stops when the goals are met.
    """
    check_outputs({"-o": out}, [cell])
    _check_cell(cell)
    enable_compilation_cache()
    from jcalib.workflow.devices import parse_image_size
    from jcalib.workflow.plan import check_plan_options, run_plan

    check_plan_options(kind, stations=stations, goal=goal, max_stations=max_stations, tool=tool, camera=camera,
                       target=target, candidates=candidates, sigma_px=sigma_px)
    from jcalib.app.lens_at import check_lens_specs, lens_plan

    check_lens_specs(lens_settings)
    planned = run_plan(cell, kind, out, robot=robot, num_stations=stations, camera=camera, target=target,
                       tool=tool, amplitude_deg=amplitude_deg, image_size=parse_image_size(image_size),
                       num_candidates=candidates, seed=seed, sigma_px=sigma_px, goals=goal,
                       max_stations=max_stations)  # fmt: skip
    for what, why in planned.dropped.items():
        typer.echo(f"dropped {why}: {what}" if kind in ("kinematics", "optimal") else f"dropped {what}: {why}",
                   err=True)
    if kind in ("kinematics", "optimal"):
        from jcalib.workflow.plan import kinematic_plan_lines, optimal_plan_lines

        for line in (kinematic_plan_lines if kind == "kinematics" else optimal_plan_lines)(planned):
            typer.echo(line)
    n = lens_plan(out, lens_settings) if lens_settings else len(planned.plan)
    typer.echo(f"wrote {out}: {n} stations ({kind})")


@app.command()
def simulate(
    cell: Annotated[Path, typer.Option("--cell", help="Cell spec (jcalib.cell/1 YAML).")],
    robot_protocol: Annotated[str, typer.Option("--robot-protocol", help="kuka, abb or ur.")],
    camera: Annotated[list[str], typer.Option("--camera", help="NAME=127.0.0.x, one per camera.")],
    robot_port: Annotated[Optional[int], typer.Option("--robot-port", help="TCP port on 127.0.0.1 (0: any free). "
                          "Optional with ur: UR's ports are fixed (RTDE 30004, URScript 30002); 0 puts both on "
                          "free ports.")] = None,
    truth: Annotated[Optional[Path], typer.Option("--truth", help="Write the ground truth here (JSON).")] = None,
    robot: Annotated[Optional[str], typer.Option(help="Robot preset (default: the cell's robot.model).")] = None,
    image_size: Annotated[Optional[str], typer.Option(help="WxH of cameras without intrinsics.")] = None,
    time_scale: Annotated[float, typer.Option(callback=number(0, 1000, "", lo_open=False),
                                              help="Motion-time scale (0: instantaneous moves).")] = 1.0,
    seed: Annotated[int, typer.Option(callback=SEED, help="Noise seed.")] = 0,
    noise: Annotated[
        str, typer.Option(help="Image noise: clean (bright, sharp) or realistic (dim, defocused, ~0.1 px corners).")
    ] = "clean",
    kinematic_errors: Annotated[
        Optional[int],
        typer.Option("--kinematic-errors", metavar="SEED", callback=SEED,
                     help="Hide seeded realistic kinematic errors (joint offsets, link lengths, twists) in the robot: "
                          "the controller reports its preset's kinematics, the cameras see the true arm; --truth "
                          "then holds the true parameters."),
    ] = None,
    kinematic_error_scale: Annotated[
        float, typer.Option(callback=number(0, 1000, "", lo_open=False),
                            help="--kinematic-errors: factor on their σ (1: ~0.05 deg, 0.5 mm).")
    ] = 1.0,
    fast_noise: Annotated[
        bool, typer.Option("--fast-noise", help="Draw sensor noise by its normal approximation (float32): a frame "
                           "of a still robot then costs ~20 ms at 1280x960, for live views (jcalib ui --simulate).")
    ] = False,
) -> None:
    """Run a simulated cell (robot server + fake GigE cameras) on loopback until interrupted."""
    check_outputs({"--truth": truth}, [cell])
    _check_cell(cell)
    enable_compilation_cache()
    import signal
    import threading

    from jcalib.app.simulate import run_simulate
    from jcalib.workflow.devices import parse_image_size, parse_named

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())

    def ready(info: dict) -> None:
        cams = " ".join(f"--camera {n}={u}" for n, u in info["cameras"].items())
        typer.echo(f"READY --robot {info['robot']} {cams}")
        sys.stdout.flush()

    run_simulate(cell, robot_protocol=robot_protocol, robot_port=robot_port, camera_addresses=parse_named(camera),
                 truth=truth, robot=robot, image_size=parse_image_size(image_size), time_scale=time_scale,
                 seed=seed, noise=noise, stop=stop, on_ready=ready, kinematic_errors=kinematic_errors,
                 kinematic_error_scale=kinematic_error_scale, fast_noise=fast_noise)  # fmt: skip


@app.command()
def capture(
    robot: Annotated[str, typer.Option("--robot", help="kuka://HOST[:PORT], abb://HOST[:PORT] or ur://HOST.")],
    camera: Annotated[list[str], typer.Option("--camera", help="NAME=gige://IPV4 (or replay://DIR), one per camera.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Session folder to write.")],
    plan: Annotated[Optional[Path], typer.Option("--plan", help="Station plan (jcalib.plan/1); or --goal.")] = None,
    cell: Annotated[Optional[Path], typer.Option("--cell", help="Cell spec, stored in the session.")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue the session in --out.")] = False,
    packet_size: Annotated[Optional[int], typer.Option(callback=count(576, 16384, "bytes"),
                                                       help="GigE packet size, bytes (jumbo: 8000+).")] = None,
    setting: Annotated[
        Optional[list[str]],
        typer.Option("--setting", help="CAMERA.FEATURE=VALUE, a GenICam feature set before capturing (e.g. "
                     "cam0.ExposureTime=5000); overrides the cell's cameras.<id>.settings; repeatable."),
    ] = None,
    kind: Annotated[
        str, typer.Option("--kind", help="stations (grab at each planned station) or tcp (servo the tool tip onto "
                          "the image centre at each station of a `plan --kind tcp` plan, then grab).")
    ] = "stations",
    goal: Annotated[
        Optional[list[str]],
        typer.Option("--goal", help="NAME:QUANTITY<=VALUE, e.g. T_flange_cam0:translation_mm<=0.05 (repeatable): "
                     "instead of --plan, choose each station as the capture goes, calibrate after each, stop when "
                     "every goal is achieved (needs --cell; without --plan and --goal, the cell's goals: are used).")
    ] = None,
    max_stations: Annotated[Optional[int], typer.Option(callback=count(1, 500),
                                                        help="--goal: most stations to capture [30].")] = None,
    image_size: Annotated[Optional[str], typer.Option(help="--goal: WxH of cameras without intrinsics.")] = None,
    seed: Annotated[int, typer.Option(callback=SEED, help="--goal: random seed of the candidate stations.")] = 0,
    candidates: Annotated[Optional[int], typer.Option(callback=count(1, 100_000),
                                                      help="--goal: candidate stations to choose from [400].")] = None,
) -> None:
    """Drive the robot through a plan (--plan), or adaptively until accuracy goals are met (--goal), grab every
    camera at every station, write a session."""
    check_output_dir("--out", out, [plan, cell], managed=("session.json", "stations.jsonl", ".lock", "images"))
    if not goal and plan is None and cell is not None:  # the cell's goals: stand in for --goal
        from jcalib.io.cell import load_cell

        goal = [g.text for g in load_cell(cell).goals] or None
    if goal:
        from jcalib.app.adaptive import capture_command

        capture_command(robot=robot, camera=camera, out=out, plan=plan, cell=cell, resume=resume,
                        packet_size=packet_size, setting=setting, kind=kind, goal=goal, max_stations=max_stations,
                        image_size=image_size, seed=seed, candidates=candidates, echo=typer.echo)
        return
    from jcalib.errors import BadInputError

    if plan is None:
        raise BadInputError("capture: give a station plan (--plan PLAN) or accuracy goals (--goal GOAL ...)")
    if max_stations is not None or image_size is not None or candidates is not None:
        raise BadInputError("--max-stations, --image-size and --candidates apply to adaptive capture (--goal); a "
                            "--plan capture visits the plan's stations")
    if cell is not None:
        _check_cell(cell)
    from jcalib.io.plan import load_plan

    load_plan(plan)
    from jcalib.workflow.capture import run_capture
    from jcalib.workflow.devices import parse_named, parse_settings

    res = run_capture(robot_url=robot, camera_urls=parse_named(camera), plan_path=plan, out=out, cell=cell,
                      resume=resume, packet_size=packet_size, settings=parse_settings(setting or []),
                      kind=kind)  # fmt: skip
    for sid, why in res.skipped.items():
        typer.echo(f"skipped {sid}: {why}", err=True)
    typer.echo(
        f"wrote {out}: {len(res.captured)} stations captured, {len(res.skipped)} skipped, "
        f"{res.already_done} already there ({res.elapsed_s:.1f} s)"
    )


@app.command()
def ui(
    cell: Annotated[Optional[Path], typer.Option("--cell", help="Cell spec (jcalib.cell/1 YAML) the app reads and, "
                                                 "when you edit it, writes.")] = None,
    session: Annotated[Path, typer.Option("--session", help="Capture session folder (created by the first capture; "
                                          "an existing one is continued).")] = Path("jcalib-session"),
    robot: Annotated[Optional[str], typer.Option("--robot", help="kuka://HOST[:PORT], abb://HOST[:PORT] or ur://HOST.")] = None,
    camera: Annotated[Optional[list[str]], typer.Option("--camera", help="NAME=gige://IPV4 (or replay://DIR), "
                                                         "one per camera.")] = None,
    simulate: Annotated[bool, typer.Option("--simulate", help="Start the simulated cell of `jcalib demo` (a KUKA "
                                           "robot and two GigE cameras in a private network namespace).")] = False,
    port: Annotated[Optional[int], typer.Option("--port", help="TCP port [8765, or the next free one; 0: any].")] = None,
    host: Annotated[str, typer.Option("--host", help="Address to listen on; an address other than loopback lets "
                                      "other machines reach the app (the token still guards every request).")]
    = "127.0.0.1",
    image_size: Annotated[str, typer.Option(help="--simulate: WxH of the simulated cameras without intrinsics (the "
                                          "demo's 640x480: the tool stations are planned for what it shows).")]
    = "640x480",
    seed: Annotated[int, typer.Option(help="--simulate: noise seed of the simulated cell.")] = 0,
) -> None:
    """Start the operator's web app: live view, plan and capture toward goals, calibrate and inspect, export.

    Prints the URL with its access token (open it in a browser on this machine). Stop it with Ctrl-C.
    """
    from jcalib.errors import BadInputError

    if port is not None and not 0 <= port <= 65535:
        raise BadInputError(f"--port: expected 0..65535, got {port}")
    if seed < 0:
        raise BadInputError(f"--seed: expected a seed >= 0, got {seed}")
    if cell is not None:
        _check_cell(cell)
    cameras = {}
    if camera:
        from jcalib.workflow.devices import check_urls, parse_named

        cameras = parse_named(camera)
        check_urls(robot, cameras)
    elif robot:
        from jcalib.workflow.devices import check_urls

        check_urls(robot, {})
    from jcalib.workflow.devices import parse_image_size

    parse_image_size(image_size)
    enable_compilation_cache()
    from jcalib.ui.launch import run_ui

    code = run_ui(cell=cell, session=session, robot=robot, cameras=cameras, simulate=simulate, port=port, host=host,
                  image_size=image_size, seed=seed, print_url=typer.echo)
    if code:
        raise typer.Exit(code)


@app.command()
def schema(
    name: Annotated[str, typer.Argument(help="cell, observations, result, session, station (a stations.jsonl line), "
                                             "plan or exclusions.")],
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="Write it to FILE instead of stdout.")] = None,
) -> None:
    """Print the JSON Schema (draft 2020-12) of a file format, for editors and validators."""
    from jcalib.io.schema.export import schema_command

    schema_command(name, out)


def _register_study() -> None:
    from jcalib.app.study import study_command

    app.command("study")(study_command)


_register_study()


def _register_compare() -> None:
    from jcalib.app.compare import compare_command, cross_validate_command

    app.command("compare")(compare_command)
    app.command("cross-validate")(cross_validate_command)


_register_compare()
from jcalib.app.sensitivity import sensitivity_command  # noqa: E402 (typer only: --help stays instant)
app.command("sensitivity")(sensitivity_command)


def _printable(text: str) -> str:
    """``text`` with control characters (terminal escapes, carriage returns) shown as escapes."""
    return "".join(c if c in "\n\t" or (ord(c) >= 32 and ord(c) != 127 and not 0x80 <= ord(c) < 0xA0)
                   else repr(c)[1:-1] for c in text)


def _print_error(prefix: str, message: str, style: str = "bold red") -> None:
    """Print ``prefix`` + ``message`` on stderr; the message is plain text (no rich markup)."""
    from rich.console import Console
    from rich.text import Text

    Console(stderr=True, soft_wrap=True, highlight=False, emoji=False).print(
        Text.assemble((prefix, style), _printable(message)))


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    from jcalib.errors import InputWarning

    if issubclass(category, InputWarning):
        _print_error("jcalib warning: ", str(message), style="bold yellow")
    else:
        _default_showwarning(message, category, filename, lineno, file, line)


_default_showwarning = None


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: exit status 0 on success, 2 on bad input (a jcalib error or a
    usage error: click's usage message), 3 not observable, 4 device error, 130 interrupted; never
    a traceback (an unexpected error is reported as a bug, its traceback shown with JCALIB_DEBUG=1)."""
    import warnings

    from jcalib.errors import InputWarning

    global _default_showwarning
    # Small numpy solves (closed forms) run far slower with a multithreaded BLAS on busy cores.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        with warnings.catch_warnings():
            _default_showwarning = warnings.showwarning
            warnings.simplefilter("always", InputWarning)
            warnings.showwarning = _show_warning  # jcalib's warnings as one plain line on stderr
            app(args=argv, prog_name="jcalib", standalone_mode=True)
    except JcalibError as e:
        _print_error("jcalib error: ", str(e))
        sys.exit(e.exit_code)
    except SystemExit:
        raise
    except (Exception, RecursionError, MemoryError) as e:  # a bug: say so in one paragraph
        if os.environ.get("JCALIB_DEBUG"):
            raise
        _print_error("jcalib internal error (a bug, please report it with the command and its input files): ",
                     f"{type(e).__name__}: {str(e)[:500]}; run with JCALIB_DEBUG=1 for the traceback")
        sys.exit(1)
