"""Typed errors of the estimation package.

Every error carries what a person needs to act on it: which file, field or input was wrong, what was
found and what is allowed. Command-line front ends map :class:`InputError` to exit code 2 and any other
:class:`CalibError` to exit code 1.
"""

from __future__ import annotations


class CalibError(Exception):
    """Base class of every error raised by :mod:`calib`."""


class InputError(CalibError, ValueError):
    """The user's input (a file, a CSV column, an argument) is unusable.

    Parameters
    ----------
    message
        One line saying what is wrong and what to do.
    source
        The file, field or argument the problem is in (``"lamp.csv line 12"``, ``"--grid"``).
    """

    def __init__(self, message: str, *, source: str | None = None) -> None:
        self.source = source
        super().__init__(f"{source}: {message}" if source else message)


class SpectrumError(InputError):
    """A spectrum is malformed: non-monotonic wavelengths, NaN, negative values, too narrow a range."""


class EstimationError(CalibError):
    """The estimation could not produce a trustworthy result (e.g. a singular system, no peaks found)."""
