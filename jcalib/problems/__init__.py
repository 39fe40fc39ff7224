"""The one problem builder and its presets: every calibration of a cell is one joint problem.

Public API::

    calibrate(cell, observations, options=None, *, prior=None) -> Result    # every cell
    calibrate_cell(cell_spec, obs, options) -> Calibration                  # the pipeline
    CalibrationOptions(...)                                                 # one options type
"""

from jcalib.problems.api import calibrate
from jcalib.problems.assemble import Calibration
from jcalib.problems.calibrate import Result, calibrate_cell, result_file
from jcalib.problems.options import CalibrationOptions

__all__ = ["Calibration", "CalibrationOptions", "Result", "calibrate", "calibrate_cell", "result_file"]
