"""One input layer: every file jcalib reads is read within limits and checked against a schema.

:func:`read_document` reads a JSON / YAML file within a size budget, as UTF-8, with limits on
nesting, YAML aliases and duplicate keys; the ``validate_*_document`` functions check a loaded
document (types, shapes, ranges, known keys with "did you mean", names, units); the loaders of
:mod:`jcalib.io` call both before they build their data classes. :func:`check_cell_observations`
checks a cell spec and observations against each other. Errors are :class:`SchemaError`
(a :class:`~jcalib.errors.BadInputError`, exit status 2) naming the file, the key path and what to do.
"""

from jcalib.io.schema.base import SchemaError, check_name, did_you_mean
from jcalib.io.schema.cell import validate_cell_document
from jcalib.io.schema.consistency import check_cell_observations
from jcalib.io.schema.observations import validate_observations_document
from jcalib.io.schema.pixels import validate_pixels_document, validate_points_document
from jcalib.io.schema.plan import validate_plan_document
from jcalib.io.schema.reading import max_file_bytes, read_document
from jcalib.io.schema.result import validate_result_document
from jcalib.io.schema.session import validate_session_meta, validate_station_record

__all__ = [
    "SchemaError",
    "check_cell_observations",
    "check_name",
    "did_you_mean",
    "max_file_bytes",
    "read_document",
    "validate_cell_document",
    "validate_observations_document",
    "validate_pixels_document",
    "validate_plan_document",
    "validate_points_document",
    "validate_result_document",
    "validate_session_meta",
    "validate_station_record",
]
