"""Rendered hand-eye data sets with ground truth for the importer tests (jcalib.sim): the images and
robot poses that each test writes in another tool's exact layout, then imports, detects and calibrates."""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass

import numpy as np
import pytest

from jcalib.planning.layout import cell_layout
from jcalib.planning.stations import plan_cell
from jcalib.app.simcell import scene_from_layout

sys.path.insert(0, os.path.dirname(__file__))  # importer_roundtrip: the shared round-trip steps

IMAGE_SIZE = (480, 360)


@dataclass(frozen=True)
class Rendered:
    """Images (H, W) uint8, flange poses (N, 4, 4) m, the truth: T_flange_cam (eye-in-hand), the board pose
    T_base_target, the camera matrix K (px) and the cell-spec target entry."""

    images: list
    T_base_flange: np.ndarray
    T_flange_cam: np.ndarray
    T_base_target: np.ndarray
    K: np.ndarray
    target: dict


def render(target: dict, num_stations: int = 10) -> Rendered:
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "pinhole", "mount": "flange"}},
            "targets": {"board": {**target, "mount": "base"}}}
    layout = cell_layout(cell, image_size=IMAGE_SIZE)
    plan = plan_cell(layout, "handeye", num_stations=num_stations).plan
    scene = scene_from_layout(layout)
    T = np.stack([s.T_base_flange for s in plan.stations])
    images = [scene.render("cam0", Tk, rng=k) for k, Tk in enumerate(T)]
    cam, tgt = layout.cameras["cam0"], layout.targets["board"]
    return Rendered(images, T, cam.pose, tgt.pose, cam.K, target)


@pytest.fixture(scope="session")
def chessboard_set() -> Rendered:
    return render({"type": "checkerboard", "cols": 8, "rows": 6, "square": 0.02})


@pytest.fixture(scope="session")
def aprilgrid_set() -> Rendered:
    # a Kalibr AprilGrid (tag36h11, 2-bit borders, crossing squares), as kalibr_create_target_pdf prints it
    return render({"type": "aprilgrid", "family": "tag36h11", "cols": 5, "rows": 4, "tag_size": 0.03,
                   "tag_spacing": 0.3})


@pytest.fixture(scope="session")
def charuco_set() -> Rendered:
    # industrial_calibration's example board layout (rows 7, cols 5), DICT_6X6_250 (OpenCV id 10)
    return render({"type": "charuco", "squares_x": 5, "squares_y": 7, "square": 0.03, "marker": 0.022,
                   "dictionary": "DICT_6X6_250", "legacy": True})
