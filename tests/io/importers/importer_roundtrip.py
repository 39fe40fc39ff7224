"""Shared steps of the importer round trips: run the CLI in-process, calibrate a session, compare with truth."""

from __future__ import annotations

import contextlib
import io
import json
import sys
from pathlib import Path

import numpy as np

from jcalib.geometry.se3 import invert, log_so3


def cli(*args) -> tuple[int, str]:
    """``jcalib ARGS`` in this process: (exit status, stdout + stderr)."""
    from jcalib.app.cli import main

    buf = io.StringIO()
    old, sys.argv = sys.argv, ["jcalib", *map(str, args)]
    try:
        with contextlib.redirect_stderr(buf), contextlib.redirect_stdout(buf):
            main()
        return 0, buf.getvalue()
    except SystemExit as e:
        return int(e.code or 0), buf.getvalue()
    finally:
        sys.argv = old


def detect_and_calibrate(session: Path, tmp: Path) -> dict:
    """``jcalib detect --session`` then ``jcalib calibrate SESSION/cell.yaml SESSION/observations.json``."""
    code, text = cli("detect", "--session", session)
    assert code == 0, text
    code, text = cli("calibrate", session / "cell.yaml", session / "observations.json", "-o", tmp / "result.json")
    assert code == 0, text
    return json.loads((tmp / "result.json").read_text())


def assert_pose_near(T_est, cov, T_true, n_sigma: float = 5.0, floor_m: float = 5e-4, floor_rad: float = 1e-3):
    """|error| within ``n_sigma`` of the reported σ plus a floor, per tangent component (rx ry rz tx ty tz,
    right perturbation as the result file states).

    The floor (0.5 mm, 0.06°) is the renderer's systematic corner error, which the a-posteriori σ of a
    noiseless render does not hold (RMS 0.02 px against σ̂ 0.016 px; ~0.2 mm along the optical axis
    at this range). A convention error (inverted or swapped pose, wrong quaternion order, wrong mount)
    is centimetres and tens of degrees off, or does not converge.
    """
    T_est, T_true = np.asarray(T_est), np.asarray(T_true)
    D = invert(T_true) @ T_est
    err = np.concatenate([log_so3(D[:3, :3]), D[:3, 3]])
    sigma = np.sqrt(np.diag(np.asarray(cov)))
    floor = np.array([floor_rad] * 3 + [floor_m] * 3)
    assert np.all(np.abs(err) <= n_sigma * sigma + floor), (err, sigma)
