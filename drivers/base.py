"""Device interfaces, the typed error hierarchy, and the transcript record every driver writes.

Devices are small :class:`typing.Protocol` s (as in Bluesky's ``protocols.py``), not base classes: a real
driver, an emulator-backed driver and a replay driver all satisfy them structurally. The rig's runner is
the only code that calls them.

Conventions
-----------
- Relay channels are numbered from 1, as printed on the boards.
- Exposure times are in seconds (``exposure_s``) for cameras and milliseconds (``exposure_ms``) for
  spectrometers, following each instrument family's own unit.
- Every blocking call has a deadline; a driver raises :class:`DeviceTimeout` rather than hang.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Literal, Protocol, runtime_checkable

if TYPE_CHECKING:  # annotations only: the errors here load with every command, numpy need not
    import numpy as np
    from numpy.typing import NDArray

# ------------------------------------------------------------------------------------------ errors


class DeviceError(Exception):
    """Base of every device error.

    Attributes
    ----------
    device
        Which device: model and port/serial, e.g. ``"PR-655 on /dev/ttyACM0"``.
    reason
        A short machine-readable reason recorded in the session log (``"timeout"``, ``"busy"`` …).
    retryable
        Whether repeating the same step may succeed (the runner retries only these, with backoff).
    """

    reason: ClassVar[str] = "device_error"
    retryable: ClassVar[bool] = False

    def __init__(self, device: str, message: str) -> None:
        self.device = device
        self.message = message
        super().__init__(f"{device}: {message}")


class DeviceNotFound(DeviceError):
    """No device matches the configured port, serial number or model."""

    reason = "not_found"


class DeviceTimeout(DeviceError):
    """The device did not answer within the deadline."""

    reason = "timeout"
    retryable = True

    def __init__(
        self, device: str, message: str, *, command: bytes | str | None = None, timeout_s: float
    ) -> None:
        self.command = command
        self.timeout_s = timeout_s
        super().__init__(device, message)


class ProtocolError(DeviceError):
    """The device answered something the protocol does not allow (garbled, truncated, unexpected)."""

    reason = "protocol"
    retryable = True

    def __init__(
        self, device: str, message: str, *, command: bytes | str | None, reply: bytes | str | None
    ) -> None:
        self.command = command
        self.reply = reply
        super().__init__(device, f"{message} (sent {command!r}, got {reply!r})")


class InstrumentError(DeviceError):
    """The instrument reported an error code of its own (e.g. too dark, over range)."""

    reason = "instrument_error"

    def __init__(
        self, device: str, message: str, *, code: str, command: bytes | str | None
    ) -> None:
        self.code = code
        self.command = command
        super().__init__(device, f"{message} (code {code}, command {command!r})")


class DeviceBusy(DeviceError):
    """The device is busy (PTP busy, measurement in progress); retrying later may succeed."""

    reason = "busy"
    retryable = True


class Disconnected(DeviceError):
    """The device went away (unplugged, port closed, USB reset)."""

    reason = "disconnected"


class StateMismatch(DeviceError):
    """A setting read back after it was set differs from what was asked (relay state, exposure)."""

    reason = "state_mismatch"

    def __init__(self, device: str, message: str, *, expected: object, actual: object) -> None:
        self.expected = expected
        self.actual = actual
        super().__init__(device, f"{message}: expected {expected!r}, read back {actual!r}")


# --------------------------------------------------------------------------------------- records


@dataclass(frozen=True)
class DeviceIdentity:
    """Who a device says it is; recorded in the session's start document."""

    kind: Literal["spectrometer", "camera", "relay"]
    model: str
    serial: str | None = None
    firmware: str | None = None
    port: str | None = None
    extra: dict[str, str] = field(default_factory=dict)

    def describe(self) -> str:
        where = f" on {self.port}" if self.port else ""
        serial = f" (serial {self.serial})" if self.serial else ""
        return f"{self.model}{serial}{where}"


@dataclass(frozen=True, eq=False)
class SpectrumReading:
    """One spectrometer measurement.

    ``wavelength_nm`` and ``values`` have shape ``(n,)``; ``units`` is the instrument's own unit
    (e.g. ``"W/(sr·m²·nm)"``); ``exposure_ms`` is the integration time actually used (adaptive
    exposure reports what it chose), ``None`` when the instrument does not say; ``bandwidth_nm``
    is the FWHM of the instrument's slit function (its spectral resolution), when known.
    """

    wavelength_nm: NDArray[np.float64]
    values: NDArray[np.float64]
    units: str
    exposure_ms: float | None = None
    extra: dict[str, str] = field(default_factory=dict)
    bandwidth_nm: float | None = None


@dataclass(frozen=True, eq=False)
class DarkReading:
    """Dark spectra measured with the light off, one per integration time.

    ``counts`` has shape ``(len(integration_ms), n_pixels)``: raw counts averaged over the scans, on
    the instrument's pixel wavelengths ``wavelength_nm`` (shape ``(n_pixels,)``, increasing).
    """

    wavelength_nm: NDArray[np.float64]
    integration_ms: tuple[float, ...]
    counts: NDArray[np.float64]


@dataclass(frozen=True)
class CapturedFile:
    """A frame downloaded from the camera to ``path``; ``camera_path`` is where it was on the camera."""

    path: Path
    camera_path: str
    exposure_s: float
    settings: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class SettingInfo:
    """A camera setting: its current value and, for choice widgets, the allowed choices."""

    name: str
    value: str
    choices: tuple[str, ...] = ()
    read_only: bool = False


TranscriptDirection = Literal["tx", "rx", "call", "return", "error", "event"]


@dataclass(frozen=True)
class TranscriptEntry:
    """One exchange with a device, as the transport saw it.

    ``tx``/``rx`` carry raw bytes (serial, USB control transfers); ``call``/``return``/``error``
    carry a UTF-8 JSON description of an API call (libgphoto2); ``event`` marks open/close/reset.
    ``monotonic_s`` is :func:`time.monotonic` at the exchange.
    """

    device: str
    direction: TranscriptDirection
    payload: bytes
    monotonic_s: float


class TranscriptSink(Protocol):
    """Where a transport writes its exchanges (the session's ``transcripts/`` files, or a list)."""

    def record(self, entry: TranscriptEntry) -> None: ...


class ListTranscript:
    """A transcript sink that keeps entries in memory (tests, dry runs)."""

    def __init__(self) -> None:
        self.entries: list[TranscriptEntry] = []

    def record(self, entry: TranscriptEntry) -> None:
        self.entries.append(entry)


# ------------------------------------------------------------------------------------ protocols


@runtime_checkable
class Spectrometer(Protocol):
    """A spectroradiometer that measures a lamp's spectrum."""

    def identify(self) -> DeviceIdentity: ...

    def set_exposure(self, exposure_ms: float | None) -> None:
        """Set the integration time in ms; ``None`` selects the instrument's adaptive exposure."""

    def measure(self) -> SpectrumReading: ...

    def close(self) -> None: ...


@runtime_checkable
class DarkCorrecting(Protocol):
    """A spectrometer that subtracts a dark of its own measuring (an Ocean Optics spectrometer).

    The rig calls :meth:`measure_dark` with every lamp off, after setting the exposure and before
    the first :meth:`Spectrometer.measure`.
    """

    def measure_dark(self) -> DarkReading: ...


@runtime_checkable
class Camera(Protocol):
    """A tethered camera that captures RAW frames and downloads them."""

    def identify(self) -> DeviceIdentity: ...

    def list_settings(self) -> dict[str, SettingInfo]: ...

    def get_setting(self, name: str) -> str: ...

    def set_setting(self, name: str, value: str) -> str:
        """Set a widget by name (nearest choice for choice widgets); return the value read back."""

    def exposure_range_s(self) -> tuple[float, float]:
        """Shortest and longest exposure the camera can make (bulb extends the longest)."""

    def set_exposure(self, exposure_s: float) -> float:
        """Select the nearest available exposure time; return the exposure actually set, read back."""

    def capture(self, destination: Path, *, sync: bool = True) -> CapturedFile:
        """Expose one frame, download it to ``destination`` (a file path) and delete it on the camera.

        ``sync=False``: the file is not fsynced; the caller syncs it before relying on it.
        """

    def close(self) -> None: ...


@runtime_checkable
class RelayBoard(Protocol):
    """A relay board switching lamps; channels numbered from 1."""

    @property
    def channels(self) -> int: ...

    def identify(self) -> DeviceIdentity: ...

    def set(self, channel: int, on: bool) -> None:
        """Switch one channel and verify by reading the state back (raises :class:`StateMismatch`)."""

    def state(self) -> tuple[bool, ...]:
        """The state of channels 1..n as read from the board."""

    def all_off(self) -> None:
        """Switch every channel off and verify."""

    def close(self) -> None: ...
