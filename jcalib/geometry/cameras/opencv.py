"""OpenCV's distortion models with 4, 5, 8, 12 and 14 coefficients.

``dist`` is in OpenCV's order ``k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tx, ty]]]]``;
the formulas, the valid region (where the radial map stops being monotonic) and the inversion are
documented in :mod:`jcalib.geometry.cameras.perspective`.
"""

from __future__ import annotations

from typing import ClassVar

from jcalib.geometry.cameras.perspective import AbstractPerspectiveModel


class OpenCV4(AbstractPerspectiveModel):
    """OpenCV model with ``k1, k2, p1, p2``."""

    name: ClassVar[str] = "opencv4"
    mrcal_name: ClassVar[str | None] = "LENSMODEL_OPENCV4"
    num_coeffs: ClassVar[int] = 4


class OpenCV5(AbstractPerspectiveModel):
    """OpenCV model with ``k1, k2, p1, p2, k3`` (OpenCV's default)."""

    name: ClassVar[str] = "opencv5"
    mrcal_name: ClassVar[str | None] = "LENSMODEL_OPENCV5"
    num_coeffs: ClassVar[int] = 5


class OpenCV8(AbstractPerspectiveModel):
    """OpenCV rational model: ``k1, k2, p1, p2, k3, k4, k5, k6`` (``CALIB_RATIONAL_MODEL``)."""

    name: ClassVar[str] = "opencv8"
    mrcal_name: ClassVar[str | None] = "LENSMODEL_OPENCV8"
    num_coeffs: ClassVar[int] = 8


class OpenCV12(AbstractPerspectiveModel):
    """Rational model plus thin prism ``s1..s4`` (``CALIB_THIN_PRISM_MODEL``)."""

    name: ClassVar[str] = "opencv12"
    mrcal_name: ClassVar[str | None] = "LENSMODEL_OPENCV12"
    num_coeffs: ClassVar[int] = 12


class OpenCV14(AbstractPerspectiveModel):
    """Rational + thin prism + tilted sensor ``tx, ty`` in radians (``CALIB_TILTED_MODEL``)."""

    name: ClassVar[str] = "opencv14"
    mrcal_name: ClassVar[str | None] = None
    num_coeffs: ClassVar[int] = 14
