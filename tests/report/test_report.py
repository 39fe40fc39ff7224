"""The one-page HTML report: contents checked against independent references, rendered by Chromium."""

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
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.result import ResultFile, TransformResult
from jcalib.report import render_report, write_report
from jcalib.report.html import POSES_KEY
from jcalib.report.plots import projection_sigma_map
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.025)
CELL = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "opencv5"}},
    "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025}},
}
CHROMIUM = "/usr/bin/chromium"
JCALIB = [sys.executable, "-c", "from jcalib.app.cli import main; main()"]


@pytest.fixture(scope="module")
def observations():
    rng = np.random.default_rng(11)
    cam = camera_from_opencv(np.array([[1000.0, 0, 640], [0, 1000, 480], [0, 0, 1]]),
                             np.array([-0.2, 0.05, 0, 0, 0]), (1280, 960))
    stations = []
    for i, T in enumerate(random_calibration_views(cam, BOARD.points, 8, rng=rng)):
        pix, _ = project_target(cam, T, BOARD.points)
        pix = pix + 0.2 * rng.standard_normal(pix.shape)
        stations.append({"id": f"s{i:02d}", "detections": [{
            "camera": "cam0", "target": "board", "point_index": list(range(54)), "pixels": pix.tolist()}]})
    return {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": [1280, 960]}},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}


@pytest.fixture(scope="module")
def result(observations):
    return jcalib.calibrate(CELL, observations)


@pytest.fixture(scope="module")
def page(result, observations):
    """The report of an in-memory Result (its details carry the per-view poses)."""
    return render_report(result, observations)


def _images(html: str) -> list[np.ndarray]:
    pngs = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html)
    return [cv2.imdecode(np.frombuffer(base64.b64decode(p), np.uint8), cv2.IMREAD_COLOR) for p in pngs]


def _self_contained(html: str) -> None:
    low = html.lower()
    assert "http://" not in low and "https://" not in low and "file:" not in low
    assert "<script" not in low and "<link" not in low and "@import" not in low and "url(" not in low
    # every src is an inline data URI, never a file
    srcs = re.findall(r'src\s*=\s*"([^"]*)"', html)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)


# ------------------------------------------------------------------------------ contents


def test_page_is_self_contained_with_tables_and_plots(page, result):
    _self_contained(page)
    cam = result.file.cameras["cam0"]
    for name, value in zip(cam.param_names, cam.params):
        # a table row per intrinsic with its value and σ (from the result, 8 and 3 significant digits)
        row = f'<td>{name}</td><td class="num">{value:.8g}</td><td class="num">{cam.std[name]:.3g}</td>'
        assert row in page, name
    for label in ("reprojection RMS", "a-posteriori σ", "residuals", "outliers rejected"):
        assert f"<td>{label}</td>" in page
    assert result.file.provenance.input_hash in page
    assert f"jcalib {jcalib.__version__}" in page
    images = _images(page)
    # per-view RMS, uncertainty map, correlation heat map, residual vectors, radial residuals
    assert len(images) == 5 and page.count("<img") == 5
    for section in ("Task-space uncertainty", "Correlations", "Weakest directions", "What would help"):
        assert f"<h2>{section}</h2>" in page
    # no figure wider than the page's 1100 px column (less its 2 x 24 px padding): no sideways scroll
    assert all(im is not None and im.shape[1] <= 1052 for im in images), [im.shape for im in images]
    assert "max-width:1100px" in page
    assert "Includes" in page and "Excludes" in page and "pose" in page


def test_projection_sigma_matches_opencv_jacobian(result):
    """σ map against an independent J C Jᵀ: OpenCV's analytic projectPoints Jacobian w.r.t.
    (fx, fy, cx, cy, k1, k2, p1, p2, k3) at rays found by OpenCV's undistortPoints."""
    cam = result.file.cameras["cam0"]
    u, v, sigma = projection_sigma_map(cam, grid=(9, 7))
    pix = np.stack([u.ravel(), v.ravel()], axis=-1)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xy = cv2.undistortPointsIter(pix[:, None, :], cam.K, cam.dist, None, None, crit)[:, 0, :]
    p = np.concatenate([xy, np.ones((len(xy), 1))], axis=-1)
    proj, jac = cv2.projectPoints(p[:, None, :], np.zeros(3), np.zeros(3), cam.K, cam.dist)
    np.testing.assert_allclose(proj[:, 0, :], pix, atol=1e-6)  # the rays are right
    J = jac[:, 6:].reshape(len(p), 2, 9)
    cov = np.einsum("nip,pq,njq->nij", J, cam.covariance, J)
    ref = np.sqrt(np.linalg.eigvalsh(cov)[:, -1])
    # same linearisation, float64 both: agreement far below any displayed digit
    np.testing.assert_allclose(sigma.ravel(), ref, rtol=1e-6)
    # at the principal point only cx, cy move the projection: σ = sqrt(λ_max(C[cx, cy]))
    pp = camera_sigma_at(cam, np.array([[cam.K[0, 2], cam.K[1, 2]]]))
    np.testing.assert_allclose(pp, np.sqrt(np.linalg.eigvalsh(cam.covariance[2:4, 2:4])[-1]), rtol=1e-9)


def camera_sigma_at(cam, pixels):
    """σ (px) at arbitrary pixels ``(n, 2)`` through the report's jitted propagation."""
    import jax.numpy as jnp

    from jcalib.report import plots

    model = plots._camera_model(cam)
    rays = model.unproject(jnp.asarray(pixels))
    fn = plots._sigma_fn(type(model), tuple(model.image_size), bool(model.has_skew))
    c = np.asarray(fn(jnp.asarray(cam.params), rays, jnp.asarray(cam.covariance)))
    return np.sqrt(np.linalg.eigvalsh(c)[:, -1])


def test_residual_plot_matches_opencv_reprojection(page, result, observations):
    """The residual caption's RMS equals the RMS of OpenCV's reprojection with the solver's poses."""
    cam = result.file.cameras["cam0"]
    res = []
    for st in observations["stations"]:
        T = result.details.T_cam_target[st["id"]]["cam0"]
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        proj, _ = cv2.projectPoints(BOARD.points, rvec, T[:3, 3], cam.K, cam.dist)
        res.append(np.asarray(st["detections"][0]["pixels"]) - proj[:, 0, :])
    res = np.concatenate(res)
    rms = float(np.sqrt(np.mean(res**2)))
    m = re.search(r"arrows magnified \d+x, RMS ([0-9.e+-]+) px", page)
    assert m is not None
    assert m.group(1) == f"{rms:.3g}"
    assert "radial residuals of cam0" in page


def test_warnings_first_transforms_and_file_poses(result, observations):
    """Warnings come before the summary; transforms read in mm / deg with σ; poses from the file."""
    f = result.file
    c = np.cos(np.pi / 6)
    T = np.array([[c, -0.5, 0, 0.1], [0.5, c, 0, -0.2], [0, 0, 1, 0.3], [0, 0, 0, 1]])  # 30° about z
    cov = np.diag([1e-6, 4e-6, 9e-6, 1e-8, 4e-8, 9e-8])  # σ r = 1, 2, 3 mrad; σ t = 0.1, 0.2, 0.3 mm
    poses = {sid: {"cam0": Tc.tolist()} for sid, per in result.details.T_cam_target.items()
             for Tc in [per["cam0"]]}
    file = ResultFile(
        cameras=f.cameras, transforms={"T_flange_cam0": TransformResult(T, cov)},
        stats={**f.stats, "warnings": ["lens model is probably too simple <b>"]},
        provenance=f.provenance, extra={POSES_KEY: poses},
    )
    html = render_report(file, observations)
    _self_contained(html)
    warn = html.index("lens model is probably too simple &lt;b&gt;")  # escaped, not markup
    assert warn < html.index("<h2>Summary</h2>")
    assert 'class="warn"' in html
    assert "100.000 -200.000 300.000" in html and "0.100 0.200 0.300" in html
    assert "0.0000 0.0000 30.0000" in html
    assert " ".join(f"{np.degrees(x):.4f}" for x in (1e-3, 2e-3, 3e-3)) in html
    assert "radial residuals of cam0" in html  # residuals from the file's poses, no details


def test_cli_report_without_poses_shows_coverage(tmp_path, result, observations):
    result.to_json(tmp_path / "result.json")
    (tmp_path / "obs.json").write_text(json.dumps(observations))
    proc = subprocess.run([*JCALIB, "report", "result.json", "-o", "report.html", "--observations", "obs.json"],
                          capture_output=True, text=True, cwd=tmp_path, check=False)
    assert proc.returncode == 0, proc.stderr
    html = (tmp_path / "report.html").read_text()
    _self_contained(html)
    assert "radial residuals" in html  # the result file keeps the per-view poses
    # A result without per-view poses (e.g. written by an older jcalib): coverage instead.
    data = json.loads((tmp_path / "result.json").read_text())
    del data["T_cam_target"]
    (tmp_path / "result.json").write_text(json.dumps(data))
    proc = subprocess.run([*JCALIB, "report", "result.json", "-o", "report.html", "--observations", "obs.json"],
                          capture_output=True, text=True, cwd=tmp_path, check=False)
    assert proc.returncode == 0, proc.stderr
    html = (tmp_path / "report.html").read_text()
    _self_contained(html)
    assert "432 detected corners in 8 views" in html  # 8 views x 54 corners
    assert "radial residuals" not in html
    proc = subprocess.run([*JCALIB, "report", "missing.json", "-o", "r.html"],
                          capture_output=True, text=True, cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "missing.json" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "r.html").exists()


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


def test_chromium_renders_report_without_console_errors(tmp_path, result, observations):
    # the fullest page: with the cell, the cross-validation section and its map are added
    path = write_report(result, tmp_path / "report.html", observations=observations, cell=CELL)
    html = path.read_text()
    _self_contained(html)
    assert "<h2>Cross-validation</h2>" in html and 'alt="cross-validation of cam0"' in html
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
