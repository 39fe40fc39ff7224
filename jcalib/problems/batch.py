"""Many data sets of one kind of cell at once: Monte-Carlo studies, fleets of identical cells.

Each data set is started on the host (closed forms) as :func:`jcalib.problems.calibrate.calibrate_cell`
does; the solves and every refinement round then run as vmapped calls over the data sets of one
problem structure (:func:`jcalib.problems.refine.refine_many`, :func:`jcalib.solve.solve_many`), padded
to one shape bucket: one compiled function serves the whole batch.
"""

from __future__ import annotations

from collections.abc import Sequence

from jcalib.errors import BadInputError, JcalibError
from jcalib.io.cell import load_cell
from jcalib.io.observations import load_observations
from jcalib.problems.assemble import Calibration, assemble
from jcalib.problems.calibrate import options_and_given, prepare
from jcalib.problems.refine import Member, refine_many


def calibrate_batch(cells, observations: Sequence, options=None, *,
                    raise_errors: bool = False) -> list[Calibration | JcalibError]:
    """Calibrate each ``(cell, observations)`` pair; the solves of same-structure data sets are batched.

    Args:
        cells: one cell spec for every data set, or a sequence of one per data set (paths, dicts or
            :class:`~jcalib.io.cell.CellSpec`).
        observations: a sequence of observations (paths, dicts or Observations).
        options: :class:`~jcalib.problems.options.CalibrationOptions` (or a dict) for all.
        raise_errors: raise the first data set's error instead of returning it in its place.

    Returns:
        One :class:`Calibration` per data set, or the :class:`jcalib.JcalibError` that data set raised.

    Raises:
        BadInputError: no data sets, or a list of cells whose length is not that of ``observations``.
    """
    observations = list(observations)
    if not observations:
        raise BadInputError("observations: got an empty list, expected one observations document per data set")
    if isinstance(cells, (list, tuple)):
        if len(cells) != len(observations):
            raise BadInputError(f"cells: got {len(cells)} cell specs for {len(observations)} observations, expected "
                                "one cell spec for all or one per data set")
        cells = [load_cell(c) for c in cells]
    else:
        cells = [load_cell(cells)] * len(observations)
    opts, given = options_and_given(options)
    members: list[Member | JcalibError] = []
    for cell, obs in zip(cells, observations):
        try:
            members.append(Member(*prepare(cell, load_observations(obs), opts, given=given)))
        except JcalibError as err:
            if raise_errors:
                raise
            members.append(err)
    live = [m for m in members if isinstance(m, Member)]
    refined = iter(refine_many(live, opts, batched=True))
    out: list[Calibration | JcalibError] = []
    for m in members:
        if not isinstance(m, Member):
            out.append(m)
            continue
        r = next(refined)
        if isinstance(r, JcalibError):
            if raise_errors:
                raise r
            out.append(r)
            continue
        out.append(assemble(m.g, m.start, m.built, r))
    return out
