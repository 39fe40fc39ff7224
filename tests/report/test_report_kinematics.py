"""Calibrated robot kinematics in the console tables, the HTML report and ``jcalib report``: a 2-axis positioner
calibrated once (parameters free and held, controller offsets, flange correction RMS)."""

from __future__ import annotations

import html
import io
import json
import math
import re

import numpy as np
import pytest
from rich.console import Console

import jcalib
from jcalib.report import render_report
from jcalib.report.console import print_result
from jcalib.report.kinematics import offset_rows, parameter_rows
from jcalib.sim.kinematic_cells import synthetic_positioner_cell


@pytest.fixture(scope="module")
def positioner(tmp_path_factory):
    """``(folder, cell, observations, jcalib.Result)``: the positioner calibrated once, its files on disk."""
    cell, obs, _ = synthetic_positioner_cell(3, num_stations=16, num_heldout=4)
    result = jcalib.calibrate(cell, obs)
    folder = tmp_path_factory.mktemp("kinematics")
    result.to_json(folder / "result.json")
    (folder / "observations.json").write_text(json.dumps(obs), encoding="utf-8")
    (folder / "cell.json").write_text(json.dumps(cell), encoding="utf-8")
    return folder, cell, obs, result


def _text(page: str) -> str:
    """The page's text, one table row or paragraph per line."""
    page = re.sub(r"<(tr|p|h3|h4)\b[^>]*>", "\n", page)
    return re.sub(r"[ \t]+", " ", html.unescape(re.sub(r"<[^>]+>", " ", page)))


def test_rows_come_from_the_result(positioner):
    k = positioner[3].file.kinematics["robot"]
    rows = parameter_rows(k)
    assert [r.name for r in rows] == list(k.calibrated) and rows
    for r in rows:
        i = k.names.index(r.name)
        scale = 1e3 if r.unit == "mm" else 180.0 / math.pi
        assert r.calibrated == pytest.approx(k.values[i] * scale, rel=1e-12)
        assert r.change == pytest.approx((k.values[i] - k.nominal[i]) * scale, rel=1e-9, abs=1e-12)
        assert r.std == pytest.approx(k.std[r.name] * scale, rel=1e-12)
    offsets = {o.joint: o for o in offset_rows(k)}
    assert set(offsets) == {"tilt", "rotate"}
    for joint, o in offsets.items():
        assert (o.held is None) == (f"{joint}.theta" in k.calibrated)
        if o.held is not None:
            assert o.held == k.extra["held"][f"{joint}.theta"]


def test_console_shows_the_kinematics_table(positioner):
    k = positioner[3].file.kinematics["robot"]
    out = io.StringIO()
    print_result(positioner[3].file, Console(file=out, width=200, color_system=None))
    text = out.getvalue()
    assert "Robot kinematics: robot (dh)" in text
    for r in parameter_rows(k):
        line = next(line for line in text.splitlines() if f" {r.name} " in line)
        for cell in (f"{r.nominal:.5f}", f"{r.calibrated:.5f}", f"{r.change:+.4g}", f"{r.std:.3g}", r.unit):
            assert cell in line, (cell, line)
    held = next(line for line in text.splitlines() if line.startswith("held at nominal:"))
    assert all(name in held for name in k.extra["held"])
    assert "flange correction RMS per station" in text and "stated repeatability" in text


def test_html_has_the_kinematics_section(positioner):
    _folder, _, obs, result = positioner
    k = result.file.kinematics["robot"]
    text = _text(render_report(result, obs, cross_validation=False))
    section = text[text.index("Robot kinematics"):text.index("Per-view reprojection error")]
    for r in parameter_rows(k):
        assert f"{r.name} {r.nominal:.5f} {r.calibrated:.5f} {r.change:+.4g} {r.std:.3g} {r.unit}" in section
    for name, why in k.extra["held"].items():
        assert f"{name} {why}" in section
    assert "tilt" in section and "controller zero offset" in section
    assert "the calibrated arm at the controller reading q is the nominal arm at q + offset" in section.lower()
    assert "flange correction RMS per station" in section


def test_html_from_the_result_file_restores_the_solve(positioner):
    """A result file with its observations and cell: the solve is restored (kinematics started at the builder's
    start, not the file's) and must land on the file's kinematics (report.model checks it to 1e-3 σ)."""
    _, cell, obs, result = positioner
    text = _text(render_report(result.file, obs, cell=cell, cross_validation=False))
    assert "Robot kinematics" in text and "needs the calibration's solve" not in text


def test_cli_report_on_a_kinematic_result(positioner, run_cli):
    """The result file alone: the joint covariance's kinematics block is read (correlations, weak directions)."""
    folder = positioner[0]
    code, text = run_cli("report", folder / "result.json", "-o", folder / "report.html")
    assert code == 0, text
    page = _text((folder / "report.html").read_text(encoding="utf-8"))
    assert "Robot kinematics" in page and "tilt.alpha" in page
    assert np.isfinite(positioner[3].file.kinematics["robot"].values).all()
