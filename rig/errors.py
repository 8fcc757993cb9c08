"""Typed errors of the orchestration layer, each with a machine-readable ``reason`` for the session log.

Device errors come from :mod:`drivers.base` (``DeviceError`` and its subclasses) and keep their own
``reason``. The errors here are the rig's: a plan that cannot go on (a lamp that never settles, a
bracket that cannot satisfy the policy, limits the hardware cannot meet), a session that cannot be
written, a step that overran its deadline. ``exit_code`` is what the ``rig`` command returns: 2 when
the user's input (configuration, limits) must change, 1 for a failure of the rig.
"""

from __future__ import annotations

import signal
from collections.abc import Mapping
from typing import Any, ClassVar

from drivers.base import DeviceError


class RigError(Exception):
    """Base of the rig's own errors."""

    reason: ClassVar[str] = "rig_error"
    exit_code: ClassVar[int] = 1


class PlanFailure(RigError):
    """A plan decided, from the readings it received, that the measurement cannot succeed."""

    reason = "plan_failure"

    def __init__(self, message: str, *, key: str | None = None) -> None:
        self.key = key
        super().__init__(message)


class LampNotStable(PlanFailure):
    """A lamp's spectrum kept changing beyond the tolerance until the warm-up timeout."""

    reason = "lamp_not_stable"


class LampDark(PlanFailure):
    """A lamp that was switched on gives no light (an all-zero spectrum)."""

    reason = "lamp_dark"


class BeamNotFound(PlanFailure):
    """The spectrometer, aimed at a beam of the grating, measured no light there."""

    reason = "beam_not_found"


class BracketImpossible(PlanFailure):
    """Automatic bracketing cannot meet the HDR policy within the exposure range or frame budget."""

    reason = "bracket_impossible"


class WrongFrameFormat(PlanFailure):
    """The camera delivered a frame in a format the measurement cannot use (JPEG instead of RAW)."""

    reason = "wrong_frame_format"


class LimitsExceeded(PlanFailure):
    """The plan asks for something the hardware cannot do (exposure range, relay channels)."""

    reason = "limits"
    exit_code = 2


class PlanProtocolError(RigError):
    """A plan broke the step protocol (a repeated key, an unexpected result type): a bug in the plan."""

    reason = "plan_protocol"


class FrameAnalysisError(RigError):
    """A frame could not be analysed (no direct spot or first-order band found, unreadable RAW)."""

    reason = "frame_analysis"

    def __init__(self, frame: str, message: str) -> None:
        self.frame = frame
        super().__init__(f"{frame}: {message}")


class SessionWriteError(RigError):
    """The session could not be written (disk full, I/O error): the run stops rather than go on unrecorded."""

    reason = "session_write"


class SessionFormatError(RigError):
    """A session directory or its log is not valid (bad record, unsafe path, missing file)."""

    reason = "session_format"
    exit_code = 2


class StationOpenFailed(RigError):
    """Devices could not be opened. Every device was tried, and every failure is named; a capture
    creates no session and a resume writes nothing.

    Attributes
    ----------
    failures
        The error of each device that failed, by role (``relays``, ``spectrometer``, ``camera``).
    lamps_off
        Whether the relay board was opened and read back all off (``False``: it could not be
        opened or confirmed, so a lamp a killed run left on may still be on).
    """

    reason = "devices_unavailable"

    def __init__(self, failures: Mapping[str, BaseException], *, lamps_off: bool) -> None:
        self.failures = dict(failures)
        self.lamps_off = lamps_off
        listed = "; ".join(str(error) for error in self.failures.values())
        count = len(self.failures)
        super().__init__(
            f"{count} device{'s' if count != 1 else ''} could not be opened, nothing was recorded: "
            f"{listed}"
        )


class OpeningInterrupted(RigError):
    """A signal (Ctrl-C, SIGTERM) arrived while the devices were being opened: the run stopped
    before anything was recorded, with the lamps switched off as far as the relay board opened."""

    reason = "interrupted"

    def __init__(self, signal_name: str, *, lamps_off: bool) -> None:
        self.signal_name = signal_name
        self.lamps_off = lamps_off
        lamps = "every lamp switched off" if lamps_off else "the lamps could not be confirmed off"
        super().__init__(
            f"{signal_name} while the devices were being opened: stopped before anything was "
            f"recorded ({lamps})"
        )

    @property
    def signal_exit_code(self) -> int:
        """128 + the signal's number, as a shell reports a process stopped by it (130 for SIGINT)."""
        return 128 + int(signal.Signals[self.signal_name])


class StationUnavailable(RigError):
    """No driver is available for a configured device kind in this installation."""

    reason = "station_unavailable"


class StepTimeout(DeviceError):
    """A device call overran the step's deadline; the device is left in an unknown state.

    Not retryable: the call may still be running in its worker thread, so the same device cannot be
    used again until it returns.
    """

    reason = "step_timeout"
    retryable = False

    def __init__(self, device: str, message: str, *, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        super().__init__(device, message)


class LampsNotOff(DeviceError):
    """A relay channel reads as on where every lamp must be off (before a dark frame)."""

    reason = "lamps_not_off"


class InvalidReading(DeviceError):
    """A device returned a reading that is not a valid measurement (e.g. a malformed spectrum)."""

    reason = "invalid_reading"


class StaleReading(DeviceError):
    """The first readings after a settings change kept showing the old setting (or an old frame)."""

    reason = "stale_reading"


class ResumeConfigRefused(RigError):
    """``rig resume --config`` was given a configuration that changes what the session measures."""

    reason = "resume_config"
    exit_code = 2


class NotResumable(RigError):
    """``rig resume`` was given a session it cannot continue (complete, or without a start record)."""

    reason = "not_resumable"
    exit_code = 2


class ResumeMismatch(RigError):
    """A resumed run found the devices answering differently from the recorded run."""

    reason = "resume_mismatch"


def _plain(part: object) -> bool:
    text = str(part)
    return bool(text) and text.isprintable() and text.strip() == text


def first_validation_problem(errors: list[Any], default_where: str) -> str:
    """``where: what`` of the first of pydantic's ``ValidationError.errors()``, on one line.

    Keys come from files anyone may have written: a part of the location that is not a plain
    printable word is shown as its ``repr`` (a key ``"\\n"`` must not break the line), and the
    message's white space is folded.
    """
    first = errors[0]
    parts = [str(part) if _plain(part) else repr(part) for part in first["loc"]]
    return f"{'.'.join(parts) or default_where}: {' '.join(str(first['msg']).split())}"
