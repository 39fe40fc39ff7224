"""industrial_calibration's kinematic-calibration data sets (``measurements.yaml``) -> session -> calibrate.

The data set is written by the test in the tool's layout (one entry per observation: ``target_joints`` in
rad, empty ``camera_joints``, the target's ``pose`` in the sensor frame as x y z qw qx qy qz) from a simulated
2-axis positioner with hidden DH errors measured by a fixed 6-DOF sensor. ``jcalib import
industrial-calibration --option kinematics=<preset or FILE>`` -> ``jcalib calibrate`` recovers the DH
parameters within their σ of the simulation's truth (χ²).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from importer_roundtrip import cli
from scipy import stats

from jcalib.geometry import kinematic_models, kinematic_tables
from jcalib.geometry.se3 import quat_from_matrix
from jcalib.io.cell import load_cell
from jcalib.io.result import ResultFile
from jcalib.sim.kinematic_cells import synthetic_positioner_cell

PRESET = "positioner_2axis"


def write_measurements(folder, seed: int = 4, num: int = 16):
    """An industrial_calibration kinematic data set of a simulated positioner; its truth."""
    _, obs, truth = synthetic_positioner_cell(seed, num_stations=num, num_heldout=2, form="sensor")
    doc = {}
    for i, (q, st) in enumerate(zip(truth["fitted"]["q"], obs["stations"])):
        T = np.asarray(st["poses"][0]["T_sensor_target"])
        w, x, y, z = (float(v) for v in quat_from_matrix(T[:3, :3]))
        doc[str(i)] = {"target_joints": [float(v) for v in q], "camera_joints": [],
                       "pose": {"x": float(T[0, 3]), "y": float(T[1, 3]), "z": float(T[2, 3]),
                                "qw": w, "qx": x, "qy": y, "qz": z}}
    folder.mkdir()
    (folder / "measurements.yaml").write_text(yaml.safe_dump(doc))
    return truth


def test_kinematic_data_set_imports_and_calibrates_within_sigma(tmp_path):
    truth = write_measurements(tmp_path / "src")
    code, text = cli("import", "industrial-calibration", tmp_path / "src", "--out", tmp_path / "sess",
                     "--option", f"kinematics={PRESET}", "--option", "repeatability_mm=0.01",
                     "--option", "repeatability_deg=0.001")
    assert code == 0, text
    cell = load_cell(tmp_path / "sess" / "cell.yaml")
    assert cell.sensors["camera"].mount == "base" and not cell.cameras
    assert cell.targets["target"].mount == "flange"
    code, text = cli("calibrate", tmp_path / "sess" / "cell.yaml", tmp_path / "sess" / "observations.json",
                     "-o", tmp_path / "result.json", "--pose-sigma-deg", "0.005", "--pose-sigma-m", "0.00002")
    assert code == 0, text
    k = ResultFile.load(tmp_path / "result.json").kinematics["robot"]
    assert list(k.names) == truth["names"]
    free = [truth["names"].index(n) for n in k.calibrated]
    assert len(free) >= 2
    e = (np.asarray(k.values) - truth["params"])[free]
    cov = np.asarray(k.covariance)
    assert float(e @ np.linalg.solve(cov, e)) < stats.chi2.ppf(0.999, len(free)), (k.calibrated, e)
    d = (truth["params"] - truth["nominal"])[free]
    assert float(d @ np.linalg.solve(cov, d)) > 100.0  # the nominal model is far off: the data were informative


def test_kinematics_from_a_dh_table_file(tmp_path):
    """``kinematics=FILE``: a DH table in the cell-spec form, the same chain as the preset."""
    write_measurements(tmp_path / "src", num=4)
    model = kinematic_models.PRESETS[PRESET]()
    table = kinematic_tables.to_spec(model, model.nominal)
    (tmp_path / "dh.yaml").write_text(yaml.safe_dump({"kinematics": table}))
    code, text = cli("import", "industrial-calibration", tmp_path / "src" / "measurements.yaml", "--out",
                     tmp_path / "sess", "--option", f"kinematics={tmp_path / 'dh.yaml'}")
    assert code == 0, text
    kin = load_cell(tmp_path / "sess" / "cell.yaml").robot.kinematics
    obs = json.loads((tmp_path / "sess" / "observations.json").read_text())
    q = np.radians(np.array([s["joints_deg"] for s in obs["stations"]]))
    fk = [np.asarray(kinematic_models.forward(m, m.nominal, qi)) for m in (kin, model) for qi in q]
    np.testing.assert_allclose(fk[:len(q)], fk[len(q):], atol=1e-12)
    assert set(obs["stations"][0]["poses"][0]) == {"sensor", "target", "T_sensor_target"}


@pytest.mark.parametrize("edit, options, match", [
    (None, [], "kinematics=<preset>"),
    (None, ["kinematics=no_such_robot"], "not a kinematics preset"),
    (lambda d: d["0"].update(target_joints=[0.1, 0.2, 0.3]), ["kinematics=" + PRESET], "3 joint values"),
    (lambda d: d["0"].update(camera_joints=[0.1]), ["kinematics=" + PRESET], "both the target and the camera"),
    (lambda d: d["1"]["pose"].pop("qw"), ["kinematics=" + PRESET], "missing qw"),
])
def test_bad_kinematic_data_sets_are_refused_by_name(tmp_path, edit, options, match):
    write_measurements(tmp_path / "src", num=3)
    if edit is not None:
        f = tmp_path / "src" / "measurements.yaml"
        doc = yaml.safe_load(f.read_text())
        edit(doc)
        f.write_text(yaml.safe_dump(doc))
    args = [a for o in options for a in ("--option", o)]
    code, text = cli("import", "industrial-calibration", tmp_path / "src", "--out", tmp_path / "sess", *args)
    assert code == 2 and match in text, text


def test_a_moving_camera_chain_puts_the_sensor_on_the_flange(tmp_path):
    """``camera_joints`` moving (``target_joints`` empty): the sensor rides on the chain, the target is fixed."""
    write_measurements(tmp_path / "src", num=3)
    f = tmp_path / "src" / "measurements.yaml"
    doc = yaml.safe_load(f.read_text())
    for entry in doc.values():
        entry["camera_joints"], entry["target_joints"] = entry["target_joints"], []
    f.write_text(yaml.safe_dump(doc))
    code, text = cli("import", "industrial-calibration", tmp_path / "src", "--out", tmp_path / "sess",
                     "--option", f"kinematics={PRESET}", "--mount", "base")
    assert code == 2 and "--mount base" in text, text  # contradicts the moving camera chain
    code, text = cli("import", "industrial-calibration", tmp_path / "src", "--out", tmp_path / "sess",
                     "--option", f"kinematics={PRESET}")
    assert code == 0, text
    cell = load_cell(tmp_path / "sess" / "cell.yaml")
    assert cell.sensors["camera"].mount == "flange" and cell.targets["target"].mount == "base"
    q = [np.radians(s["joints_deg"]) for s in json.loads((tmp_path / "sess" / "observations.json").read_text())["stations"]]
    np.testing.assert_allclose(q, [e["camera_joints"] for e in doc.values()], atol=1e-12)
