"""The importers' input rules (issue 32), one case each: linear-time pairing patterns, --out as a new
folder written whole, strict numbers, paths inside the source, no file contents in messages.
(tests/fuzz/test_import_fuzz.py mutates every format; these pin the rules down by name.)"""

from __future__ import annotations

import json
import re
import time

import cv2
import numpy as np
import pytest
import yaml
from importer_roundtrip import cli

from jcalib.errors import BadInputError
from jcalib.io.importers import import_session
from jcalib.io.importers.calibration_rs import filename_pattern

PATTERNS = [r"^Cam\d+_(?<v>\d+)\.png$", r"(?<v>\d+)", r"img_(?<v>[0-9]{2,4})", r"(?<v>a|ab)(c|bcd)", r"(?<v>a*?)b",
            r"(?<v>\d+?)\d", r"^(?<v>[^_]+)_", r"(?<v>\w+)\.(png|jpg)$", r"(?:(?<v>\d)|[a-z])+$", r"(?<v>.*)_(\d+)"]


@pytest.mark.parametrize("pattern", PATTERNS)
def test_file_name_patterns_match_as_python_re(pattern):
    rng = np.random.default_rng(1)
    rx = re.compile(pattern.replace("(?<", "(?P<"))
    fp = filename_pattern(pattern, "test")
    for _ in range(300):
        name = "".join(rng.choice(list("ab0123_.xyzcdp"), size=rng.integers(0, 12)))
        m1, m2 = rx.search(name), fp.search(name)
        assert (m1 is None) == (m2 is None), name
        if m1 is not None:
            assert m1.group("v") == m2.group("v"), name


def test_file_name_pattern_time_is_linear_on_a_backtracking_pattern():
    t0 = time.perf_counter()
    assert filename_pattern(r"^Cam(\d+)+_(?<view>(\d+)+)\.png$", "test").search("Cam" + "1" * 250 + "x.png") is None
    assert time.perf_counter() - t0 < 2.0  # Python's re: 2^250 steps; a hang, not a timing
    with pytest.raises(BadInputError, match="RE2"):
        filename_pattern(r"(?=x)", "test")
    with pytest.raises(BadInputError, match="RE2"):
        filename_pattern(r"(a)\1", "test")


def _moveit(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    f = src / "samples.yaml"
    f.write_text(yaml.safe_dump([{"effector_wrt_world": np.eye(4).reshape(-1).tolist(),
                                  "object_wrt_sensor": np.eye(4).reshape(-1).tolist()}]))
    return f


def test_out_must_be_new_or_empty_and_outside_the_source(tmp_path):
    f = _moveit(tmp_path)
    old = tmp_path / "old"
    old.mkdir()
    (old / "cell.yaml").write_text("mine\n")
    code, text = cli("import", "moveit", f, "--mount", "base", "--out", old)
    assert code == 2 and "already holds files" in text and "--resume" not in text
    assert (old / "cell.yaml").read_text() == "mine\n"
    for out in (f, f.parent):
        with pytest.raises(BadInputError, match="not a folder|source"):
            import_session("moveit", f.parent if out == f.parent else f, out, mount="base")
    empty = tmp_path / "empty"
    empty.mkdir()
    import_session("moveit", f, empty, mount="base")  # an empty folder is taken
    assert (empty / "session.json").is_file()


def test_a_failed_import_leaves_no_partial_session(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    for k in range(2):
        cv2.imwrite(str(src / f"{k}.png"), np.full((12, 16), 99, np.uint8))
    (src / "2.png").write_bytes(b"")  # the third image is empty: found while the session is written
    (src / "dataset.toml").write_text('version = 1\ntopology = "planar_intrinsics"\n[[cameras]]\nid = "cam0"\n'
                                      'images = { kind = "glob", pattern = "*.png" }\n[target]\nkind = "chessboard"\n'
                                      "rows = 6\ncols = 8\nsquare_size_m = 0.02\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(BadInputError, match="empty"):
        import_session("calibration-rs", src, tmp_path / "sess")
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no sess, no temporary sibling
    (src / "dataset.toml").write_text((src / "dataset.toml").read_text().replace("rows = 6", "rows = 7.9"))
    with pytest.raises(BadInputError, match=r"target.rows: expected an integer, got 7.9"):
        import_session("calibration-rs", src, tmp_path / "sess")


def test_paths_outside_the_source_are_refused_and_contents_never_shown(tmp_path):
    src = tmp_path / "src"
    (src / "images").mkdir(parents=True)
    cv2.imwrite(str(src / "images" / "0.png"), np.full((12, 16), 99, np.uint8))
    secret = tmp_path / "secret.yaml"
    secret.write_text("x: TOP-SECRET-VALUE\ny: 0\nz: 0\nqx: 0\nqy: 0\nqz: 0\nqw: 1\n")
    cfg = {"data": [{"image": "images/0.png", "pose": str(secret)}], "static_camera": False,
           "target_finder": {"type": "ModifiedCircleGridTargetFinder", "rows": 5, "cols": 5, "spacing": 0.02}}
    (src / "cal_data.yaml").write_text(yaml.safe_dump(cfg))
    with pytest.raises(BadInputError, match="outside the data set's folder") as e:
        import_session("industrial-calibration", src, tmp_path / "sess")
    assert "allow_outside=true" in str(e.value)
    with pytest.raises(BadInputError, match="expected a number") as e:  # allowed, but not a pose
        import_session("industrial-calibration", src, tmp_path / "sess", allow_outside="true")
    assert "TOP-SECRET" not in str(e.value)
    assert not (tmp_path / "sess").exists()
    secret.write_text(secret.read_text().replace("TOP-SECRET-VALUE", "0.5"))
    import_session("industrial-calibration", src, tmp_path / "sess", allow_outside="true")
    assert json.loads((tmp_path / "sess" / "session.json").read_text())["imported_from"]["format"] == "industrial-calibration"
