"""`jcalib calibrate` on degenerate hand-eye data, as a user runs it: exit status 3 and a message
naming the undetermined unknown, no traceback."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

_path = Path(__file__).resolve().parents[1] / "problems" / "test_handeye_degenerate.py"
_spec = importlib.util.spec_from_file_location("_handeye_degenerate_helpers_cli", _path)
D = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(D)

JCALIB = [sys.executable, "-c", "from jcalib.app.cli import main; main()"]


def _few_stations():
    cell, obs, _ = D.J.make_data(4, "flange", n=5)
    obs["stations"] = obs["stations"][:2]
    return D.J.with_known_intrinsics(cell), obs


def _one_axis():
    """Rotations about the flange x axis only (not the base z), translations of all kinds."""
    cell, obs, _ = D.scara_data(8)
    rng = np.random.default_rng(8)
    T0 = np.asarray(obs["stations"][0]["T_base_flange"])
    for st, ang in zip(obs["stations"], np.linspace(-30, 30, len(obs["stations"]))):
        c, s = np.cos(np.radians(ang)), np.sin(np.radians(ang))
        Rx = np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])
        Rx[:3, 3] = rng.uniform(-0.02, 0.02, 3)
        st["T_base_flange"] = (T0 @ Rx).tolist()  # pixels are not re-rendered: the check comes first
    return cell, obs


SUITES = {
    "scara": (lambda: D.scara_data(1)[:2], "translation of T_flange_cam0 along the common rotation axis",
              "planar motion (SCARA-like)"),
    "one_axis": (_one_axis, "translation of T_flange_cam0 along the common rotation axis", "parallel"),
    "pure_translation": (lambda: D.scara_data(2, rotate=False)[:2], "translation of T_flange_cam0 (all 3",
                         "pure translations"),
    "small_rotations": (lambda: D.scara_data(3, angles_deg=np.linspace(-0.004, 0.004, 6),
                                             pose_noise=(1e-4, 0.01))[:2],
                        "rotation of T_flange_cam0", "too small"),
    "two_stations": (_few_stations, "rotation of T_flange_cam0", "got 2 station(s)"),
}


@pytest.mark.parametrize("suite", sorted(SUITES))
def test_degenerate_motion_exits_3_naming_the_unknown(tmp_path, suite):
    make, unknown, why = SUITES[suite]
    cell, obs = make()
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    (tmp_path / "obs.json").write_text(json.dumps(obs))
    proc = subprocess.run([*JCALIB, "calibrate", "cell.yaml", "obs.json", "-o", "result.json"], cwd=tmp_path,
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 3, (proc.returncode, proc.stderr)
    err = " ".join(proc.stderr.split())  # rich wraps long lines
    assert unknown in err and why in err, err
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "result.json").exists()
