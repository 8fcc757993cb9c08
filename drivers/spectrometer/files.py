"""Spectra measured once, elsewhere, as a spectrometer: one file per lamp.

A lab that borrowed a spectroradiometer for an afternoon (or has its lamps' certificates) keeps
the files and captures with the rig whenever it likes. :class:`FilesSpectrometer` "measures" by
returning the file of the lamp that is lit: it knows which one from the relay board it watches
(:class:`SwitchedRelays`, which remembers every channel the rig switched), so a measurement with no
lamp or several lamps on is an error, as it would be a wrong reading on a real instrument.

The driver reads nothing itself: its ``reader`` turns a file into a :class:`drivers.base.SpectrumReading`
(the rig's, :mod:`rig.spectrum_files`, uses ``calib``'s readers; replay's serves the recording).
Every file is read once when the device opens, so a missing or unreadable file stops the capture
before anything starts; the identity names each file with its sha256, and its ``serial`` is a
digest of them all, so ``rig resume`` refuses files that changed since the session started.

The transcript: a ``call`` per file read at open (``{"read": lamp, "file": name}``) and a ``return``
with the spectrum as read (wavelengths, values, units, bandwidth), which replay serves back; each
measurement is an ``event`` naming the lamp (which lamp is lit is the relays' transcript's to check).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.base import (
    DeviceIdentity,
    DeviceNotFound,
    InstrumentError,
    RelayBoard,
    SpectrumReading,
    TranscriptDirection,
    TranscriptEntry,
    TranscriptSink,
)
from drivers.lifecycle import ClosesOnExit

__all__ = [
    "FilesSpectrometer",
    "LampFile",
    "SpectrumReader",
    "SwitchedRelays",
    "reading_from_json",
    "reading_to_json",
]

SpectrumReader = Callable[[Path], SpectrumReading]
"""Reads one spectrum file (raises ``ValueError`` with a message naming the file when it cannot)."""


@dataclass(frozen=True)
class LampFile:
    """A lamp's spectrum file and the relay channel that lights it."""

    lamp: str
    channel: int
    path: Path


class SwitchedRelays:
    """A relay board that remembers which channels the rig switched on.

    Wraps any :class:`drivers.base.RelayBoard` (every call goes through); :meth:`on_channels`
    answers from what was asked and verified, without another exchange with the board.
    """

    def __init__(self, board: RelayBoard) -> None:
        self.board = board
        self._on: set[int] = set()

    @property
    def channels(self) -> int:
        return self.board.channels

    def identify(self) -> DeviceIdentity:
        return self.board.identify()

    def set(self, channel: int, on: bool) -> None:
        self._on.discard(channel)
        self.board.set(channel, on)
        if on:
            self._on.add(channel)

    def state(self) -> tuple[bool, ...]:
        state = self.board.state()
        self._on = {index for index, lit in enumerate(state, start=1) if lit}
        return state

    def all_off(self) -> None:
        self.board.all_off()
        self._on.clear()

    def close(self) -> None:
        self.board.close()

    def on_channels(self) -> frozenset[int]:
        """The channels switched on (and verified) by the rig."""
        return frozenset(self._on)


def reading_to_json(reading: SpectrumReading) -> dict[str, object]:
    """A reading as JSON-able data (what the transcript's ``return`` holds)."""
    return {
        "wavelength_nm": [float(v) for v in reading.wavelength_nm],
        "values": [float(v) for v in reading.values],
        "units": reading.units,
        "bandwidth_nm": reading.bandwidth_nm,
    }


def reading_from_json(data: Mapping[str, object]) -> SpectrumReading:
    """The reading :func:`reading_to_json` wrote."""
    bandwidth = data.get("bandwidth_nm")
    return SpectrumReading(
        wavelength_nm=np.asarray(data["wavelength_nm"], dtype=np.float64),
        values=np.asarray(data["values"], dtype=np.float64),
        units=str(data["units"]),
        bandwidth_nm=None if bandwidth is None else float(str(bandwidth)),
    )


def _file_sha256(path: Path) -> str:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return "unreadable"


class FilesSpectrometer(ClosesOnExit):
    """Returns the lit lamp's measured spectrum; implements :class:`drivers.base.Spectrometer`.

    Parameters
    ----------
    directory
        Where the files are (the identity's port).
    lamps
        Each lamp's file and channel.
    reader
        Reads a file.
    relays
        The relay board the rig switches (wrapped in :class:`SwitchedRelays`).
    transcript
        Where every read goes.
    digests
        Each lamp's file sha256 (default: computed from the files; replay passes the recorded).

    Raises
    ------
    DeviceNotFound
        A file is missing or cannot be read as a spectrum (named, with the reader's reason).
    """

    def __init__(
        self,
        directory: Path,
        lamps: Sequence[LampFile],
        reader: SpectrumReader,
        relays: SwitchedRelays,
        transcript: TranscriptSink | None = None,
        *,
        digests: Mapping[str, str] | None = None,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.directory = directory
        self.lamps = {lamp.lamp: lamp for lamp in lamps}
        self.reader = reader
        self.relays = relays
        self.transcript = transcript
        self.label = f"spectrum files in {directory}"
        self._monotonic = monotonic
        self.digests = dict(digests or {lamp.lamp: _file_sha256(lamp.path) for lamp in lamps})
        self.readings = {lamp.lamp: self._read(lamp) for lamp in lamps}

    def _record(self, direction: TranscriptDirection, value: object) -> None:
        if self.transcript is not None:
            payload = json.dumps(value, sort_keys=True).encode("utf-8")
            self.transcript.record(
                TranscriptEntry(self.label, direction, payload, self._monotonic())
            )

    def _read(self, lamp: LampFile) -> SpectrumReading:
        self._record("call", {"read": lamp.lamp, "file": lamp.path.name})
        try:
            reading = self.reader(lamp.path)
        except (OSError, ValueError) as exc:
            self._record("error", {"error": str(exc)})
            raise DeviceNotFound(
                self.label,
                f"lamp {lamp.lamp!r}: {lamp.path}: {exc} (devices.spectrometer.lamps)",
            ) from None
        self._record("return", reading_to_json(reading))
        return reading

    def identify(self) -> DeviceIdentity:
        listed = {
            name: {
                "file": str(lamp.path.name),
                "channel": lamp.channel,
                "sha256": self.digests[name],
            }
            for name, lamp in self.lamps.items()
        }
        together = hashlib.sha256(json.dumps(listed, sort_keys=True).encode()).hexdigest()
        return DeviceIdentity(
            kind="spectrometer",
            model="spectrum files",
            serial=together[:16],
            port=str(self.directory),
            extra={"driver": "files", "lamps": json.dumps(listed)},  # in reading order
        )

    def set_exposure(self, exposure_ms: float | None) -> None:
        """Files have no integration time; a fixed one is refused."""
        if exposure_ms is not None:
            raise ValueError(f"{self.label}: files have no integration time; set it to null")

    def measure(self) -> SpectrumReading:
        """The spectrum of the one lamp that is on.

        Raises
        ------
        InstrumentError
            No lamp of the files is on, or several are (``code`` ``no_lamp`` / ``several_lamps``).
        """
        on = self.relays.on_channels()
        lit = [name for name, lamp in self.lamps.items() if lamp.channel in on]
        if len(lit) != 1:
            code = "no_lamp" if not lit else "several_lamps"
            raise InstrumentError(
                self.label,
                f"{'no lamp' if not lit else ', '.join(lit)} on (channels "
                f"{sorted(on) or 'none'}): a measured file stands for exactly one lit lamp",
                code=code,
                command="measure",
            )
        if self.transcript is not None:
            note = f"measure: {lit[0]} ({self.lamps[lit[0]].path.name})".encode()
            self.transcript.record(TranscriptEntry(self.label, "event", note, self._monotonic()))
        return self.readings[lit[0]]

    def close(self) -> None:
        """Nothing is held open."""
