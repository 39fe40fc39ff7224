"""What a result's uncertainty means, in one import: the linear model read from the solve, task-space
σ, correlations, weak directions, what would help, residual diagnostics, cross-validation and the
ordered warnings. The report shows them; each lives in its own module:

- :mod:`jcalib.report.model`: :class:`LinearModel` (covariance and information of the shared
  unknowns, from :class:`jcalib.solve.Solution`), :func:`calibration_of` (a result's calibration, or
  the one restored from ``result.json`` + observations + cell), correlations;
- :mod:`jcalib.report.candidates`: hypothetical stations built by the one builder and linearised by
  :func:`jcalib.solve.information` (:func:`what_would_help`);
- :mod:`jcalib.report.advice`: tolerances, weakest directions, warnings;
- :mod:`jcalib.report.diagnostics`: the solve's residuals per camera and factor group;
- :mod:`jcalib.problems.taskspace`: projection σ maps, transform σ, projection differences;
- :mod:`jcalib.report.crossval`: calibrations of the two halves of the stations.
"""

from jcalib.report.advice import (
    DEFAULT_TOLERANCES,
    Warning,
    WeakDirection,
    analysis_warnings,
    unknown_tolerances,
    weak_directions,
)
from jcalib.report.candidates import STATION_KINDS, Candidate, Suggestion, candidates, station_information, what_would_help
from jcalib.report.crossval import CrossValidation, cross_validate
from jcalib.report.diagnostics import (
    GroupStatistics,
    RadialTest,
    ResidualDiagnostics,
    group_statistics,
    radial_structure,
    residual_diagnostics,
)
from jcalib.report.model import (
    JOINT_COVARIANCE_KEY,
    LinearModel,
    Unknown,
    calibration_of,
    correlations,
    joint_covariance,
    linear_model,
    model_from_file,
    result_file,
)
from jcalib.problems.taskspace import pixel_effect, projection_difference, projection_sigma_map, transform_sigma

__all__ = [
    "DEFAULT_TOLERANCES",
    "JOINT_COVARIANCE_KEY",
    "STATION_KINDS",
    "Candidate",
    "CrossValidation",
    "GroupStatistics",
    "LinearModel",
    "RadialTest",
    "ResidualDiagnostics",
    "Suggestion",
    "Unknown",
    "Warning",
    "WeakDirection",
    "analysis_warnings",
    "calibration_of",
    "candidates",
    "correlations",
    "cross_validate",
    "group_statistics",
    "joint_covariance",
    "linear_model",
    "model_from_file",
    "pixel_effect",
    "projection_difference",
    "projection_sigma_map",
    "radial_structure",
    "residual_diagnostics",
    "result_file",
    "station_information",
    "transform_sigma",
    "unknown_tolerances",
    "weak_directions",
    "what_would_help",
]
