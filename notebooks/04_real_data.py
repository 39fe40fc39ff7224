# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # 04 — Real data tour: jcalib against the published answers
#
# Five public data sets recorded by other people (`tests/data/real/README.md`, bundled
# with the repository), each solved with jcalib's public API and compared with the answer its authors
# published:
#
# | data | jcalib call | published answer |
# |---|---|---|
# | Zhang 1998 (5 images, 256 corners) | `jcalib.calibrate_cell`, opencv5 + skew, p1 = p2 = k3 = 0 | Zhang's a, b, u0, v0, c, k1, k2 |
# | OpenCV left01..14 (13 images, 9x6) | `jcalib.calibrate_cell`, opencv5, fixed aspect ratio | OpenCV's `left_intrinsics.yml` |
# | camodocal hand-eye (42 pose pairs, eye-to-hand) | `calibrate_hand_eye_pairs` | `CalibratedTransform.yml` (another estimator, AX = XB relative to station 0; the data is noisy: degrees, cm) |
# | UCL pivot (1151 tracker poses, mm) | `refine_pivot` (Newey–West σ) | no published tip: the linear least-squares pivot (`pivot_calibration`) |
# | mrcal Figueroa (186 views, 6016x4016, wide angle) | `jcalib.calibrate_cell`, opencv8 | no published intrinsics in the README: RMS and σ only |
#
# "σ" is jcalib's reported 1σ (a-posteriori): sampling noise only, not model error (the published
# values come from other estimators, corner detectors or distortion models, so differences of a few σ
# are expected on the camera sets; on camodocal the station-loop RMS of both answers says which fits
# the data better). The hand-eye translation σ is the tangent σ rotated to the flange axes (≈). The table is printed and saved as `04_real_data_table.csv` and
# `.md`; the figure shows each difference in units of jcalib's σ.
#
# **Trial count.** No random trials here: the published table and figure are exactly what this script
# prints. `JCALIB_NB_TRIALS` (default 3, CI) below 10 uses every 3rd mrcal view (62 views) to keep CI
# fast; the published table used `JCALIB_NB_TRIALS=20`, i.e. all 186 views.

# %%
from __future__ import annotations

import os
from pathlib import Path

import matplotlib

if not os.environ.get("DISPLAY"):
    matplotlib.use("Agg")
import cv2
import matplotlib.pyplot as plt
import numpy as np

import jcalib
from jcalib.solve.cache import enable_compilation_cache
from jcalib.init.pivot import pivot_calibration
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.io.importers.opencv_pairs import read_calibrated_transform, read_transform_pairs
from jcalib.problems.handeye_pairs import calibrate_hand_eye_pairs
from jcalib.problems.pivot import refine_pivot

enable_compilation_cache()
TRIALS = int(os.environ.get("JCALIB_NB_TRIALS", "3"))
OUT = Path(os.environ.get("JCALIB_NB_OUT", Path(__file__).resolve().parent / "_out"))
OUT.mkdir(parents=True, exist_ok=True)
REAL = Path(__file__).resolve().parents[1] / "tests" / "data" / "real"
assert REAL.is_dir(), f"real data not found at {REAL}"
ROWS: list[tuple] = []  # (data set, quantity, unit, jcalib, sigma, published)


def add(data, quantity, unit, value, sigma, published):
    ROWS.append((data, quantity, unit, float(value), float(sigma) if sigma is not None else np.nan,
                 float(published) if published is not None else np.nan))


def camera_params(cal, name):
    cam = cal.cameras[name]
    p = dict(zip(cam.param_names, np.asarray(cam.params)))
    s = dict(zip(cam.param_names, np.sqrt(np.diag(cal.intrinsics_covariance[name]))))
    return p, s


# %% [markdown]
# ## Zhang 1998

# %%
z = REAL / "zhang1998"
model = np.loadtxt(z / "Model.txt").reshape(-1, 2) * 0.0254  # inches -> m
points = np.c_[model, np.zeros(len(model))]
obs = parse_observations({
    "schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [640, 480]}},
    "targets": {"board": {"points": points.tolist()}},
    "stations": [{"id": f"CalibIm{i}", "detections": [{
        "camera": "cam", "target": "board", "point_index": list(range(len(points))),
        "pixels": np.loadtxt(z / f"data{i}.txt").reshape(-1, 2).tolist()}]} for i in range(1, 6)]})
cell = parse_cell({"schema": "jcalib.cell/1",
                   "cameras": {"cam": {"model": "opencv5", "skew": True, "fix": ["p1", "p2", "k3"]}},
                   "targets": {"board": {"type": "checkerboard", "cols": 2, "rows": 2, "square": 0.01}}})
cal = jcalib.calibrate_cell(cell, obs, jcalib.CalibrationOptions(outlier_threshold=None))
p, s = camera_params(cal, "cam")
zhang = {"fx": 832.5, "fy": 832.53, "cx": 303.959, "cy": 206.585, "skew": 0.204494, "k1": -0.228601, "k2": 0.190353}
for k, v in zhang.items():
    add("Zhang 1998", k, "px" if k in ("fx", "fy", "cx", "cy", "skew") else "-", p[k], s[k], v)
add("Zhang 1998", "RMS", "px", cal.rms_px, None, None)

# %% [markdown]
# ## OpenCV left images (Bouguet's example 5), as OpenCV's calibration sample found the corners

# %%
folder = REAL / "opencv_left_right_chessboard"
flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_FAST_CHECK | cv2.CALIB_CB_NORMALIZE_IMAGE
board = np.array([[j * 0.025, i * 0.025, 0.0] for i in range(6) for j in range(9)]).astype(np.float32).astype(float)
stations = []
for i in [i for i in range(1, 15) if i != 10]:
    img = cv2.imread(str(folder / "images" / f"left{i:02d}.jpg"), cv2.IMREAD_COLOR)
    found, corners = cv2.findChessboardCorners(img, (9, 6), flags=flags)
    assert found, f"left{i:02d}.jpg"
    corners = cv2.cornerSubPix(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), corners, (11, 11), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.1))
    stations.append({"id": f"left{i:02d}", "detections": [{"camera": "left", "target": "board",
                                                             "point_index": list(range(54)),
                                                             "pixels": corners[:, 0].astype(float).tolist()}]})
obs = parse_observations({"schema": "jcalib.observations/1", "cameras": {"left": {"image_size": [640, 480]}},
                          "targets": {"board": {"points": board.tolist()}}, "stations": stations})
cell = parse_cell({"schema": "jcalib.cell/1", "cameras": {"left": {"model": "opencv5", "fix": ["aspect"]}},
                   "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025}}})
cal = jcalib.calibrate_cell(cell, obs, jcalib.CalibrationOptions(outlier_threshold=None, reseed_views=False))
p, s = camera_params(cal, "left")
fs = cv2.FileStorage(str(folder / "reference" / "opencv_samples_data_left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
K_pub, d_pub = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat().ravel()
rms_pub = fs.getNode("avg_reprojection_error").real()
fs.release()
pub = dict(fx=K_pub[0, 0], fy=K_pub[1, 1], cx=K_pub[0, 2], cy=K_pub[1, 2],
           **dict(zip(("k1", "k2", "p1", "p2", "k3"), d_pub)))
for k, v in pub.items():
    add("OpenCV left", k, "px" if k in ("fx", "fy", "cx", "cy") else "-", p[k], s[k], v)
add("OpenCV left", "RMS", "px", cal.rms_px, None, rms_pub)

# %% [markdown]
# ## camodocal hand-eye: AR marker on the gripper, fixed camera (eye-to-hand), 42 pose pairs

# %%
folder = REAL / "handeye_camodocal_example"
T1, T2 = read_transform_pairs(folder / "TransformPairsInput.yml")
ref = read_calibrated_transform(folder / "CalibratedTransform.yml")
res = calibrate_hand_eye_pairs(T1, T2, mode="eye_to_hand")
std = res.T_other_std  # rx, ry, rz (rad), tx, ty, tz (m), tangent of the marker frame
for k, name in enumerate("xyz"):
    add("camodocal hand-eye", f"T_flange_marker t{name}", "mm", 1e3 * res.T_other[k, 3],
        1e3 * np.linalg.norm(res.T_other[:3, :3][k] * std[3:]), 1e3 * ref[k, 3])
dR = ref[:3, :3].T @ res.T_other[:3, :3]
angle = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
add("camodocal hand-eye", "rotation difference", "deg", angle, np.degrees(np.linalg.norm(std[:3])), 0.0)


def loop_rms_mm(Y):
    """RMS translation of the station loops Y^-1 T1^-1 X T2 (X: chordal mean of the T_base_cam that Y implies)."""
    Xs = T1 @ Y @ np.linalg.inv(T2)
    U, _, Vt = np.linalg.svd(Xs[:, :3, :3].mean(axis=0))
    X = np.eye(4)
    X[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    X[:3, 3] = Xs[:, :3, 3].mean(axis=0)
    E = np.linalg.inv(Y) @ np.linalg.inv(T1) @ X @ T2
    return float(1e3 * np.sqrt(np.mean(np.sum(E[:, :3, 3] ** 2, axis=1))))


add("camodocal hand-eye", "station loop RMS (lower fits better)", "mm", loop_rms_mm(res.T_other), None, loop_rms_mm(ref))
add("camodocal hand-eye", "robot+marker noise, rotation", "deg", res.noise.rotation_deg, None, None)
add("camodocal hand-eye", "robot+marker noise, translation", "mm", 1e3 * res.noise.translation_m, None, None)

# %% [markdown]
# ## UCL pivot: a tracked pointer pivoting about its tip (1151 poses, mm)

# %%
files = sorted((REAL / "pivot_ucl_ndi" / "matrices").glob("*.txt"))
poses = np.stack([np.loadtxt(f) for f in files])
lin = pivot_calibration(poses)
piv = refine_pivot(poses, serial_correlation=True)
sd = np.sqrt(np.diag(piv.covariance))
for k, name in enumerate("xyz"):
    add("UCL pivot", f"tip {name} (marker frame)", "mm", piv.p_flange_tip[k], sd[k], lin.p_flange_tip[k])
for k, name in enumerate("xyz"):
    add("UCL pivot", f"pivot {name} (tracker frame)", "mm", piv.p_base_pivot[k], sd[3 + k], lin.p_base_pivot[k])
add("UCL pivot", "RMS 3-D tip distance", "mm", piv.rms_distance, None, None)

# %% [markdown]
# ## mrcal Figueroa: wide-angle 6016x4016, 10x10 board (weights ignored, outliers dropped)

# %%
raw = np.loadtxt(REAL / "mrcal_figueroa" / "board_observations.csv", delimiter=",", comments="#")
view, row, col, u, v, w = raw.T
keep = w > 0
views = np.unique(view[keep]).astype(int)
if TRIALS < 10:
    views = views[::3]  # CI: every 3rd view
grid = np.array([[j * 0.077, i * 0.077, 0.0] for i in range(10) for j in range(10)])
stations = []
for k in views:
    m = keep & (view == k)
    stations.append({"id": f"{k:03d}", "detections": [{"camera": "cam", "target": "board",
                     "point_index": (row[m] * 10 + col[m]).astype(int).tolist(), "pixels": np.c_[u[m], v[m]].tolist()}]})
obs = parse_observations({"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [6016, 4016]}},
                          "targets": {"board": {"points": grid.tolist()}}, "stations": stations})
cell = parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv8"}},
                   "targets": {"board": {"type": "checkerboard", "cols": 10, "rows": 10, "square": 0.077}}})
cal = jcalib.calibrate_cell(cell, obs)
p, s = camera_params(cal, "cam")
label = f"mrcal Figueroa ({len(views)} views)"
for k in ("fx", "fy", "cx", "cy", "k1", "k2"):
    add(label, k, "px" if k in ("fx", "fy", "cx", "cy") else "-", p[k], s[k], None)
add(label, "RMS", "px", cal.rms_px, None, None)
add(label, "rejected corners", "-", len(cal.outliers), None, None)

# %% [markdown]
# ## The table

# %%
def fmt(x):
    return "" if not np.isfinite(x) else (f"{x:.6g}" if abs(x) < 1e5 else f"{x:.1f}")


header = "| data | quantity | unit | jcalib | jcalib σ | published | difference | difference / σ |"
lines = [header, "|---|---|---|---|---|---|---|---|"]
for data, q, unit, val, sig, pub in ROWS:
    diff = val - pub
    lines.append(f"| {data} | {q} | {unit} | {fmt(val)} | {fmt(sig)} | {fmt(pub)} | {fmt(diff)} | "
                 f"{fmt(diff / sig) if np.isfinite(sig) and sig > 0 else ''} |")
table = "\n".join(lines)
print(table)
(OUT / "04_real_data_table.md").write_text(table + "\n")
with open(OUT / "04_real_data_table.csv", "w") as f:
    f.write("data,quantity,unit,jcalib,jcalib_sigma,published,difference\n")
    for data, q, unit, val, sig, pub in ROWS:
        f.write(f"{data},{q},{unit},{val:.10g},{sig:.6g},{pub:.10g},{val - pub:.6g}\n")

# %%
cmp = [(f"{d}: {q}", (val - pub) / sig) for d, q, unit, val, sig, pub in ROWS
       if np.isfinite(pub) and np.isfinite(sig) and sig > 0]
fig, ax = plt.subplots(figsize=(8, 0.32 * len(cmp) + 1.5), constrained_layout=True)
y = np.arange(len(cmp))
vals = np.array([c[1] for c in cmp])
ax.barh(y, vals, color=np.where(np.abs(vals) <= 3, "tab:green", "tab:red"))
ax.axvline(-3, color="k", ls=":", lw=1)
ax.axvline(3, color="k", ls=":", lw=1, label="±3σ")
for yi, val in zip(y, vals):
    ax.annotate(f"{val:.2g}", (val, yi), xytext=(3 if val >= 0 else -3, 0), textcoords="offset points",
                ha="left" if val >= 0 else "right", va="center", fontsize=7)
ax.set_yticks(y, [c[0] for c in cmp], fontsize=8)
ax.invert_yaxis()
ax.set_xscale("symlog", linthresh=3)
ax.set_xlabel("(jcalib − published) / jcalib σ  (–, symlog)")
ax.set_title("Real data: jcalib − published answer,\nin units of jcalib's reported σ (|x| <= 3: green)")
ax.legend()
fig.savefig(OUT / "04_real_data_vs_published.png", dpi=110)
plt.close(fig)
print("wrote", OUT / "04_real_data_table.md", OUT / "04_real_data_vs_published.png")
