"""Tracking a target through a live stream: the previous frame's detection says where to look.

A board moves little between frames of a live view (5-30 per second): the region around its last
detection, widened by :data:`MARGIN` of the board's size on every side, holds it again, and detecting in
that crop costs a fraction of the whole frame. When the crop does not hold the whole board (it moved
fast, left the crop, was covered), the whole frame is searched as :func:`jcalib.vision.detect_target`
searches it. Either way the detection is checked exactly as a full one (the same code runs on the crop).

For a board whose labelling its symmetry leaves open (``"orientation_ambiguous"``), the labelling closest
to the previous frame's is kept, so that point indices do not flip between frames of a live overlay while
the board turns slowly; the warning stays (the ambiguity is not resolved, only kept steady).
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from jcalib.errors import DetectionError
from jcalib.vision.detect import TargetDetection, detect_target
from jcalib.vision.image import load_image

__all__ = ["MARGIN", "track_target"]

#: The crop around the previous detection: its bounding box widened by this fraction of its larger side on
#: every side (and by at least 32 px).
MARGIN = 0.35


def track_target(
    image,
    target,
    previous: TargetDetection | None,
    *,
    name: str | None = None,
    retry: bool = False,
    **options,
) -> TargetDetection:
    """Detect a target in a frame of a live stream, using the previous frame's detection as a hint.

    With a ``previous`` detection the crop around it (:data:`MARGIN`) is searched first; the result then
    has ``attempt == "tracked"`` and :attr:`TargetDetection.tracked` true. When that fails, or without a
    ``previous`` detection, the whole frame is searched (``tracked`` false, ``attempt`` as for
    :func:`jcalib.vision.detect_target`). Pixels, ``image_size`` and indices are always those of the whole
    frame (``contrast`` and ``edge_width_px`` of a tracked one describe the crop); every detection is
    checked as a full one.

    Meant for the operator's live view (5 and more frames per second per camera at 1280x960): pass the
    last detection back with the next frame, or None after a failure or when the view jumped.

    Args:
        image: a path, or an (H, W[, 3|4]) uint8 / uint16 array (colour in BGR order).
        target: ``Checkerboard``, ``Charuco`` or ``CircleGrid``.
        previous: the detection of the previous frame of the same camera, or None.
        name: how messages refer to the frame.
        retry: let the whole-frame search run the further attempts of :mod:`jcalib.vision.attempts`
            (slower; a live view usually prefers the next frame).
        **options: passed to :func:`jcalib.vision.detect_target` (``min_points``, ...).

    Returns:
        :class:`TargetDetection` (``tracked`` says which way it was found).

    Raises:
        DetectionError: not found in the crop nor in the whole frame (the reason of the whole-frame
            search).
        BadInputError: as :func:`jcalib.vision.detect_target`.
    """
    if isinstance(image, (str, os.PathLike)):
        name = name or os.fspath(image)
        image = load_image(image)
    name = name or "<array>"
    if previous is not None and previous.num_points >= 4:
        found = _in_crop(image, target, previous, name, options)
        if found is not None:
            return found
    found = detect_target(image, target, name=name, retry=retry, **options)
    return _steady(found, target, previous)


def _in_crop(image, target, previous: TargetDetection, name: str, options: dict) -> TargetDetection | None:
    a = np.asarray(image)
    h, w = a.shape[:2]
    lo, hi = previous.pixels.min(axis=0), previous.pixels.max(axis=0)
    pad = max(32.0, MARGIN * float(np.max(hi - lo)))
    x0, y0 = (max(0, int(np.floor(v - pad))) for v in lo)
    x1, y1 = min(w, int(np.ceil(hi[0] + pad)) + 1), min(h, int(np.ceil(hi[1] + pad)) + 1)
    if x1 - x0 < 16 or y1 - y0 < 16:
        return None
    if (x1 - x0) * (y1 - y0) > 0.8 * w * h:  # the board fills the frame: nothing to gain
        return None
    try:
        crop = detect_target(np.ascontiguousarray(a[y0:y1, x0:x1]), target, name=name, retry=False, **options)
    except DetectionError:
        return None
    full = dataclasses.replace(crop, pixels=crop.pixels + [x0, y0], image_size=(w, h), attempt="tracked",
                               attempts=("tracked",))  # fmt: skip
    return _steady(full, target, previous)


def _steady(found: TargetDetection, target, previous: TargetDetection | None) -> TargetDetection:
    """For an ambiguous labelling: the one of the board's symmetries closest to the previous frame's."""
    if previous is None or "orientation_ambiguous" not in found.warnings:
        return found
    from jcalib.vision.orientation import point_symmetries

    prev = dict(zip(previous.point_index.tolist(), previous.pixels))
    best, best_err = None, np.inf
    for perm in point_symmetries(target.points[:, :2]):
        index = perm[found.point_index]
        common = [k for k, i in enumerate(index) if int(i) in prev]
        if len(common) < 4:
            continue
        err = float(np.mean([np.linalg.norm(found.pixels[k] - prev[int(index[k])]) for k in common]))
        if err < best_err:
            best, best_err = index, err
    if best is None:
        return found
    order = np.argsort(best)
    return dataclasses.replace(found, point_index=best[order], pixels=found.pixels[order])
