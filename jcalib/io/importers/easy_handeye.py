"""easy_handeye (ROS 1) and easy_handeye2 (ROS 2) hand-eye samples -> capture session of pose pairs.

Two sample layouts are read (YAML):

- easy_handeye2 ``~/.ros2/easy_handeye2/calibrations/NAME.samples`` (``message_to_yaml`` of
  ``easy_handeye2_msgs/SampleList``)::

      parameters: {name, calibration_type: eye_in_hand | eye_on_base, robot_base_frame,
                   robot_effector_frame, tracking_base_frame, tracking_marker_frame, ...}
      samples:
      - robot:    {translation: {x, y, z}, rotation: {x, y, z, w}}
        tracking: {translation: {x, y, z}, rotation: {x, y, z, w}}

- easy_handeye ``easy_handeye/SampleList`` as ``rostopic echo`` / a service response prints it
  (optionally under a ``samples:`` key; ``---`` separators allowed)::

      hand_world_samples:    [{translation: {x, y, z}, rotation: {x, y, z, w}}, ...]
      camera_marker_samples: [{translation: ..., rotation: ...}, ...]

Conventions (the tools' samplers): ``geometry_msgs/Transform``, metres, quaternion by named fields
(ROS order x, y, z, w). ``tracking`` / ``camera_marker`` is ``lookup_transform(tracking_base_frame,
tracking_marker_frame)`` = ``T_cam_marker``. ``robot`` / ``hand_world`` is ``lookup_transform(base,
effector)`` = ``T_base_flange`` for an eye-in-hand calibration but ``lookup_transform(effector, base)``
= ``T_flange_base`` (inverted here) for eye-on-base: its meaning depends on the calibration type, so the
type must be known, from ``parameters.calibration_type`` (``eye_in_hand`` / ``eye_on_base``, or ROS 1's
``eye_on_hand: true/false``) or from ``--mount`` (``flange`` = eye-in-hand); both given must agree;
neither is refused. The robot's effector frame is taken as the flange.

The file is read with jcalib's guarded YAML loader (16 MiB, aliases, depth, duplicate keys); a
trailing ``---`` (as ``rostopic echo`` prints) is allowed, a second document is refused by its line.
"""

from __future__ import annotations

import os
from typing import Any

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import invert
from jcalib.io.importers.common import (
    check_options,
    pose_from_xyz_quat,
    pose_pair_session,
    resolve_source,
)
from jcalib.io.importers.source import SourceFolder

FORMAT = "easy-handeye"
OPTIONS = {"camera": "camera id (default cam0)", "target": "marker id (default marker)"}


def _transform(t: Any, where: str):
    try:
        tr, rot = t["translation"], t["rotation"]
        return pose_from_xyz_quat([tr["x"], tr["y"], tr["z"]], [rot["x"], rot["y"], rot["z"], rot["w"]], where)
    except (KeyError, TypeError, IndexError):
        raise BadInputError(f"{where}: expected {{translation: {{x, y, z}}, rotation: {{x, y, z, w}}}}") from None


def _single_document(text: str, path) -> str:
    """``text`` without the document separators a ROS tool prints after a message; a second document
    with content is refused by its line (its data would otherwise be dropped without a word)."""
    lines = text.split("\n")
    k = len(lines)
    while k and lines[k - 1].strip() in ("", "---", "..."):
        k -= 1
    body = lines[:k]
    content = False
    for n, line in enumerate(body):
        marker = line.rstrip() == "..." or (line.startswith("---") and (len(line) == 3 or line[3] in " \t"))
        if marker and content:
            raise BadInputError(f"{path} line {n + 1}: a second YAML document starts here; an easy_handeye file holds "
                                "one sample list: keep one document (or import each as its own session)")
        if line.strip() and not line.lstrip().startswith(("#", "%")) and not marker:
            content = True
    return "\n".join(body) + "\n"


def _mount_from_parameters(params: Any) -> str | None:
    if not isinstance(params, dict):
        return None
    ct = params.get("calibration_type")
    if ct in ("eye_in_hand", "eye_on_base"):
        return "flange" if ct == "eye_in_hand" else "base"
    if isinstance(params.get("eye_on_hand"), bool):
        return "flange" if params["eye_on_hand"] else "base"
    return None


def import_source(source: str | os.PathLike, out: str | os.PathLike, *, mount: str | None = None, **options: Any):
    """Import easy_handeye / easy_handeye2 samples (module docstring) into session ``out``.

    Raises:
        BadInputError: not a sample file, mismatched list lengths, an unknown calibration type, or a
            ``mount`` contradicting it.
    """
    from jcalib.io.schema.reading import parse_yaml

    check_options(FORMAT, options, OPTIONS)
    path = resolve_source(source, None, f"import {FORMAT}")
    folder = SourceFolder(path.parent, FORMAT)
    doc = parse_yaml(_single_document(folder.read_text(path, f"import {FORMAT}: samples", "yaml"), path), str(path))
    if isinstance(doc, dict) and isinstance(doc.get("samples"), dict):
        doc = {**doc["samples"], "parameters": doc.get("parameters")}
    if not isinstance(doc, dict):
        raise BadInputError(f"{path}: expected an easy_handeye sample list (samples: or hand_world_samples:)")
    params = doc.get("parameters")
    if isinstance(doc.get("samples"), list):
        raw = [(s.get("robot"), s.get("tracking")) if isinstance(s, dict) else (None, None) for s in doc["samples"]]
        layout = "easy_handeye2 .samples"
    elif "hand_world_samples" in doc and "camera_marker_samples" in doc:
        hw, cm = doc["hand_world_samples"] or [], doc["camera_marker_samples"] or []
        if not isinstance(hw, list) or not isinstance(cm, list):
            raise BadInputError(f"{path}: hand_world_samples and camera_marker_samples must be lists of transforms")
        if len(hw) != len(cm):
            raise BadInputError(f"{path}: {len(hw)} hand_world_samples but {len(cm)} camera_marker_samples")
        raw, layout = list(zip(hw, cm)), "easy_handeye SampleList"
    else:
        raise BadInputError(f"{path}: neither 'samples' (easy_handeye2) nor 'hand_world_samples' / "
                            "'camera_marker_samples' (easy_handeye)")
    if isinstance(params, dict) and params.get("calibration_type") not in (None, "", "eye_in_hand", "eye_on_base"):
        raise BadInputError(f"{path}: parameters.calibration_type {str(params['calibration_type'])[:40]!r}; expected "
                            "eye_in_hand or eye_on_base")
    from_file = _mount_from_parameters(params)
    if from_file is not None and mount is not None and from_file != mount:
        raise BadInputError(f"{path}: the samples are {'eye-in-hand' if from_file == 'flange' else 'eye-on-base'} "
                            f"(camera on the {from_file}), but --mount {str(mount)[:40]} was given")
    mount = from_file or mount
    if mount is None:
        raise BadInputError(f"{path}: the calibration type is not recorded (parameters.calibration_type is empty); "
                            "the robot transform is T_base_effector for eye-in-hand but T_effector_base for "
                            "eye-on-base: say which with --mount flange (eye-in-hand) or --mount base (eye-on-base)")
    pairs = []
    for i, (rob, trk) in enumerate(raw):
        T_rob = _transform(rob, f"{path}: sample {i} robot")
        T_cam_marker = _transform(trk, f"{path}: sample {i} tracking")
        pairs.append((T_rob if mount == "flange" else invert(T_rob), T_cam_marker))
    conventions = (f"{layout}: robot = T_base_effector (eye-in-hand) / T_effector_base inverted (eye-on-base), "
                   "tracking = T_cam_marker; geometry_msgs/Transform, m, quaternion x y z w")
    return pose_pair_session(out, pairs, mount=mount, fmt=FORMAT, source=path, conventions=conventions,
                             camera=str(options.get("camera", "cam0")), target=str(options.get("target", "marker")),
                             extra={"parameters": params} if isinstance(params, dict) else None)
