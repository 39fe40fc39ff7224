"""`jcalib detect` end to end on OpenCV's real left images, and its exit statuses on bad input."""

import json
import subprocess
import sys

import numpy as np

JCALIB = [sys.executable, "-c", "from jcalib.app.cli import main; main()"]

CELL = """schema: jcalib.cell/1
cameras:
  left: {model: opencv5}
targets:
  board: {type: checkerboard, cols: 9, rows: 6, square: 0.030}
"""


def run(*args, cwd):
    return subprocess.run([*JCALIB, *map(str, args)], capture_output=True, text=True, cwd=cwd)


def test_detect_writes_observations_for_all_left_images(tmp_path, real_data):
    (tmp_path / "cell.yaml").write_text(CELL)
    images = sorted((real_data / "opencv_left_right_chessboard" / "images").glob("left*.jpg"))
    assert len(images) == 13
    proc = run("detect", "--cell", "cell.yaml", "--camera", "left", *images, "-o", "obs.json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    obs = json.loads((tmp_path / "obs.json").read_text())
    assert obs["schema"] == "jcalib.observations/1"
    assert obs["cameras"] == {"left": {"image_size": [640, 480]}}
    assert [s["id"] for s in obs["stations"]] == [p.stem for p in images]
    for station in obs["stations"]:
        (det,) = station["detections"]
        assert sorted(det["point_index"]) == list(range(54))
        pixels = np.asarray(det["pixels"])
        assert pixels.shape == (54, 2)
        assert np.all((pixels > 0) & (pixels < [640, 480]))


def test_detect_reports_undetectable_images_and_bad_cell(tmp_path):
    import cv2

    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 128, np.uint8))
    (tmp_path / "cell.yaml").write_text(CELL)
    proc = run("detect", "--cell", "cell.yaml", "--camera", "left", blank, "-o", "obs.json", cwd=tmp_path)
    assert proc.returncode == 2
    assert "not_found" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "obs.json").exists()

    (tmp_path / "bad.yaml").write_text(CELL.replace("opencv5", "opencv6"))
    proc = run("detect", "--cell", "bad.yaml", "--camera", "left", blank, "-o", "obs.json", cwd=tmp_path)
    assert proc.returncode == 2
    assert "opencv6" in proc.stderr and "Traceback" not in proc.stderr

    proc = run("detect", "--cell", "cell.yaml", "--camera", "right", blank, "-o", "obs.json", cwd=tmp_path)
    assert proc.returncode == 2 and "right" in proc.stderr
