"""``jcalib capture --goal ...``: the command over :func:`jcalib.workflow.adaptive.run_adaptive_capture`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from jcalib.errors import BadInputError


def capture_command(*, robot: str, camera: Sequence[str], out: Path, plan: Path | None, cell: Path | None,
                    resume: bool, packet_size: int | None, setting: Sequence[str] | None, kind: str,
                    goal: Sequence[str], max_stations: int | None, image_size: str | None, seed: int,
                    candidates: int | None, echo: Callable[[str], None] = print) -> None:
    """The ``jcalib capture --goal`` command: check the options, run :func:`run_adaptive_capture`, print the
    outcome (goals unmet is a finished capture, not an error: exit status 0 with the reason printed)."""
    from jcalib.workflow.adaptive import run_adaptive_capture
    from jcalib.workflow.devices import parse_image_size, parse_named, parse_settings
    from jcalib.io.goals import parse_goals

    if plan is not None:
        raise BadInputError("capture: --plan and --goal exclude each other: a plan fixes the stations, goals choose "
                            "them as the capture goes; give one of them")
    if kind != "stations":
        raise BadInputError(f"--kind {kind}: adaptive capture (--goal) grabs at each chosen station; the tool-tip "
                            "servo (--kind tcp) needs a `plan --kind tcp` plan (--plan)")
    goals = parse_goals(goal)
    if cell is not None:
        from jcalib.io.cell import load_cell

        load_cell(cell)
    outcome = run_adaptive_capture(
        robot_url=robot, camera_urls=parse_named(camera), cell=cell, goals=goals,
        max_stations=30 if max_stations is None else max_stations, out=Path(out), resume=resume,
        packet_size=packet_size, settings=parse_settings(setting or []), image_size=parse_image_size(image_size),
        seed=seed, num_candidates=candidates, echo=echo)
    tried = len(outcome.failed)
    echo(f"wrote {out}: {len(outcome.stations)} stations calibrated"
         + (f", {tried} candidate(s) replaced (unreachable or nothing detected)" if tried else "")
         + (f"; result {Path(out) / 'result.json'}" if outcome.result is not None else ""))
    echo(("goals met: " if outcome.met else "goals NOT met: ") + outcome.message)
