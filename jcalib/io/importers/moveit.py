"""MoveIt Calibration (``moveit_calibration``) hand-eye samples -> capture session of pose pairs.

Layouts read:

- the rviz plugin's "Save samples" YAML: a sequence of ``{effector_wrt_world: [16 values],
  object_wrt_sensor: [16 values]}``, each a 4x4 matrix in row-major order;
- the JSON of its solver test data (``pose_samples.json``): ``[[effector 4x4, object 4x4], ...]``.

Conventions (``ControlTabWidget::takeTransformSamples`` / ``loadSamplesBtnClicked``):
``effector_wrt_world`` is the end effector's pose in the robot base ("TF base-to-eef") = ``T_base_flange``;
``object_wrt_sensor`` is the target's pose in the camera ("TF camera-to-target") = ``T_cam_target``;
metres. The sensor mount type (eye-in-hand / eye-to-hand) lives in the rviz config, not in the sample
file: ``--mount`` is required. The file is read with jcalib's guarded JSON / YAML readers (size, UTF-8,
aliases, depth, duplicate keys); matrix entries must be finite numbers.
"""

from __future__ import annotations

import os
from typing import Any

from jcalib.errors import BadInputError
from jcalib.io.importers.common import (
    cell_entries_for_mount,
    check_options,
    pose_from_matrix,
    pose_pair_session,
    resolve_source,
)
from jcalib.io.importers.source import SourceFolder

FORMAT = "moveit"
OPTIONS = {"camera": "camera id (default cam0)", "target": "target id (default marker)"}


def import_source(source: str | os.PathLike, out: str | os.PathLike, *, mount: str | None = None, **options: Any):
    """Import MoveIt Calibration samples (module docstring) into session ``out``.

    Raises:
        BadInputError: not a sample file, a malformed matrix, or no ``mount``.
    """
    check_options(FORMAT, options, OPTIONS)
    path = resolve_source(source, None, f"import {FORMAT}")
    cell_entries_for_mount(mount, FORMAT, "the sample file does not record the sensor mount type")
    folder = SourceFolder(path.parent, FORMAT)
    what = f"import {FORMAT}: samples"
    data = folder.read_json(path, what) if path.suffix.lower() == ".json" else folder.read_yaml(path, what)
    if not isinstance(data, list) or not data:
        raise BadInputError(f"{path}: expected a list of samples")
    pairs = []
    for i, s in enumerate(data):
        where = f"{path}: sample {i}"
        if isinstance(s, dict) and "effector_wrt_world" in s and "object_wrt_sensor" in s:
            eef, obj = s["effector_wrt_world"], s["object_wrt_sensor"]
        elif isinstance(s, list) and len(s) == 2:
            eef, obj = s
        else:
            raise BadInputError(f"{where}: expected {{effector_wrt_world, object_wrt_sensor}} or [effector, object]")
        pairs.append((pose_from_matrix(eef, where + " effector_wrt_world"), pose_from_matrix(obj, where + " object_wrt_sensor")))
    return pose_pair_session(out, pairs, mount=mount, fmt=FORMAT, source=path,
                             conventions="effector_wrt_world = T_base_flange, object_wrt_sensor = T_cam_target, "
                                         "row-major 4x4, m",
                             camera=str(options.get("camera", "cam0")), target=str(options.get("target", "marker")))
