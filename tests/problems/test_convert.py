"""Converting a camera model into another lens model over a region: exact where the target contains the
source, the reported error against OpenCV's own projections, the propagated covariance against a
finite-difference re-conversion, and clear refusals."""

import cv2
import numpy as np
import pytest

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import camera_from_opencv
from jcalib.problems.convert import convert_camera

K5 = np.array([[900.0, 0, 640.0], [0, 905.0, 481.0], [0, 0, 1]])
D5 = np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02])
KF = np.array([[420.0, 0, 640.0], [0, 421.0, 480.0], [0, 0, 1]])
DF = np.array([0.02, -0.01, 0.003, -0.0005])
SIZE = (1280, 960)


def test_a_model_inside_the_target_converts_exactly_and_keeps_its_covariance():
    """opencv5 is opencv8 with k4 = k5 = k6 = 0: the fit is exact and the covariance of the common
    coefficients is the source's (the fit's derivative is the identity on them)."""
    source = camera_from_opencv(K5, D5, SIZE)
    rng = np.random.default_rng(0)
    B = rng.normal(size=(9, 9)) * np.array([0.3, 0.3, 0.2, 0.2, 1e-3, 1e-3, 1e-5, 1e-5, 1e-3])
    cov = B @ B.T
    c = convert_camera(source, "opencv8", covariance=cov, fix=["k4", "k5", "k6"])
    assert c.max_px < 1e-8 and c.num_left_out == 0
    np.testing.assert_allclose(np.asarray(c.model.params)[:9], np.asarray(source.params), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(c.covariance[:9, :9], cov, rtol=1e-6, atol=1e-12 * np.abs(cov).max())
    assert np.all(c.covariance[9:, :] == 0.0)


def test_fisheye_to_opencv5_error_agrees_with_opencv():
    """The reported RMS / max difference over the region equals what OpenCV computes for the same rays:
    cv2.fisheye.undistortPoints gives each sample pixel's ray, cv2.projectPoints the converted model's pixel."""
    source = camera_from_opencv(KF, DF, SIZE, fisheye=True)
    region = (440, 330, 840, 630)
    c = convert_camera(source, "opencv5", region=region, grid=(21, 16))
    assert c.region == region and c.num_pixels == 21 * 16
    u, v = np.meshgrid(np.linspace(440, 840, 21), np.linspace(330, 630, 16))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1)
    xy = cv2.fisheye.undistortPoints(pixels[:, None, :], KF, DF,
                                     criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))[:, 0]
    rays = np.c_[xy, np.ones(len(xy))]
    K, dist = c.model.to_opencv()
    again, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, dist)
    length = np.linalg.norm(again[:, 0] - pixels, axis=1)
    assert abs(np.sqrt(np.mean(length**2)) - c.rms_px) < 1e-6 * max(1.0, c.rms_px)
    assert abs(length.max() - c.max_px) < 1e-6 * max(1.0, c.max_px)
    assert 1e-3 < c.max_px < 5.0  # a fisheye is not a 5-coefficient OpenCV lens, but close in the centre


def test_propagated_covariance_matches_a_finite_difference_reconversion():
    """Σ_θ = A Σ_ψ Aᵀ with A = ∂θ*/∂ψ: with Σ_ψ = e_j e_jᵀ the result is a_j a_jᵀ, a_j the change of the
    converted coefficients per unit change of the source's coefficient j (central differences)."""
    source = camera_from_opencv(KF, DF, SIZE, fisheye=True)
    region, grid = (400, 300, 880, 660), (12, 9)
    for j, h in ((0, 0.02), (6, 1e-5)):  # the source's fx and k3
        moved = []
        for sign in (1.0, -1.0):
            psi = np.asarray(source.params).copy()
            psi[j] += sign * h
            moved.append(np.asarray(convert_camera(type(source).from_params(SIZE, psi), "opencv5", region=region,
                                                   grid=grid).model.params))
        a = (moved[0] - moved[1]) / (2 * h)
        e = np.zeros(8)
        e[j] = 1.0
        cov = convert_camera(source, "opencv5", covariance=np.outer(e, e), region=region, grid=grid).covariance
        np.testing.assert_allclose(cov, np.outer(a, a), rtol=1e-4, atol=1e-6 * np.abs(np.outer(a, a)).max())


def test_refusals_name_what_is_wrong():
    source = camera_from_opencv(K5, D5, SIZE)
    with pytest.raises(BadInputError, match="unknown camera model"):
        convert_camera(source, "opencv9")
    with pytest.raises(BadInputError, match="region"):
        convert_camera(source, "opencv5", region=(0, 0, 2000, 100))
    with pytest.raises(BadInputError, match="k7"):
        convert_camera(source, "opencv8", fix=["k7"])
    with pytest.raises(NotObservableError, match="fix"):
        convert_camera(source, "opencv8")  # rational terms vs k1, k2 on this field of view
    wide = camera_from_opencv(np.array([[200.0, 0, 640.0], [0, 200.0, 480.0], [0, 0, 1]]), DF, SIZE, fisheye=True)
    with pytest.raises(BadInputError, match="rays"):
        convert_camera(wide, "opencv5", region=(0, 0, 60, 40))  # every ray beyond 85° from the axis
