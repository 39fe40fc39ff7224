"""jcalib's exceptions.

Every error a user can cause is a :class:`JcalibError` whose message says what is wrong, where
(file, station id, camera id) and what to do about it. The CLI turns them into exit statuses:
2 for bad input, 3 when the data cannot determine the unknowns.
"""

from __future__ import annotations


class JcalibError(Exception):
    """Base class of all errors jcalib raises on purpose."""

    exit_code: int = 1


class BadInputError(JcalibError, ValueError):
    """The input is malformed: wrong shape, unknown name, NaN, missing file. CLI exit status 2."""

    exit_code = 2


class NotObservableError(JcalibError):
    """The data cannot determine some unknowns (degenerate motion, too few views). CLI exit status 3.

    Attributes:
        unknowns: names of the undetermined unknowns (or directions), e.g.
            ``["T_flange_cam0.tz (along the common rotation axis)"]``.
    """

    exit_code = 3

    def __init__(self, message: str, unknowns: list[str] | tuple[str, ...] = ()):
        super().__init__(message)
        self.unknowns = list(unknowns)


class DetectionError(JcalibError):
    """A target could not be detected in one image (not found, partially visible, too blurred).

    Batch detection records these per image instead of stopping.
    """

    exit_code = 2

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason

    def __reduce__(self):  # picklable (detection in worker processes)
        return (type(self), (str(self), self.reason))


class DeviceError(JcalibError):
    """A camera or robot could not be reached or refused a command. CLI exit status 4."""

    exit_code = 4


class InputWarning(UserWarning):
    """The input is usable but probably not what was meant (e.g. observed target points that differ
    from the cell's target geometry). The CLI prints it as ``jcalib warning: ...`` on stderr."""
