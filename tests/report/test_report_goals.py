"""Accuracy goals against a result file (jcalib.problems.goals): each goal's σ checked against an independent
computation from the JSON (numpy eigenvalues of the covariance blocks; a projection Jacobian by central
differences of OpenCV's projectPoints at rays from OpenCV's undistortPointsIter), the Goals table in the HTML
report and ``jcalib report --plan``."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from jcalib.errors import BadInputError
from jcalib.io.goals import parse_goals
from jcalib.io.result import CameraResult, PointResult, ResultFile, TransformResult
from jcalib.io.plan import plan_goals
from jcalib.problems.goals import achieved_sigmas, goal_rows
from jcalib.report.goals import goals_html

K = np.array([[400.0, 0.0, 159.5], [0.0, 405.0, 119.5], [0.0, 0.0, 1.0]])
DIST = np.array([-0.12, 0.05, 1e-3, -8e-4, 0.01])
SIZE = (320, 240)


def _spd(rng: np.random.Generator, n: int, scale: np.ndarray) -> np.ndarray:
    """A random SPD matrix with strongly unequal directions (so the worst direction matters)."""
    A = rng.normal(size=(n, n)) * scale[None, :]
    return A.T @ A / n


@pytest.fixture(scope="module")
def result_path(tmp_path_factory):
    rng = np.random.default_rng(5)
    T = np.eye(4)
    T[:3, 3] = [0.01, -0.02, 0.05]
    cov6 = _spd(rng, 6, np.array([1e-4, 3e-4, 2e-5, 2e-4, 5e-5, 1e-3]))
    point_cov = _spd(rng, 3, np.array([1e-4, 2e-5, 4e-4]))
    cam_cov = _spd(rng, 9, np.array([0.5, 0.5, 0.4, 0.4, 2e-3, 4e-3, 1e-4, 1e-4, 5e-3]))
    file = ResultFile(
        cameras={"cam0": CameraResult("opencv5", SIZE, K, DIST, covariance=cam_cov)},
        transforms={"T_flange_cam0": TransformResult(T, cov6), "T_base_board": TransformResult(np.eye(4)),
                    "T_flange_torch": TransformResult(T, cov6, extra={"calibrated": ["tx", "ty", "tz"]})},
        points={"divot": PointResult(np.array([0.4, 0.1, 0.02]), "base", point_cov)},
        stats={"rms_px": 0.2, "num_residuals": 100, "sigma_px": 0.2})
    path = tmp_path_factory.mktemp("goals") / "result.json"
    file.save(path)
    return path


def _worst(C: np.ndarray) -> float:
    return float(np.sqrt(np.linalg.eigvalsh(C)[-1]))


def _fd_projection_sigma(cam: dict, cov: np.ndarray) -> float:
    """Worst σ over the 9 x 7 grid: rays by cv2.undistortPointsIter, Jacobian by central differences of
    cv2.projectPoints over (fx, fy, cx, cy, k1, k2, p1, p2, k3)."""
    Kf, dist = np.array(cam["K"], float), np.array(cam["dist"], float)
    w, h = cam["image_size"]
    u, v = np.meshgrid(np.linspace(0, w - 1, 9), np.linspace(0, h - 1, 7))
    pix = np.stack([u.ravel(), v.ravel()], -1)
    xy = cv2.undistortPointsIter(pix.reshape(-1, 1, 2), Kf, dist, np.eye(3), np.eye(3),
                                 (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)).reshape(-1, 2)
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    theta = np.array([Kf[0, 0], Kf[1, 1], Kf[0, 2], Kf[1, 2], *dist])

    def project(t):
        Kt = np.array([[t[0], 0, t[2]], [0, t[1], t[3]], [0, 0, 1.0]])
        p, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), Kt, t[4:])
        return p.reshape(-1, 2)

    J = np.zeros((len(rays), 2, 9))
    for j in range(9):
        step = 1e-4 * max(abs(theta[j]), 1e-2)
        tp, tm = theta.copy(), theta.copy()
        tp[j] += step
        tm[j] -= step
        J[:, :, j] = (project(tp) - project(tm)) / (2 * step)
    return max(_worst(Jg @ cov @ Jg.T) for Jg in J)


def test_achieved_sigmas_match_an_independent_computation(result_path):
    data = json.loads(result_path.read_text())
    goals = ["T_flange_cam0:translation_mm<=0.05", "T_flange_cam0:rotation_deg<=0.01", "divot:position_mm<=0.1",
             "cam0:projection_px<=0.5", "T_flange_torch:position_mm<=1"]
    got = achieved_sigmas(goals, result_path)
    cov6 = np.array(data["transforms"]["T_flange_cam0"]["covariance"])
    # float64 eigenvalues of the same matrix: identical up to round-off
    assert got[goals[0]] == pytest.approx(1e3 * _worst(cov6[3:, 3:]), rel=1e-9)
    assert got[goals[1]] == pytest.approx(np.degrees(_worst(cov6[:3, :3])), rel=1e-9)
    assert got[goals[2]] == pytest.approx(1e3 * _worst(np.array(data["points"]["divot"]["covariance"])), rel=1e-9)
    assert got[goals[4]] == pytest.approx(1e3 * _worst(cov6[3:, 3:]), rel=1e-9)
    # autodiff through jcalib's lens model vs central differences of OpenCV: the projection is a low-degree
    # polynomial in the intrinsics, so central differences are exact up to round-off (measured 3e-12)
    cam = data["cameras"]["cam0"]
    ref = _fd_projection_sigma(cam, np.array(cam["covariance"]))
    assert got[goals[3]] == pytest.approx(ref, rel=1e-8)
    assert all(isinstance(v, float) for v in got.values())


def test_goals_naming_what_the_result_lacks_are_refused(result_path):
    for goal, words in [("T_flange_cam1:translation_mm<=1", ["T_flange_cam1", "T_flange_cam0"]),
                        ("cam1:projection_px<=1", ["cam1", "cam0"]),
                        ("needle_tip:position_mm<=1", ["needle_tip", "divot"]),
                        ("T_base_board:translation_mm<=1", ["T_base_board", "no covariance"]),
                        ("T_flange_torch:rotation_deg<=1", ["rotation of T_flange_torch", "not calibrated"])]:
        with pytest.raises(BadInputError) as e:
            achieved_sigmas([goal], result_path)
        assert all(w in str(e.value) for w in words), str(e.value)


def test_goals_table_in_the_html_report(result_path):
    from jcalib.report import render_report
    from jcalib.report.html import SECTIONS

    goals = parse_goals(["T_flange_cam0:translation_mm<=1000", "divot:position_mm<=1e-6"])
    rows = goal_rows(goals, result_path, {goals[0].text: 0.5})
    assert [r.met for r in rows] == [True, False]
    assert rows[0].predicted == 0.5 and rows[1].predicted is None
    html = goals_html(rows)
    assert "<h3>Goals</h3>" in html and "1 of 2 goal(s) met" in html and "divot:position_mm&lt;=1e-6" in html
    page = render_report(result_path, goals=rows)
    assert "<h3>Goals</h3>" in page
    import re

    assert re.findall(r"<h2>(.*?)</h2>", page) == list(SECTIONS)  # a subsection: the page keeps its sections


def test_report_command_with_a_plan(result_path, tmp_path, run_cli):
    plan = {"schema": "jcalib.plan/1", "stations": [{"id": "s000", "T_base_flange": np.eye(4).tolist()}],
            "planner": {"kind": "optimal", "goals": ["T_flange_cam0:translation_mm<=1000", "cam0:projection_px<=1e-9"],
                        "predicted": {"T_flange_cam0:translation_mm<=1000": 0.123, "cam0:projection_px<=1e-9": 0.2}}}
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    goals, predicted = plan_goals(tmp_path / "plan.json")
    assert [g.text for g in goals] == plan["planner"]["goals"] and predicted["T_flange_cam0:translation_mm<=1000"] == 0.123
    code, text = run_cli("report", result_path, "--plan", tmp_path / "plan.json", "-o", tmp_path / "r.html")
    assert code == 0, text
    assert "Goals" in text and "0.123" in text and "yes" in text and "no" in text
    assert "<h3>Goals</h3>" in (tmp_path / "r.html").read_text()
    del plan["planner"]["goals"]
    (tmp_path / "bad.json").write_text(json.dumps(plan))
    code, text = run_cli("report", result_path, "--plan", tmp_path / "bad.json", "-o", tmp_path / "r2.html")
    assert code == 2 and "no goals" in text and "Traceback" not in text
