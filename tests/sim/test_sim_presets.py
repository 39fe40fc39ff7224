"""Image-formation presets and glare: the "realistic" preset gives the corner noise of real captures."""

from __future__ import annotations

import numpy as np
import pytest

from jcalib.errors import BadInputError
from jcalib.geometry import camera_from_opencv
from jcalib.geometry.targets import Checkerboard
from jcalib.sim.render import RenderOptions, render_target_image
from jcalib.sim.scene import project_target, random_calibration_views
from jcalib.sim.textures import target_texture
from jcalib.vision import detect_target

K = np.array([[768.0, 0.0, 319.5], [0.0, 768.0, 239.5], [0.0, 0.0, 1.0]])
CAMERA = camera_from_opencv(K, np.zeros(4), (640, 480))  # the demo's hand camera
BOARD = Checkerboard(8, 6, 0.025)
TEXTURE = target_texture(BOARD, 0.025 / 24)


def _corner_rms(options: RenderOptions, views: int = 4) -> float:
    errors = []
    for i, T in enumerate(random_calibration_views(CAMERA, BOARD.points, views, 7)):
        truth, _ = project_target(CAMERA, T, BOARD.points)
        img = render_target_image(CAMERA, T, TEXTURE, options, rng=100 + i)
        det = detect_target(img, BOARD)
        e = det.pixels - truth[det.point_index]
        if "orientation_ambiguous" in det.warnings and np.median(np.abs(e)) > 5:  # 180° relabelling
            e = det.pixels - truth[::-1][det.point_index]
        errors.append(e)
    return float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))


def test_realistic_preset_gives_real_corner_noise_and_clean_does_not():
    # real calibrations leave 0.1-0.3 px residuals; the clean defaults are ~10x more precise
    realistic = _corner_rms(RenderOptions.preset("realistic"))
    clean = _corner_rms(RenderOptions.preset("clean"))
    assert 0.06 < realistic < 0.3, realistic
    assert clean < 0.03 and realistic > 4 * clean, (clean, realistic)


def test_presets_are_deterministic_per_seed_and_checked():
    T = random_calibration_views(CAMERA, BOARD.points, 1, 3)[0]
    opts = RenderOptions.preset("realistic")
    a = render_target_image(CAMERA, T, TEXTURE, opts, rng=5)
    np.testing.assert_array_equal(a, render_target_image(CAMERA, T, TEXTURE, opts, rng=5))
    assert np.any(a != render_target_image(CAMERA, T, TEXTURE, opts, rng=6))
    assert RenderOptions.preset("clean") == RenderOptions()
    assert RenderOptions.preset("realistic", blur_sigma_px=2.0).blur_sigma_px == 2.0
    with pytest.raises(BadInputError, match="expected one of"):
        RenderOptions.preset("noisy")
    with pytest.raises(BadInputError, match="preset"):
        RenderOptions.preset("realistic", exposure=3)


def test_glare_brightens_and_saturates_its_spot():
    T = random_calibration_views(CAMERA, BOARD.points, 1, 3)[0]
    plain = render_target_image(CAMERA, T, TEXTURE, RenderOptions(shot_noise=False, read_noise_e=0.0), rng=0)
    opts = RenderOptions(shot_noise=False, read_noise_e=0.0, glare=((0.25, 0.5, 0.05, 2.0),))
    glared = render_target_image(CAMERA, T, TEXTURE, opts, rng=0)
    u, v = int(round(0.25 * 639)), int(round(0.5 * 479))
    assert glared[v, u] == 255 and plain[v, u] < 255
    assert np.array_equal(glared[:, 400:], plain[:, 400:])  # far from the spot (0.05 * 640 = 32 px σ): unchanged
    assert opts.to_dict()["glare"] == [[0.25, 0.5, 0.05, 2.0]]
    for bad in ([(0.5, 0.5, 0.0, 1.0)], [(0.5, 0.5, 0.1)], [(0.5, float("nan"), 0.1, 1.0)]):
        with pytest.raises(BadInputError, match="glare"):
            RenderOptions(glare=bad)
