"""``jcalib.calibrate(cell, observations) -> Result``: the one entry point from data to a result file."""

from __future__ import annotations

import os
import warnings

from jcalib.errors import InputWarning
from jcalib.io.cell import load_cell
from jcalib.io.exclusions import FILENAME as EXCLUSIONS_FILE
from jcalib.io.exclusions import apply_exclusions, load_exclusions, session_of_observations
from jcalib.io.observations import load_observations
from jcalib.io.schema import check_cell_observations
from jcalib.problems.calibrate import Result, calibrate_cell, input_hash, options_and_given, result_file
from jcalib.problems.reoptimise import reoptimise


def calibrate(cell, observations, options=None, *, prior=None) -> Result:
    """Calibrate a cell from observations: the one entry point.

    Args:
        cell: a ``jcalib.cell/1`` spec: path, dict or :class:`~jcalib.io.cell.CellSpec`.
        observations: a ``jcalib.observations/1`` document: path, dict or
            :class:`~jcalib.io.observations.Observations`. A path inside a capture session folder
            (``SESSION/observations.json``, what ``jcalib detect --session`` writes) honours the
            session's ``exclusions.json`` (:mod:`jcalib.io.exclusions`): the views and stations it
            names are left out (an :class:`~jcalib.errors.InputWarning` says which, and the result's
            ``stats["excluded"]`` lists them).
        options: :class:`CalibrationOptions` (or a dict of its fields) for every kind of cell. An
            option set to something other than its default that the cell cannot use is refused.
        prior: a previous result (path, :class:`~jcalib.io.result.ResultFile` or :class:`Result`) of
            the same robot cell: re-optimisation (:func:`jcalib.problems.reoptimise.reoptimise`). The new
            data are solved on their own, every unknown is compared with the old value by a χ² test on
            the difference (both covariances), and the final solve keeps the old values as priors for
            the unknowns that did not move. ``stats["reoptimisation"]`` lists each test and what moved.

    Returns:
        :class:`Result`. Uncertainties are sampling noise, not model error.

    Raises:
        BadInputError: malformed input, naming the file, station and camera; observations naming a
            camera, target, tool or point the cell does not define.
        NotObservableError: the data cannot determine some unknowns, naming them.
    """
    cell_spec = load_cell(cell)
    obs = load_observations(observations)
    left_out: list[str] = []
    session = session_of_observations(observations) if isinstance(observations, (str, os.PathLike)) else None
    if session is not None:
        obs, left_out = apply_exclusions(obs, load_exclusions(session))
        if left_out:
            warnings.warn(f"left out {len(left_out)} view(s) or station(s) named by {session / EXCLUSIONS_FILE}: "
                          f"{', '.join(left_out[:12])}{' ...' if len(left_out) > 12 else ''}", InputWarning,
                          stacklevel=2)
    check_cell_observations(cell_spec, obs)
    opts, given = options_and_given(options)
    hash_ = input_hash(cell, observations, cell_spec, obs)
    if prior is not None:
        result = reoptimise(cell_spec, obs, prior, opts, input_hash=hash_, given=given).result
    else:
        cal = calibrate_cell(cell_spec, obs, opts, given=given)
        result = Result(result_file(cal, opts, hash_), cal)
    if left_out:
        result.file.stats["excluded"] = left_out
    return result
