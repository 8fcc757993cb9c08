"""The records of a session's ``log.jsonl``: one pydantic model per record type, validated on read.

The format is documented in ``docs/decisions/0002-session-format.md``. Every record carries ``seq``
(its line number, from 0, continuous across runs) and ``run`` (1 for the first process, one more for
each resume). Paths in file records are untrusted input when read: :func:`check_session_path` accepts
only relative POSIX paths below ``frames/``, ``spectra/`` or ``transcripts/`` made of plain names.
"""

from __future__ import annotations

import re
from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

SCHEMA_NAME: Literal["spectral-rig/session"] = "spectral-rig/session"
#: Version 2 adds the ``discard`` and ``resume`` records (issue 6); version 1 logs still read.
SCHEMA_VERSION: Literal[2] = 2
LOG_NAME = "log.jsonl"
FRAMES_DIR = "frames"
SPECTRA_DIR = "spectra"
TRANSCRIPTS_DIR = "transcripts"
DATA_DIRS = (FRAMES_DIR, SPECTRA_DIR, TRANSCRIPTS_DIR)

# Matched whole (fullmatch): with re.match, "$" also matches before a trailing newline.
_PATH_PART = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]{0,127}")
_KEY = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*(/[A-Za-z0-9][A-Za-z0-9._+-]*)*")
MAX_PATH_CHARS = 512


def check_session_path(path: str) -> str:
    """Return ``path`` if it is a safe session-relative file path, else raise ``ValueError``.

    Safe: at most 512 characters, POSIX separators, no empty, ``.`` or ``..`` component, no
    leading ``/``, every component a plain name (letters, digits, ``._+-``, not starting with a dot),
    and the first component one of ``frames``, ``spectra``, ``transcripts``.
    """
    if not path or len(path) > MAX_PATH_CHARS:
        raise ValueError(f"path must have 1..{MAX_PATH_CHARS} characters, got {len(path)}")
    parts = path.split("/")
    if len(parts) < 2 or parts[0] not in DATA_DIRS:
        raise ValueError(f"path {path!r} must lie inside {', '.join(d + '/' for d in DATA_DIRS)}")
    for part in parts:
        if part in ("", ".", "..") or not _PATH_PART.fullmatch(part):
            raise ValueError(
                f"path {path!r} has an unsafe component {part!r}: only plain names of letters, "
                "digits and '._+-' are allowed"
            )
    return path


def _check_key(key: str) -> str:
    if len(key) > MAX_PATH_CHARS or not _KEY.fullmatch(key) or ".." in key.split("/"):
        raise ValueError(f"step key {key!r} is not a '/'-separated list of plain names")
    return key


SessionPath = Annotated[str, AfterValidator(check_session_path)]
StepKey = Annotated[str, AfterValidator(_check_key)]
Reason = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$", max_length=64)]
ExitStatus = Literal["success", "abort", "fail"]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Record(_Model):
    """Fields every record has."""

    seq: int = Field(ge=0)
    run: int = Field(ge=1)


class SoftwareInfo(_Model):
    """What software wrote the session."""

    name: str
    version: str
    python: str
    platform: str


class DeviceRecord(_Model):
    """A device's identity (from ``drivers.base.DeviceIdentity``) under its role in the rig."""

    kind: Literal["spectrometer", "camera", "relay"]
    model: str
    serial: str | None = None
    firmware: str | None = None
    port: str | None = None
    extra: dict[str, str] = Field(default_factory=dict)

    def describe(self) -> str:
        """Model and serial number: the instrument, wherever it was plugged in."""
        return f"{self.model}{f' (serial {self.serial})' if self.serial else ''}"


class PlanInfo(_Model):
    """The plan that drove the session, by registered name, with its JSON arguments."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_]*$")
    args: dict[str, Any]


class ErrorInfo(_Model):
    """An error as recorded: machine-readable ``reason``, exception type and message."""

    reason: Reason
    type: str
    message: str
    device: str | None = None
    retryable: bool = False
    traceback: str | None = None


class StartRecord(Record):
    """First record of a run: everything needed to know what was done and to do it again."""

    type: Literal["start"] = "start"
    schema_name: Literal["spectral-rig/session"] = SCHEMA_NAME
    schema_version: Literal[1, 2] = SCHEMA_VERSION
    session_id: str = Field(pattern=r"^[0-9a-f]{32}$")
    wall_time: datetime
    software: SoftwareInfo
    plan: PlanInfo
    config: dict[str, Any]
    devices: dict[str, DeviceRecord]
    clock: str = Field(description="the runner's clock class; times below are on it")


class StepRecord(Record):
    """One executed step: ``done`` with its result, or ``failed`` with the error that ended it."""

    type: Literal["step"] = "step"
    key: StepKey
    action: str = Field(pattern=r"^[A-Z][A-Za-z]*$")
    params: dict[str, Any]
    status: Literal["done", "failed"]
    attempts: int = Field(ge=1)
    started_s: float
    duration_s: float = Field(ge=0)
    result: dict[str, Any] | None = None
    error: ErrorInfo | None = None

    @model_validator(mode="after")
    def _status_matches_payload(self) -> StepRecord:
        if self.status == "done" and self.result is None:
            raise ValueError("a done step must have a result")
        if self.status == "failed" and self.error is None:
            raise ValueError("a failed step must have an error")
        return self


class RetryRecord(Record):
    """A failed attempt of a step that will be tried again after ``backoff_s``."""

    type: Literal["retry"] = "retry"
    key: StepKey
    attempt: int = Field(ge=1)
    error: ErrorInfo
    backoff_s: float = Field(ge=0)


class FileRecord(Record):
    """A file the session acknowledges: written completely, synced, renamed into place."""

    type: Literal["file"] = "file"
    key: StepKey
    role: Literal["frame", "dark", "spectrum", "transcript"]
    path: SessionPath
    size: int = Field(ge=0)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    units: str | None = None
    #: A spectrum's instrument bandwidth (FWHM, nm), when the spectrometer reports one.
    bandwidth_nm: float | None = Field(default=None, gt=0)


class DiscardRecord(Record):
    """An acknowledged file that must not be used: a stale reading, or a file that no longer verifies.

    ``stale``: the first reading after a settings change did not match the new setting (a frame whose
    metadata shows the old exposure, or a copy of an earlier frame); the step took the reading again.
    ``unverified``: at resume, the file was missing or its size or sha256 differed from its ``file``
    record; its step is done again.
    """

    type: Literal["discard"] = "discard"
    key: StepKey
    path: SessionPath
    reason: Literal["stale", "unverified"]
    message: str


class ResumeRecord(Record):
    """Second record of a resumed run: what the previous runs left and what this run does about it.

    Parameters
    ----------
    previous_status, previous_reason
        The session's status before this run (``interrupted`` or ``failed``) and the last stop's
        reason, or ``no_stop_record`` after a crash, ``kill -9`` or a power loss.
    previous_run
        The run being continued.
    relays_found_on
        Relay channels (from 1) that read as on when this run opened the board; switched off before
        anything else.
    torn_line
        Where a torn last line of the log was moved (``log.torn-<n>``), if there was one.
    skipped, redo
        How many recorded steps are reused without touching a device, and the keys of recorded
        steps done again (device set-up, and the warm-up and spectra of the lamp that was on).
    resume_key
        The first step that was not done (``None``: every step was, only the stop was missing).
    """

    type: Literal["resume"] = "resume"
    previous_status: Literal["interrupted", "failed"]
    previous_reason: Reason
    previous_run: int = Field(ge=1)
    relays_found_on: list[int] = Field(default_factory=list)
    torn_line: str | None = None
    skipped: int = Field(ge=0)
    redo: list[StepKey] = Field(default_factory=list)
    resume_key: StepKey | None = None


class InterruptionRecord(Record):
    """A signal the run received, and what it did about it."""

    type: Literal["interruption"] = "interruption"
    signal: str = Field(pattern=r"^SIG[A-Z0-9]+$")
    t_s: float
    action: Literal["finish-step", "stop-now"]


class StopRecord(Record):
    """Last record of a run: how it ended and whether every lamp was confirmed off."""

    type: Literal["stop"] = "stop"
    exit_status: ExitStatus
    reason: Reason
    message: str
    wall_time: datetime
    t_s: float
    failed_key: StepKey | None = None
    error: ErrorInfo | None = None
    lamps_off: bool
    counts: dict[str, int] = Field(default_factory=dict)


AnyRecord = Annotated[
    StartRecord
    | StepRecord
    | RetryRecord
    | FileRecord
    | DiscardRecord
    | ResumeRecord
    | InterruptionRecord
    | StopRecord,
    Field(discriminator="type"),
]
