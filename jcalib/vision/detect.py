"""Target detection: images -> (point_index, pixels) observations, with diagnostics and failure reasons."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from jcalib.errors import BadInputError, DetectionError
from jcalib.geometry.targets import AprilGrid, AprilTag, Charuco, Checkerboard, CircleGrid
from jcalib.vision.image import image_notes, image_stats, read_image, to_gray

__all__ = ["DETECTION_FAILURE_REASONS", "TargetDetection", "default_jobs", "detect_many", "detect_target"]

DETECTION_FAILURE_REASONS = ("not_found", "partially_visible", "too_blurred", "unreadable")


@dataclass(frozen=True)
class TargetDetection:
    """The target points found in one image.

    Attributes:
        point_index: (n,) int64 rows of ``target.points`` that were found (ascending for ChArUco).
        pixels: (n, 2) float64 their image positions, px, OpenCV convention (centre of the top-left
            pixel is (0, 0)).
        image_size: (width, height), px.
        name: the image path or ``"<array>"``.
        fraction_found: n / number of target points.
        edge_width_px: sharpness, about 1-3 px for a focused image (see ``image_stats``).
        contrast: grey-level spread, 0..1.
        method: the OpenCV functions used.
        warnings: ``"orientation_ambiguous"`` for a 180°-symmetric board (see
            :mod:`jcalib.vision.orientation`), ``"blurred"`` when edges are wider than
            ``max_edge_width_px``, ``"points_dropped"`` when points inconsistent with the board
            were left out (see ``dropped``).
        attempt: which attempts of :mod:`jcalib.vision.attempts` found what was kept: ``"default"``
            when the default search sufficed, else e.g. ``"default+clahe"`` (ChArUco markers
            collected over several attempts) or ``"downscale_2x"``; ``"tracked"`` when
            :func:`jcalib.vision.track_target` found it around the previous frame's detection.
        attempts: every attempt run, in order (``("default",)`` when nothing was retried).
        dropped: points (or ChArUco markers) found but left out because they disagree with the board
            layout and their neighbours (:mod:`jcalib.vision.validate`).
        image_notes: what the image file holds that its decoded pixels leave out (later pages, an EXIF
            orientation not applied: :func:`jcalib.vision.image.image_notes`); empty for an array.
    """

    point_index: np.ndarray
    pixels: np.ndarray
    image_size: tuple[int, int]
    name: str = "<array>"
    fraction_found: float = 1.0
    edge_width_px: float = float("nan")
    contrast: float = float("nan")
    method: str = ""
    warnings: tuple[str, ...] = field(default_factory=tuple)
    attempt: str = "default"
    attempts: tuple[str, ...] = ("default",)
    dropped: int = 0
    image_notes: tuple[str, ...] = ()

    @property
    def retried(self) -> bool:
        """Whether the defaults did not suffice (another attempt found points that were kept)."""
        return self.attempt not in ("default", "tracked")

    @property
    def tracked(self) -> bool:
        """Whether :func:`jcalib.vision.track_target` found it around the previous frame's detection
        (False: a whole-frame detection)."""
        return self.attempt == "tracked"

    @property
    def num_points(self) -> int:
        return int(len(self.point_index))

    def to_json(self) -> dict:
        """``{"point_index": [...], "pixels": [[u, v], ...]}`` as in ``observations.json``."""
        return {"point_index": self.point_index.tolist(), "pixels": self.pixels.tolist()}


def detect_target(
    image,
    target,
    *,
    name: str | None = None,
    min_points: int = 6,
    max_edge_width_px: float = 8.0,
    min_contrast: float = 0.1,
    retry: bool = True,
) -> TargetDetection:
    """Find a calibration target's points in one image.

    Chessboard: a fast pass on a reduced image, then (where the X-junction locator finds a lattice)
    ``cv2.findChessboardCorners`` and ``findChessboardCornersSB`` on the located region at the level its
    squares suggest, then ``cornerSubPix`` and a saddle-point fit on the full-resolution image (see
    :mod:`jcalib.vision.chessboard` for the search and the measured accuracy); the whole board must be
    visible, and every corner must be an inner corner of a checker pattern (a board with a row covered is
    rejected, not numbered 180° off). ChArUco: ArUco markers, then ``cv2.aruco.CharucoDetector``'s
    corners, partial views allowed (at least ``min_points`` corners, each id checked against the markers
    around it). Circle grids: ``cv2.findCirclesGrid`` after a quick look for a lattice of blobs; the whole
    grid must be visible. AprilGrids and AprilTags: :mod:`jcalib.vision.apriltag` (the corners of the tags
    wholly in view, at least ``min_points`` of a grid, all 4 of a single tag). Point indices of chessboards
    and circle grids follow
    :mod:`jcalib.vision.orientation` (180°-symmetric boards get the warning ``"orientation_ambiguous"``,
    a circle grid with an ``origin_dot`` is labelled from its larger dot).

    When the default search finds no board and the image plausibly holds one (chessboards, circle
    grids), or misses markers the board predicts inside the image (ChArUco), the detection is tried
    again with adapted preparations and parameters (:mod:`jcalib.vision.attempts`: threshold windows,
    board-guided marker recovery, CLAHE, 2x up- and down-scaling, smoothing); ``attempt`` / ``attempts``
    of the result say which. Every detection, default or not, is checked against the board model
    (:mod:`jcalib.vision.validate`): points whose position disagrees with their neighbours on the board
    are dropped (``dropped``); a grid with more than a tenth of its points inconsistent is not the board
    and counts as not found.

    Args:
        image: a path, or an (H, W[, 3|4]) uint8 / uint16 array (colour in BGR order).
        target: ``Checkerboard``, ``Charuco``, ``CircleGrid``, ``AprilGrid`` or ``AprilTag``.
        name: how messages refer to the image (default: the path, or ``"<array>"``).
        min_points: fewest ChArUco or AprilGrid corners accepted (>= 4).
        max_edge_width_px: a failed image whose edges are wider than this is ``"too_blurred"``; a
            found one gets the warning ``"blurred"``.
        min_contrast: a failed image with less grey-level spread (0..1) is ``"not_found"``.
        retry: try further attempts when the defaults fall short (False: the defaults only).

    Returns:
        :class:`TargetDetection`.

    Raises:
        DetectionError: reason ``"not_found"``, ``"partially_visible"``, ``"too_blurred"`` or
            ``"unreadable"``; the message names the image.
        BadInputError: an unknown target type, a bad array or option.
    """
    notes: tuple[str, ...] = ()
    if isinstance(image, (str, os.PathLike)):
        name = name or os.fspath(image)
        image, header = read_image(image)  # the pixel and memory budgets checked from the header first
        notes = image_notes(header)
    name = name or "<array>"
    _check_arguments(target, min_points)
    gray = to_gray(image, name)
    image = None  # the decoded array is not needed once the grey image exists (a colour image's memory)
    contrast, edge_width = image_stats(gray)
    common = dict(image_size=gray.size, name=name, edge_width_px=edge_width, contrast=contrast, image_notes=notes)
    blurred = ("blurred",) if edge_width > max_edge_width_px else ()

    def fail(partial_detail: str | None, rejected: tuple[str, ...] = ()) -> DetectionError:
        what = f"{target.type} {_describe(target)}"
        if rejected:  # grids found but not the board: say why, whatever else is true
            return DetectionError(f"{name}: {what} not found; grids rejected: {'; '.join(rejected)}", "not_found")
        if contrast < min_contrast:
            return DetectionError(
                f"{name}: {what} not found (the image is nearly uniform: contrast {contrast:.3f} < {min_contrast})",
                "not_found",
            )
        if partial_detail is not None:
            return DetectionError(f"{name}: {what} only partially visible ({partial_detail})", "partially_visible")
        if edge_width > max_edge_width_px:
            return DetectionError(
                f"{name}: {what} not found and the image is too blurred (edge width {edge_width:.1f} px > "
                f"{max_edge_width_px} px); refocus or reduce motion",
                "too_blurred",
            )
        return DetectionError(f"{name}: {what} not found", "not_found")

    if isinstance(target, (AprilGrid, AprilTag)):
        return _detect_apriltags(gray, target, min_points, retry, blurred, fail, common)

    if isinstance(target, Charuco):
        from jcalib.vision.charuco import find_charuco

        found = find_charuco(gray, target, retry=retry, contrast=contrast)
        ids, pixels = found.ids, found.pixels
        dropped = found.dropped_markers + found.dropped_corners
        if len(ids) < min_points:
            detail = None
            if found.num_markers > 0 or len(ids) > 0 or dropped:
                detail = (f"{found.num_markers} markers and {len(ids)} corners found, at least {min_points} corners "
                          f"needed")  # fmt: skip
                if found.dropped_markers:
                    detail += f"; {found.dropped_markers} markers inconsistent with the board layout left out"
                if found.dropped_corners:
                    detail += f"; {found.dropped_corners} corners inconsistent with the markers around them left out"
                detail += _tried(found.attempts)
                hint = _layout_hint(gray, target) if len(ids) == 0 else ""
                detail += hint
            raise fail(detail)
        return TargetDetection(
            point_index=ids,
            pixels=pixels,
            fraction_found=len(ids) / target.num_points,
            method="ArucoDetector+CharucoDetector+cornerSubPix",
            warnings=blurred + (("points_dropped",) if dropped else ()),
            attempt="+".join(found.contributing) or "default",
            attempts=found.attempts,
            dropped=dropped,
            **common,
        )

    from jcalib.vision.orientation import assign_grid_indices
    from jcalib.vision.validate import consistent_points

    if isinstance(target, Checkerboard):
        from jcalib.vision.chessboard import find_chessboard

        grid = find_chessboard(gray, target.cols, target.rows, retry=retry, contrast=contrast)
        pixels, method, tried = grid.pixels, grid.method, grid.attempts
        if pixels is None:
            size = grid.partial
            detail = None
            if size is not None:
                detail = (
                    f"a {size[0]}x{size[1]} corner chessboard is visible, {target.cols}x{target.rows} expected; "
                    "check that the whole board is in view (and the cols/rows of the target)"
                )
            raise fail(detail, grid.rejected)
    else:
        from jcalib.vision.circles import count_blobs, find_circles

        pixels, tried, seen = find_circles(gray, target, retry=retry)
        method = "findCirclesGrid"
        if pixels is None:
            n_blobs, n_border = count_blobs(gray) if seen is not None else (0, 0)
            detail = None
            if n_blobs >= max(4, target.num_points // 4) and (n_border > 0 or n_blobs < target.num_points):
                detail = (
                    f"{n_blobs} of {target.num_points} circles found, {n_border} of them at the image border"
                )
            raise fail(detail)
    point_index, ambiguous = assign_grid_indices(target, pixels, gray)
    if isinstance(target, Checkerboard):
        good = ~grid.suspect  # every check, the board's homography included (jcalib.vision.chessboard)
    else:
        good = consistent_points(target.points[point_index, :2], pixels)
    dropped = int(np.sum(~good))
    if dropped > 0.1 * len(good):
        raise DetectionError(
            f"{name}: {target.type} {_describe(target)} not found: the grid found ({method}, attempt {tried[-1]}) has "
            f"{dropped} of {len(good)} points inconsistent with the board layout (a wrong or distorted grid)",
            "not_found",
        )
    order = np.argsort(point_index[good])
    return TargetDetection(
        point_index=point_index[good][order],
        pixels=pixels[good][order],
        fraction_found=float(np.sum(good)) / target.num_points,
        method=method,
        warnings=(("orientation_ambiguous",) if ambiguous else ()) + blurred + (("points_dropped",) if dropped else ()),
        attempt=tried[-1],
        attempts=tried,
        dropped=dropped,
        **common,
    )


def _detect_apriltags(gray, target, min_points, retry, blurred, fail, common) -> TargetDetection:
    """AprilGrid / AprilTag corners (:mod:`jcalib.vision.apriltag`); partial grids allowed (at least
    ``min_points`` corners, all 4 of a single tag)."""
    from jcalib.vision.apriltag import find_apriltags

    found = find_apriltags(gray, target, retry=retry)
    need = min(min_points, target.num_points)
    dropped = found.dropped_tags + found.dropped_corners
    if len(found.point_index) < need:
        detail = None
        if len(found.tags) or dropped:
            detail = f"{len(found.tags)} tags and {len(found.point_index)} corners found, at least {need} corners needed"
            if found.dropped_tags:
                detail += (f"; {found.dropped_tags} tags left out (inconsistent with the board, a second copy of a tag, "
                           "or not wholly in view)")
            if found.dropped_corners:
                detail += f"; {found.dropped_corners} corners that could not be refined or checked left out"
            detail += _tried(found.attempts)
        raise fail(detail)
    corner = "cornerSubPix+saddle" if isinstance(target, AprilGrid) else "edge lines"
    return TargetDetection(
        point_index=found.point_index,
        pixels=found.pixels,
        fraction_found=len(found.point_index) / target.num_points,
        method=f"ArucoDetector+AprilTag decoding+{corner}",
        warnings=blurred + (("points_dropped",) if dropped else ()),
        attempt="+".join(found.contributing) or "default",
        attempts=found.attempts,
        dropped=dropped,
        **common,
    )


def _tried(attempts: tuple[str, ...]) -> str:
    return f" (attempts: {', '.join(attempts)})" if len(attempts) > 1 else ""


def _layout_hint(gray, target) -> str:
    """When markers but no corners are found: does the transposed or legacy layout fit the markers?"""
    import dataclasses

    from jcalib.vision.charuco import find_charuco

    for alt in (
        dataclasses.replace(target, squares_x=target.squares_y, squares_y=target.squares_x),
        dataclasses.replace(target, legacy=not target.legacy),
        dataclasses.replace(target, squares_x=target.squares_y, squares_y=target.squares_x, legacy=not target.legacy),
    ):
        if alt == target:
            continue
        try:
            found = find_charuco(gray, alt, retry=False)
        except Exception:  # noqa: BLE001  (only a hint)
            continue
        if len(found.ids) >= 4:
            return (f"; the markers fit a {alt.squares_x}x{alt.squares_y} board (legacy={alt.legacy}): check "
                    "squares_x/squares_y (squares along the board's x axis, its first marker row) and legacy")  # fmt: skip
    return ""


def _check_arguments(target, min_points) -> None:
    if not isinstance(target, (Checkerboard, Charuco, CircleGrid, AprilGrid, AprilTag)):
        raise BadInputError(
            f"detect_target: argument 'target' got {type(target).__name__}, expected Checkerboard, Charuco, "
            "CircleGrid, AprilGrid or AprilTag"
        )
    if isinstance(min_points, bool) or not isinstance(min_points, (int, np.integer)) or min_points < 4:
        raise BadInputError(f"detect_target: option 'min_points' got {min_points!r}, expected an integer >= 4")


def _describe(target) -> str:
    if isinstance(target, AprilGrid):
        return f"{target.cols}x{target.rows} tags ({target.family})"
    if isinstance(target, AprilTag):
        return f"id {target.id} ({target.family})"
    if isinstance(target, Charuco):
        return f"{target.squares_x}x{target.squares_y} squares ({target.dictionary})"
    kind = " asymmetric" if isinstance(target, CircleGrid) and target.asymmetric else ""
    return f"{target.cols}x{target.rows}{kind}"


def _detect_or_error(i: int, item, target, options: dict) -> TargetDetection | DetectionError:
    """One image of :func:`detect_many`: its detection, or the :class:`DetectionError` saying why not."""
    label = os.fspath(item) if isinstance(item, (str, os.PathLike)) else f"<array {i}>"
    try:
        return detect_target(item, target, name=label, **options)
    except DetectionError as e:
        return e
    except BadInputError as e:  # arguments were checked by the caller: this is the image
        return DetectionError(f"{label}: {e}", "unreadable")
    except Exception as e:  # noqa: BLE001  (an OpenCV failure on one image must not stop a batch)
        return DetectionError(f"{label}: detection failed ({type(e).__name__}: {e})", "not_found")


def _worker_init() -> None:
    import cv2

    cv2.setNumThreads(1)  # one process per core: OpenCV's own threads would only compete


def _worker(job):
    return _detect_or_error(*job)


def default_jobs() -> int:
    """The cores this process may run on (``--jobs`` default)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def detect_many(
    images: Iterable | Sequence, target, progress: bool = True, jobs: int | None = 1, **options
) -> list[TargetDetection | DetectionError]:
    """Detect a target in many images; never stops on a bad image.

    Args:
        images: paths and/or arrays.
        target: the target to find.
        progress: show a rich progress bar (on stderr).
        jobs: worker processes (None: every core, :func:`default_jobs`). Each image is detected alone,
            so the results are the same as with one process, in the same order; fewer than four images
            per worker run in fewer workers (starting one costs about a second). Workers are spawned, not
            forked (the caller may hold JAX's threads): a script calling this with ``jobs != 1`` needs the
            ``if __name__ == "__main__":`` guard, as with any spawned ``multiprocessing``.
        **options: passed to :func:`detect_target`.

    Returns:
        one entry per image, in order: a :class:`TargetDetection`, or the :class:`DetectionError`
        explaining the failure (reason ``"unreadable"`` for a file that cannot be read, or for an
        array that is not an image).
    """
    items = list(images)
    _check_arguments(target, options.get("min_points", 6))
    workers = default_jobs() if jobs is None else jobs
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise BadInputError(f"detect_many: option 'jobs' got {jobs!r}, expected an integer >= 1 (or None: every core)")
    workers = min(int(workers), len(items) // 4)
    jobs_list = [(i, item, target, options) for i, item in enumerate(items)]
    if workers <= 1:
        results = map(_worker, jobs_list)
        pool = None
    else:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # spawn: the parent may hold JAX's threads, which a fork would copy half-initialised
        pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=_worker_init)
        results = pool.map(_worker, jobs_list, chunksize=1)
    try:
        if not progress:
            return list(results)
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        columns = (TextColumn("detecting {task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
        out: list[TargetDetection | DetectionError] = []
        with Progress(*columns, console=Console(stderr=True), transient=True) as bar:
            task = bar.add_task(f"{target.type}", total=len(items))
            for r in results:
                out.append(r)
                bar.advance(task)
        return out
    finally:
        if pool is not None:
            pool.shutdown()
