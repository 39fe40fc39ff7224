"""A rendered fisheye calibration scene shared by ``test_fisheye_end_to_end.py`` and
``benchmarks/bench_fisheye.py``: the KB4 camera (its truth), the ChArUco board, the image formation
and board views spread over the whole image, near the rim too.

The camera: 1024x768, fx ≈ fy ≈ 331 px, cv2.fisheye coefficients of the size real 180° lenses get
(k1 = 0.021, k2 = -0.012, k3 = 0.004, k4 = -0.0006; the polynomial is monotonic up to 127° from the
axis). Its field of view is 174° across the width and over 180° across the diagonal: the image
corners (about 110° from the axis) see behind the camera plane, like a real full-frame fisheye.

The board: ChArUco 9x7 squares of 40 mm (markers 30 mm, DICT_5X5_100, 48 corners). ChArUco rather
than a chessboard because each corner is identified by the markers around it: a partial view (part
of the board outside the image or too compressed at the rim to be found) still gives its corners,
while ``findChessboardCorners`` needs the whole board and fails on curved rows near the rim.
"""

from __future__ import annotations

import math

import numpy as np

from jcalib.geometry import Fisheye
from jcalib.geometry.se3 import rotation, rotation_z_to
from jcalib.geometry.targets import Charuco
from jcalib.sim.render import RenderOptions
from jcalib.sim.scene import project_target

IMAGE_SIZE = (1024, 768)
#: The truth: fx, fy, cx, cy (px), k1..k4 (cv2.fisheye's D).
TRUE_PARAMS = np.array([331.2, 330.6, 515.4, 381.9, 0.021, -0.012, 0.004, -0.0006])
CAMERA = Fisheye(IMAGE_SIZE, TRUE_PARAMS[:2], TRUE_PARAMS[2:4], TRUE_PARAMS[4:])
PARAM_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")

BOARD = Charuco(9, 7, 0.04, 0.03, "DICT_5X5_100")
CELL = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "fisheye"}},
    "targets": {"board": BOARD.to_spec()},
}
#: Texture resolution of the printed board, m per texel (0.2 mm: ~5x finer than the image at 0.3 m).
TEXTURE_M_PER_PX = 0.0002

#: Image formation: the renderer's "realistic" sensor (read noise 6 e-, gain to ~70 % of 8 bits, shot
#: noise) with a 1.2 px defocus; a brighter exposure than the preset's 120 e- (the ArUco cells are
#: 3-6 px wide here, and a real fisheye calibration is lit for them), and a fisheye's gentle light
#: fall-off (cos¹ of the field angle: cos⁴ would leave the rim black at 85°).
RENDER = RenderOptions.preset(
    "realistic", white_electrons=1500.0, gain_dn_per_e=255.0 / (1.4 * 1500.0), blur_sigma_px=1.2,
    vignetting_power=1.0,
)


def board_views(camera, board, num_views: int, seed: int, *, max_angle_deg: float = 82.0,
                min_visible: float = 0.5) -> list[np.ndarray]:
    """Board poses ``T_cam_board`` (4, 4, m) spread over the whole image of a wide-angle camera.

    Each view's board centre lies on the ray of a random pixel of its own cell of a ``g x g`` grid
    over the image (``g² >= num_views``; rays more than ``max_angle_deg`` from the axis are drawn
    again), the board faces the camera centre (normal along that ray, not along the optical axis:
    at the rim a board parallel to the image plane is seen edge-on), tilted by up to 40° and turned
    about its normal at random, at a distance where it spans 45-75° of the view. At least
    ``min_visible`` of its corners are in the image.
    """
    rng = np.random.default_rng(seed)
    points = board.points
    centre = points.mean(axis=0)
    radius = float(np.max(np.linalg.norm(points - centre, axis=1)))
    w, h = camera.image_size
    g = int(math.ceil(math.sqrt(num_views)))
    cells = rng.permutation(g * g)[:num_views]
    out = []
    for k in range(num_views):
        for attempt in range(500):
            row, col = divmod(int(cells[k] if attempt < 50 else rng.integers(g * g)), g)
            pixel = np.array([(col + rng.random()) / g * (w - 1), (row + rng.random()) / g * (h - 1)])
            ray = np.asarray(camera.unproject(pixel))
            if math.degrees(math.acos(min(1.0, float(ray[2])))) > max_angle_deg:
                continue
            distance = radius / math.tan(math.radians(rng.uniform(45.0, 75.0)) / 2.0)
            phi = rng.uniform(0.0, 2.0 * math.pi)
            R = (rotation_z_to(ray) @ rotation(np.array([math.cos(phi), math.sin(phi), 0.0]),
                                               math.radians(rng.uniform(0.0, 40.0)))
                 @ rotation(np.array([0.0, 0.0, 1.0]), rng.uniform(-math.pi, math.pi)))
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R, distance * ray - R @ centre
            if project_target(camera, T, points)[1].mean() >= min_visible:
                out.append(T)
                break
        else:  # pragma: no cover  (the constraints above always leave room)
            raise RuntimeError(f"board_views: no pose for view {k}")
    return out


def observations(point_index, pixels, image_size=IMAGE_SIZE) -> dict:
    """A ``jcalib.observations/1`` document of one camera ``cam0`` seeing ``board`` in each view."""
    return {
        "schema": "jcalib.observations/1",
        "cameras": {"cam0": {"image_size": list(image_size)}},
        "targets": {"board": {"points": BOARD.points.tolist()}},
        "stations": [
            {"id": f"v{i:02d}", "detections": [{"camera": "cam0", "target": "board",
                                                "point_index": np.asarray(idx).tolist(),
                                                "pixels": np.asarray(px).tolist()}]}
            for i, (idx, px) in enumerate(zip(point_index, pixels))
        ],
    }


def splined_truth():
    """A lens no KB4 fisheye describes (``test_splined_calibration.py``, ``bench_splined.py``): a stereographic
    projection with this scene's focal length and principal point plus a smooth, non-radial spline of ~1.3 px."""
    from jcalib.geometry.cameras.splined import GRID, SplinedStereographic, fov_covering

    nx, ny = GRID
    fov = fov_covering(CAMERA.focal, CAMERA.principal_point, IMAGE_SIZE)
    j, i = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    bump = 0.004 * np.stack([np.sin(i / 3.0) * np.cos(j / 4.0), np.cos(i / 4.0) * np.sin(j / 3.0)], axis=-1)
    return SplinedStereographic(IMAGE_SIZE, CAMERA.focal, CAMERA.principal_point, fov, bump)


def projection_error(model, truth, pixels) -> np.ndarray:
    """``|model.project(R · ray_truth(q)) − q|`` over pixels ``q`` after the best rotation ``R`` (two
    calibrations of one lens may differ by a rotation of the camera frame)."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    rays = np.asarray(truth.unproject(pixels))

    def residual(w):
        return (np.asarray(model.project(rays @ Rotation.from_rotvec(w).as_matrix().T)) - pixels).ravel()

    return np.linalg.norm(least_squares(residual, np.zeros(3)).fun.reshape(-1, 2), axis=1)
