"""`jcalib calibrate` and `jcalib demo` as a user runs them: files in, result out, exit statuses.

The commands run in this process (``jcalib.app.cli.main`` with the arguments, in the folder of the files, stdout
and stderr captured apart): what the user sees, without a JAX import and a fresh compilation per command. One
bad input runs as a separate process (``process=True``), so that the exit status and stderr of a real process
are checked too.
"""

import contextlib
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.sim.scene import project_target, random_calibration_views

JCALIB = [sys.executable, "-c", "from jcalib.app.cli import main; main()"]
#: the checkout under test (a subprocess started elsewhere would import whichever jcalib is installed)
ROOT = Path(__file__).resolve().parents[2]
BOARD = Checkerboard(cols=9, rows=6, square=0.025)
CELL = """schema: jcalib.cell/1
cameras:
  cam0: {model: opencv5}
targets:
  board: {type: checkerboard, cols: 9, rows: 6, square: 0.025}
"""


def run(*args, cwd, process=False) -> subprocess.CompletedProcess:
    """``jcalib ARGS`` run in folder ``cwd``: its exit status, stdout and stderr; in this process unless ``process``."""
    args = [str(a) for a in args]
    if process:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
        return subprocess.run([*JCALIB, *args], capture_output=True, text=True, cwd=cwd, env=env)
    from jcalib.app.cli import main

    out, err, here = io.StringIO(), io.StringIO(), os.getcwd()
    try:
        os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            main(args)
        code = 0
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(["jcalib", *args], code, out.getvalue(), err.getvalue())


@pytest.fixture(scope="module")
def observations():
    rng = np.random.default_rng(11)
    cam = camera_from_opencv(np.array([[1000.0, 0, 640], [0, 1000, 480], [0, 0, 1]]),
                             np.array([-0.2, 0.05, 0, 0, 0]), (1280, 960))
    stations = []
    for i, T in enumerate(random_calibration_views(cam, BOARD.points, 10, rng=rng)):
        pix, _ = project_target(cam, T, BOARD.points)
        pix = pix + 0.2 * rng.standard_normal(pix.shape)
        stations.append({"id": f"s{i:02d}", "detections": [{
            "camera": "cam0", "target": "board", "point_index": list(range(54)), "pixels": pix.tolist()}]})
    return {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": [1280, 960]}},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}


def test_calibrate_writes_result_contract(tmp_path, observations):
    (tmp_path / "cell.yaml").write_text(CELL)
    (tmp_path / "obs.json").write_text(json.dumps(observations))
    proc = run("calibrate", "cell.yaml", "obs.json", "-o", "result.json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["schema"] == "jcalib.result/1"
    cam = result["cameras"]["cam0"]
    assert cam["model"] == "opencv5" and cam["image_size"] == [1280, 960]
    assert abs(cam["K"][0][0] - 1000.0) < 5 * cam["std"]["fx"] + 1e-9
    assert 0.1 < result["stats"]["sigma_px"] < 0.3  # simulated with 0.2 px
    assert result["provenance"]["input_hash"].startswith("sha256:")
    assert "fx" in proc.stdout


def _mutated(observations, fn):
    data = json.loads(json.dumps(observations))
    fn(data)
    return data


@pytest.mark.parametrize(
    "case, mutate, cell, status, needle",
    [
        # "nan" runs in a separate process (the exit status and stderr of a real `jcalib` process)
        ("nan", lambda d: d["stations"][1]["detections"][0]["pixels"][4].__setitem__(0, float("nan")), CELL, 2, "NaN"),
        ("three points", lambda d: d["stations"][2]["detections"][0].update(
            point_index=[0, 1, 2], pixels=d["stations"][2]["detections"][0]["pixels"][:3]), CELL, 2, "s02"),
        ("ids", lambda d: d["stations"][0]["detections"][0].update(point_index=list(range(1, 55))), CELL, 2,
         "out of range"),
        ("model", lambda d: None, CELL.replace("opencv5", "brown7"), 2, "brown7"),
        ("parallel", lambda d: [s["detections"][0].update(pixels=(np.asarray(BOARD.points[:, :2]) * 4000
                                + [200.0 + 10 * i, 150.0]).tolist()) for i, s in enumerate(d["stations"])],
         CELL, 3, "not observable"),
    ],
)
def test_bad_input_exit_status_and_message(tmp_path, observations, case, mutate, cell, status, needle):
    (tmp_path / "cell.yaml").write_text(cell)
    (tmp_path / "obs.json").write_text(json.dumps(_mutated(observations, mutate), allow_nan=True))
    proc = run("calibrate", "cell.yaml", "obs.json", "-o", "result.json", cwd=tmp_path, process=case == "nan")
    assert proc.returncode == status, (case, proc.stderr)
    assert needle.lower() in proc.stderr.lower(), proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "result.json").exists()


def test_demo_short_run_matches_truth(tmp_path):
    """A shortened `jcalib demo --camera-only`: rendered images -> detection -> calibration within its σ of truth."""
    proc = run("demo", "--camera-only", "--views", "8", "--out", tmp_path / "demo", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    from jcalib.app.demo_camera import DEMO_DIST, DEMO_K

    result = json.loads((tmp_path / "demo" / "result.json").read_text())
    cam = result["cameras"]["cam0"]
    truth = dict(fx=DEMO_K[0, 0], fy=DEMO_K[1, 1], cx=DEMO_K[0, 2], cy=DEMO_K[1, 2],
                 **dict(zip(("k1", "k2", "p1", "p2", "k3"), DEMO_DIST)))
    estimate = dict(fx=cam["K"][0][0], fy=cam["K"][1][1], cx=cam["K"][0][2], cy=cam["K"][1][2],
                    **dict(zip(("k1", "k2", "p1", "p2", "k3"), cam["dist"])))
    # 9 parameters, each within 4.5 σ (two-sided 99.999 %): a wrong σ or a biased detector fails.
    for name, t in truth.items():
        assert abs(estimate[name] - t) < 4.5 * cam["std"][name], name
    import cv2

    fs = cv2.FileStorage(str(tmp_path / "demo" / "cam0_opencv.yaml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(fs.getNode("camera_matrix").mat(), np.asarray(cam["K"]), rtol=1e-9)


def test_too_simple_lens_model_is_flagged(tmp_path, observations):
    """A pinhole fitted to a lens with k1 = -0.2 cannot reach the corner noise: the result says so."""
    (tmp_path / "cell.yaml").write_text(CELL.replace("opencv5", "pinhole"))
    (tmp_path / "obs.json").write_text(json.dumps(observations))
    proc = run("calibrate", "cell.yaml", "obs.json", "-o", "result.json", "--outlier-threshold", "0", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["stats"]["rms_px"] > 1.25  # 5x the stated 0.25 px
    assert any("lens model is probably too simple" in w for w in result["stats"]["warnings"])
    assert "warning" in proc.stdout
