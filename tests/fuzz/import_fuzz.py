"""The `jcalib import` fuzzer: valid data sets of the six formats, mutated, run through the CLI in-process.

Each case gets a fresh workspace ``case/`` holding the source ``src/`` (a copy of the format's valid
data set, written in the layouts of tests/io/importers), a canary file outside it, a file and a folder
that already exist (``keep.txt``, ``old/`` with a cell.yaml and an observations.json), and the mutation:
byte flips, truncation, non-UTF-8 bytes, type swaps, NaN / inf, huge numbers, deep nesting, YAML alias
bombs, a second YAML document, duplicate keys and entries, path escapes (absolute, ``..``, globs,
symlinks to the canary), surplus pairs, zero-size images, a pairing regex that backtracks, a joint-state
message of changing length, and bad ``--out`` / ``--option`` values.

:func:`run_case` runs the import and reports the exit status, whether it was an internal error, which
files that existed changed, what the command left behind, and whether the canary was opened (a ``sys``
audit hook sees every ``open`` and ``sqlite3.connect``, symlinks resolved). Most cases call what the
``import`` command's body calls (``parse_options`` then ``import_session``; a :class:`JcalibError` is its
exit status, anything else an internal error): building the typer app costs 0.4 s a call, so the CLI
itself (``main``) runs only the cases marked ``via_cli``. The test (``test_import_fuzz.py``) asserts on
the outcomes; ``benchmarks/bench_import_fuzz.py`` tabulates them.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import io
import json
import os
import random
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "io" / "importers"))  # the importer tests' writers

FORMATS = ("industrial-calibration", "calibration-rs", "easy-handeye", "moveit", "opencv-pairs", "rosbag")
CAMODOCAL = HERE.parent / "data" / "real" / "handeye_camodocal_example"


# ------------------------------------------------------------------------------------------ seeds


def _poses(n: int, seed: int = 3) -> list[np.ndarray]:
    """Plausible flange poses (m): a camera looking down from about 0.5 m."""
    from jcalib.geometry.se3 import exp_so3, make_pose

    rng = np.random.default_rng(seed)
    return [make_pose(exp_so3(rng.normal(0, 0.2, 3)) @ exp_so3(np.array([np.pi, 0, 0])), rng.normal([0.5, 0, 0.5], 0.05))
            for _ in range(n)]


def _images(n: int) -> list[np.ndarray]:
    return [np.full((12, 16), 60 + 40 * k, np.uint8) for k in range(n)]


def _data(n: int = 3) -> SimpleNamespace:
    """What the importer tests' writers take (tests/io/importers/conftest.py's Rendered), tiny and fake."""
    K = np.array([[20.0, 0, 8.0], [0, 20.0, 6.0], [0, 0, 1]])
    return SimpleNamespace(images=_images(n), T_base_flange=np.stack(_poses(n)), K=K,
                           target={"type": "checkerboard", "cols": 8, "rows": 6, "square": 0.02})


CALIBRATION_RS_TOML = """version = 1
topology = "single_cam_handeye"
description = "fuzz seed"

[[cameras]]
id = "cam0"
images = { kind = "glob", pattern = "*.png" }

[target]
kind = "chessboard"
rows = 6
cols = 8
square_size_m = 0.02

[robot_poses]
path = "RobotPosesVec.txt"
format = "rowmajor4x4"

[pose_pairing]
kind = "by_index"

[pose_convention]
transform = "t_base_tcp"
rotation_format = "matrix4x4_row_major"
translation_units = "m"
"""

CALIBRATION_RS_CSV_TOML = """version = 1
topology = "single_cam_handeye"
[[cameras]]
id = "left"
images = { kind = "list", paths = ["Cam0_0000.png", "Cam0_0001.png", "Cam0_0002.png"] }
[target]
kind = "charuco"
rows = 7
cols = 5
square_size_m = 0.03
marker_size_m = 0.022
dictionary = "DICT_6X6_250"
[robot_poses]
path = "poses.csv"
format = "csv"
columns = { pose_id = "view", tx = "tx", ty = "ty", tz = "tz", rotation = ["qx", "qy", "qz", "qw"] }
[pose_pairing]
kind = "shared_filename_token"
regex = '^Cam\\d+_(?<view>\\d+)\\.png$'
group = "view"
[pose_convention]
transform = "t_tcp_base"
rotation_format = "quat_xyzw"
translation_units = "mm"
"""


def _transform(T: np.ndarray) -> dict:
    from jcalib.geometry.se3 import quat_from_matrix

    w, x, y, z = (float(v) for v in quat_from_matrix(T[:3, :3]))
    return {"translation": {"x": float(T[0, 3]), "y": float(T[1, 3]), "z": float(T[2, 3])},
            "rotation": {"x": x, "y": y, "z": z, "w": w}}


def _pairs(n: int = 4) -> list[tuple[np.ndarray, np.ndarray]]:
    from jcalib.geometry.se3 import invert

    Tb = _poses(n, seed=5)
    Y = _poses(1, seed=6)[0]
    return [(T, invert(T) @ Y) for T in Tb]


@dataclass
class Seed:
    """A valid data set: ``source`` (relative to the workspace), the CLI arguments that import it, and its
    files by role (``manifest``, ``text`` (YAML / TOML / CSV / text), ``json``, ``binary``, ``image``)."""

    fmt: str
    variant: str
    source: str
    args: list[str]
    files: dict[str, list[str]]


def write_seed(fmt: str, variant: str, ws: Path) -> Seed:
    """Write the valid data set ``variant`` of ``fmt`` into ``ws/src`` (and a target file beside it for bags)."""
    import cv2

    src = ws / "src"
    src.mkdir(parents=True)
    if fmt == "industrial-calibration":
        from test_import_images import write_industrial_calibration

        write_industrial_calibration(src, _data(3))
        pngs = [f"src/images/{k}.png" for k in range(3)]
        return Seed(fmt, variant, "src", [], {"manifest": ["src/cal_data.yaml"], "text": [f"src/poses/{k}.yaml" for k in range(3)],
                                              "image": pngs})
    if fmt == "calibration-rs" and variant == "rowmajor":
        d = _data(3)
        for k, img in enumerate(d.images):
            cv2.imwrite(str(src / f"{k + 1}.png"), img)
        (src / "RobotPosesVec.txt").write_text("".join("\t".join(f"{v:.12f}" for v in T.reshape(-1)) + "\n"
                                                       for T in d.T_base_flange))
        (src / "dataset.toml").write_text(CALIBRATION_RS_TOML)
        return Seed(fmt, variant, "src", ["--mount", "flange"], {"manifest": ["src/dataset.toml"],
                                                                  "text": ["src/RobotPosesVec.txt"],
                                                                  "image": [f"src/{k + 1}.png" for k in range(3)]})
    if fmt == "calibration-rs":  # csv poses (mm, quaternions), token pairing, an image list
        from jcalib.geometry.se3 import invert, quat_from_matrix

        d = _data(3)
        rows = ["view,tx,ty,tz,qx,qy,qz,qw"]
        for k in range(3):
            Ti = invert(d.T_base_flange[k])
            w, x, y, z = (float(v) for v in quat_from_matrix(Ti[:3, :3]))
            rows.append(f"{k:04d},{float(Ti[0, 3]) * 1e3!r},{float(Ti[1, 3]) * 1e3!r},{float(Ti[2, 3]) * 1e3!r},{x!r},{y!r},{z!r},{w!r}")
            cv2.imwrite(str(src / f"Cam0_{k:04d}.png"), d.images[k])
        (src / "poses.csv").write_text("\n".join(rows) + "\n")
        (src / "dataset.toml").write_text(CALIBRATION_RS_CSV_TOML)
        return Seed(fmt, variant, "src", ["--mount", "base"], {"manifest": ["src/dataset.toml"], "text": ["src/poses.csv"],
                                                                "image": [f"src/Cam0_{k:04d}.png" for k in range(3)]})
    if fmt == "easy-handeye":
        params = {"name": "demo", "calibration_type": "eye_in_hand", "robot_base_frame": "base",
                  "robot_effector_frame": "tool0", "tracking_base_frame": "camera", "tracking_marker_frame": "marker"}
        doc = {"parameters": params, "samples": [{"robot": _transform(a), "tracking": _transform(b)} for a, b in _pairs()]}
        (src / "demo.samples").write_text(yaml.safe_dump(doc, sort_keys=False))
        return Seed(fmt, variant, "src/demo.samples", [], {"manifest": ["src/demo.samples"]})
    if fmt == "moveit" and variant == "yaml":
        doc = [{"effector_wrt_world": a.reshape(-1).tolist(), "object_wrt_sensor": b.reshape(-1).tolist()} for a, b in _pairs()]
        (src / "samples.yaml").write_text(yaml.safe_dump(doc))
        return Seed(fmt, variant, "src/samples.yaml", ["--mount", "base"], {"manifest": ["src/samples.yaml"]})
    if fmt == "moveit":
        (src / "pose_samples.json").write_text(json.dumps([[a.tolist(), b.tolist()] for a, b in _pairs()]))
        return Seed(fmt, variant, "src/pose_samples.json", ["--mount", "base"], {"json": ["src/pose_samples.json"]})
    if fmt == "opencv-pairs" and variant == "camodocal":
        for name in ("TransformPairsInput.yml", "CalibratedTransform.yml"):
            shutil.copy(CAMODOCAL / name, src / name)
        return Seed(fmt, variant, "src", ["--mount", "base"], {"manifest": ["src/TransformPairsInput.yml"],
                                                                "text": ["src/CalibratedTransform.yml"]})
    if fmt == "opencv-pairs":
        fs = cv2.FileStorage(str(src / "TransformPairsInput.yml"), cv2.FILE_STORAGE_WRITE)
        pairs = _pairs()
        fs.write("frameCount", len(pairs))
        for i, (a, b) in enumerate(pairs):
            fs.write(f"T1_{i}", a)
            fs.write(f"T2_{i}", b)
        fs.release()
        return Seed(fmt, variant, "src", ["--mount", "flange"], {"manifest": ["src/TransformPairsInput.yml"]})
    if fmt == "rosbag":
        return _bag_seed(variant, ws)
    raise ValueError(f"no seed {fmt}/{variant}")


def _bag_seed(variant: str, ws: Path) -> Seed:
    from rosbags.typesys import Stores
    from test_import_rosbag import write_bag

    d = _data(2)
    (ws / "target.yaml").write_text(yaml.safe_dump(d.target))
    opts = ["--mount", "flange", "--option", f"target={ws / 'target.yaml'}", "--option", "base_frame=base_link",
            "--option", "flange_frame=tool0", "--option", "camera_model=pinhole"]
    if variant == "ros1":
        write_bag(ws / "src" / "calib.bag", d, Stores.ROS1_NOETIC, ros2=False)
        return Seed("rosbag", variant, "src/calib.bag", opts, {"binary": ["src/calib.bag"]})
    if variant == "ros2":
        write_bag(ws / "src" / "bag", d, Stores.ROS2_HUMBLE, ros2=True)
        db = next(p.name for p in (ws / "src" / "bag").iterdir() if p.suffix in (".db3", ".mcap"))
        return Seed("rosbag", variant, "src/bag", opts, {"manifest": ["src/bag/metadata.yaml"],
                                                         "binary": [f"src/bag/{db}"]})
    _joint_state_bag(ws / "src" / "js.bag", bad=variant == "joints-bad")
    js_opts = ["--mount", "flange", "--option", f"target={ws / 'target.yaml'}", "--option", "poses=joint_states"]
    return Seed("rosbag", variant, "src/js.bag", js_opts, {"binary": ["src/js.bag"]})


def _joint_state_bag(path: Path, bad: bool) -> None:
    """A ROS 1 bag of one image and /joint_states at 100 Hz around it; ``bad``: one message with a joint
    fewer (a message whose length changes inside the bag)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    sec = 1_000_000_000

    def header(ns):
        return T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=ns // sec, nanosec=ns % sec),
                                        frame_id="base")

    names = [f"joint_{k}" for k in range(6)]
    with Writer(path) as w:
        cj = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        ci = w.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        t0 = 100 * sec
        for j in range(20):
            t = t0 + j * sec // 100
            n = 5 if bad and j == 7 else 6
            msg = T["sensor_msgs/msg/JointState"](header=header(t), name=names[:n] if not bad else names,
                                                  position=np.linspace(0.1, 0.6, n), velocity=np.zeros(0),
                                                  effort=np.zeros(0))
            w.write(cj, t, ts.serialize_ros1(msg, "sensor_msgs/msg/JointState"))
        ti = t0 + 95 * sec // 1000
        img = _images(1)[0]
        msg = T["sensor_msgs/msg/Image"](header=header(ti), height=img.shape[0], width=img.shape[1], encoding="mono8",
                                         is_bigendian=0, step=img.shape[1], data=img.reshape(-1))
        w.write(ci, ti + 1000, ts.serialize_ros1(msg, "sensor_msgs/msg/Image"))


#: format -> seed variants
VARIANTS = {"industrial-calibration": ("charuco",), "calibration-rs": ("rowmajor", "csv-token"),
            "easy-handeye": ("samples2",), "moveit": ("yaml", "json"), "opencv-pairs": ("synthetic", "camodocal"),
            "rosbag": ("ros1", "ros2", "joints", "joints-bad")}


# ------------------------------------------------------------------------------------------ mutations

_ALIAS_BOMB = "".join(f"bomb{k}: &b{k} [" + ", ".join([f"*b{k - 1}" if k else "lol"] * 10) + "]\n" for k in range(9))
_DEEP = "[" * 3000 + "]" * 3000


@dataclass
class Case:
    """One import to run: the workspace, the CLI arguments after ``import``, and the mutation's name."""

    fmt: str
    variant: str
    mutation: str
    ws: Path
    args: list[str]
    allow_outside: bool = False
    via_cli: bool = False


def _pick(rng: random.Random, seed: Seed, *roles: str) -> str | None:
    files = [f for r in roles for f in seed.files.get(r, [])]
    return rng.choice(files) if files else None


def _value_lines(text: str) -> list[int]:
    """Lines of a YAML / TOML / CSV text that hold a scalar after ``key:`` / ``key =`` / ``,``."""
    out = []
    for k, line in enumerate(text.split("\n")):
        s = line.strip()
        if s and not s.startswith(("#", "[", "%")) and (":" in s or "=" in s or "," in s):
            out.append(k)
    return out


def _replace_value(text: str, rng: random.Random, literal: str) -> str:
    lines = text.split("\n")
    cand = _value_lines(text)
    if not cand:
        return literal + "\n" + text
    k = rng.choice(cand)
    line = lines[k]
    for sep in (": ", " = ", "="):
        if sep in line:
            head = line[: line.index(sep) + len(sep)]
            lines[k] = head + literal
            return "\n".join(lines)
    cells = line.split(",")  # CSV
    cells[rng.randrange(len(cells))] = literal
    lines[k] = ",".join(cells)
    return "\n".join(lines)


def _json_mutate(data, rng: random.Random, value):
    """Replace one random leaf of parsed JSON with ``value``."""
    path, node = [], data
    while isinstance(node, (list, dict)) and node:
        key = rng.choice(list(node.keys()) if isinstance(node, dict) else range(len(node)))
        path.append(key)
        node = node[key]
    if not path:
        return value
    parent = data
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = value
    return data


def _text_mutation(kind: str) -> Callable:
    literal = {"type-text": '"seven"', "type-bool": "true", "type-list": "[1, 2]", "nan": "nan", "inf": "-inf",
               "huge": "1e308", "bigint": "9" * 400, "float-for-int": "7.9", "deep": _DEEP, "empty-value": '""'}[kind]

    def mutate(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
        name = _pick(rng, seed, "manifest", "text")
        if name is None:
            return None
        f = ws / name
        lit = literal
        if f.suffix in (".yaml", ".yml", ".samples") and kind in ("nan", "inf"):
            lit = ".nan" if kind == "nan" else "-.inf"
        f.write_text(_replace_value(f.read_text(), rng, lit))
        return []
    return mutate


def _json_value_mutation(value) -> Callable:
    def mutate(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
        name = _pick(rng, seed, "json")
        if name is None:
            return None
        f = ws / name
        v = value() if callable(value) else value
        f.write_text(json.dumps(_json_mutate(json.loads(f.read_text()), rng, v)))
        return []
    return mutate


def _bytes_mutation(kind: str) -> Callable:
    def mutate(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
        name = _pick(rng, seed, "manifest", "text", "json", "binary", "image")
        f = ws / name
        data = bytearray(f.read_bytes())
        if kind == "flip":
            for _ in range(rng.randint(1, 4)):
                if data:
                    data[rng.randrange(len(data))] ^= rng.randint(1, 255)
        elif kind == "truncate":
            data = data[: rng.randrange(max(len(data), 1))]
        elif kind == "non-utf8":
            k = rng.randrange(len(data) + 1)
            data[k:k] = b"\xff\xfe\xc3("
        elif kind == "empty":
            data = bytearray()
        f.write_bytes(bytes(data))
        return []
    return mutate


def _yaml_file(ws: Path, seed: Seed, rng: random.Random) -> Path | None:
    names = [f for f in seed.files.get("manifest", []) + seed.files.get("text", [])
             if f.endswith((".yaml", ".samples")) and not f.endswith(".yml")]
    return ws / rng.choice(names) if names else None


def _alias_bomb(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
    f = _yaml_file(ws, seed, rng)
    if f is None:
        return None
    text = f.read_text()
    f.write_text(text.rstrip("\n") + "\n" + _ALIAS_BOMB if not text.lstrip().startswith("-") else
                 "- " + _ALIAS_BOMB.replace("\n", "\n  "))
    return []


def _second_document(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
    f = _yaml_file(ws, seed, rng)
    if f is None:
        return None
    text = f.read_text()
    f.write_text(text + "---\n" + text)
    return []


def _duplicate_line(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
    name = _pick(rng, seed, "manifest", "text")
    if name is None:
        return None
    f = ws / name
    lines = f.read_text().split("\n")
    cand = [k for k in _value_lines("\n".join(lines)) if not lines[k].lstrip().startswith("-")]
    if not cand:
        return None
    k = rng.choice(cand)
    lines.insert(k + 1, lines[k])
    f.write_text("\n".join(lines))
    return []


# --- path escapes: the canary ``case/canary.png`` lies outside src/


def _escape_paths(ws: Path, seed: Seed, rng: random.Random, how: str) -> list[str] | None:
    canary = ws / "canary.png"
    target = {"absolute": str(canary), "dotdot": "../canary.png", "symlink": "link.png",
              "glob": "../*.png"}[how]
    if seed.fmt not in ("industrial-calibration", "calibration-rs", "rosbag") or (seed.fmt == "rosbag" and seed.variant != "ros2"):
        return None  # no paths in the file: nothing to escape with
    if how == "symlink" and seed.fmt != "rosbag":
        os.symlink(canary, ws / Path(seed.files["image"][0]).parent / "link.png")
    if seed.fmt == "industrial-calibration":
        f = ws / "src" / "cal_data.yaml"
        cfg = yaml.safe_load(f.read_text())
        k = rng.randrange(len(cfg["data"]))
        if how == "symlink":
            target = "images/link.png"
        key = rng.choice(["image", "pose"])
        cfg["data"][k][key] = target.replace("*", "0").replace(".png", ".yaml" if key == "pose" and how != "symlink" else ".png")
        f.write_text(yaml.safe_dump(cfg, sort_keys=False))
        return []
    if seed.fmt == "calibration-rs":
        f = ws / "src" / "dataset.toml"
        text = f.read_text()
        if seed.variant == "rowmajor":
            if rng.random() < 0.5:
                text = text.replace('pattern = "*.png"', f'pattern = "{target}"' if how != "absolute" else
                                    f'pattern = "{ws}/*.png"')
            else:
                text = text.replace('path = "RobotPosesVec.txt"', f'path = "{target.replace("*", "canary")}"')
        else:
            text = text.replace('"Cam0_0001.png"', f'"{target.replace("*", "canary")}"')
        f.write_text(text)
        return []
    if seed.fmt == "rosbag" and seed.variant == "ros2":
        bag = ws / "src" / "bag"
        db = next(p for p in bag.iterdir() if p.suffix == ".db3")
        shutil.move(db, ws / "canary.db3")
        os.symlink(ws / "canary.db3", db)
        return []
    return None


def _duplicates(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
    """An entry given twice: an image with another pose, a camera id, a sample, a surplus pair."""
    src = ws / "src"
    if seed.fmt == "industrial-calibration":
        f = src / "cal_data.yaml"
        cfg = yaml.safe_load(f.read_text())
        cfg["data"].append({"image": cfg["data"][0]["image"], "pose": cfg["data"][1]["pose"]})
        f.write_text(yaml.safe_dump(cfg, sort_keys=False))
    elif seed.fmt == "calibration-rs":
        f = src / "dataset.toml"
        text = f.read_text()
        if seed.variant == "rowmajor":  # a second camera with the same id
            text = text.replace("[target]", '[[cameras]]\nid = "cam0"\nimages = { kind = "glob", pattern = "*.png" }\n\n[target]')
        else:
            text = text.replace('"Cam0_0002.png"]', '"Cam0_0002.png", "Cam0_0001.png"]')
        f.write_text(text)
    elif seed.fmt == "easy-handeye":
        f = src / "demo.samples"
        doc = yaml.safe_load(f.read_text())
        doc["samples"].append(doc["samples"][0])
        f.write_text(yaml.safe_dump(doc, sort_keys=False))
    elif seed.fmt == "moveit":
        f = ws / seed.source
        doc = yaml.safe_load(f.read_text())  # JSON is YAML
        doc.append(doc[-1])
        f.write_text(json.dumps(doc) if f.suffix == ".json" else yaml.safe_dump(doc))
    elif seed.fmt == "opencv-pairs":  # frameCount smaller than the pairs in the file
        f = src / "TransformPairsInput.yml"
        text = f.read_text()
        n = int(text.split("frameCount:")[1].split()[0])
        f.write_text(text.replace(f"frameCount: {n}", f"frameCount: {n - 1}", 1))
    else:
        return None
    return []


def _regex_backtracking(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
    if seed.fmt != "calibration-rs" or seed.variant != "csv-token":
        return None
    src = ws / "src"
    f = src / "dataset.toml"
    long_name = "Cam0_" + "1" * 60 + "x.png"
    shutil.copy(src / "Cam0_0001.png", src / long_name)
    text = f.read_text().replace("'^Cam\\d+_(?<view>\\d+)\\.png$'", "'^Cam(\\d+)+_(?<view>(\\d+)+)\\.png$'")
    f.write_text(text.replace('"Cam0_0001.png"', f'"{long_name}"'))
    return []


def _zero_image(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
    name = _pick(rng, seed, "image")
    if name is None:
        return None
    (ws / name).write_bytes(b"")
    return []


# --- outputs and options


def _out(kind: str) -> Callable:
    def mutate(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
        manifest = (seed.files.get("manifest") or seed.files.get("json") or seed.files.get("binary"))[0]
        out = {"existing-file": ws / "keep.txt", "manifest": ws / manifest, "source": ws / seed.source,
               "inside-source": (ws / seed.source if (ws / seed.source).is_dir() else ws / "src") / "sess",
               "non-empty": ws / "old", "no-parent": ws / "nope" / "sess",
               "empty-dir": ws / "empty"}[kind]
        if kind == "empty-dir":
            out.mkdir()
        return ["--out", str(out)]
    return mutate


def _option(kind: str) -> Callable:
    def mutate(ws: Path, seed: Seed, rng: random.Random) -> list[str] | None:
        return {"unknown": ["--option", "colour=red"], "mount-key": ["--option", "mount=flange"],
                "duplicate": ["--option", "target=a", "--option", "target=b"],
                "colliding": ["--option", "camera-model=x", "--option", "camera_model=y"],
                "no-equals": ["--option", "camera"], "allow-outside-bad": ["--option", "allow_outside=maybe"]}[kind]
    return mutate


MUTATIONS: dict[str, Callable] = {
    **{f"bytes:{k}": _bytes_mutation(k) for k in ("flip", "truncate", "non-utf8", "empty")},
    **{f"value:{k}": _text_mutation(k) for k in ("type-text", "type-bool", "type-list", "nan", "inf", "huge", "bigint",
                                                  "float-for-int", "deep", "empty-value")},
    "json:nan": _json_value_mutation(float("nan")), "json:text": _json_value_mutation("1.0"),
    "json:bool": _json_value_mutation(True), "json:deep": _json_value_mutation(lambda: json.loads("[" * 500 + "]" * 500)),
    "json:huge": _json_value_mutation(1e308),
    "yaml:alias-bomb": _alias_bomb, "yaml:second-document": _second_document, "dup-key": _duplicate_line,
    **{f"escape:{k}": functools.partial(_escape_paths, how=k) for k in ("absolute", "dotdot", "symlink", "glob")},
    "duplicates": _duplicates, "regex-backtracking": _regex_backtracking, "zero-size-image": _zero_image,
    **{f"out:{k}": _out(k) for k in ("existing-file", "manifest", "source", "inside-source", "non-empty", "no-parent",
                                     "empty-dir")},
    **{f"option:{k}": _option(k) for k in ("unknown", "mount-key", "duplicate", "colliding", "no-equals",
                                           "allow-outside-bad")},
}


def _prepare(ws: Path) -> None:
    """What exists around the source before the import: a canary outside it, a file, a session-like folder."""
    import cv2

    cv2.imwrite(str(ws / "canary.png"), np.zeros((4, 4), np.uint8))
    (ws / "canary.yaml").write_text("x: 1.0\ny: 0\nz: 0\nqx: 0\nqy: 0\nqz: 0\nqw: 1\n")
    (ws / "keep.txt").write_text("the user's notes\n")
    (ws / "old").mkdir()
    (ws / "old" / "cell.yaml").write_text("schema: jcalib.cell/1\n")
    (ws / "old" / "observations.json").write_text("{}\n")


_TEMPLATES: dict[tuple[str, str], tuple[Path, Seed]] = {}


def make_case(fmt: str, variant: str, mutation: str, root: Path, rng: random.Random) -> Case | None:
    """A fresh workspace under ``root`` with the seed, the mutation applied; None if it does not apply."""
    key = (fmt, variant)
    if key not in _TEMPLATES:
        tpl = root / f"template-{fmt}-{variant}"
        _TEMPLATES[key] = (tpl, write_seed(fmt, variant, tpl))
    tpl, seed = _TEMPLATES[key]
    ws = root / f"case{len(list(root.iterdir())):05d}"
    shutil.copytree(tpl, ws, symlinks=True)
    seed = Seed(seed.fmt, seed.variant, seed.source,
                [a.replace(str(tpl), str(ws)) for a in seed.args], seed.files)
    _prepare(ws)
    extra = MUTATIONS[mutation](ws, seed, rng) if mutation != "none" else []
    if extra is None:
        shutil.rmtree(ws)
        return None
    args = [fmt, str(ws / seed.source), *seed.args, *extra]
    if "--out" not in extra:
        args += ["--out", str(ws / "sess")]
    return Case(fmt, variant, mutation, ws, args, allow_outside="allow_outside=true" in args)


#: Cases run through the CLI's ``main`` (the rest call the command's body), one variant per format.
VIA_CLI = ("none", "option:mount-key", "out:non-empty")


def cases(fmt: str, root: Path, seed: int = 0, per_variant: int = 1) -> list[Case]:
    """Every mutation (``per_variant`` draws each) on every seed variant of ``fmt``, plus the valid seeds
    and their ``allow_outside=true`` escapes (which must then succeed); fixed ``seed``."""
    rng = random.Random(f"{fmt}:{seed}")
    out = []
    for variant in VARIANTS[fmt]:
        for mutation in ["none", *MUTATIONS]:
            for _ in range(per_variant if mutation.startswith(("bytes", "value", "json:")) else 1):
                c = make_case(fmt, variant, mutation, root, rng)
                if c is not None:
                    c.via_cli = mutation in VIA_CLI and variant == VARIANTS[fmt][0]
                    out.append(c)
        c = make_case(fmt, variant, "escape:absolute", root, rng)
        if c is not None and fmt in ("industrial-calibration", "calibration-rs"):
            c.args += ["--option", "allow_outside=true"]
            c.mutation, c.allow_outside = "escape:absolute+allowed", True
            out.append(c)
    return out


# ------------------------------------------------------------------------------------------ running


@dataclass
class Outcome:
    """What one import did."""

    code: int
    text: str
    internal_error: bool
    changed: list[str] = field(default_factory=list)
    left_behind: list[str] = field(default_factory=list)
    canary_opened: bool = False


def snapshot(ws: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file (a symlink by its target, never followed), and folders."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(ws):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            rel = str(p.relative_to(ws))
            if p.is_symlink():
                out[rel] = "link:" + os.readlink(p)
            elif p.is_dir():
                out[rel] = "dir"
            else:
                out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


_WATCH: dict[str, object] = {"canaries": set(), "hit": False, "busy": False}


def _audit(event: str, args: tuple) -> None:
    if not _WATCH["canaries"] or _WATCH["busy"] or event not in ("open", "sqlite3.connect", "os.listdir", "os.scandir"):
        return
    path = args[0] if args else None
    if not isinstance(path, (str, bytes, os.PathLike)):
        return
    _WATCH["busy"] = True
    try:
        real = os.path.realpath(os.fsdecode(path))
        if real in _WATCH["canaries"] and event in ("open", "sqlite3.connect"):
            _WATCH["hit"] = True
    except (OSError, ValueError):
        pass
    finally:
        _WATCH["busy"] = False


sys.addaudithook(_audit)


def _call(args: list[str]) -> tuple[int, str]:
    """What the ``import`` command's body does with ``args`` (FORMAT SOURCE [--mount M] [--option K=V]...
    --out OUT): (exit status, message); an exception that is not a JcalibError is an internal error."""
    from jcalib.errors import JcalibError
    from jcalib.io.importers import import_session, parse_options

    fmt, source, rest = args[0], args[1], args[2:]
    mount, out, items = None, None, []
    for flag, value in zip(rest[::2], rest[1::2], strict=False):
        if flag == "--mount":
            mount = value
        elif flag == "--out":
            out = value
        else:
            items.append(value)
    if len(rest) % 2:  # "--option" without a value: the CLI's usage error
        return 2, "usage error"
    try:
        import_session(fmt, source, out, mount=mount, **parse_options(fmt, items))
    except JcalibError as e:
        return e.exit_code, f"jcalib error: {e}"
    except Exception as e:  # noqa: BLE001 - the fuzzer's finding: the CLI would say "internal error"
        return 1, f"jcalib internal error: {type(e).__name__}: {e}"
    return 0, "ok"


def run_case(case: Case) -> Outcome:
    """Run the import of the case in this process (module docstring)."""
    from jcalib.app.cli import main

    before = snapshot(case.ws)
    canaries = {os.path.realpath(case.ws / n) for n in ("canary.png", "canary.yaml", "canary.db3")}
    buf = io.StringIO()
    code = 0
    _WATCH["hit"], _WATCH["canaries"] = False, canaries
    try:
        if case.via_cli:
            with contextlib.redirect_stderr(buf), contextlib.redirect_stdout(buf):
                main(["import", *case.args])
        else:
            code, text = _call(case.args)
            buf.write(text)
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    finally:
        _WATCH["canaries"] = set()
    text = buf.getvalue()
    after = snapshot(case.ws)
    changed = sorted(k for k, v in before.items() if after.get(k) != v)
    out = Path(case.args[case.args.index("--out") + 1]) if "--out" in case.args else None
    new = sorted(k for k in after if k not in before)
    if code == 0 and out is not None:
        rel = str(out.relative_to(case.ws)) if out.is_relative_to(case.ws) else ""
        new = [k for k in new if k != rel and not k.startswith(rel + os.sep)]
        if rel in before:  # an empty folder replaced by the session
            changed = [k for k in changed if k != rel]
    return Outcome(code, text, "internal error" in text or "Traceback" in text, changed, new,
                   bool(_WATCH["hit"]))
