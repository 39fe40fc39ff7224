"""Every option of ``jcalib calibrate`` has an effect on every kind of cell, or is refused by name.

Issue 16: "Every CLI option has an effect on every cell kind or a refusal; a test walks the option x
cell-kind matrix". For each kind of cell (tiny synthetic data: a few stations each) the command runs
once with its defaults and once per option set to a value other than its default; the option run
must either write a different result (estimates, covariances or statistics; the provenance, which
records the options, is left out of the comparison) or exit with status 2 and a message that names
the option. An option that is silently dropped fails the test.

Values are chosen to differ from the effective default: a rig's ``--reference-camera`` is a camera
other than the first; a cell with one camera has no other camera to name, so an unknown name is given
and must be refused by name. The data carry what data-dependent options act on: a gross corner /
tip outlier (``--outlier-threshold``, ``--loss``, ``--loss-scale``), noisy robot poses with the
cell's ``pose_noise`` (``--pose-model``).

Runs are in-process (``jcalib.app.cli.main`` with ``sys.argv``), as a user's shell would run them;
one test per kind of cell, so that pytest-xdist spreads the kinds over its workers. Most runs reuse
the kind's compiled solve; options that change the problem's structure or a static solver setting
(``--loss``, ``--max-iterations``, ``--pose-model``, ``--noise`` with variance components,
``--prior``, ``--reference-camera``) compile their own.

``KNOWN_GAPS`` lists the (kind, option) pairs whose effect these data cannot show; each is a strict
xfail, so that the day it shows an effect (or is refused) the gap must be removed from the list.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.geometry.cameras import Pinhole
from jcalib.sim.cells import synthetic_cell, synthetic_two_robot_cell
from jcalib.sim.scene import project_target, random_calibration_views

_path = Path(__file__).resolve().parents[1] / "problems" / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_matrix", _path)
J = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(J)

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
SIZE = (1280, 960)
ROBOT_NOISE = {"translation_m": 1e-4, "rotation_deg": 0.01}


def _rot(rotvec) -> np.ndarray:
    return Rotation.from_rotvec(rotvec).as_matrix()


def _pose(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _perturb(T, rng, sigma_m=1e-4, sigma_deg=0.01):
    d = _pose(_rot(np.radians(sigma_deg) * rng.standard_normal(3)), sigma_m * rng.standard_normal(3))
    return T @ d


# ------------------------------------------------------------------------------------ cells


def camera_rig(num_cameras: int, seed: int):
    """``num_cameras`` cameras without a robot (a rig; one camera: camera-only) seeing a board in 6
    stations, 0.2 px noise, one corner 25 px off."""
    rng = np.random.default_rng(seed)
    cams = {f"cam{i}": camera_from_opencv(np.array([[900.0 + 30 * i, 0, 640], [0, 905.0, 480], [0, 0, 1]]),
                                          np.array([-0.2, 0.05, 0, 0, 0]), SIZE) for i in range(num_cameras)}
    T_ci_c0 = [_pose(_rot([0.0, -0.08 * i, 0.0]), [-0.1 * i, 0.0, 0.005 * i]) for i in range(num_cameras)]
    stations = []
    for k, T in enumerate(random_calibration_views(cams["cam0"], BOARD.points, 30, rng=rng, fill=(0.25, 0.45))):
        seen = [project_target(cams[f"cam{i}"], T_ci_c0[i] @ T, BOARD.points) for i in range(num_cameras)]
        if not all(vis.all() for _, vis in seen):
            continue
        dets = []
        for i, (pix, _) in enumerate(seen):
            pix = pix + 0.2 * rng.standard_normal(pix.shape)
            if len(stations) == 2 and i == 0:
                pix[10] += [25.0, -10.0]
            dets.append({"camera": f"cam{i}", "target": "board", "point_index": list(range(len(BOARD.points))),
                         "pixels": pix.tolist()})
        stations.append({"id": f"s{len(stations):02d}", "detections": dets})
        if len(stations) == 6:
            break
    assert len(stations) == 6
    cell = {"schema": "jcalib.cell/1", "cameras": {n: {"model": "opencv5"} for n in cams},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}
    obs = {"schema": "jcalib.observations/1", "cameras": {n: {"image_size": list(SIZE)} for n in cams},
           "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}
    return cell, obs


def hand_eye(mount: str, seed: int):
    """Eye-in-hand (``mount="flange"``) or eye-to-hand (``"base"``): 7 stations, robot pose noise
    stated in the cell, one corner 25 px off."""
    cell, obs, _ = J.make_data(seed, mount, n=7, sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    obs["stations"][3]["detections"][0]["pixels"][12][0] += 25.0
    return cell, obs


TIP = np.array([0.015, -0.01, 0.16])  # in the flange, m
TOOL_AXIS = np.array([0.1, -0.05, 1.0]) / np.linalg.norm([0.1, -0.05, 1.0])  # flange frame


def tcp_from_tips(seed: int):
    """A tool's tip (and its imaged axis) seen by one fixed, calibrated camera at 8 flange poses
    turned about the tip; robot pose noise stated; one tip detection 20 px off."""
    rng = np.random.default_rng(seed)
    cam = Pinhole((1280, 1024), focal=(2400.0, 2410.0), principal_point=(641.0, 509.5))
    T_base_cam = _pose(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]) @ _rot([0.02, -0.03, 0.01]),
                       [0.0, 0.0, 0.0])
    T_base_cam[:3, 3] = np.array([0.6, 0.0, 0.3]) - 0.4 * T_base_cam[:3, 2]
    R0 = np.diag([1.0, -1.0, -1.0]) @ _rot(np.radians([4.0, -3.0, 25.0]))
    stations = []
    for k in range(8):
        phi = k * np.pi / 4
        axis = np.array([np.cos(np.pi / 4) * (1.0 if k % 2 else -1.0), 0.7 * np.cos(phi), 0.7 * np.sin(phi)])
        R = _rot(axis / np.linalg.norm(axis) * np.pi / 8 * (1.0 if k % 3 else -1.0)) @ R0
        T_true = _pose(R, np.array([0.6, 0.0, 0.3]) + rng.uniform(-0.01, 0.01, 3) - R @ TIP)

        def pixel(p_flange):
            p = T_true[:3, :3] @ p_flange + T_true[:3, 3]
            pc = (p - T_base_cam[:3, 3]) @ T_base_cam[:3, :3]
            return np.asarray(cam.project(pc))

        tip = pixel(TIP) + 0.2 * rng.standard_normal(2)
        if k == 5:
            tip = tip + [20.0, 0.0]
        axis_px = np.stack([pixel(TIP - s * TOOL_AXIS) for s in (0.01, 0.02, 0.03)])
        axis_px = axis_px + 0.3 * rng.standard_normal(axis_px.shape)
        stations.append({"id": f"p{k}", "T_base_flange": _perturb(T_true, rng).tolist(),
                         "detections": [{"camera": "cam", "tool": "tcp", "pixel": tip.tolist(),
                                         "axis": axis_px.tolist()}]})
    K = [[2400.0, 0.0, 641.0], [0.0, 2410.0, 509.5], [0.0, 0.0, 1.0]]
    cell = {"schema": "jcalib.cell/1",
            "cameras": {"cam": {"model": "pinhole", "mount": "base", "pose": T_base_cam.tolist(),
                                "intrinsics": {"K": K, "dist": []}, "fix": ["fx", "fy", "cx", "cy"]}},
            "targets": {}, "tools": {"tcp": {"observed_by": ["cam"]}}, "robot": {"pose_noise": ROBOT_NOISE},
            "fixed": ["cam"]}
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [1280, 1024]}}, "targets": {},
           "stations": stations}
    return cell, obs


def pivot(seed: int):
    """A needle touching one divot at 8 tilted flange poses (robot pose noise stated)."""
    rng = np.random.default_rng(seed)
    tip, divot = np.array([0.012, -0.004, 0.185]), np.array([0.62, 0.11, 0.05])
    stations = []
    for k in range(8):
        tilt = np.r_[rng.standard_normal(2), 0.0]
        R = _rot([0, 0, rng.uniform(-np.pi, np.pi)]) @ _rot(tilt / np.linalg.norm(tilt) * np.radians(rng.uniform(5, 30)))
        R = R @ _rot([np.pi, 0, 0])
        stations.append({"id": f"c{k}", "T_base_flange": _perturb(_pose(R, divot - R @ tip), rng).tolist(),
                         "detections": [], "contacts": [{"tool": "needle", "point": "divot"}]})
    cell = {"schema": "jcalib.cell/1", "cameras": {}, "targets": {}, "tools": {"needle": {"observed_by": []}},
            "points": {"divot": {}}, "robot": {"pose_noise": ROBOT_NOISE}}
    obs = {"schema": "jcalib.observations/1", "cameras": {}, "targets": {}, "stations": stations}
    return cell, obs


def pose_pairs(seed: int):
    """Hand-eye from 6-DOF pose measurements (a camera measuring a marker's pose, no pixels): 8 stations."""
    rng = np.random.default_rng(seed)
    X = _pose(_rot([0.3, -0.2, 0.5]), [0.05, -0.02, 0.1])  # T_flange_cam
    Y = _pose(_rot([np.pi, 0, 0]), [0.8, 0.1, 0.0])  # T_base_target
    stations = []
    for k in range(8):
        T_target_cam = _pose(_rot(rng.uniform(-0.6, 0.6, 3)) @ _rot([np.pi, 0, 0]),
                             [*rng.uniform(-0.1, 0.1, 2), rng.uniform(0.4, 0.7)])
        T_bf = Y @ T_target_cam @ np.linalg.inv(X)
        T_ct = _perturb(np.linalg.inv(T_target_cam), rng, 5e-4, 0.05)
        stations.append({"id": f"s{k}", "T_base_flange": T_bf.tolist(), "detections": [],
                         "poses": [{"camera": "cam", "target": "marker", "T_cam_target": T_ct.tolist()}]})
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "pinhole", "mount": "flange"}},
            "targets": {"marker": {"type": "points", "mount": "base"}}, "robot": {}}
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [640, 480]}}, "targets": {},
           "stations": stations}
    return cell, obs


def whole_cell(seed: int):
    cell, obs, _ = synthetic_cell(seed, num_board_stations=6, num_tool_stations=8)
    det = next(d for d in obs["stations"][2]["detections"] if d.get("camera") == "cam0")
    det["pixels"][4][0] += 25.0
    return cell, obs


def two_robots(seed: int):
    """The synthetic two-robot cell without its tool and cross stations (fewer factor groups: a cheaper
    compilation; the tool is the whole cell's): r1's flange camera sees the world board, the world
    camera sees it and the board r2 carries."""
    cell, obs, _ = synthetic_two_robot_cell(seed, num_board_stations=5, num_r2_stations=5, num_cross_stations=0,
                                            num_tool_stations=0)
    cell["tools"] = {}
    obs["stations"] = [s for s in obs["stations"] if not any("tool" in d for d in s["detections"])]
    det = next(d for d in obs["stations"][1]["detections"] if d.get("camera") == "cam0")
    det["pixels"][4][0] += 25.0
    return cell, obs


KINDS = {
    "camera_only": lambda: camera_rig(1, 1),
    "stereo_rig": lambda: camera_rig(2, 2),
    "eye_in_hand": lambda: hand_eye("flange", 3),
    "eye_to_hand": lambda: hand_eye("base", 4),
    "tcp_from_tips": lambda: tcp_from_tips(5),
    "pivot_contacts": lambda: pivot(6),
    "pose_pairs": lambda: pose_pairs(7),
    "whole_cell": lambda: whole_cell(8),
    "two_robots": lambda: two_robots(9),
}

# ------------------------------------------------------------------------------------ options

#: option -> its command-line arguments (a value other than the default).
OPTIONS = {
    "sigma_px": ["--sigma-px", "0.5"],
    "tip_sigma_px": ["--tip-sigma-px", "0.5"],
    "axis_sigma_px": ["--axis-sigma-px", "1.0"],
    "contact_sigma_m": ["--contact-sigma-m", "1e-4"],
    "pose_sigma_deg": ["--pose-sigma-deg", "0.2"],
    "pose_sigma_m": ["--pose-sigma-m", "2e-3"],
    "noise": ["--noise", "stated"],
    "loss": ["--loss", "huber"],
    "loss_scale": ["--loss-scale", "1.5"],
    "outlier_threshold": ["--outlier-threshold", "0"],
    "reseed_views": ["--no-reseed-views"],
    "pose_model": ["--no-pose-model"],
    "method": ["--method", "tsai_lenz"],
    "max_iterations": ["--max-iterations", "2"],
    "reference_camera": None,  # per cell: see reference_camera_args
    "fix_unobservable": ["--fix-unobservable"],
    "unobservable_prior_m": ["--unobservable-prior-m", "0.01"],
    "unobservable_prior_sigma_m": ["--unobservable-prior-sigma-m", "1e-3"],
    "prediction": ["--no-prediction"],
    "prior": None,  # per cell: the default run's own result
}


def reference_camera_args(cell: dict) -> list[str]:
    cams = list(cell["cameras"])
    return ["--reference-camera", cams[1] if len(cams) > 1 else "no_such_camera"]


def test_every_calibrate_option_is_in_the_matrix():
    """The matrix covers every option of ``jcalib calibrate`` (a new option must join it)."""
    import typer.main

    from jcalib.app.cli import app

    command = typer.main.get_command(app).commands["calibrate"]
    names = {p.name for p in command.params if p.param_type_name == "option"} - {"out"}
    assert names == set(OPTIONS)


# ------------------------------------------------------------------------------------ runs


def run_cli(args: list[str]) -> tuple[int, str]:
    """``jcalib <args>`` in this process: (exit status, stderr)."""
    import contextlib
    import io

    from jcalib.app.cli import main

    argv, err = sys.argv, io.StringIO()
    sys.argv = ["jcalib", *args]
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            main()
        code = 0
    except SystemExit as e:
        code = int(e.code or 0)
    finally:
        sys.argv = argv
    return code, " ".join(err.getvalue().split())


def content(path: Path) -> dict:
    """A result file without its provenance (which records the options and the time)."""
    data = json.loads(path.read_text())
    data.pop("provenance")
    return data


def differs(a, b, rtol: float = 1e-9) -> bool:
    """Whether two result trees differ: any key or string, or a number beyond ``rtol`` (float noise of
    an identical computation is exactly zero; 1e-9 keeps an option whose only trace is rounding out)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() != b.keys() or any(differs(a[k], b[k], rtol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) != len(b) or any(differs(x, y, rtol) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return not abs(a - b) <= rtol * max(abs(a), abs(b)) and not (a != a and b != b)
    return a != b


@pytest.fixture(autouse=True)
def _release_compiled_code_per_kind():
    """Drop JAX's compiled functions after each kind: the matrix compiles dozens of solves, and every
    XLA:CPU executable holds memory mappings (a process reaches vm.max_map_count and crashes)."""
    yield
    jax.clear_caches()


def walk(kind: str, folder: Path, options=OPTIONS) -> dict[str, tuple[int, str, bool]]:
    """Run the default and every option of ``options`` on ``kind``: option -> (exit status, stderr,
    result differs from the default run)."""
    cell, obs = KINDS[kind]()
    (folder / "cell.yaml").write_text(json.dumps(cell))  # JSON is YAML
    (folder / "obs.json").write_text(json.dumps(obs))
    base = [str(folder / "cell.yaml"), str(folder / "obs.json")]
    code, err = run_cli(["calibrate", *base, "-o", str(folder / "default.json")])
    assert code == 0, (kind, err)
    default = content(folder / "default.json")
    out = {}
    for option in options:
        args = OPTIONS[option]
        if option == "reference_camera":
            args = reference_camera_args(cell)
        elif option == "prior":
            args = ["--prior", str(folder / "default.json")]
        path = folder / f"{option}.json"
        code, err = run_cli(["calibrate", *base, "-o", str(path), *args])
        out[option] = (code, err, code == 0 and differs(content(path), default))
    return out


#: (kind, option) whose effect these data cannot show, with why; each has a strict xfail test below.
KNOWN_GAPS = {
    ("camera_only", "reseed_views"): "re-seeding acts only on a view that started in the flipped planar-PnP minimum "
                                     "and whose re-started solve lowers the cost; the views here (and every synthetic "
                                     "set tried) start right, and the result does not record the views it checked",
    ("stereo_rig", "reseed_views"): "as for camera_only (a re-started solve that lands in the same minimum, lower "
                                    "by rounding only, is not taken: RESEED_MIN_DECREASE)",
}


#: the two largest cells, whose walk compiles a whole-cell solve per structural option (1.5-2 min
#: each on 2 cores with an empty compilation cache), and eye-to-hand (the eye-in-hand walk with the
#: camera on the base: the same options and residual kinds): run with ``pytest -m slow
#: tests/cli/test_option_matrix.py``. The default run walks the other six, which hold every residual
#: kind between them (corners, tips and axes, contacts, pose measurements, robot poses).
SLOW_KINDS = ("two_robots", "whole_cell", "eye_to_hand")


#: (kind, option) -> (exit status, stderr, changed) of the known gaps, run in their kind's walk (which has the
#: default run and its compiled solve at hand), for test_known_gaps in the same process.
GAP_RUNS: dict[tuple[str, str], tuple[int, str, bool]] = {}


@pytest.mark.parametrize(
    "kind", [pytest.param(k, marks=pytest.mark.slow) if k in SLOW_KINDS else k for k in KINDS])
def test_each_option_has_an_effect_or_is_refused_by_name(kind, tmp_path):
    silent, wrong = [], []
    runs = walk(kind, tmp_path)
    GAP_RUNS.update({(kind, o): runs.pop(o) for o in list(runs) if (kind, o) in KNOWN_GAPS})
    for option, (code, err, changed) in runs.items():
        flag = "--" + option.replace("_", "-")
        if code == 2:
            if flag not in err and option not in err:
                wrong.append(f"{option}: exit 2 without naming the option: {err[:200]}")
        elif code != 0:
            wrong.append(f"{option}: exit {code}: {err[:200]}")
        elif not changed:
            silent.append(option)
    assert not wrong, wrong
    assert not silent, f"{kind}: options with no effect and no refusal: {silent}"


@pytest.mark.parametrize(("kind", "option"), list(KNOWN_GAPS))
@pytest.mark.xfail(strict=True, reason="no effect on these data and not refused (KNOWN_GAPS)")
def test_known_gaps(kind, option, tmp_path):
    """The gap's run from its kind's walk above when it ran in this process (else a walk of its own)."""
    code, err, changed = GAP_RUNS.get((kind, option)) or walk(kind, tmp_path, [option])[option]
    assert changed or (code == 2 and ("--" + option.replace("_", "-") in err or option in err)), KNOWN_GAPS[kind, option]
