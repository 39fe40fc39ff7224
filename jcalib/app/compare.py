"""The bodies of ``jcalib compare A.json B.json`` and ``jcalib cross-validate CELL OBSERVATIONS``.

Registered in :mod:`jcalib.app.cli` with ``app.command("compare")(compare_command)`` and
``app.command("cross-validate")(cross_validate_command)`` (typer reads the annotations below).
Exit statuses: 0 consistent, 1 the calibrations differ by more than their σ predict, 2 bad input,
3 (cross-validate) a half cannot determine the unknowns.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from jcalib.app.checks import SEED, grid, number

_GRID_HELP = "Grid points across the image, WxH (edges and corners included)."
_DISTANCE_HELP = ("Range of the compared points, m (default: infinity). Central lens models and a rotation-only "
                  "fit: the difference is the same at every range.")
_ROTATION_HELP = "Fit the rotation between the two camera frames (a frame rotation is not a lens difference)."
_GRID = grid(2, 400)
_DISTANCE = number(0, float("inf"), "m", allow_inf=True)


def _grid(text: str) -> tuple[int, int]:
    from jcalib.errors import BadInputError

    w, sep, h = text.lower().partition("x")
    if not sep or not w.strip().isdigit() or not h.strip().isdigit():
        raise BadInputError(f"--grid: expected WxH such as 24x18 (grid points across and down), got {text!r}")
    return int(w), int(h)


def _exit(comparisons) -> None:
    raise typer.Exit(1 if any(c.verdict == "differ" for c in comparisons.values()) else 0)


def compare_command(
    a: Annotated[Path, typer.Argument(help="First result (jcalib.result/1 JSON).")],
    b: Annotated[Path, typer.Argument(help="Second result (jcalib.result/1 JSON) of the same cameras.")],
    camera: Annotated[Optional[list[str]], typer.Option("--camera", help="Camera to compare (repeatable; default: "
                                                                          "every camera estimated in both).")] = None,
    grid: Annotated[str, typer.Option("--grid", callback=_GRID, help=_GRID_HELP)] = "24x18",
    distance: Annotated[Optional[float], typer.Option("--distance", callback=_DISTANCE, help=_DISTANCE_HELP)] = None,
    fit_rotation: Annotated[bool, typer.Option("--fit-rotation/--no-fit-rotation", help=_ROTATION_HELP)] = True,
    json_out: Annotated[Optional[Path], typer.Option("--json", help="Write the comparison (per-point differences, "
                                                                    "covariances, χ²) to this JSON file.")] = None,
) -> None:
    """Compare two calibrations of the same cameras: projection difference against its predicted σ.

    Each grid pixel is unprojected by A, rotated by the best-fit rotation between the two camera frames,
    projected by B; the difference is tested against the σ both covariances predict (per-point 2-dof χ²).
    Exit status 0: consistent; 1: they differ by more than their σ predict; 2: bad input.
    """
    from jcalib.io.outputs import check_outputs

    check_outputs({"--json": json_out}, [a, b])
    size = _grid(grid)
    from jcalib.io.result import load_result

    fa, fb = load_result(a), load_result(b)  # bad input fails here, before anything heavy
    from jcalib.report.compare import (
        compare_results,
        print_comparisons,
        write_comparisons,
    )
    from jcalib.solve.cache import enable_compilation_cache

    enable_compilation_cache()
    comparisons = compare_results(fa, fb, cameras=camera, grid=size, distance_m=distance, fit_rotation=fit_rotation)
    print_comparisons(comparisons, title=f"Projection difference: B ({b.name}) − A ({a.name})")
    if json_out is not None:
        write_comparisons(json_out, comparisons, {"a": str(a), "b": str(b)})
        typer.echo(f"wrote {json_out}")
    _exit(comparisons)


def cross_validate_command(
    cell: Annotated[Path, typer.Argument(help="Cell spec (jcalib.cell/1 YAML).")],
    observations: Annotated[Path, typer.Argument(help="Observations (jcalib.observations/1 JSON).")],
    split: Annotated[str, typer.Option("--split", help="interleaved (even / odd stations in file order) or random "
                                                       "(--seed).")] = "interleaved",
    seed: Annotated[int, typer.Option("--seed", callback=SEED, help="Seed of the random split.")] = 0,
    camera: Annotated[Optional[list[str]], typer.Option("--camera", help="Camera to compare (repeatable; default: "
                                                                          "every camera with estimated intrinsics).")] = None,
    grid: Annotated[str, typer.Option("--grid", callback=_GRID, help=_GRID_HELP)] = "24x18",
    distance: Annotated[Optional[float], typer.Option("--distance", callback=_DISTANCE, help=_DISTANCE_HELP)] = None,
    fit_rotation: Annotated[bool, typer.Option("--fit-rotation/--no-fit-rotation", help=_ROTATION_HELP)] = True,
    sigma_px: Annotated[Optional[float], typer.Option(callback=number(0, 100, "px"),
                                                      help="Target-corner noise σ, pixels [0.25].")] = None,
    noise: Annotated[Optional[str], typer.Option(help="Covariance scale: a_posteriori or stated [a_posteriori].")] = None,
    outlier_threshold: Annotated[Optional[float], typer.Option(callback=number(0, 1e6, "σ", lo_open=False),
                                                               help="Reject measurements beyond this many σ (0 keeps "
                                                                    "every measurement) [5].")] = None,
    json_out: Annotated[Optional[Path], typer.Option("--json", help="Write the comparison (and the halves' station "
                                                                    "ids) to this JSON file.")] = None,
) -> None:
    """Split-half cross-validation: calibrate two halves of the stations separately and compare the cameras.

    The halves are disjoint views with independent noise: their calibrations should differ by what their
    covariances predict. "differ" means model error (the lens model does not fit the lens), a camera that
    changed during the capture, or σ that are too small. Needs at least 4 views of each camera per half.
    Exit status 0: consistent; 1: the halves differ; 2: bad input; 3: a half cannot determine the unknowns.
    """
    from jcalib.io.outputs import check_outputs

    check_outputs({"--json": json_out}, [cell, observations])
    size = _grid(grid)
    from jcalib.io.cell import load_cell
    from jcalib.io.observations import load_observations
    from jcalib.io.schema import check_cell_observations

    cell_spec, obs = load_cell(cell), load_observations(observations)
    check_cell_observations(cell_spec, obs)
    options = {k: v for k, v in dict(sigma_px=sigma_px, noise=noise, outlier_threshold=outlier_threshold).items()
               if v is not None}
    if options.get("outlier_threshold") == 0:
        options["outlier_threshold"] = None
    from jcalib.report.compare import (
        print_comparisons,
        split_half_comparison,
        write_comparisons,
    )
    from jcalib.solve.cache import enable_compilation_cache

    enable_compilation_cache()
    cv = split_half_comparison(cell_spec, obs, options, split=split, seed=seed, cameras=camera, grid=size,
                               distance_m=distance, fit_rotation=fit_rotation)
    ids = cv.halves.stations
    typer.echo(f"halves ({split}): A {len(ids[0])} stations, B {len(ids[1])} stations")
    for name, why in cv.skipped.items():
        typer.echo(f"skipped {name}: {why}", err=True)
    print_comparisons(cv.comparisons, title="Split-half cross-validation: B (second half) − A (first half)")
    if json_out is not None:
        write_comparisons(json_out, cv.comparisons, {"split": split, "seed": seed,
                                                     "stations": {"a": list(ids[0]), "b": list(ids[1])}})
        typer.echo(f"wrote {json_out}")
    _exit(cv.comparisons)
