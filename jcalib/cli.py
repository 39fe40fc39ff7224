"""The ``jcalib`` command. Thin: parse arguments, call one public function, print or write its result.

Heavy imports (JAX, OpenCV) happen inside the commands, so ``jcalib --help`` is instant.
Exit statuses: 0 success, 2 bad input, 3 data cannot determine the unknowns, 4 device error.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

import jcalib
from jcalib.errors import JcalibError

app = typer.Typer(
    name="jcalib",
    help="Calibrate robot cells: cameras, hand-eye, TCP — one joint problem, honest uncertainty.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def enable_compilation_cache() -> None:
    """Turn on JAX's persistent compilation cache (``$JCALIB_CACHE_DIR`` or ~/.cache/jcalib/jax)."""
    import jax

    cache_dir = os.environ.get("JCALIB_CACHE_DIR") or str(Path.home() / ".cache" / "jcalib" / "jax")
    jax.config.update("jax_compilation_cache_dir", cache_dir)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", help="Print the version and exit.")] = False,
) -> None:
    if version:
        typer.echo(f"jcalib {jcalib.__version__}")
        raise typer.Exit(0)


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder for images and results.")] = Path(
        "demo-output"
    ),
    views: Annotated[int, typer.Option(help="Number of rendered views.")] = 20,
    seed: Annotated[int, typer.Option(help="Random seed of the simulated scene.")] = 0,
) -> None:
    """Render a simulated calibration, detect the target, calibrate, and compare with ground truth."""
    enable_compilation_cache()
    from jcalib.demo import run_demo

    run_demo(out_dir=out, num_views=views, seed=seed)


@app.command()
def detect(
    images: Annotated[list[Path], typer.Argument(help="Image files, one station per image.")],
    cell: Annotated[Path, typer.Option("--cell", help="Cell spec (jcalib.cell/1 YAML).")],
    camera: Annotated[str, typer.Option("--camera", help="Camera id in the cell spec.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Observations JSON to write.")],
    target: Annotated[
        Optional[str], typer.Option("--target", help="Target id (default: the cell's only target).")
    ] = None,
) -> None:
    """Detect the cell's calibration target in images and write observations.json."""
    from jcalib.detect import detect_images_to_file

    detect_images_to_file(
        cell_path=cell, camera=camera, image_paths=images, out_path=out, target=target
    )


@app.command()
def calibrate(
    cell: Annotated[Path, typer.Argument(help="Cell spec (jcalib.cell/1 YAML).")],
    observations: Annotated[Path, typer.Argument(help="Observations (jcalib.observations/1 JSON).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Result JSON to write.")],
    loss: Annotated[str, typer.Option(help="Robust loss: none, huber or cauchy.")] = "none",
    sigma_px: Annotated[float, typer.Option(help="Stated corner noise σ in pixels.")] = 0.25,
    noise: Annotated[
        str, typer.Option(help="Covariance scale: a_posteriori (from residuals) or stated.")
    ] = "a_posteriori",
    outlier_threshold: Annotated[
        Optional[float], typer.Option(help="Reject corners beyond this many σ (omit: keep all).")
    ] = 5.0,
) -> None:
    """Calibrate a cell from observations and write result.json."""
    enable_compilation_cache()
    from jcalib.calibration import calibrate as run
    from jcalib.problems.camera import CameraCalibrationOptions
    from jcalib.report.console import print_result

    options = CameraCalibrationOptions(
        loss=loss, sigma_px=sigma_px, noise=noise, outlier_threshold=outlier_threshold
    )
    result = run(cell, observations, options)
    result.to_json(out)
    print_result(result.file)
    typer.echo(f"wrote {out}")


def main() -> None:
    """Console-script entry point: maps jcalib errors to exit statuses without tracebacks."""
    try:
        app(standalone_mode=False)
    except JcalibError as e:
        from rich.console import Console

        Console(stderr=True, soft_wrap=True).print(f"[bold red]jcalib error:[/] {e}", highlight=False)
        sys.exit(e.exit_code)
    except typer.Abort:
        sys.exit(130)
    except SystemExit:
        raise
    except Exception as e:  # click usage errors
        import click

        if isinstance(e, click.ClickException):
            e.show()
            sys.exit(2)
        raise
