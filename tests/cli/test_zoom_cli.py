"""Zoom lenses on the command line: stations at one setting refused with exit 3 naming ``lens:cam0``;
``export --at`` writes the camera at a setting, refuses one outside the calibrated range (exit 2) unless
``--extrapolate``; ``plan --lens-settings`` visits every station at every setting."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from jcalib.app.cli import main
from jcalib.geometry.cameras import zoom
from jcalib.sim.zoom import synthetic_zoom_cell


class Run:
    def __init__(self, exit_code: int, output: str):
        self.exit_code, self.output = exit_code, output


@pytest.fixture
def invoke(capsys):
    """``jcalib ARGS`` in process through the console entry point (its exit statuses and messages)."""
    def run(*args):
        try:
            main([str(a) for a in args])
            code = 0
        except SystemExit as stop:
            code = int(stop.code or 0)
        out = capsys.readouterr()
        return Run(code, out.out + out.err)
    return run


def lens_result(tmp_path):
    """A result file with a zoom camera (made by hand: the CLI wiring, not the solve, is under test)."""
    intr = np.array([1000.0, 1000.0, 640.0, 480.0, -0.2, 0.05, 0.0, 0.0, 0.0])
    q = np.r_[np.asarray(zoom.to_transformed(jnp.asarray(intr))), 0.0]
    lens = np.concatenate([q + k * np.r_[0.5, 0.5, 1.0, -1.0, 0.05, 0, 0, 0, 0, 0.005] for k in (1, 2, 3)])
    K = [[1000.0, 0.0, 640.0], [0.0, 1000.0, 480.0], [0.0, 0.0, 1.0]]
    doc = {"schema": "jcalib.result/1",
           "cameras": {"cam0": {"model": "opencv5", "image_size": [1280, 960], "K": K,
                                "dist": [-0.2, 0.05, 0.0, 0.0, 0.0], "std": {}}},
           "transforms": {"T_flange_cam0": {"matrix": np.eye(4).tolist()}}, "points": {}, "stats": {},
           "lenses": {"cam0": {"setting": "Zoom", "range": [100.0, 800.0], "degree": 3, "knots": 0,
                               "model": "opencv5", "image_size": [1280, 960],
                               "param_names": ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"],
                               "intrinsics": intr.tolist(), "lens": lens.tolist(), "mount": "T_flange_cam0",
                               "covariance": (1e-8 * np.eye(9 + 30 + 6)).tolist()}}}
    path = tmp_path / "result.json"
    path.write_text(json.dumps(doc))
    return path


def test_one_setting_only_exits_3_naming_the_lens(tmp_path, invoke):
    cell, obs, _ = synthetic_zoom_cell(0, settings=(300,), num_stations=4)
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    (tmp_path / "obs.json").write_text(json.dumps(obs))
    r = invoke("calibrate", tmp_path / "cell.yaml", tmp_path / "obs.json", "-o", tmp_path / "r.json")
    assert r.exit_code == 3, r.output
    assert "lens:cam0" in r.output and "one Zoom setting" in r.output
    assert "Traceback" not in r.output


def test_export_at_a_setting(tmp_path, invoke):
    path = lens_result(tmp_path)
    out = tmp_path / "cam0.yaml"
    r = invoke("export", path, "--format", "opencv", "--at", "cam0.Zoom=450", "-o", out)
    assert r.exit_code == 0, r.output
    text = out.read_text()
    assert "cam0 at lens setting Zoom=450" in text and "fx=" in text
    u = (450.0 - 100.0) / 700.0
    fx = float(np.exp(np.log(1000.0) + 0.5 * 3 * u))  # the control points rise linearly: q(u) = q0 + 3 u Δ
    assert f"{fx:.6g}"[:5] in text
    r = invoke("export", path, "--format", "ros", "--at", "cam0.Zoom=900", "-o", tmp_path / "info.yaml")
    assert r.exit_code == 2 and "outside the calibrated range" in r.output and "--extrapolate" in r.output
    r = invoke("export", path, "--format", "ros", "--at", "cam0.Zoom=900", "--extrapolate", "-o", tmp_path / "i.yaml")
    assert r.exit_code == 0, r.output
    r = invoke("export", path, "--format", "opencv", "--at", "cam0=900", "-o", tmp_path / "x.yaml")
    assert r.exit_code == 2 and "CAMERA.SETTING=VALUE" in r.output


def test_plan_lens_settings_multiply_the_stations(tmp_path, invoke):
    from jcalib.io.plan import load_plan

    cell = {"schema": "jcalib.cell/1", "robot": {"model": "kuka_kr10_r1100_sixx"},
            "cameras": {"cam0": {"model": "opencv5", "mount": "flange", "lens": {"settings": ["Zoom"]}}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "base"}}}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    r = invoke("plan", "--cell", tmp_path / "cell.yaml", "--kind", "handeye", "--stations", 4, "-o",
               tmp_path / "plan.json", "--lens-settings", "cam0.Zoom=100,400,700")
    assert r.exit_code == 0, r.output
    plan = load_plan(tmp_path / "plan.json")
    assert len(plan) % 3 == 0 and [s.lens for s in plan.stations[:3]] == [{"cam0": {"Zoom": v}} for v in (100, 400, 700)]
    assert np.array_equal(plan.stations[0].T_base_flange, plan.stations[2].T_base_flange)
    r = invoke("plan", "--cell", tmp_path / "cell.yaml", "--kind", "handeye", "-o", tmp_path / "p2.json",
               "--lens-settings", "cam0.Zoom")
    assert r.exit_code == 2 and "CAMERA.SETTING=V1,V2" in r.output
