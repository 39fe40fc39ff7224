"""ROS 1 (``.bag``) and ROS 2 (folder with ``metadata.yaml``, sqlite3 or mcap) bags -> capture session.

Read with the pure-Python ``rosbags`` library (optional extra ``jcalib[ros]``). Topics used:

- images: ``sensor_msgs/Image`` (mono8/8UC1, mono16/16UC1, bgr8, rgb8, bgra8, rgba8) or
  ``sensor_msgs/CompressedImage``, one topic per camera (option ``cameras=cam0=/topic,cam1=/topic``;
  default: the bag's only image topic as ``cam0``);
- robot: ``/tf`` and ``/tf_static`` (``tf2_msgs/TFMessage``; the chain from ``base_frame`` to
  ``flange_frame`` composed from the recorded parent -> child transforms, either direction), or
  ``sensor_msgs/JointState`` on ``/joint_states`` (option ``poses=joint_states``);
- intrinsics: ``sensor_msgs/CameraInfo`` on ``<image topic's namespace>/camera_info`` when recorded
  (``plumb_bob`` -> ``opencv5``, ``rational_polynomial`` -> ``opencv8``, ``equidistant`` -> ``fisheye``),
  as start values (``intrinsics=held`` fixes them); otherwise free, ``camera_model`` (default opencv5).

Conventions: ROS ``geometry_msgs/Transform`` (m; quaternion x, y, z, w; ``header.frame_id`` the parent
= ``T_parent_child``); joint positions in rad (revolute; converted to degrees) or m (joints named in
``prismatic=...``; converted to mm). The target is not in a bag: ``target=FILE`` names a YAML file
holding its cell-spec entry (e.g. ``{type: checkerboard, cols: 9, rows: 6, square: 0.025}``) or a
Kalibr target YAML (``target_type: aprilgrid``, ...; :mod:`jcalib.io.target_files`), and
``--mount`` says where the camera is.

Time synchronisation (stated, and checked for every image):

1. An image's time is its ``header.stamp`` (the exposure), never the bag's receive time; a zero stamp is
   refused.
2. Cameras: the first camera's images define the stations; another camera's image joins a station
   when its stamp is within ``max_dt_ms`` (default 20 ms) of it, else that camera has no image there.
3. Robot: every moving transform of the chain (or the joint states) needs a sample at most
   ``max_dt_ms`` before and one at most ``max_dt_ms`` after the image stamp, and the two must agree
   within ``still_mm`` / ``still_deg`` (default 0.5 mm, 0.05°): the robot stood still while the image
   was exposed. The pose is then the sample nearest the stamp (a sample stamped exactly at the image
   time is taken as is). Images failing this are skipped, and counted in the summary's notes.
4. Consecutive stations whose flange poses agree within ``still_mm`` / ``still_deg`` are one station
   (a robot resting while the camera streams): the first image is kept.

Input checks: a ROS 2 bag's ``metadata.yaml`` is read with jcalib's guarded YAML loader first, and its
storage files must resolve inside the bag's folder (``allow_outside=true`` to follow symlinks out); a
message that cannot be decoded, a joint-state message whose position count differs from its names,
an empty image, or non-finite values are refused by topic; numeric options must be finite and positive.
"""

from __future__ import annotations

import bisect
import os
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import invert, pose_distance
from jcalib.io.importers.common import (
    ImportedStation,
    cell_entries_for_mount,
    check_options,
    pose_from_xyz_quat,
    write_session,
)
from jcalib.io.importers.source import ALLOW_OUTSIDE_HELP, SourceFolder, flag_option
from jcalib.io.schema.common import MAX_IMAGE_SIDE_PX
from jcalib.io.target_files import read_target_file

FORMAT = "rosbag"
OPTIONS = {
    "cameras": "camera=topic pairs, comma separated (default: the only image topic as cam0)",
    "poses": "tf (default) or joint_states",
    "base_frame": "robot base frame of /tf (poses=tf)",
    "flange_frame": "flange / tool0 frame of /tf (poses=tf)",
    "joint_states_topic": "default /joint_states",
    "prismatic": "joint names (comma separated) whose positions are metres",
    "target": "YAML file with the target's cell-spec entry or a Kalibr target YAML (required)",
    "target_id": "target id (default board)",
    "max_dt_ms": "synchronisation window, ms (default 20)",
    "still_mm": "robot at rest: translation tolerance, mm (default 0.5)",
    "still_deg": "robot at rest: rotation tolerance, degrees (default 0.05)",
    "camera_model": "lens model without camera_info (default opencv5)",
    "intrinsics": "initial (default) or held: camera_info intrinsics as start values or fixed",
    "allow_outside": ALLOW_OUTSIDE_HELP + " (a ROS 2 bag's storage files)",
}
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/Image",
               "sensor_msgs/CompressedImage")
_CHANNELS = {"mono8": (1, np.uint8), "8uc1": (1, np.uint8), "mono16": (1, np.uint16), "16uc1": (1, np.uint16),
             "bgr8": (3, np.uint8), "rgb8": (3, np.uint8), "bgra8": (4, np.uint8), "rgba8": (4, np.uint8)}


def _stamp_ns(header: Any, where: str) -> int:
    st = header.stamp
    ns = int(st.sec) * 1_000_000_000 + int(getattr(st, "nanosec", getattr(st, "nsec", 0)))
    if ns == 0:
        raise BadInputError(f"{where}: header.stamp is zero; the exposure time is unknown (refusing to use the "
                            "bag's receive time)")
    return ns


def decode_image(msg: Any, where: str) -> np.ndarray:
    """An image message as an (H, W[, C]) array in OpenCV's BGR order."""
    import cv2

    if hasattr(msg, "format") and not hasattr(msg, "encoding"):  # CompressedImage
        data = np.asarray(msg.data, np.uint8).reshape(-1)
        try:
            img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
        except cv2.error:
            img = None
        if img is None or img.size == 0:
            raise BadInputError(f"{where}: compressed image ({str(msg.format)[:40]}) cannot be decoded")
        return img
    enc = str(msg.encoding).lower()
    if enc not in _CHANNELS:
        raise BadInputError(f"{where}: image encoding {str(msg.encoding)[:40]!r} not supported ({', '.join(_CHANNELS)})")
    ch, dtype = _CHANNELS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    raw = np.asarray(msg.data, np.uint8).reshape(-1)
    itemsize = np.dtype(dtype).itemsize
    if not (1 <= h <= MAX_IMAGE_SIDE_PX and 1 <= w <= MAX_IMAGE_SIDE_PX):
        raise BadInputError(f"{where}: image of {w}x{h} px; expected 1 to {MAX_IMAGE_SIDE_PX} px a side")
    if step < w * ch * itemsize or raw.size < h * step:
        raise BadInputError(f"{where}: {h}x{w} {enc} image with step {step} and {raw.size} bytes is inconsistent")
    rows = raw[: h * step].reshape(h, step)[:, : w * ch * itemsize]
    img = rows.copy().view(np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")).astype(dtype)
    img = img.reshape(h, w, ch) if ch > 1 else img.reshape(h, w)
    if enc.startswith("rgb"):
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR if ch == 3 else cv2.COLOR_RGBA2BGRA)
    return img


class _Series:
    """Time-stamped samples of one quantity (transforms or joint vectors), sorted by time."""

    def __init__(self) -> None:
        self.t: list[int] = []
        self.v: list[np.ndarray] = []

    def add(self, t: int, v: np.ndarray) -> None:
        k = bisect.bisect(self.t, t)
        self.t.insert(k, t)
        self.v.insert(k, v)

    def at_rest(self, t: int, max_dt: int, still) -> tuple[np.ndarray | None, str]:
        """The sample at ``t``, or the nearest of the two bracketing ``t`` within ``max_dt`` when they
        agree (``still``); else None and why."""
        k = bisect.bisect_left(self.t, t)
        if k < len(self.t) and self.t[k] == t:
            return self.v[k], ""
        if k == 0 or k == len(self.t):
            return None, "no robot sample on both sides of the image stamp"
        b, a = k - 1, k
        if t - self.t[b] > max_dt or self.t[a] - t > max_dt:
            return None, "no robot sample within max_dt_ms on both sides of the image stamp"
        if not still(self.v[b], self.v[a]):
            return None, "robot moving while the image was exposed"
        return self.v[b if t - self.t[b] <= self.t[a] - t else a], ""


def _parse_cameras(value: Any, image_topics: list[str]) -> dict[str, str]:
    if value is None:
        if len(image_topics) != 1:
            raise BadInputError(f"import {FORMAT}: the bag has image topics {image_topics or 'none'}; name the "
                                "camera topics with cameras=cam0=/topic[,cam1=/topic]")
        return {"cam0": image_topics[0]}
    out: dict[str, str] = {}
    for part in str(value).split(","):
        name, _, topic = (t.strip() for t in part.partition("="))
        if not name or not topic:
            raise BadInputError(f"import {FORMAT}: cameras: expected NAME=TOPIC, got {part[:80]!r}")
        if topic not in image_topics:
            raise BadInputError(f"import {FORMAT}: cameras: {topic[:80]} is not an image topic of the bag ({image_topics})")
        if name in out:
            raise BadInputError(f"import {FORMAT}: cameras: camera {name[:40]!r} named twice; give each camera one topic")
        if topic in out.values():
            raise BadInputError(f"import {FORMAT}: cameras: topic {topic[:80]} given to two cameras; each camera has "
                                "its own image topic")
        out[name] = topic
    return out


def _positive(options: dict, key: str, default: float) -> float:
    raw = options.get(key, default)
    try:
        value = float(raw)
    except (TypeError, ValueError):
        value = float("nan")
    if not (np.isfinite(value) and 0 < value < 1e9):
        raise BadInputError(f"import {FORMAT}: {key}: expected a positive number, got {str(raw)[:40]!r}")
    return value


def _check_bag_folder(path: Path, allow_outside: bool) -> None:
    """A ROS 2 bag folder: ``metadata.yaml`` through the guarded loader, storage files inside the folder."""
    from pathlib import PurePath

    meta_file = path / "metadata.yaml"
    if not meta_file.exists():
        return  # rosbags says what is missing
    folder = SourceFolder(path, FORMAT, allow_outside)
    meta = folder.read_yaml(folder.file("metadata.yaml", str(path), "metadata.yaml"), f"import {FORMAT}: metadata")
    info = meta.get("rosbag2_bagfile_information") if isinstance(meta, dict) else None
    files = info.get("relative_file_paths") if isinstance(info, dict) else None
    if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
        raise BadInputError(f"{meta_file}: rosbag2_bagfile_information.relative_file_paths: expected a list of file names")
    for f in files:
        folder.file(PurePath(f).name, str(meta_file), "relative_file_paths entry")
    topics = info.get("topics_with_message_count")
    if not isinstance(topics, list):
        raise BadInputError(f"{meta_file}: topics_with_message_count: expected a list of topics")
    for k, t in enumerate(topics):
        where = f"{meta_file}: topics_with_message_count[{k}]"
        tm = t.get("topic_metadata") if isinstance(t, dict) else None
        if not isinstance(tm, dict) or not all(isinstance(tm.get(n), str) for n in ("name", "type", "serialization_format")):
            raise BadInputError(f"{where}: expected topic_metadata with name, type and serialization_format (text)")
        if isinstance(t.get("message_count"), bool) or not isinstance(t.get("message_count"), int):
            raise BadInputError(f"{where}: message_count: expected an integer")
        qos = tm.get("offered_qos_profiles")
        if isinstance(qos, str) and qos:
            from jcalib.io.schema.reading import parse_yaml

            parse_yaml(qos, f"{where}: offered_qos_profiles")
    for key, sub in (("duration", "nanoseconds"), ("starting_time", "nanoseconds_since_epoch")):
        v = info.get(key).get(sub) if isinstance(info.get(key), dict) else None
        if isinstance(v, bool) or not isinstance(v, int):
            raise BadInputError(f"{meta_file}: {key}.{sub}: expected an integer")
    for key, kind in (("version", int), ("message_count", int), ("storage_identifier", str)):
        if isinstance(info.get(key), bool) or not isinstance(info.get(key), kind):
            raise BadInputError(f"{meta_file}: {key}: expected {'an integer' if kind is int else 'text'}")


def _chain(edges: set[tuple[str, str]], base: str, flange: str) -> list[tuple[str, str, bool]]:
    """Path base -> flange over the tf edges as ``(parent, child, forward)`` steps (BFS)."""
    nbr: dict[str, list[tuple[str, tuple[str, str, bool]]]] = {}
    for p, c in edges:
        nbr.setdefault(p, []).append((c, (p, c, True)))
        nbr.setdefault(c, []).append((p, (p, c, False)))
    prev: dict[str, tuple[str, tuple[str, str, bool]] | None] = {base: None}
    queue = [base]
    while queue:
        f = queue.pop(0)
        for g, step in nbr.get(f, []):
            if g not in prev:
                prev[g] = (f, step)
                queue.append(g)
    if flange not in prev:
        frames = sorted(nbr)
        raise BadInputError(f"import {FORMAT}: no /tf chain from {base!r} to {flange!r}; frames in the bag: {frames}")
    steps, f = [], flange
    while prev[f] is not None:
        f0, step = prev[f]
        steps.append(step)
        f = f0
    return steps[::-1]


def import_source(source: str | os.PathLike, out: str | os.PathLike, *, mount: str | None = None, **options: Any):
    """Import a ROS 1 or ROS 2 bag (module docstring) into session ``out``.

    Raises:
        BadInputError: ``rosbags`` missing, unreadable bag, missing topics, frames or options, or no image
            passing the synchronisation rules.
    """

    check_options(FORMAT, options, OPTIONS)
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise BadInputError(f"import {FORMAT}: needs the 'rosbags' package: pip install 'jcalib[ros]'") from None
    path = Path(source)
    if not path.exists():
        raise BadInputError(f"import {FORMAT}: {path} does not exist")
    cam_mount, tgt_mount = cell_entries_for_mount(mount, FORMAT, "a bag does not say where the camera is mounted")
    if "target" not in options:
        raise BadInputError(f"import {FORMAT}: a bag holds no target description: give target=FILE, a YAML file "
                            "with the target's cell-spec entry, e.g. {type: checkerboard, cols: 9, rows: 6, square: 0.025}")
    try:  # a jcalib target entry or a Kalibr target YAML (ROS users' aprilgrid.yaml)
        target = read_target_file(Path(str(options["target"])))
    except BadInputError as e:
        raise BadInputError(f"import {FORMAT}: target: {e}") from None
    mode = str(options.get("poses", "tf"))
    if mode not in ("tf", "joint_states"):
        raise BadInputError(f"import {FORMAT}: poses: expected tf or joint_states, got {mode!r}")
    if mode == "tf" and ("base_frame" not in options or "flange_frame" not in options):
        raise BadInputError(f"import {FORMAT}: poses=tf needs base_frame=... and flange_frame=... (the /tf frames of "
                            "the robot base and flange)")
    max_dt = int(_positive(options, "max_dt_ms", 20.0) * 1e6)
    still_m = _positive(options, "still_mm", 0.5) * 1e-3
    still_rad = np.deg2rad(_positive(options, "still_deg", 0.05))
    allow_outside = flag_option(options, "allow_outside", FORMAT)
    if path.is_dir():
        _check_bag_folder(path, allow_outside)
    prismatic = {s.strip() for s in str(options.get("prismatic", "")).split(",") if s.strip()}
    js_topic = str(options.get("joint_states_topic", "/joint_states"))

    try:
        reader_cm = AnyReader([path])
        reader = reader_cm.__enter__()
    except Exception as e:  # noqa: BLE001 - rosbags raises its own reader errors
        why = (str(e).strip().splitlines() or [type(e).__name__])[0][:120]
        raise BadInputError(f"import {FORMAT}: cannot open {path} as a ROS 1 or ROS 2 bag ({why})") from None
    try:
        by_topic = {c.topic: c for c in reader.connections}
        image_topics = sorted(t for t, c in by_topic.items() if c.msgtype in IMAGE_TYPES)
        cameras = _parse_cameras(options.get("cameras"), image_topics)
        info_topics = {cam: t.rsplit("/", 1)[0] + "/camera_info" for cam, t in cameras.items()}
        want = set(cameras.values()) | {t for t in info_topics.values() if t in by_topic}
        if mode == "tf":
            want |= {t for t in ("/tf", "/tf_static") if t in by_topic}
            if "/tf" not in by_topic and "/tf_static" not in by_topic:
                raise BadInputError(f"import {FORMAT}: {path} has no /tf topic (topics: {sorted(by_topic)})")
        else:
            if js_topic not in by_topic:
                raise BadInputError(f"import {FORMAT}: {path} has no {js_topic} topic (topics: {sorted(by_topic)})")
            want.add(js_topic)
        images: dict[str, list[tuple[int, Any]]] = {c: [] for c in cameras}
        topic_cam = {t: c for c, t in cameras.items()}
        infos: dict[str, Any] = {}
        tf_series: dict[tuple[str, str], _Series] = {}
        static: dict[tuple[str, str], np.ndarray] = {}
        js = _Series()
        js_names: list[str] | None = None
        for conn, _, raw in _messages(reader, [by_topic[t] for t in sorted(want)], path):
            where = f"{path} {conn.topic}"
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as e:  # noqa: BLE001 - rosbags' decoders raise many kinds on corrupt bytes
                raise BadInputError(f"{where}: a {conn.msgtype} message cannot be decoded ({type(e).__name__}); "
                                    "the bag is damaged") from None
            if conn.topic in topic_cam:
                images[topic_cam[conn.topic]].append((_stamp_ns(msg.header, where), msg))
            elif conn.topic.endswith("/camera_info"):
                infos.setdefault(conn.topic, msg)
            elif conn.topic in ("/tf", "/tf_static"):
                for tr in msg.transforms:
                    key = (str(tr.header.frame_id).lstrip("/"), str(tr.child_frame_id).lstrip("/"))
                    t, r = tr.transform.translation, tr.transform.rotation
                    T = pose_from_xyz_quat([t.x, t.y, t.z], [r.x, r.y, r.z, r.w], f"{where} {key[0]}->{key[1]}")
                    if conn.topic == "/tf_static":
                        static[key] = T
                    else:
                        tf_series.setdefault(key, _Series()).add(_stamp_ns(tr.header, where), T)
            else:
                names = [str(n) for n in msg.name]
                if js_names is None:
                    js_names = names
                if names != js_names:
                    raise BadInputError(f"{where}: joint names change between messages ({len(js_names)} names, then "
                                        f"{len(names)}); record one robot's joint states on this topic")
                q = np.asarray(msg.position, dtype=np.float64).reshape(-1)
                if q.shape != (len(names),) or not np.all(np.isfinite(q)):
                    raise BadInputError(f"{where}: a JointState message has {q.size} positions for {len(names)} names "
                                        "(or non-finite positions); every message needs one finite position per joint")
                js.add(_stamp_ns(msg.header, where), q)
    finally:
        reader_cm.__exit__(None, None, None)

    def pose_still(a: np.ndarray, b: np.ndarray) -> bool:
        dt, dr = pose_distance(a, b)
        return dt <= still_m and dr <= still_rad

    def robot_at(t: int) -> tuple[np.ndarray | None, list[float] | None, str]:
        if mode == "joint_states":
            q, why = js.at_rest(t, max_dt, lambda a, b: bool(np.all(np.abs(a - b) <= still_rad)))
            if q is None:
                return None, None, why
            scale = [1e3 if n in prismatic else float(np.rad2deg(1.0)) for n in js_names or []]
            return None, [float(v * s) for v, s in zip(q, scale, strict=True)], ""
        T = np.eye(4)
        for p, c, fwd in steps:
            if (p, c) in static:
                E = static[(p, c)]
            else:
                E, why = tf_series[(p, c)].at_rest(t, max_dt, pose_still)
                if E is None:
                    return None, None, f"{p}->{c}: {why}"
            T = T @ (E if fwd else invert(E))
        return T, None, ""

    if mode == "tf":
        steps = _chain(set(tf_series) | set(static), str(options["base_frame"]), str(options["flange_frame"]))
    ref = next(iter(cameras))
    others = [c for c in cameras if c != ref]
    stations: list[ImportedStation] = []
    skipped: dict[str, int] = {}
    merged = 0
    for t, msg in sorted(images[ref], key=lambda x: x[0]):
        T, joints, why = robot_at(t)
        if why:
            skipped[why] = skipped.get(why, 0) + 1
            continue
        if stations and T is not None and stations[-1].T_base_flange is not None and pose_still(stations[-1].T_base_flange, T):
            merged += 1
            continue
        imgs = {ref: decode_image(msg, f"{path} {cameras[ref]} @ {t}")}
        for c in others:
            near = min(images[c], key=lambda x: abs(x[0] - t), default=None)
            if near is not None and abs(near[0] - t) <= max_dt:
                imgs[c] = decode_image(near[1], f"{path} {cameras[c]} @ {near[0]}")
        stations.append(ImportedStation(id=f"s{len(stations):03d}", T_base_flange=T, images=imgs, joints_deg=joints,
                                        source={"stamp_ns": t, "topic": cameras[ref]}))
    if not stations:
        raise BadInputError(f"import {FORMAT}: no image of {cameras[ref]} passed the synchronisation rules "
                            f"({skipped or 'no images'}); check base_frame / flange_frame, max_dt_ms and still_*")
    held = str(options.get("intrinsics", "initial"))
    if held not in ("initial", "held"):
        raise BadInputError(f"import {FORMAT}: intrinsics: expected initial or held, got {held!r}")
    cell_cams = {}
    for cam, topic in info_topics.items():
        entry: dict[str, Any] = {"model": str(options.get("camera_model", "opencv5")), "mount": cam_mount}
        info = infos.get(topic)
        if info is not None:
            dm = str(info.distortion_model)
            d = [float(v) for v in info.d] if hasattr(info, "d") else [float(v) for v in info.D]
            K = np.asarray(info.k if hasattr(info, "k") else info.K, dtype=np.float64).reshape(-1)
            if K.size != 9:
                raise BadInputError(f"{path} {topic}: camera_info K has {K.size} values, expected 9")
            K = K.reshape(3, 3)
            model = {"plumb_bob": "opencv5", "rational_polynomial": "opencv8", "equidistant": "fisheye"}.get(dm)
            if model is None:
                raise BadInputError(f"{path} {topic}: distortion_model {dm[:40]!r} has no jcalib lens model")
            entry = {"model": model, "mount": cam_mount, "intrinsics": {"K": K.tolist(), "dist": d}}
            if held == "held":
                entry["fix"] = ["fx", "fy", "cx", "cy", *({"opencv5": ["k1", "k2", "p1", "p2", "k3"],
                                                          "opencv8": ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"],
                                                          "fisheye": ["k1", "k2", "k3", "k4"]}[model])]
        cell_cams[cam] = entry
    cell = {"schema": "jcalib.cell/1", "cameras": cell_cams,
            "targets": {str(options.get("target_id", "board")): {**target, "mount": tgt_mount}}, "robot": {}}
    notes = [f"{n} image(s) skipped: {why}" for why, n in skipped.items()]
    if merged:
        notes.append(f"{merged} image(s) merged into the station before (robot at rest, same pose)")
    if mode == "joint_states":
        notes.append("stations carry joints_deg only: add the robot's kinematics to cell.yaml to calibrate")
    conventions = (f"image time = header.stamp; robot sample within {max_dt / 1e6:g} ms on both sides, at rest "
                   f"({still_m * 1e3:g} mm, {np.rad2deg(still_rad):g} deg); "
                   + ("T_base_flange = /tf chain " + " * ".join(f"T_{p}_{c}" if f else f"inv(T_{p}_{c})" for p, c, f in steps)
                      if mode == "tf" else f"{js_topic} positions rad -> deg (prismatic m -> mm)")
                   + "; geometry_msgs/Transform m, quaternion x y z w")
    return write_session(out, cell, stations, fmt=FORMAT, source=path, conventions=conventions, notes=tuple(notes))


def _messages(reader: Any, connections: list, path: Path):
    """The bag's messages of ``connections``; a damaged bag is a BadInputError, not a crash."""
    it = reader.messages(connections=connections)
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except Exception as e:  # noqa: BLE001 - rosbags raises its own, struct and sqlite errors on damaged storage
            raise BadInputError(f"import {FORMAT}: {path}: cannot read the bag's messages ({type(e).__name__}); "
                                "the bag is damaged") from None
        yield item
