"""The pinhole camera: OpenCV's model without distortion (``dist`` of length 0).

``u = fx X/Z + skew Y/Z + cx``, ``v = fy Y/Z + cy``; valid for ``Z > MIN_DEPTH_M``. The
implementation is shared with the distorted models (:mod:`jcalib.geometry.cameras.perspective`).
"""

from __future__ import annotations

from typing import ClassVar

from jcalib.geometry.cameras.perspective import AbstractPerspectiveModel


class Pinhole(AbstractPerspectiveModel):
    """Pinhole camera, parameters ``fx, fy, cx, cy`` and optionally ``skew`` (pixels).

    Example: ``Pinhole((640, 480), focal=(500.0, 500.0), principal_point=(319.5, 239.5))``.
    """

    name: ClassVar[str] = "pinhole"
    mrcal_name: ClassVar[str | None] = "LENSMODEL_PINHOLE"
    num_coeffs: ClassVar[int] = 0
