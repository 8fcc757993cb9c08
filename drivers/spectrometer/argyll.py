"""X-Rite (i1Pro, i1Studio, ColorMunki …) and other instruments through ArgyllCMS's ``spotread``.

ArgyllCMS drives dozens of instruments nobody else has open drivers for; the rig does not talk to
the instrument itself but runs ArgyllCMS's spot reader once per measurement::

    spotread -a -s -N [-c N] [-H] -O reading.sp

``-a`` ambient (irradiance through the diffuser), ``-s`` print the spectrum, ``-N`` no initial
calibration (the instrument must hold a valid one: the user calibrates once with ``spotread -a -O``),
``-c`` which instrument of ``spotread -?``'s list, ``-H`` high resolution (3.3 nm bands, i1Pro),
``-O reading.sp`` measure once, save the spectrum as CGATS and exit (:mod:`.cgats` reads it).

spotread is an interactive program: it reads single keys from its terminal and, when something goes
wrong, prints a prompt and waits for one ("Hit Esc or Q to give up, any other key to retry:"). The
driver therefore runs it on a pseudo-terminal (:class:`PtyLauncher`), reads what it prints under one
deadline, answers those prompts with ``q`` / Esc, and maps what spotread said to the rig's typed
errors (the strings come from spotread's source, ``spectro/spotread.c`` and
``spectro/instappsup.c``):

========================================================  ============================================
spotread says                                             error
========================================================  ============================================
``No instrument at port N``, ``no instrument detected``   :class:`DeviceNotFound`
``Failed to initialise communications``                   :class:`Disconnected`
``Spot read needs a calibration before continuing``       :class:`InstrumentError` ``calibration_needed``
``… sensor being in the wrong position``                  :class:`InstrumentError` ``sensor_position``
``Spot read failed due to misread (…)``                   :class:`MeasurementConditionError` (retryable)
``Spot read failed due to communication problem``         :class:`ProtocolError` (retryable)
``Got fatal error '…'``, ``… initialisation failed``      :class:`InstrumentError`
``Instrument didn't return spectral data``                :class:`InstrumentError` ``not_spectral``
no output before the deadline                             :class:`DeviceTimeout` (process killed)
========================================================  ============================================

A missing ``spotread`` is :class:`DeviceNotFound` saying how to install ArgyllCMS.

The transcript of a measurement: a ``call`` (the argument list, JSON), every chunk read from the
terminal as ``rx`` (an empty ``rx`` is the end of output), every key sent as ``tx``, and a ``return``
(JSON: exit status and the ``.sp`` file's text). Replay serves it back through a launcher of its own.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import select
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from drivers.base import (
    DeviceError,
    DeviceIdentity,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    InstrumentError,
    ProtocolError,
    SpectrumReading,
    TranscriptDirection,
    TranscriptEntry,
    TranscriptSink,
)
from drivers.lifecycle import ClosesOnExit
from drivers.spectrometer.cgats import CgatsError, parse_sp, units_of
from drivers.spectrometer.errors import MeasurementConditionError

__all__ = [
    "INSTALL_HINT",
    "OUTPUT_NAME",
    "ArgyllSettings",
    "ArgyllSpotread",
    "PtyLauncher",
    "SpotreadLauncher",
    "SpotreadProcess",
    "open_argyll",
    "spotread_argv",
    "spotread_error",
]

INSTALL_HINT = (
    "install ArgyllCMS: `apt-get install argyll` (Debian, Ubuntu), `dnf install argyllcms` "
    "(Fedora), `brew install argyll-cms` (macOS), or the binaries from https://www.argyllcms.com/; "
    "or set devices.spectrometer.executable to spotread's full path"
)
#: The file spotread writes, relative to the run's own scratch directory.
OUTPUT_NAME = "reading.sp"
#: Optical resolution (FWHM) of an i1Pro, from ArgyllCMS's "i1pro High Resolution mode" note: a
#: laser line reads about 25 nm wide in the standard 10 nm mode and about 15 nm at 3.3 nm.
I1PRO_BANDWIDTH_NM = {False: 25.0, True: 15.0}
#: Between the high-resolution bands' 3.3 nm step and the standard 10 nm one.
HIGH_RESOLUTION_STEP_LIMIT_NM = 5.0
#: The key answering spotread's prompts: give up after an error, abort a calibration.
GIVE_UP = b"q"
#: The ends of the prompts that wait for a key: an error's retry question, a calibration's request.
_PROMPT = re.compile(r"any other key to retry:|Esc or Q to abort:")
_READ_CHUNK = 4096


# --------------------------------------------------------------------------------- processes


class SpotreadProcess(Protocol):
    """A running spotread, seen through its terminal."""

    def read(self, timeout_s: float) -> bytes | None:
        """What spotread printed next: at least one byte; ``b""`` once it closed its terminal;
        ``None`` when it printed nothing for ``timeout_s``."""

    def write(self, data: bytes) -> None:
        """Type ``data`` on its terminal."""

    def wait(self, timeout_s: float) -> int | None:
        """Its exit status, or ``None`` if it is still running after ``timeout_s``."""

    def kill(self) -> None:
        """End it now (and anything it started)."""

    def output(self, cwd: Path) -> str | None:
        """The text of the spectrum file it wrote into ``cwd`` (``None``: none)."""


class SpotreadLauncher(Protocol):
    """Starts spotread: on a pseudo-terminal (:class:`PtyLauncher`), or a stand-in (replay)."""

    def launch(self, argv: Sequence[str], cwd: Path) -> SpotreadProcess: ...


class _PtyProcess:
    """A child process on the slave side of a pseudo-terminal; we hold the master."""

    def __init__(self, process: subprocess.Popen[bytes], master: int) -> None:
        self._process = process
        self._master = master
        self._open = True

    def read(self, timeout_s: float) -> bytes | None:
        if not self._open:
            return b""
        ready, _, _ = select.select([self._master], [], [], max(0.0, timeout_s))
        if not ready:
            return None
        try:
            data = os.read(self._master, _READ_CHUNK)
        except OSError as exc:
            if exc.errno == errno.EIO:  # Linux: every slave end closed
                return b""
            raise
        return data

    def write(self, data: bytes) -> None:
        with contextlib.suppress(OSError):
            os.write(self._master, data)

    def wait(self, timeout_s: float) -> int | None:
        try:
            return self._process.wait(timeout=max(0.0, timeout_s))
        except subprocess.TimeoutExpired:
            return None

    def kill(self) -> None:
        if self._process.poll() is None:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self._process.pid, signal.SIGKILL)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._process.wait(timeout=5.0)
        if self._open:
            self._open = False
            with contextlib.suppress(OSError):
                os.close(self._master)

    def output(self, cwd: Path) -> str | None:
        path = cwd / OUTPUT_NAME
        try:
            return path.read_text(encoding="utf-8", errors="replace")
        except FileNotFoundError:
            return None


@dataclass(frozen=True)
class PtyLauncher:
    """Runs spotread on a fresh pseudo-terminal in its own session (so a kill ends all of it).

    ``environment`` is added to the process's environment (the twin points its fake spotread at
    the light it should measure this way).
    """

    environment: Mapping[str, str] | None = None

    def launch(self, argv: Sequence[str], cwd: Path) -> SpotreadProcess:
        master, slave = os.openpty()
        environment = {**os.environ, **(self.environment or {})}
        try:
            process = subprocess.Popen(
                list(argv),
                stdin=slave,
                stdout=slave,
                stderr=slave,
                cwd=cwd,
                env=environment,
                start_new_session=True,
                close_fds=True,
            )
        except BaseException:
            os.close(master)
            raise
        finally:
            os.close(slave)
        return _PtyProcess(process, master)


# --------------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class ArgyllSettings:
    """How spotread is run.

    Parameters
    ----------
    executable
        ``spotread`` (looked up on ``PATH``) or its full path.
    instrument
        spotread's ``-c``: the instrument's number in ``spotread -?``'s list.
    high_resolution
        ``-H``: 3.3 nm bands where the instrument has them (i1Pro, ColorMunki); spotread falls
        back to its 10 nm bands where it does not, and the reading's sampling says which it got.
        On by default: a grating rig needs the spectrum's detail (15 nm FWHM instead of 25 nm;
        on the twin the sensitivity's RE against the truth 1.33 instead of 2.39 ×10⁻²,
        decision 0046).
    timeout_s
        Deadline of one spotread run, start to exit.
    bandwidth_nm
        The instrument's optical resolution (FWHM); ``None``: an i1Pro's.
    """

    executable: str = "spotread"
    instrument: int = 1
    high_resolution: bool = True
    timeout_s: float = 60.0
    bandwidth_nm: float | None = None

    def bandwidth_of(self, high_resolution_delivered: bool) -> float:
        """The bandwidth of a reading: the stated one, else an i1Pro's in the mode the reading
        came in (``-H`` honoured, or spotread fell back to its standard bands)."""
        if self.bandwidth_nm is not None:
            return self.bandwidth_nm
        return I1PRO_BANDWIDTH_NM[high_resolution_delivered]


def delivered_high_resolution(wavelength_nm: NDArray[np.float64]) -> bool:
    """Whether spotread's spectrum is in its high-resolution bands (steps under 5 nm)."""
    steps = np.diff(np.asarray(wavelength_nm, dtype=float))
    return bool(steps.size) and float(np.median(steps)) < HIGH_RESOLUTION_STEP_LIMIT_NM


def spotread_argv(settings: ArgyllSettings, executable: str) -> list[str]:
    """The command line of one measurement.

    >>> spotread_argv(ArgyllSettings(instrument=2, high_resolution=True), "spotread")
    ['spotread', '-a', '-s', '-N', '-c', '2', '-H', '-O', 'reading.sp']
    """
    argv = [executable, "-a", "-s", "-N"]
    if settings.instrument != 1:
        argv += ["-c", str(settings.instrument)]
    if settings.high_resolution:
        argv.append("-H")
    return [*argv, "-O", OUTPUT_NAME]


# --------------------------------------------------------------------------------- errors

_CALIBRATE = (
    "calibrate it once, with the ambient diffuser in place as spotread asks: run `spotread -a -O` "
    "in a terminal, then continue the session with `rig resume`"
)
#: What spotread prints, in the order it is looked for: (pattern, error class, code, message; the
#: message's ``{0}``, ``{1}`` are the pattern's groups).
SPOTREAD_REPORTS: tuple[tuple[str, type[DeviceError], str, str], ...] = (
    (
        r"No instrument at port (\d+)", DeviceNotFound, "",
        "spotread finds no instrument at port {0} (devices.spectrometer.instrument); `spotread -?` "
        "lists what it finds. Check the cable, and that no other program (DisplayCAL, a colorimeter "
        "daemon) holds it",
    ),
    (
        r"no instrument detected", DeviceNotFound, "",
        "spotread detects no instrument it supports; plug it in, check `spotread -?` and, on "
        "Linux, ArgyllCMS's udev rule (usb/55-Argyll.rules)",
    ),
    (
        r"Failed to initialise communications with instrument[^(]*\('([^']*)' \+ '([^']*)'\)",
        Disconnected, "",
        "spotread cannot talk to the instrument ({0}: {1}); replug it and make sure no other "
        "program uses it",
    ),
    (
        r"Instrument initialisation failed with '([^']*)' \(([^)]*)\)", InstrumentError,
        "init_failed", "the instrument failed to initialise ({1}); replug it",
    ),
    (
        r"needs a calibration|instruments needs calibration", InstrumentError,
        "calibration_needed", f"the instrument needs a calibration: {_CALIBRATE}",
    ),
    (
        r"wrong position", InstrumentError, "sensor_position",
        "the instrument's sensor is in the wrong position: set it to ambient measurement (the "
        "diffuser over the aperture; ColorMunki: turn the dial to the ambient position)",
    ),
    (
        r"ambient light capability", InstrumentError, "no_ambient_mode",
        "this instrument does not measure ambient light; fit its ambient head, or use a spectral "
        "instrument with a diffuser (i1Pro, i1Studio, ColorMunki)",
    ),
    (
        r"didn't return spectral data", InstrumentError, "not_spectral",
        "the instrument returns no spectrum (a colorimeter); the rig needs a spectral instrument",
    ),
    (
        r"Spot read failed due to misread \(([^)]*)\)", MeasurementConditionError, "misread",
        "the instrument misread the light ({0})",
    ),
    (
        r"communication problem", ProtocolError, "",
        "spotread lost the instrument's communication",
    ),
    (
        r"Got fatal error '([^']*)' \(([^)]*)\)", InstrumentError, "fatal", "spotread: {0} ({1})",
    ),
    (
        r"abort or error from calibrat", InstrumentError, "calibration_failed",
        f"the instrument's calibration failed: {_CALIBRATE}",
    ),
)  # fmt: skip


def spotread_error(label: str, output: str, command: str) -> DeviceError | None:
    """The typed error for what spotread printed (``None`` when it reports none).

    >>> spotread_error("i1", "spotread: Error - No instrument at port 1", "spotread").reason
    'not_found'
    """
    for pattern, error, code, message in SPOTREAD_REPORTS:
        found = re.search(pattern, output)
        if found is None:
            continue
        text = message.format(*found.groups())
        if issubclass(error, InstrumentError):
            return error(label, text, code=code, command=command)
        if error is ProtocolError:
            return ProtocolError(label, text, command=command, reply=None)
        return error(label, text)
    return None


# --------------------------------------------------------------------------------- the driver


class ArgyllSpotread(ClosesOnExit):
    """An instrument read through spotread; implements :class:`drivers.base.Spectrometer`.

    Build it with :func:`open_argyll`. Every :meth:`measure` is one spotread run in a scratch
    directory that is removed afterwards.
    """

    def __init__(
        self,
        settings: ArgyllSettings,
        executable: str,
        launcher: SpotreadLauncher,
        transcript: TranscriptSink | None = None,
        *,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.settings = settings
        self.executable = executable
        self.launcher = launcher
        self.transcript = transcript
        self.label = f"spotread instrument {settings.instrument}"
        self._monotonic = monotonic
        self._closed = False

    # ------------------------------------------------------------------------------ records

    def _record(self, direction: TranscriptDirection, payload: bytes) -> None:
        if self.transcript is not None:
            self.transcript.record(
                TranscriptEntry(self.label, direction, payload, self._monotonic())
            )

    def _record_json(self, direction: TranscriptDirection, value: object) -> None:
        self._record(direction, json.dumps(value, sort_keys=True).encode("utf-8"))

    # ------------------------------------------------------------------------------ protocol

    def identify(self) -> DeviceIdentity:
        settings = self.settings
        extra = {
            "driver": "argyll",
            "executable": self.executable,
            "instrument": str(settings.instrument),
            "high_resolution": "on" if settings.high_resolution else "off",
            "timeout_s": f"{settings.timeout_s:g}",
        }
        if settings.bandwidth_nm is not None:
            # Only a stated one: an i1Pro's follows the bands each reading came in.
            extra["bandwidth_nm"] = f"{settings.bandwidth_nm:g}"
        return DeviceIdentity(
            kind="spectrometer",
            model="ArgyllCMS spotread",
            port=f"spotread -c {settings.instrument}",
            extra=extra,
        )

    def set_exposure(self, exposure_ms: float | None) -> None:
        """spotread always chooses its own (adaptive) integration time; a fixed one is refused."""
        if exposure_ms is not None:
            raise ValueError(
                f"{self.label}: spotread chooses its integration time itself; set "
                "spectrum.exposure_ms to null"
            )

    def measure(self) -> SpectrumReading:
        """One spotread run: the ambient spectrum it saved.

        Raises
        ------
        DeviceTimeout
            spotread did not finish within ``timeout_s`` (it is killed).
        DeviceNotFound, Disconnected, InstrumentError, MeasurementConditionError, ProtocolError
            What spotread reported (see the module docstring).
        """
        if self._closed:
            raise Disconnected(self.label, "the driver was closed")
        argv = spotread_argv(self.settings, self.executable)
        command = " ".join(argv)
        with tempfile.TemporaryDirectory(prefix="spotread-") as scratch:
            self._record_json("call", {"argv": argv})
            try:
                process = self.launcher.launch(argv, Path(scratch))
            except FileNotFoundError:
                raise DeviceNotFound(
                    self.label, f"{self.executable!r} cannot be run: {INSTALL_HINT}"
                ) from None
            except OSError as exc:
                raise DeviceNotFound(
                    self.label, f"cannot start {self.executable!r}: {exc.strerror or exc}"
                ) from None
            try:
                output, status, text = self._converse(process, command, Path(scratch))
            finally:
                process.kill()
        error = spotread_error(self.label, output, command)
        if error is not None:
            raise error
        if status != 0 or text is None:
            last = output.strip().splitlines()[-3:]
            raise InstrumentError(
                self.label,
                f"spotread ended with status {status} and no spectrum; it said: "
                f"{' / '.join(last) or '(nothing)'}",
                code=f"exit {status}",
                command=command,
            )
        try:
            spectrum = parse_sp(text, source=f"{self.label} {OUTPUT_NAME}")
        except CgatsError as exc:
            raise ProtocolError(
                self.label, str(exc), command=command, reply=text[:200].encode()
            ) from None
        high_resolution = delivered_high_resolution(spectrum.wavelength_nm)
        return SpectrumReading(
            wavelength_nm=spectrum.wavelength_nm,
            values=spectrum.values[-1],
            units=units_of(spectrum.measurement_type),
            exposure_ms=None,
            bandwidth_nm=self.settings.bandwidth_of(high_resolution),
            extra={
                "measurement_type": spectrum.measurement_type or "unknown",
                "high_resolution": "on" if high_resolution else "off",
            },
        )

    def _converse(
        self, process: SpotreadProcess, command: str, scratch: Path
    ) -> tuple[str, int | None, str | None]:
        """Read spotread's terminal to its end, answering its prompts; then its status and file."""
        timeout_s = self.settings.timeout_s
        deadline = self._monotonic() + timeout_s
        output = ""
        answered = 0
        while True:
            chunk = process.read(max(0.0, deadline - self._monotonic()))
            if chunk is None:
                self._record("event", f"no output for {timeout_s:g} s: killed".encode())
                process.kill()
                self._record_json("return", {"status": process.wait(5.0), "file": None})
                raise DeviceTimeout(
                    self.label,
                    f"spotread did not finish within {timeout_s:g} s "
                    "(devices.spectrometer.timeout_s)",
                    command=command,
                    timeout_s=timeout_s,
                )
            self._record("rx", chunk)
            if not chunk:
                break
            output += chunk.decode("utf-8", errors="replace")
            prompts = len(_PROMPT.findall(output))
            if prompts > answered:
                # Errors and calibrations need the person at the instrument, not a retry loop.
                answered = prompts
                self._record("tx", GIVE_UP)
                process.write(GIVE_UP)
            if "wrong position" in output:
                # Under -O spotread retries a wrong sensor position forever.
                self._record("event", b"sensor in the wrong position: killed")
                process.kill()
                break
        status = process.wait(max(0.0, deadline - self._monotonic()))
        text = process.output(scratch)
        self._record_json("return", {"status": status, "file": text})
        return output, status, text

    def close(self) -> None:
        """Nothing stays open between measurements."""
        self._closed = True


def resolve_executable(executable: str) -> str:
    """``executable`` as a path spotread can be run from.

    Raises
    ------
    DeviceNotFound
        Not on ``PATH`` / not an executable file (the message says how to install ArgyllCMS).
    """
    found = shutil.which(executable)
    if found is None:
        raise DeviceNotFound(
            f"spotread ({executable})", f"{executable!r} is not installed or not on PATH: "
            f"{INSTALL_HINT}",
        )  # fmt: skip
    return found


def open_argyll(
    settings: ArgyllSettings,
    *,
    launcher: SpotreadLauncher | None = None,
    transcript: TranscriptSink | None = None,
    resolve: bool = True,
) -> ArgyllSpotread:
    """The spotread instrument of ``settings``, ready to measure.

    Parameters
    ----------
    settings
        Executable, instrument number, resolution, deadline.
    launcher
        How spotread is started (default: on a pseudo-terminal).
    transcript
        Where every exchange is written.
    resolve
        Look the executable up on ``PATH`` now (replay runs the recorded one without it).

    Raises
    ------
    DeviceNotFound
        spotread is not installed.
    """
    executable = resolve_executable(settings.executable) if resolve else settings.executable
    instrument = ArgyllSpotread(settings, executable, launcher or PtyLauncher(), transcript)
    instrument._record("event", f"ready: {executable}".encode())
    return instrument
