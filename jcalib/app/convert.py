"""``jcalib convert``: a result's camera fitted by another lens model (:mod:`jcalib.problems.convert`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from jcalib.errors import BadInputError
from jcalib.geometry.cameras import camera_from_opencv
from jcalib.io.result import CameraResult, ResultFile, load_result
from jcalib.problems.convert import convert_camera

__all__ = ["run_convert"]


def _camera_name(file: ResultFile, camera: str | None) -> str:
    if camera is not None:
        if camera not in file.cameras:
            raise BadInputError(f"--camera: got {camera!r}; the result's cameras are {', '.join(file.cameras) or 'none'}")
        return camera
    if len(file.cameras) != 1:
        raise BadInputError(f"the result has {len(file.cameras)} cameras ({', '.join(file.cameras) or 'none'}); "
                            "name one with --camera")
    return next(iter(file.cameras))


def _region(text: str | None):
    if text is None:
        return None
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 4:
        raise BadInputError(f"--region: got {text!r}; expected x0,y0,x1,y1 in pixels, e.g. 100,80,1180,880")
    return values


def run_convert(result: Path, to: str, out: Path, camera: str | None, region: str | None, fix: str | None) -> None:
    """Convert the camera, print the approximation error, write the result with the converted camera.

    The converted entry keeps the file's other cameras, transforms and statistics; it records the
    conversion under ``converted`` (source model, region, RMS and max error in pixels), and the source's
    σ propagated through the fit as its covariance.
    """
    file = load_result(result)
    name = _camera_name(file, camera)
    entry = file.cameras[name]
    source = camera_from_opencv(entry.K, entry.dist, entry.image_size, fisheye=entry.model == "fisheye")
    held = [f.strip() for f in fix.split(",") if f.strip()] if fix else []
    conv = convert_camera(source, to, covariance=entry.covariance, region=_region(region), fix=held)
    converted = CameraResult.from_model(conv.model, covariance=conv.covariance)
    converted = CameraResult(converted.model, converted.image_size, converted.K, converted.dist, converted.std,
                             converted.covariance, converted.skew, {**dict(entry.extra), "converted": conv.summary()})
    cameras = {**dict(file.cameras), name: converted}
    new = ResultFile(cameras=cameras, transforms=file.transforms, points=file.points, targets=file.targets,
                     stats=file.stats, provenance=file.provenance,
                     extra={k: v for k, v in file.extra.items() if k != "joint_covariance"})
    new.save(out)
    table = Table(title=f"{name}: {entry.model} → {to}")
    for col in ("region [px]", "pixels compared", "left out", "RMS [px]", "max [px]", "worst at [px]"):
        table.add_column(col)
    table.add_row(" ".join(f"{v:g}" for v in conv.region), str(conv.num_pixels), str(conv.num_left_out),
                  f"{conv.rms_px:.4f}", f"{conv.max_px:.4f}", f"{conv.worst_pixel[0]:.0f}, {conv.worst_pixel[1]:.0f}")
    console = Console()
    console.print(table)
    if entry.std and conv.covariance is not None:
        sigma_f = float(np.sqrt(max(conv.covariance[0, 0], 0.0)))
        console.print(f"converted fx σ {sigma_f:.4f} px (the source's σ propagated; the approximation error above "
                      "is systematic and not in it)", highlight=False)
    console.print(f"wrote {out}", highlight=False)
