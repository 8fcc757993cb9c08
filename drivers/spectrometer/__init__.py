"""Spectrometers: the serial spectroradiometers (Photo Research PR-655/PR-670, Konica Minolta
CS-2000/CS-2000A: :func:`open_spectrometer` with the model and port from the config), Ocean Optics
USB spectrometers through python-seabreeze (:mod:`.ocean`), X-Rite instruments through ArgyllCMS's
``spotread`` (:mod:`.argyll`) and measured spectrum files (:mod:`.files`).
"""

from __future__ import annotations

from drivers.base import Spectrometer, TranscriptSink
from drivers.spectrometer import cs2000, pr6xx
from drivers.spectrometer.cs2000 import Cs2000, open_cs2000
from drivers.spectrometer.errors import MeasurementConditionError
from drivers.spectrometer.pr6xx import Pr6xx, open_pr6xx

__all__ = [
    "MODELS",
    "Cs2000",
    "MeasurementConditionError",
    "Pr6xx",
    "longest_measure_s",
    "open_spectrometer",
]

#: Model names accepted by :func:`open_spectrometer` (case and separators are ignored).
MODELS = ("PR-655", "PR-670", "CS-2000", "CS-2000A")

#: The spectrometers that are not serial instruments, and the longest a measurement of each may
#: take by default (s): an Ocean spectrometer ranges and averages up to its longest integration
#: time (its own USB deadlines end a silent scan sooner); one spotread run; a file read.
OTHER_KINDS = {"seabreeze": 300.0, "argyll": 120.0, "files": 5.0}


def canonical_model(model: str) -> str:
    """``"pr655"``, ``"PR 655"``, ``"cs-2000a"`` … → the canonical name in :data:`MODELS`.

    Raises
    ------
    ValueError
        Not a supported model.
    """
    key = "".join(character for character in model.upper() if character.isalnum())
    for name in MODELS:
        if key == name.replace("-", ""):
            return name
    raise ValueError(f"unknown spectrometer model {model!r}; supported: {', '.join(MODELS)}")


def longest_measure_s(
    model: str, *, timeout_s: float | None = None, measure_timeout_s: float | None = None
) -> float:
    """The longest a ``measure()`` call may take before the driver's own deadlines give up.

    What a caller's watchdog around the call must allow, so that a silent instrument ends in the
    driver's (retryable) :class:`drivers.base.DeviceTimeout` rather than in the watchdog. Parameters
    as for :func:`open_spectrometer` (``None``: the model's defaults); each driver adds up its own
    deadlines (:func:`pr6xx.longest_measure_s`, :func:`cs2000.longest_measure_s`).
    """
    if model in OTHER_KINDS:
        if measure_timeout_s is not None:
            return measure_timeout_s
        return OTHER_KINDS[model] if timeout_s is None else max(OTHER_KINDS[model], timeout_s)
    name = canonical_model(model)
    if name.startswith("PR-"):
        return pr6xx.longest_measure_s(timeout_s, measure_timeout_s)
    return cs2000.longest_measure_s(timeout_s, measure_timeout_s)


def open_spectrometer(
    model: str,
    port: str,
    *,
    timeout_s: float | None = None,
    measure_timeout_s: float | None = None,
    transcript: TranscriptSink | None = None,
    baud: int | None = None,
) -> Spectrometer:
    """Open the spectrometer ``model`` on ``port`` (device path or pyserial URL), ready to measure.

    Parameters
    ----------
    model
        One of :data:`MODELS`.
    port
        ``/dev/ttyACM0``, ``COM3``, ``/dev/serial/by-id/…`` or a pyserial URL.
    timeout_s
        Deadline of each ordinary command; ``None`` takes the model's default (PR-6xx 10 s,
        CS-2000 15 s, as their documentation recommends).
    measure_timeout_s
        The measurement allowance: for a PR-6xx the deadline of the whole measurement (default
        60 s); for a CS-2000 the margin beyond the time the instrument announces (default 10 s).
    transcript
        Where every exchange is recorded.
    baud
        Line speed; ``None`` takes the instrument's own (PR-6xx 9600, CS-2000 115200).

    Raises
    ------
    ValueError
        Unknown model.
    DeviceNotFound
        No such port, or another model answers on it.
    DeviceTimeout
        The instrument does not answer.
    """
    name = canonical_model(model)
    if name.startswith("PR-"):
        return open_pr6xx(
            name,
            port,
            timeout_s=timeout_s,
            measure_timeout_s=measure_timeout_s,
            transcript=transcript,
            baud=baud,
        )
    return open_cs2000(
        port,
        model=name,
        timeout_s=timeout_s,
        completion_margin_s=measure_timeout_s,
        transcript=transcript,
        baud=baud,
    )
