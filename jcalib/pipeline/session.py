"""Capture session → observations: the glue behind ``jcalib detect --session``.

Reads a ``jcalib.session/1`` folder (``session.json`` + ``stations.jsonl`` + images), detects the cell's
target(s) in every image of every finished station, and writes ``observations.json`` in the
``jcalib.observations/1`` format: per station its measured ``T_base_flange``, the joints the controller
reported (``joints_deg``, for kinematic calibration) and one detection per (camera, target) found.
Nothing stops the batch: skipped stations, missing or unreadable images and images without the target
are reported as :class:`SessionFailure` records.

**Tool tips.** Nothing in a session says which stations present a tool: a backlit tool image simply
shows no target. So an image of a camera that observes a tool (``tools.<tool>.observed_by`` in the
cell) in which *no* target is found (every target ``not_found``) is searched for the tool's tip
(:func:`jcalib.vision.tooltip.detect_tool_tip`; with the camera's ``intrinsics`` from the cell, the
cone edges are undistorted first). A tip found gives a ``{"camera", "tool", "pixel", "axis"}`` detection
(``axis``: one point of the imaged tool axis, :data:`AXIS_POINT_PX` into the tool) and
replaces that image's target failures; otherwise the tool's failure is listed as well. An image gives
target corners or a tool tip, never both. A camera that observes several tools cannot tell which one
was on the flange: pass ``tool=`` to say it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError, DetectionError

#: Distance (px) from the tip, into the tool along the detected axis direction, of the one axis point a tip
#: detection carries (the tool's orientation comes from it; one point: the direction is one measurement).
AXIS_POINT_PX = 50.0


def _cache_key(path: Path, what: str) -> tuple:
    st = path.stat()
    return str(path.resolve()), st.st_size, st.st_mtime_ns, what


@dataclass(frozen=True)
class SessionFailure:
    """Why a station, or one camera's image of it, gave no detection.

    Attributes:
        station: station id.  camera: camera id (None: the whole station).
        target: target id, tool id (a tool-tip search), or None.
        reason: short keyword ("skipped", "excluded" (the session's ``exclusions.json``, see
            :mod:`jcalib.io.exclusions`), "missing_image", "outside_session" (a symlink out of the
            session), "duplicate_image" (byte-identical to an earlier station's image taken at another
            robot pose), "not_found", "partially_visible", "too_blurred", "unreadable"; for a tool also
            "tip_outside_image", "ambiguous").
        message: the full explanation.
    """

    station: str
    camera: str | None
    target: str | None
    reason: str
    message: str

    def __str__(self) -> str:
        where = self.station + (f" {self.camera}" if self.camera else "") + (f" {self.target}" if self.target else "")
        return f"{where}: {self.reason}: {self.message}"


def detect_session(
    session_dir: str | os.PathLike,
    cell: Any = None,
    *,
    target: str | None = None,
    tool: str | None = None,
    tools: bool = True,
    progress: bool = True,
    notes: dict[str, str] | None = None,
    cache: dict | None = None,
    jobs: int | None = None,
    warnings: dict[str, str] | None = None,
):
    """Detect the cell's targets (and tool tips) in every station image of a capture session.

    Args:
        session_dir: the session folder.
        cell: cell spec (path, mapping or :class:`jcalib.io.cell.CellSpec`); default: the one stored
            in ``session.json`` by the capture.
        target: detect only this target (default: every target of the cell).
        tool: the tool on the flange during the capture (default: for each camera, the one tool it
            observes; images of a camera observing several tools then get an "ambiguous" failure).
        tools: search images without a target for tool tips (module docstring).
        progress: show a progress bar on stderr.
        notes: filled with ``{"<station> <camera> <target>": what the detector did}`` where its
            defaults did not suffice (:func:`jcalib.pipeline.images.retry_note`).
        cache: a dict kept between calls (the operator app's): each image's detection results are stored
            under its path, size and modification time, so a second call detects only new or changed
            images. The caller empties it when the cell's targets or tools change.
        jobs: worker processes for the detection (None: every core; :func:`jcalib.vision.detect_many`).
        warnings: filled with ``{"<station> <camera> <target>": warning}`` where the board's orientation
            is ambiguous (the detection carries ``orientation_ambiguous`` too).

    Returns:
        ``(observations, failures)``: an :class:`jcalib.io.observations.Observations` with one station
        per station that has at least one detection (ids, ``T_base_flange`` in m and ``joints_deg`` from
        the session, pixels in the OpenCV convention; a tool tip is one pixel) and the list of :class:`SessionFailure`.

    Raises:
        BadInputError: not a session, no cell spec, an unknown target or tool, a station image naming
            a camera the cell lacks, one image file named by two stations, or images of one camera with
            different sizes.
    """
    from jcalib.io.cell import load_cell
    from jcalib.io.exclusions import FILENAME as EXCLUSIONS_FILE
    from jcalib.io.exclusions import load_exclusions
    from jcalib.io.session import read_session
    from jcalib.io.observations import Detection, Observations, Station
    from jcalib.pipeline.image_checks import (identical_images, outside_session, recorded_settings, same_file_twice,
                                              size_warnings)
    from jcalib.pipeline.images import orientation_warning, retry_note
    from jcalib.vision import detect_many

    d = Path(session_dir)
    if not (d / "session.json").is_file():
        raise BadInputError(f"--session: {d} has no session.json; it is not a jcalib capture session")
    meta, records = read_session(d)
    if cell is None:
        cell = meta.get("cell")
        if not cell:
            raise BadInputError(
                f"--session {d}: session.json holds no cell spec (captured without --cell); pass --cell CELL"
            )
    spec = load_cell(cell)
    targets = [spec.target(target)] if target is not None else list(spec.targets.values())
    if tool is not None and tool not in spec.tools:
        raise BadInputError(f"tool: no tool {tool!r} in the cell {spec.source} (has {', '.join(spec.tools) or 'none'})")
    tool_of = _tool_per_camera(spec, tool) if tools else {}
    if not targets and not tool_of:
        raise BadInputError(f"{spec.source}: the cell has no target (and no tool seen by a camera) to detect")
    geometries = {t.name: t.geometry() for t in targets}

    failures: list[SessionFailure] = []
    images: list[tuple[str, str, Path]] = []  # (station, camera, image path)
    excluded = load_exclusions(d)
    for rec in records:
        sid = str(rec["id"])
        status = str(rec.get("status", "ok"))
        if status != "ok":
            failures.append(SessionFailure(sid, None, None, "skipped", status))
            continue
        if excluded.excludes(sid):
            failures.append(SessionFailure(sid, None, None, "excluded", f"left out by {d / EXCLUSIONS_FILE}"))
            continue
        for cam, rel in (rec.get("images") or {}).items():
            if excluded.excludes(sid, cam):
                failures.append(SessionFailure(sid, cam, None, "excluded", f"left out by {d / EXCLUSIONS_FILE}"))
                continue
            if cam not in spec.cameras:
                raise BadInputError(
                    f"session {d}: station {sid} has an image of camera {cam!r}, which the cell spec "
                    f"{spec.source} lacks (it has {', '.join(spec.cameras)}); pass the cell used for the capture"
                )
            path = d / rel
            outside = outside_session(d, path)
            if outside:
                failures.append(SessionFailure(sid, cam, None, "outside_session", outside))
                continue
            if not path.is_file():
                failures.append(SessionFailure(sid, cam, None, "missing_image", f"{path} does not exist"))
                continue
            images.append((sid, cam, path))
    same_file_twice([(sid, p) for sid, _, p in images], f"session {d}")
    twins = identical_images([p for _, _, p in images])
    pose_of = {str(r["id"]): (r.get("T_base_flange"), r.get("flange_poses"), r.get("joints_deg")) for r in records}
    kept = []
    for sid, cam, path in images:  # a later station's image identical to an earlier one: a stale frame?
        twin = twins.get(path)
        if twin is None:
            kept.append((sid, cam, path))
            continue
        tsid = next(s for s, _, p in images if p == twin)
        what = f"byte-identical to {twin} (station {tsid})"
        if pose_of.get(tsid) != pose_of.get(sid):
            failures.append(SessionFailure(sid, cam, None, "duplicate_image", f"{path} is {what}, taken at another "
                                           "robot pose: a stale frame? left out (the earlier station keeps it)"))
            continue
        if warnings is not None:
            warnings[f"{sid} {cam}"] = f"{path} is {what}; both are kept (the same robot pose)"
        kept.append((sid, cam, path))
    images = kept

    found: dict[tuple[str, str, str], Any] = {}
    sizes: dict[str, tuple[int, int]] = {}
    image_failures: dict[tuple[str, str], list[SessionFailure]] = {}

    def check_size(cam: str, path: Path, size: tuple[int, int]) -> None:
        if sizes.setdefault(cam, size) != size:
            raise BadInputError(
                f"session {d}: {path} is {size[0]}x{size[1]} px but other images of camera {cam!r} "
                f"are {sizes[cam][0]}x{sizes[cam][1]}; one camera must keep one image size"
            )

    def cached(key_of: str, paths: list[Path], detect):
        """``detect(paths)``, each image's result kept in ``cache`` under its path, size and time stamp."""
        if cache is None:
            return detect(paths)
        keys = [_cache_key(p, key_of) for p in paths]
        todo = [i for i, k in enumerate(keys) if k not in cache]
        if todo:
            for i, res in zip(todo, detect([paths[i] for i in todo]), strict=True):
                cache[keys[i]] = res
        return [cache[k] for k in keys]

    for tname, geom in geometries.items():
        results = cached(f"target {tname}", [p for _, _, p in images],
                         lambda paths, geom=geom: detect_many(paths, geom, progress=progress, jobs=jobs))
        for (sid, cam, path), res in zip(images, results, strict=True):
            if isinstance(res, DetectionError):
                image_failures.setdefault((sid, cam), []).append(SessionFailure(sid, cam, tname, res.reason, str(res)))
                continue
            check_size(cam, path, (int(res.image_size[0]), int(res.image_size[1])))
            found[(sid, cam, tname)] = res
            note = retry_note(res)
            if notes is not None and note:
                notes[f"{sid} {cam} {tname}"] = note
            if warnings is not None and "orientation_ambiguous" in res.warnings:
                warnings[f"{sid} {cam} {tname}"] = orientation_warning(tname)
            if warnings is not None and res.image_notes:
                warnings[f"{sid} {cam}"] = f"{path}: " + "; ".join(res.image_notes)

    # tool tips: images of a camera observing a tool in which no target was found at all
    tips: dict[tuple[str, str], tuple[str, np.ndarray, np.ndarray]] = {}
    for sid, cam, path in images:
        fails = image_failures.get((sid, cam), [])
        if cam not in tool_of or any(f.reason != "not_found" for f in fails) or len(fails) < len(geometries):
            continue
        tname, message = tool_of[cam]
        if message:
            fails.append(SessionFailure(sid, cam, None, "ambiguous", message))
            continue
        res = cached(f"tip {cam}", [path], lambda paths, cam=cam: [_detect_tip(p, spec.cameras[cam]) for p in paths])[0]
        if isinstance(res, DetectionError):
            fails.append(SessionFailure(sid, cam, tname, res.reason, str(res)))
            continue
        check_size(cam, path, res.image_size)
        pixel = np.asarray(res.pixel, dtype=np.float64).reshape(1, 2)
        # one point on the imaged tool axis, AXIS_POINT_PX into the tool: it carries the axis direction
        axis = pixel + AXIS_POINT_PX * np.asarray(res.axis_direction, dtype=np.float64).reshape(1, 2)
        tips[(sid, cam)] = (tname, pixel, axis)
        image_failures[(sid, cam)] = []  # a tool image: its targets were not expected
    for sid, cam, _ in images:
        failures.extend(image_failures.get((sid, cam), []))

    stations = []
    for rec in records:
        sid = str(rec["id"])
        dets = [
            Detection(camera=cam, target=tname, point_index=np.asarray(r.point_index, dtype=np.int64),
                      pixels=np.asarray(r.pixels, dtype=np.float64),
                      orientation_ambiguous="orientation_ambiguous" in r.warnings)
            for (s, cam, tname), r in found.items() if s == sid
        ]  # fmt: skip
        dets += [Detection(camera=cam, pixels=px, tool=tname, axis=axis)
                 for (s, cam), (tname, px, axis) in tips.items() if s == sid]
        if not dets:
            continue
        T = rec.get("T_base_flange")
        stations.append(
            Station(id=sid, detections=tuple(dets), T_base_flange=None if T is None else np.asarray(T, dtype=np.float64),
                    joints_deg=_joints(rec.get("joints_deg")),
                    lens={str(c): {str(k): float(v) for k, v in (values or {}).items()}
                          for c, values in (rec.get("lens") or {}).items()})  # zoom settings read back at capture
        )
    for cam, size in sizes.items():
        said = size_warnings(spec.cameras[cam], size, recorded_settings(meta, cam), str(d / "session.json"))
        if warnings is not None and said:
            warnings[f"camera {cam}"] = "; ".join(said)
    for cam in {c for _, c, _ in images} - set(sizes):  # cameras that never saw a target: size from an image
        from jcalib.vision.image import image_header_size

        size = image_header_size(next(p for _, c, p in images if c == cam))
        if size is not None:
            sizes[cam] = size
    obs = Observations(
        cameras=dict(sorted(sizes.items())),
        targets={name: np.asarray(g.points, dtype=np.float64) for name, g in geometries.items()},
        stations=tuple(stations),
        source=str(d),
    )
    return obs, failures


def _joints(value: Any) -> np.ndarray | dict[str, np.ndarray] | None:
    """A session record's ``joints_deg`` (a list, or robot -> list) as the observations' station holds it."""
    if value is None:
        return None
    if isinstance(value, dict):
        return {str(r): np.asarray(q, dtype=np.float64) for r, q in value.items()}
    return np.asarray(value, dtype=np.float64)


def _tool_per_camera(spec: Any, tool: str | None) -> dict[str, tuple[str, str]]:
    """For each camera observing a tool: ``(tool name, "")``, or ``(tool names, why it is ambiguous)``."""
    seen: dict[str, list[str]] = {}
    for t in spec.tools.values():
        if tool is not None and t.name != tool:
            continue
        for cam in t.observed_by:
            seen.setdefault(cam, []).append(t.name)
    out = {}
    for cam, names in seen.items():
        if len(names) == 1:
            out[cam] = (names[0], "")
        else:
            why = (f"camera {cam!r} observes the tools {', '.join(names)}; which one was on the flange is not "
                   "recorded: name it (detect_session(tool=...))")  # fmt: skip
            out[cam] = (", ".join(names), why)
    return out


def _detect_tip(path: Path, cam_spec: Any):
    """The tool tip in one image (a :class:`~jcalib.vision.tooltip.ToolTipDetection`) or the
    :class:`DetectionError` saying why not; the camera's cell intrinsics undistort the edges when given."""
    from jcalib.vision.image import load_image
    from jcalib.vision.tooltip import detect_tool_tip

    try:
        img = load_image(path)  # within the pixel budget
    except DetectionError as e:
        return e
    camera = None
    if cam_spec.K is not None:
        from jcalib.geometry.cameras.factory import camera_from_opencv

        dist = np.zeros(0) if cam_spec.dist is None else np.asarray(cam_spec.dist, dtype=np.float64)
        camera = camera_from_opencv(np.asarray(cam_spec.K, dtype=np.float64), dist, (img.shape[1], img.shape[0]),
                                    fisheye=cam_spec.model == "fisheye")  # fmt: skip
    try:
        return detect_tool_tip(img, camera=camera, name=str(path))
    except DetectionError as e:
        return e
    except BadInputError as e:
        return DetectionError(f"{path}: {e}", "unreadable")


def detect_session_to_file(
    session_dir: str | os.PathLike,
    cell: Any = None,
    out_path: str | os.PathLike | None = None,
    *,
    target: str | None = None,
    progress: bool = True,
    cache: dict | None = None,
    jobs: int | None = None,
):
    """``jcalib detect --session``: detect, write ``observations.json`` (default: in the session), report
    retries, orientation warnings and failures (``jobs``: worker processes, None: every core).

    Returns:
        ``(observations, failures)`` as :func:`detect_session`.

    Raises:
        BadInputError: as :func:`detect_session`, or the target was found in no image at all.
    """
    from rich.console import Console
    from rich.markup import escape

    from jcalib.io.observations import save_observations

    notes: dict[str, str] = {}
    warned: dict[str, str] = {}
    obs, failures = detect_session(session_dir, cell, target=target, progress=progress, notes=notes, jobs=jobs,
                                   warnings=warned, cache=cache)
    console = Console(stderr=True, soft_wrap=True)
    for what, note in notes.items():
        console.print(f"retried {what}: {note}", highlight=False, markup=False)
    for what, warning in warned.items():
        console.print(f"[yellow]warning[/] {escape(f'{what}: {warning}')}", highlight=False)
    for f in failures:
        word = "[cyan]excluded[/]" if f.reason == "excluded" else "[yellow]skipped[/]"
        console.print(f"{word} {escape(str(f))}", highlight=False)
    if not obs.stations:
        raise BadInputError(
            f"session {session_dir}: the target was found in no image ({len(failures)} failures); check the "
            "cell's target geometry (cols/rows are INNER corners for a checkerboard) and the images"
        )
    out = Path(out_path) if out_path is not None else Path(session_dir) / "observations.json"
    save_observations(out, obs)
    console.print(
        escape(f"wrote {out}: {len(obs.stations)} stations, {obs.num_detections()} detections, "
               f"{len(failures)} failures" + (f", {len(notes)} found or cleaned by retries" if notes else "")
               + (f", {len(warned)} with an ambiguous orientation" if warned else "")),
        highlight=False,
    )  # fmt: skip
    return obs, failures
