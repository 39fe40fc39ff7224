"""The one-page HTML report: the same sections for every cell, contents checked against independent
references, the command line on result files, rendered by Chromium."""

import base64
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

import jcalib
from jcalib.io.result import ResultFile, TransformResult
from jcalib.report import render_report
from jcalib.report.html import SECTIONS

CHROMIUM = "/usr/bin/chromium"
JCALIB = [sys.executable, "-c", "from jcalib.app.cli import main; main()"]


def _images(html: str) -> list[np.ndarray]:
    pngs = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html)
    return [cv2.imdecode(np.frombuffer(base64.b64decode(p), np.uint8), cv2.IMREAD_COLOR) for p in pngs]


def _self_contained(html: str) -> None:
    low = html.lower()
    assert "http://" not in low and "https://" not in low and "file:" not in low
    assert "<script" not in low and "<link" not in low and "@import" not in low and "url(" not in low
    srcs = re.findall(r'src\s*=\s*"([^"]*)"', html)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)


def _sections(html: str) -> list[str]:
    return re.findall(r"<h2>(.*?)</h2>", html)


@pytest.fixture(scope="module")
def pages(camera_case, handeye_case, cell_case):
    """The reports of a camera, a hand-eye cell and a whole cell (in-memory results, with observations)."""
    return {name: render_report(case[2], case[1], cross_validation=False)
            for name, case in (("camera", camera_case), ("hand-eye", handeye_case), ("cell", cell_case))}


def test_every_cell_has_the_same_sections(pages, camera_case):
    """Camera, hand-eye and whole-cell reports: the same sections in the same order, each with content
    from the solve (no 'needs the calibration's solve' note); a result file alone still has every section."""
    for name, html in pages.items():
        assert _sections(html) == list(SECTIONS), name
        assert "needs the calibration&#x27;s solve" not in html and "needs the calibration's solve" not in html, name
        assert html.count("<th>one more station</th>") == 1, name  # the what-would-help table
        assert "σ / tolerance" in html and "Every measurement group of the solve" in html, name
        _self_contained(html)
    alone = render_report(camera_case[2].file)
    assert _sections(alone) == list(SECTIONS)
    assert "needs the calibration" in alone


def test_whole_cell_page_has_the_camera_and_handeye_analyses(pages, cell_case):
    """The whole cell gets what the camera and hand-eye pages have (correlations over every shared unknown,
    projection maps, residual plots per camera) plus its TCP and tool-tip stations in what would help."""
    html, file = pages["cell"], cell_case[2].file
    assert 'alt="correlation matrix every shared unknown of the solve"' in html
    assert 'alt="projection uncertainty of cam0"' in html and 'alt="residual vectors of cam0"' in html
    assert "<h3>TCP</h3>" in html and "T_flange_needle" in html
    assert "with needle turned 30° about" in html  # a tool-tip station is a candidate
    assert "<code>tips:cam1/needle</code>" in html and "<code>corners:cam0/board</code>" in html
    for name, cam in file.cameras.items():  # every intrinsic with its value and σ from the file
        for pname, value in zip(cam.param_names, cam.params):
            std = cam.std[pname]
            s = "fixed" if std == 0.0 else f"{std:.3g}"
            assert f'<td>{pname}</td><td class="num">{value:.8g}</td><td class="num">{s}</td>' in html, (name, pname)


def test_camera_page_tables_and_plots(pages, camera_case):
    html, result = pages["camera"], camera_case[2]
    for label in ("reprojection RMS per point (error norms, as OpenCV)", "a-posteriori σ per coordinate", "residuals",
                  "outliers rejected"):
        assert f"<td>{label}</td>" in html
    assert result.file.provenance.input_hash in html and f"jcalib {jcalib.__version__}" in html
    images = _images(html)
    # per-view RMS, uncertainty map, correlation heat map, residual vectors, radial residuals
    assert len(images) == 5 and html.count("<img") == 5
    assert all(im is not None and im.shape[1] <= 1052 for im in images), [im.shape for im in images]
    assert "max-width:1100px" in html and "Includes" in html and "Excludes" in html


def test_residual_caption_matches_opencv_reprojection(pages, camera_case, cases):
    """The residual caption's RMS equals the RMS of OpenCV's reprojection with the solve's view poses."""
    html, (_, obs, result) = pages["camera"], camera_case
    cam = result.file.cameras["cam0"]
    res = []
    for st in obs["stations"]:
        T = result.details.T_cam_target[st["id"]]["cam0"]
        proj, _ = cv2.projectPoints(cases.BOARD.points, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], cam.K, cam.dist)
        res.append(np.asarray(st["detections"][0]["pixels"]) - proj[:, 0, :])
    res = np.concatenate(res)
    assert result.file.stats["num_outliers"] == 0
    m = re.search(r"arrows magnified \d+x, RMS ([0-9.e+-]+) px", html)
    assert m is not None and m.group(1) == f"{np.sqrt(np.mean(np.sum(res**2, axis=-1))):.3g}"


def test_warnings_first_escaped_and_transforms_in_mm_deg(camera_case):
    """A result file alone: warnings come before the summary (escaped), transforms read in mm / deg with σ."""
    f = camera_case[2].file
    c = np.cos(np.pi / 6)
    T = np.array([[c, -0.5, 0, 0.1], [0.5, c, 0, -0.2], [0, 0, 1, 0.3], [0, 0, 0, 1]])  # 30° about z
    cov = np.diag([1e-6, 4e-6, 9e-6, 1e-8, 4e-8, 9e-8])  # σ r = 1, 2, 3 mrad; σ t = 0.1, 0.2, 0.3 mm
    file = ResultFile(cameras=f.cameras, transforms={"T_flange_cam0": TransformResult(T, cov)},
                      stats={**f.stats, "warnings": ["lens model is probably too simple <b>"]}, provenance=f.provenance)
    html = render_report(file)
    _self_contained(html)
    warn = html.index("lens model is probably too simple &lt;b&gt;")  # escaped, not markup
    assert warn < html.index("<h2>Summary</h2>") and 'class="warn"' in html
    assert "100.000 -200.000 300.000" in html and "0.100 0.200 0.300" in html
    assert "0.0000 0.0000 30.0000" in html
    assert " ".join(f"{np.degrees(x):.4f}" for x in (1e-3, 2e-3, 3e-3)) in html
    # 3 mrad = 0.17° about z is over the 0.05° tolerance: named from the file's σ
    assert "T_flange_cam0 rotation z is weakly determined" in html


def test_cli_report_restores_the_solve_from_files(tmp_path, camera_case):
    """``jcalib report RESULT --observations OBS --cell CELL``: the calibration restored from the files (every
    section from the solve, cross-validation included); with observations only: the coverage of the
    detections and a note; a missing file: exit 2 with the name, no traceback, no page."""
    cell, obs, result = camera_case
    result.to_json(tmp_path / "result.json")
    (tmp_path / "obs.json").write_text(json.dumps(obs))
    (tmp_path / "cell.json").write_text(json.dumps(cell))
    run = {"capture_output": True, "text": True, "cwd": tmp_path, "check": False}
    proc = subprocess.run([*JCALIB, "report", "result.json", "-o", "report.html", "--observations", "obs.json",
                           "--cell", "cell.json"], **run)
    assert proc.returncode == 0, proc.stderr
    html = (tmp_path / "report.html").read_text()
    _self_contained(html)
    assert _sections(html) == list(SECTIONS)
    assert "radial residuals of cam0" in html and "one more station" in html
    assert 'alt="cross-validation of cam0"' in html
    proc = subprocess.run([*JCALIB, "report", "result.json", "-o", "report.html", "--observations", "obs.json"], **run)
    assert proc.returncode == 0, proc.stderr
    html = (tmp_path / "report.html").read_text()
    assert "486 detected corners in 9 views" in html and "radial residuals" not in html  # 9 views x 54 corners
    assert _sections(html) == list(SECTIONS)
    proc = subprocess.run([*JCALIB, "report", "missing.json", "-o", "r.html"], **run)
    assert proc.returncode == 2 and "missing.json" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "r.html").exists()


def test_wrong_cell_for_the_result_is_refused(camera_case, cell_case):
    """A result with the observations and cell of another calibration: a clear error, not a page."""
    from jcalib.errors import BadInputError

    with pytest.raises(BadInputError, match="cell"):
        render_report(cell_case[2].file, camera_case[1], cell=camera_case[0])


# ------------------------------------------------------------------------------ rendering


def _chromium(html_path: Path, tmp_path: Path) -> tuple[Path, str]:
    if not Path(CHROMIUM).exists():
        if os.environ.get("CI"):
            pytest.fail(f"{CHROMIUM} is missing; scripts/setup installs Debian's chromium in CI")
        pytest.skip(f"{CHROMIUM} not installed (apt-get install chromium)")
    png = tmp_path / (html_path.stem + ".png")
    proc = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         f"--user-data-dir={tmp_path / ('profile-' + html_path.stem)}", "--enable-logging=stderr", "--v=0",
         f"--screenshot={png}", "--window-size=1280,2000", html_path.resolve().as_uri()],
        capture_output=True, text=True, timeout=120, check=False,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return png, proc.stdout + proc.stderr


def _console_errors(log: str) -> list[str]:
    return [line for line in log.splitlines() if "Uncaught" in line or ":CONSOLE" in line]


def test_chromium_renders_report_without_console_errors(tmp_path, pages):
    path = tmp_path / "report.html"
    path.write_text(pages["cell"])  # the fullest page: a whole cell
    html = path.read_text()
    assert all(im.shape[1] <= 1052 for im in _images(html))  # no figure wider than the column
    png, log = _chromium(path, tmp_path)
    assert _console_errors(log) == []
    shot = cv2.imread(str(png), cv2.IMREAD_COLOR)
    assert shot is not None and shot.shape[:2] == (2000, 1280)
    # not blank: text and plots give many distinct colours and dark pixels on the light page
    assert len(np.unique(shot.reshape(-1, 3), axis=0)) > 200
    assert np.mean(shot.min(axis=-1) < 100) > 0.005
    # the control: the same capture does see a page's console error
    bad = tmp_path / "bad.html"
    bad.write_text("<!DOCTYPE html><html><body><p>x</p><script>throw new Error('boom')</script></body></html>")
    _, bad_log = _chromium(bad, tmp_path)
    assert any("boom" in line for line in _console_errors(bad_log)), bad_log[-2000:]


@pytest.mark.skipif(shutil.which("chromium") is None and not os.environ.get("CI"), reason="no chromium")
def test_chromium_present_in_ci():
    assert Path(CHROMIUM).exists()


def test_rms_is_said_per_point_and_per_coordinate(pages, camera_case, cases):
    """``stats.rms_px`` is per point (OpenCV's RMS of the error norms), ``stats.rms_px_per_coordinate`` per
    coordinate (mrcal's), both from OpenCV's own reprojection with the solve's view poses; the console and the
    report print both, named."""
    from rich.console import Console

    from jcalib.report.console import print_result

    html, (_, obs, result) = pages["camera"], camera_case
    cam, stats = result.file.cameras["cam0"], result.file.stats
    res = []
    for st in obs["stations"]:
        T = result.details.T_cam_target[st["id"]]["cam0"]
        proj, _ = cv2.projectPoints(cases.BOARD.points, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], cam.K, cam.dist)
        res.append(np.asarray(st["detections"][0]["pixels"]) - proj[:, 0, :])
    res = np.concatenate(res)
    np.testing.assert_allclose(stats["rms_px"], np.sqrt(np.mean(np.sum(res**2, axis=-1))), rtol=1e-6)
    np.testing.assert_allclose(stats["rms_px_per_coordinate"], np.sqrt(np.mean(res**2)), rtol=1e-6)
    assert set(stats["view_rms_px_per_coordinate"]) == set(stats["view_rms_px"])
    for key, v in stats["view_rms_px"].items():  # 2-D residuals: per coordinate = per point / √2 exactly
        np.testing.assert_allclose(stats["view_rms_px_per_coordinate"][key], v / np.sqrt(2.0), rtol=1e-12)
    assert "<td>reprojection RMS per point (error norms, as OpenCV)</td>" in html
    assert f"<td>reprojection RMS per coordinate (x and y errors, as mrcal)</td><td class=\"num\">" \
           f"{stats['rms_px_per_coordinate']:.4g}" in html
    console = Console(record=True, width=300)
    print_result(result.file, console)
    text = console.export_text()
    assert (f"RMS {stats['rms_px']:.4f} px per point ({stats['rms_px_per_coordinate']:.4f} px per coordinate)"
            in text)


def test_robot_accuracy_estimate_is_shown_beside_the_stated_one(camera_case):
    """``stats.robot`` (a whole cell with a pose model): the console and the report's summary show the
    a-posteriori flange-pose σ and, beside it, the stated pose_noise."""
    from rich.console import Console

    from jcalib.report.console import print_result

    f = camera_case[2].file
    robot = {"prior_sigma_translation_m": [1e-4] * 3, "prior_sigma_rotation_deg": [0.01] * 3,
             "a_posteriori_sigma_translation_m": [2.5e-4] * 3, "a_posteriori_sigma_rotation_deg": [0.03] * 3,
             "correction_rms_translation_m": [2e-4] * 3, "correction_rms_rotation_deg": [0.02] * 3, "redundancy": 40.0}
    file = ResultFile(cameras=f.cameras, stats={**f.stats, "robot": robot}, provenance=f.provenance)
    line = ("flange-pose σ estimated x y z 0.2500 0.2500 0.2500 mm, 0.03000 0.03000 0.03000 deg (a posteriori, from "
            "the stations' flange corrections); stated (pose_noise) 0.1000 0.1000 0.1000 mm, 0.01000 0.01000 "
            "0.01000 deg")
    console = Console(record=True, width=400)
    print_result(file, console)
    assert f"robot accuracy: {line}" in console.export_text()
    html = render_report(file)
    assert "<td>robot accuracy</td>" in html and line.replace("'", "&#x27;") in html
