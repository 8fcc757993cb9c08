"""Spectrometer-specific refinements of the device errors."""

from __future__ import annotations

from drivers.base import InstrumentError


class MeasurementConditionError(InstrumentError):
    """The instrument could not measure this light right now (unstable source, lost sync, adaptive
    exposure timed out); measuring again, e.g. once a lamp has settled, may succeed."""

    reason = "measurement_condition"
    retryable = True
