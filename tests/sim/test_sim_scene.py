"""Scene tests: random calibration views meet their constraints (checked with cv2), robot pose
composition against explicit point chains, render_dataset files and ground truth, bad input."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sim_standins import make_camera, make_checkerboard, make_checkerboard_texture

from jcalib.errors import BadInputError
from jcalib.sim.render import RenderOptions
from jcalib.sim.scene import (
    Scene,
    SceneCamera,
    SceneTarget,
    View,
    camera_calibration_scene,
    random_calibration_views,
    render_dataset,
    render_view,
)

W, H = 640, 480
K = np.array([[520.0, 0.0, 321.0], [0.0, 521.0, 238.5], [0.0, 0.0, 1.0]])
DIST = np.array([-0.25, 0.09, 0.0005, -0.0004, -0.015])
CAM = make_camera(K, DIST, (W, H))
BOARD = make_checkerboard(7, 5, 0.03)
TEXTURE = make_checkerboard_texture(BOARD, 0.0003, 0.03)


def _random_pose(rng: np.random.Generator, scale: float = 0.5) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rng.normal(size=3))[0]
    T[:3, 3] = rng.normal(size=3) * scale
    return T


@settings(max_examples=12)
@given(seed=st.integers(0, 2**31 - 1))
def test_random_views_satisfy_constraints(seed):
    """Every corner in front of the camera, inside the image with the margin (cv2.projectPoints),
    tilt <= max_tilt (angle between board normal and optical axis), the printed face towards the
    camera, and the views spread over the image (centres span > 25 % of each side)."""
    margin, max_tilt = 15.0, 45.0
    poses = random_calibration_views(CAM, BOARD.points, 8, rng=seed, margin_px=margin, max_tilt_deg=max_tilt)
    assert len(poses) == 8
    centres = []
    for T in poses:
        p_cam = BOARD.points @ T[:3, :3].T + T[:3, 3]
        assert np.all(p_cam[:, 2] > 0)
        px, _ = cv2.projectPoints(BOARD.points, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K, DIST)
        px = px.reshape(-1, 2)
        assert np.all(px >= margin - 1e-6) and np.all(px[:, 0] <= W - 1 - margin + 1e-6)
        assert np.all(px[:, 1] <= H - 1 - margin + 1e-6)
        tilt = np.degrees(np.arccos(np.clip(T[2, 2], -1.0, 1.0)))
        assert tilt <= max_tilt + 1e-9
        assert (-T[:3, :3].T @ T[:3, 3])[2] < 0  # camera on the printed (-z) side
        centres.append(px.mean(axis=0))
    centres = np.array(centres)
    assert np.ptp(centres[:, 0]) > 0.25 * W and np.ptp(centres[:, 1]) > 0.25 * H


def test_random_views_reproducible_and_impossible_raises():
    a = random_calibration_views(CAM, BOARD.points, 5, rng=3)
    b = random_calibration_views(CAM, BOARD.points, 5, rng=np.random.default_rng(3))
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    with pytest.raises(BadInputError, match="margin_px"):
        random_calibration_views(CAM, BOARD.points, 1, rng=0, margin_px=300.0, max_attempts=30)
    with pytest.raises(BadInputError, match="num_views"):
        random_calibration_views(CAM, BOARD.points, 0)


def test_robot_pose_composition():
    """Eye-in-hand, eye-to-hand and both-fixed T_cam_target agree with moving one point through
    the frames step by step (1e-12: float64 products of a few 4x4 matrices)."""
    rng = np.random.default_rng(0)
    T_base_flange, T_flange_cam, T_base_target, T_base_cam, T_flange_target = (_random_pose(rng) for _ in range(5))
    p_target = np.array([0.1, -0.2, 0.0, 1.0])
    view = View("s000", T_base_flange=T_base_flange)
    cases = [
        (("flange", T_flange_cam, "base", T_base_target),
         np.linalg.solve(T_flange_cam, np.linalg.solve(T_base_flange, T_base_target @ p_target))),
        (("base", T_base_cam, "flange", T_flange_target),
         np.linalg.solve(T_base_cam, T_base_flange @ (T_flange_target @ p_target))),
        (("base", T_base_cam, "base", T_base_target), np.linalg.solve(T_base_cam, T_base_target @ p_target)),
    ]
    for (cm, cp, tm, tp), p_cam in cases:
        scene = Scene({"cam0": SceneCamera(CAM, cm, cp)}, {"board": SceneTarget(BOARD, TEXTURE, tm, tp)}, [view])
        T = scene.T_cam_target(0, "cam0", "board")
        np.testing.assert_allclose(T @ p_target, p_cam, atol=1e-12)


def test_scene_bad_input():
    with pytest.raises(BadInputError, match="pose"):
        Scene({"cam0": SceneCamera(CAM, "flange")}, {"board": SceneTarget(BOARD, TEXTURE, "base", np.eye(4))}, [])
    with pytest.raises(BadInputError, match="T_base_flange"):
        Scene(
            {"cam0": SceneCamera(CAM, "flange", np.eye(4))},
            {"board": SceneTarget(BOARD, TEXTURE, "base", np.eye(4))},
            [View("s0")],
        )
    with pytest.raises(BadInputError, match="mount"):
        Scene({"cam0": SceneCamera(CAM, "ceiling")}, {"board": SceneTarget(BOARD, TEXTURE)}, [])
    with pytest.raises(BadInputError, match="unknown camera"):
        bad_view = View("v0", T_cam_target={("x", "board"): np.eye(4)})
        Scene({"cam0": SceneCamera(CAM)}, {"board": SceneTarget(BOARD, TEXTURE)}, [bad_view])


def test_render_dataset_files_truth_and_determinism(tmp_path):
    """PNG + truth.json: images decode to what render_view gives with seed [seed, view, camera];
    truth pixels equal cv2.projectPoints (1e-6 px: two float64 implementations of the same formula);
    visibility = inside the image; a second run with the same seed writes identical bytes."""
    scene = camera_calibration_scene(CAM, BOARD, TEXTURE, 3, seed=1)
    options = RenderOptions(bit_depth=12)
    truth_path = render_dataset(scene, tmp_path / "a", options, seed=4)
    truth = json.loads(truth_path.read_text())
    assert truth["schema"] == "jcalib.sim.truth/1"
    assert truth["cameras"]["cam0"]["image_size"] == [W, H]
    np.testing.assert_allclose(truth["cameras"]["cam0"]["K"], K)
    np.testing.assert_allclose(truth["cameras"]["cam0"]["dist"], DIST)
    assert truth["render_options"]["read_noise_e"] == options.read_noise_e
    assert len(truth["views"]) == 3
    for i, view in enumerate(truth["views"]):
        image = cv2.imread(str(tmp_path / "a" / view["images"]["cam0"]), cv2.IMREAD_UNCHANGED)
        assert image.dtype == np.uint16 and image.shape == (H, W) and image.max() < 4096
        assert np.array_equal(image, render_view(scene, i, "cam0", options, np.random.default_rng([4, i, 0])))
        (obs,) = view["observations"]
        T = np.array(obs["T_cam_target"])
        px, _ = cv2.projectPoints(BOARD.points, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K, DIST)
        np.testing.assert_allclose(np.array(obs["pixels"]), px.reshape(-1, 2), atol=1e-6)
        assert all(obs["visible"])
    render_dataset(scene, tmp_path / "b", options, seed=4)
    for rel in ["truth.json"] + [v["images"]["cam0"] for v in truth["views"]]:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes()


def test_render_dataset_robot_scene_partial_visibility(tmp_path):
    """An eye-in-hand station where the board is half out of view: the image renders, truth marks
    the points outside the image as not visible (checked against the image bounds)."""
    T_base_target = np.eye(4)
    T_base_target[:3, 3] = [0.5, 0.0, 0.0]
    T_flange_cam = np.eye(4)
    stations = []
    for k, dx in enumerate([0.0, 0.36]):  # second station: camera shifted, board partly outside
        T_base_flange = np.eye(4)
        T_base_flange[:3, 3] = [0.5 + 0.09 + dx, 0.06, -0.5]
        stations.append(View(f"s{k:03d}", T_base_flange=T_base_flange))
    scene = Scene(
        {"cam0": SceneCamera(CAM, "flange", T_flange_cam)},
        {"board": SceneTarget(BOARD, TEXTURE, "base", T_base_target)},
        stations,
    )
    truth = json.loads(render_dataset(scene, tmp_path, RenderOptions(), seed=0).read_text())
    assert "T_flange_cam0" in truth["cameras"]["cam0"] and "T_base_board" in truth["targets"]["board"]
    full, partial = (v["observations"][0] for v in truth["views"])
    assert all(full["visible"])
    vis = np.array(partial["visible"])
    px = np.array([p if p is not None else [np.nan, np.nan] for p in partial["pixels"]], dtype=float)
    inside = (px[:, 0] >= -0.5) & (px[:, 0] <= W - 0.5) & (px[:, 1] >= -0.5) & (px[:, 1] <= H - 0.5)
    assert 0 < vis.sum() < len(vis)
    np.testing.assert_array_equal(vis, inside)
    assert np.array(truth["views"][1]["T_base_flange"]).shape == (4, 4)
