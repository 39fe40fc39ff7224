"""Tool-tip detection on rendered backlight images, and the tool renderer against closed forms / OpenCV."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jcalib.errors import BadInputError, DetectionError
from jcalib.geometry.cameras import camera_from_opencv
from jcalib.sim.render import RenderOptions
from jcalib.sim.tool import SymmetricTool, render_tool_image, tool_rays_hit
from jcalib.vision.tooltip import TOOLTIP_FAILURE_REASONS, detect_tool_tip

W, H = 640, 480
K = np.array([[1216.0, 0.0, 322.8], [0.0, 1216.0, 237.4], [0.0, 0.0, 1.0]])
DIST = np.array([-0.25, 0.12, 0.001, -0.0005, -0.02])
# A long tool: its shaft always leaves the image, as when it is held by a robot.
TOOL = SymmetricTool(shaft_radius_m=0.003, cone_half_angle_deg=20.0, length_m=0.5)


def pose_from(tip_cam: np.ndarray, axis_cam: np.ndarray) -> np.ndarray:
    """T_cam_tcp with the tip at ``tip_cam`` (m) and the tool axis (tcp +z) along ``axis_cam``."""
    z = axis_cam / np.linalg.norm(axis_cam)
    a = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = tip_cam
    return T


def random_pose(rng: np.random.Generator, dist: np.ndarray | None, margin: float = 40.0) -> np.ndarray:
    """Tip inside the image (``margin`` px from the border), 0.2-0.4 m away, the axis at a random
    angle in the image and tilted out of the image plane by up to +-45 degrees."""
    u, v = rng.uniform(margin, W - 1 - margin), rng.uniform(margin, H - 1 - margin)
    p = cv2.undistortPoints(np.array([[[u, v]]]), K, dist if dist is not None else np.zeros(5)).reshape(2)
    depth = rng.uniform(0.2, 0.4)
    theta, tilt = rng.uniform(-np.pi, np.pi), np.deg2rad(rng.uniform(-45.0, 45.0))
    axis = np.array([np.cos(tilt) * np.cos(theta), np.cos(tilt) * np.sin(theta), np.sin(tilt)])
    return pose_from(np.array([p[0] * depth, p[1] * depth, depth]), axis)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))


def detection_errors(camera, dist, options, n, seed, tool=TOOL, use_camera=False):
    rng = np.random.default_rng(seed)
    tip_err, axis_err = [], []
    for _ in range(n):
        rendered = render_tool_image(camera, random_pose(rng, dist), tool, options, rng)
        det = detect_tool_tip(rendered.image, camera=camera if use_camera else None)
        assert det.pixel.dtype == np.float64 and det.pixel.shape == (2,)
        tip_err.append(float(np.linalg.norm(det.pixel - rendered.tip_px)))
        axis_err.append(angle_deg(det.axis_direction, rendered.axis_direction))
    return np.array(tip_err), np.array(axis_err)


@pytest.fixture(scope="module")
def pinhole():
    return camera_from_opencv(K, None, (W, H))


@pytest.fixture(scope="module")
def distorted():
    return camera_from_opencv(K, DIST, (W, H))


# ----------------------------------------------------------------------------------------- renderer


def test_shaft_width_matches_closed_form(pinhole):
    # Axis parallel to the image x axis through the optical axis at depth D: the planes through the
    # camera centre tangent to the shaft project to the rows cy +- f r / sqrt(D^2 - r^2).
    D, r = 0.3137, 0.003
    T = pose_from(np.array([-0.02, 0.0, D]), np.array([1.0, 0.0, 0.0]))
    out = render_tool_image(pinhole, T, TOOL, RenderOptions(shot_noise=False, read_noise_e=0.0), 0)
    expected = 2.0 * K[0, 0] * r / math.sqrt(D * D - r * r)
    widths = out.coverage[:, 450:630].sum(axis=0)
    # 16 x 16 samples on the boundary pixels: each horizontal edge is quantised to 1/16 px.
    np.testing.assert_allclose(widths, expected, atol=2.0 / 16.0)
    # Cone: tangent lines through the apex image; its width 10 px behind the tip.
    tip_u = K[0, 2] + K[0, 0] * -0.02 / D
    col = int(round(tip_u + 10.0))
    half_angle = math.radians(TOOL.cone_half_angle_deg)
    z = (col - K[0, 2]) * D / K[0, 0] + 0.02  # tcp z of that column (axis in the image plane)
    rc = z * math.tan(half_angle)
    expected_cone = 2.0 * K[0, 0] * rc / math.sqrt(D * D - rc * rc)
    assert out.coverage[:, col].sum() == pytest.approx(expected_cone, abs=0.15)


def test_ground_truth_matches_opencv(distorted):
    rng = np.random.default_rng(3)
    for _ in range(3):
        T = random_pose(rng, DIST)
        out = render_tool_image(distorted, T, TOOL, RenderOptions(supersample=1), rng, edge_supersample=1)
        rvec = cv2.Rodrigues(T[:3, :3])[0]
        pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1e-7]])
        proj = cv2.projectPoints(pts, rvec, T[:3, 3], K, DIST)[0].reshape(2, 2)
        np.testing.assert_allclose(out.tip_px, proj[0], atol=1e-9)  # float64 identity
        fd = (proj[1] - proj[0]) / np.linalg.norm(proj[1] - proj[0])
        assert angle_deg(out.axis_direction, fd) < 1e-3  # finite difference over 0.1 um
        assert out.tip_in_image


def test_ray_hits_against_point_sampling():
    # Independent reference: march densely along each ray and test the points against the profile.
    tool = SymmetricTool(shaft_radius_m=0.003, cone_half_angle_deg=25.0, length_m=0.05, tip_radius_m=0.0008)
    rng = np.random.default_rng(0)
    origin = np.array([0.02, -0.01, 0.03])
    targets = rng.uniform([-0.005, -0.005, -0.003], [0.005, 0.005, 0.06], size=(400, 3))
    dirs = targets - origin
    hit = tool_rays_hit(tool, origin, dirs)
    t = np.linspace(0.0, 2.0, 20001)
    p = origin[None, None, :] + t[None, :, None] * dirs[:, None, :]
    rr = np.hypot(p[..., 0], p[..., 1])
    z = p[..., 2]
    alpha = math.radians(tool.cone_half_angle_deg)
    cone = (z >= tool.sphere_end_z_m) & (z <= tool.length_m) & (rr <= tool.shaft_radius_m)
    cone &= rr <= math.tan(alpha) * (z - tool.apex_z_m)
    sphere = rr**2 + (z - tool.tip_radius_m) ** 2 <= tool.tip_radius_m**2
    marched = (cone | sphere).any(axis=1)
    # rays grazing the surface can differ between marching steps; none of these 400 does
    assert np.mean(hit == marched) >= 0.995
    assert 50 < hit.sum() < 350


# ----------------------------------------------------------------------------------------- accuracy


def test_tip_accuracy_default_noise(pinhole):
    # RenderOptions defaults: 8-bit, 10 000 e- full well, shot noise + 3 e- read noise (backlight
    # ~6300 e-: ~1.3 % noise), Gaussian blur sigma 0.7 px, cos^4 vignetting. Measured over 40 poses:
    # mean 0.03 px, max 0.09 px; axis mean 0.003 deg. Bounds have ~3x margin.
    tip, axis = detection_errors(pinhole, None, RenderOptions(), 12, seed=11)
    assert tip.mean() < 0.1 and tip.max() < 0.3
    assert axis.mean() < 0.05 and axis.max() < 0.2


def test_tip_accuracy_distorted_with_camera(distorted):
    # The edge points are undistorted before the line fits: as accurate as a pinhole.
    tip, axis = detection_errors(distorted, DIST, RenderOptions(), 8, seed=12, use_camera=True)
    assert tip.mean() < 0.1 and tip.max() < 0.3
    assert axis.mean() < 0.05 and axis.max() < 0.2


def test_tip_accuracy_blurred(pinhole):
    # Gaussian blur sigma 1.5 px with default noise: measured mean 0.06 px over 20 poses.
    tip, axis = detection_errors(pinhole, None, RenderOptions(blur_sigma_px=1.5), 8, seed=13)
    assert tip.mean() < 0.2 and tip.max() < 0.5
    assert axis.mean() < 0.1


def test_rounded_tip_gives_the_cone_apex(pinhole):
    # The edge lines meet at the cone's virtual apex, (0, 0, apex_z) in the tcp frame.
    tool = SymmetricTool(shaft_radius_m=0.003, cone_half_angle_deg=20.0, length_m=0.5, tip_radius_m=0.0003)
    rng = np.random.default_rng(14)
    for _ in range(3):
        T = random_pose(rng, None)
        out = render_tool_image(pinhole, T, tool, RenderOptions(), rng)
        det = detect_tool_tip(out.image)
        apex = T[:3, :3] @ np.array([0.0, 0.0, tool.apex_z_m]) + T[:3, 3]
        apex_px = (K @ apex)[:2] / apex[2]
        assert np.linalg.norm(det.pixel - apex_px) < 0.3
        assert np.linalg.norm(det.pixel - out.tip_px) > 0.5  # the apex is measurably beyond the tip


def test_uint16_and_colour_input(pinhole):
    rng = np.random.default_rng(15)
    out = render_tool_image(pinhole, random_pose(rng, None), TOOL, RenderOptions(bit_depth=12), rng)
    det16 = detect_tool_tip(out.image)
    bgr = cv2.cvtColor((out.image >> 4).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    det8 = detect_tool_tip(bgr)
    assert np.linalg.norm(det16.pixel - out.tip_px) < 0.3
    assert np.linalg.norm(det8.pixel - out.tip_px) < 0.3
    assert det16.to_json() == {"pixel": [float(det16.pixel[0]), float(det16.pixel[1])]}
    assert det16.diagnostics["method"] == "cone_edges"


# ----------------------------------------------------------------------------------------- failures


def reason(image, **kw) -> str:
    with pytest.raises(DetectionError) as info:
        detect_tool_tip(image, **kw)
    assert info.value.reason in TOOLTIP_FAILURE_REASONS
    return info.value.reason


def test_blank_dark_and_flat_images_are_not_found():
    rng = np.random.default_rng(0)
    assert reason(np.zeros((H, W), np.uint8)) == "not_found"
    assert reason(np.full((H, W), 255, np.uint8)) == "not_found"
    assert reason(np.full((H, W), 160, np.uint8)) == "not_found"
    noisy = np.clip(rng.normal(160, 2.0, (H, W)), 0, 255).astype(np.uint8)
    assert reason(noisy) == "not_found"
    dark_noise = np.clip(rng.normal(3, 1.5, (H, W)), 0, 255).astype(np.uint8)
    assert reason(dark_noise) == "not_found"


def test_two_tools_are_ambiguous(pinhole):
    a = render_tool_image(pinhole, pose_from(np.array([-0.03, -0.03, 0.3]), np.array([-1.0, 0, 0])), TOOL)
    b = render_tool_image(pinhole, pose_from(np.array([0.03, 0.03, 0.3]), np.array([1.0, 0, 0])), TOOL)
    assert reason(np.minimum(a.image, b.image)) == "ambiguous"


def test_tip_outside_the_image(pinhole):
    # tip 20 px beyond the right border, the tool coming in from the left
    u = W + 20.0
    x = (u - K[0, 2]) / K[0, 0] * 0.3
    out = render_tool_image(pinhole, pose_from(np.array([x, 0.0, 0.3]), np.array([-1.0, 0.1, 0.0])), TOOL)
    assert not out.tip_in_image
    assert reason(out.image) == "tip_outside_image"


def test_tip_at_the_border_is_partially_visible(pinhole):
    # tip 1 px inside the top border: the cone's edges cannot be measured up to it
    v = 1.0
    y = (v - K[1, 2]) / K[1, 1] * 0.3
    out = render_tool_image(pinhole, pose_from(np.array([0.0, y, 0.3]), np.array([0.3, 1.0, 0.0])), TOOL)
    assert out.tip_in_image
    assert reason(out.image) in ("partially_visible", "tip_outside_image")


def test_bad_input():
    with pytest.raises(BadInputError, match="image"):
        detect_tool_tip(np.zeros((4, 4), np.uint8))
    with pytest.raises(BadInputError, match="image"):
        detect_tool_tip(np.zeros((20, 20, 2), np.uint8))
    with pytest.raises(BadInputError, match="tip_radius_m"):
        SymmetricTool(tip_radius_m=0.01)


@given(
    kind=st.sampled_from(["uniform", "noise", "rectangles", "saltpepper"]),
    level=st.integers(0, 255),
    seed=st.integers(0, 2**16),
    size=st.tuples(st.integers(8, 64), st.integers(8, 64)),
)
def test_never_crashes(kind, level, seed, size):
    """Any image gives a detection or a DetectionError with a known reason, never another error."""
    rng = np.random.default_rng(seed)
    h, w = size
    if kind == "uniform":
        img = np.full((h, w), level, np.uint8)
    elif kind == "noise":
        img = rng.integers(0, 256, (h, w)).astype(np.uint8)
    elif kind == "saltpepper":
        img = np.where(rng.random((h, w)) < 0.05, 0, level).astype(np.uint8)
    else:
        img = np.full((h, w), level, np.uint8)
        for _ in range(rng.integers(1, 4)):
            x0, y0 = rng.integers(0, w), rng.integers(0, h)
            img[y0 : y0 + rng.integers(1, h), x0 : x0 + rng.integers(1, w)] = rng.integers(0, 256)
    try:
        det = detect_tool_tip(img)
    except DetectionError as e:
        assert e.reason in TOOLTIP_FAILURE_REASONS
    else:
        assert np.all(np.isfinite(det.pixel)) and abs(np.linalg.norm(det.axis_direction) - 1.0) < 1e-9
