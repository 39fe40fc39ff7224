"""Images → observations: the glue behind ``jcalib detect`` (cell spec in, observations.json out)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

from jcalib.errors import BadInputError, DetectionError
from jcalib.io.cell import load_cell
from jcalib.io.observations import Detection, Observations, Station, save_observations
from jcalib.pipeline.image_checks import identical_images, same_file_twice, size_warnings


def detect_images(
    cell, camera: str, image_paths: Sequence[str | os.PathLike], target: str | None = None,
    progress: bool = True, notes: dict[str, str] | None = None, jobs: int | None = None,
    warnings: dict[str, str] | None = None,
) -> tuple[Observations, dict[str, DetectionError]]:
    """Detect the cell's target in each image; one station per image (id = file stem).

    ``notes``, when given, is filled with ``{image path: what the detector did}`` for the images where
    the defaults did not suffice or points inconsistent with the board were left out
    (:func:`retry_note`); ``warnings`` with ``{image path: warning}`` where the board's orientation is
    ambiguous (:func:`orientation_warning`; the detection carries ``orientation_ambiguous`` too).
    ``jobs``: worker processes (None: every core; :func:`jcalib.vision.detect_many`).

    Returns:
        The observations of the images where the target was found, and ``{image path: error}`` for
        the others (each error says why: not found, partially visible, too blurred, unreadable).
    """
    from jcalib.vision import detect_many

    cell = load_cell(cell)
    cell.camera(camera)
    target_spec = cell.target(target)
    geometry = target_spec.geometry()
    paths = [Path(p) for p in image_paths]
    if not paths:
        raise BadInputError("no images given: pass one or more image files")
    ids = [p.stem for p in paths]
    if len(set(ids)) != len(ids):
        raise BadInputError("two images share a file name stem; station ids must be unique")
    same_file_twice(list(zip(ids, paths)), "detect")
    if warnings is not None:
        for path, twin in identical_images(paths).items():
            warnings[str(path)] = f"byte-identical to {twin}: two stations with one view (a copy or a stale frame?)"
    results = detect_many(paths, geometry, progress=progress, jobs=jobs)
    image_size = None
    stations, failures = [], {}
    for path, sid, res in zip(paths, ids, results):
        if isinstance(res, DetectionError):
            failures[str(path)] = res
            continue
        size = tuple(int(v) for v in res.image_size)
        if image_size is not None and size != image_size:
            raise BadInputError(
                f"{path}: image size {size} differs from the first image's {image_size}; "
                f"all images of camera '{camera}' must have one size"
            )
        image_size = size
        note = retry_note(res)
        if notes is not None and note:
            notes[str(path)] = note
        ambiguous = "orientation_ambiguous" in res.warnings
        said = [orientation_warning(target_spec.name)] if ambiguous else []
        said += list(res.image_notes) + ([warnings[str(path)]] if warnings is not None and str(path) in warnings else [])
        if warnings is not None and said:
            warnings[str(path)] = "; ".join(said)
        det = Detection(camera=camera, target=target_spec.name, point_index=res.point_index, pixels=res.pixels,
                        orientation_ambiguous=ambiguous)
        stations.append(Station(id=sid, detections=(det,)))
    said_size = size_warnings(cell.camera(camera), image_size) if image_size else []
    if warnings is not None and said_size:
        warnings[f"camera {camera}"] = "; ".join(said_size)
    obs = Observations(
        cameras={camera: image_size} if image_size else {},
        targets={target_spec.name: geometry.points},
        stations=tuple(stations),
    )
    return obs, failures


def orientation_warning(target: str) -> str:
    """The warning printed for a detection whose labelling the board's symmetry leaves open."""
    return (f"orientation_ambiguous: target '{target}' looks the same turned by 180° and nothing printed on it "
            "tells which way round it was seen; its point indices may be flipped in this view (recorded in "
            "observations.json; the calibration resolves it from the robot motion or stops naming it). A board "
            "with cols + rows odd, a ChArUco board or a circle grid with an origin dot has no such ambiguity")


def retry_note(det) -> str:
    """What the detector did beyond its defaults for one :class:`~jcalib.vision.TargetDetection`, or ""."""
    parts = []
    if getattr(det, "attempt", "default") != "default":
        parts.append(f"found by attempt {det.attempt} (tried {', '.join(det.attempts)})")
    if getattr(det, "dropped", 0):
        parts.append(f"{det.dropped} points inconsistent with the board left out")
    return "; ".join(parts)


def detect_images_to_file(cell_path, camera, image_paths, out_path, target=None, jobs: int | None = None) -> Observations:
    """``jcalib detect``: detect, write observations.json, print a summary of retries, warnings and failures."""
    from rich.console import Console
    from rich.markup import escape

    notes: dict[str, str] = {}
    warned: dict[str, str] = {}
    obs, failures = detect_images(cell_path, camera, image_paths, target=target, notes=notes, jobs=jobs,
                                  warnings=warned)
    console = Console(stderr=True)
    for path, note in notes.items():
        console.print(f"retried {path}: {note}", highlight=False, markup=False)
    for path, warning in warned.items():
        console.print(f"[yellow]warning[/] {escape(f'{path}: {warning}')}", highlight=False)
    for path, err in failures.items():
        console.print(f"[yellow]skipped[/] {escape(f'{path}: {err.reason} — {err}')}", highlight=False)
    if not obs.stations:
        raise BadInputError(
            f"the target was found in none of the {len(failures)} images; check the cell's target "
            "geometry (cols/rows are INNER corners for a checkerboard) and the images"
        )
    save_observations(out_path, obs)
    console.print(
        escape(
            f"wrote {out_path}: {len(obs.stations)} stations, {len(failures)} images skipped"
            + (f", {len(notes)} found or cleaned by retries" if notes else "")
            + (f", {len(warned)} with an ambiguous orientation" if warned else "")
        ),
        highlight=False,
    )
    return obs
