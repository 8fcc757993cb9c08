"""A pyusb backend that emulates Ocean Optics spectrometers at the USB bulk-transfer level.

Two firmware families, byte for byte as python-seabreeze's pyseabreeze speaks to them
(``src/seabreeze/pyseabreeze/{protocol,devices}.py`` and the features it uses):

- **USB2000+** (OOI protocol, VID 0x2457 PID 0x101E; endpoints 0x01 out, 0x81 low-speed in,
  0x82/0x86 high-speed in): ``01`` initialise; ``02 <uint32 µs>`` integration time; ``05 <slot>``
  EEPROM slot, answered on 0x81 with 17 bytes (``05 slot`` + 15 bytes: ASCII for the serial (slot 0),
  the wavelength polynomial (1–4), the nonlinearity polynomial (6–13) and its order (14); slot 17
  holds the saturation level as a little-endian uint16 at bytes 6–7); ``6B <register>`` FPGA
  register, answered with ``register uint16`` (register 4: firmware version, below 3.0 for a
  USB2000+); ``FE`` status, 16 bytes whose byte 14 is the USB speed (0x80 high speed); ``09``
  spectrum, answered on 0x82 with 2048 little-endian uint16 and the sync byte 0x69.
- **STS** (OBP protocol, VID 0x2457 PID 0x4000; endpoints 0x01 out, 0x81 in): 64-byte-minimum
  frames (``C0 C1``, version 0x1100, flags, error, 32-bit message type, immediate data up to 16
  bytes or a payload, ``C5 C4 C3 C2`` footer); serial and its length, wavelength coefficient count
  and coefficients (float32), integration time (µs, acknowledged when asked), raw spectrum
  (1024 little-endian uint16). An unknown message gets a NACK with error 2.

The detector: the light of ``source`` through a Gaussian slit function on the pixel wavelengths,
times a responsivity, integrated for the active integration time; plus a baseline, fixed-pattern
dark current and a per-scan common-mode baseline wobble that only the optically masked pixels see
too; a compressive nonlinearity (corrected by the polynomial the EEPROM stores), shot and read
noise, and clipping at the saturation level. As the real instruments do (seabreeze issues #110,
#177) the first scan after a change of integration time is still integrated with the old one.

Faults come from :class:`mocks.faults.FaultSchedule` with these labels: OOI ``init``,
``integration``, ``eeprom <slot>``, ``fpga <register>``, ``status``, ``spectrum``; OBP ``serial
length``, ``serial``, ``wavelength count``, ``wavelength <i>``, ``integration``, ``spectrum``.
``NO_REPLY`` / ``LATE_REPLY`` time out or delay the answer, ``TRUNCATED_REPLY`` cuts it short,
``GARBLED_REPLY`` corrupts its framing (the OOI sync byte, the OBP start bytes), ``ERROR_CODE``
stalls the endpoint (OOI) or answers with a NACK (OBP, error 6 unless the fault gives one),
``DISCONNECT`` unplugs the device, ``BUSY`` answers EBUSY.
"""

from __future__ import annotations

import array
import errno
import struct
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Literal

import numpy as np
import usb.backend
import usb.core
from numpy.typing import NDArray

from mocks.emulators.radiometer import RadianceSource, Radiometer, RadiometerOptics
from mocks.faults import Fault, FaultKind, FaultSchedule
from mocks.lamps import Clock, WallClock
from mocks.usb_relay_backend import device_descriptor

__all__ = [
    "OCEAN_MODELS",
    "STS",
    "USB2000PLUS",
    "EmulatedOcean",
    "OceanBackend",
    "OceanModel",
    "ocean_calibration",
]

FloatArray = NDArray[np.float64]
Protocol = Literal["ooi", "obp"]

OCEAN_VENDOR_ID = 0x2457
HIGH_SPEED = 3  # pyusb's SPEED_HIGH
OOI_SYNC = 0x69
OBP_START, OBP_VERSION, OBP_FOOTER = 0xC0C1, 0x1100, 0xC2C3C4C5
OBP_HEADER = struct.Struct("<HHHHLL6sBB16sL")
OBP_RESPONSE, OBP_ACK, OBP_REQUEST_ACK, OBP_NACK = 0x0001, 0x0002, 0x0004, 0x0008
OBP_UNKNOWN_MESSAGE, OBP_INVALID_PAYLOAD = 2, 6


@dataclass(frozen=True)
class OceanModel:
    """One emulated model: its USB identity, detector and optics."""

    name: str
    protocol: Protocol
    product_id: int
    endpoints_in: tuple[int, ...]
    spectrum_endpoint: int
    pixels: int
    wavelength_coefficients: tuple[float, float, float, float]
    dark_pixels: tuple[int, ...]
    max_counts: int
    saturation_counts: int
    integration_min_us: int
    bandwidth_nm: float
    baseline_counts: float
    peak_responsivity: float  # counts per ms per W/(sr·m²·nm) at the peak
    nonlinearity_compression: float  # fractional loss of signal at full scale
    read_noise_counts: float
    serial: str
    firmware: int = 0x2090  # FPGA register 4 (OOI): v2.9.0, a USB2000+, not a Flame-S

    def wavelength_nm(self) -> FloatArray:
        index = np.arange(self.pixels, dtype=np.float64)
        return np.asarray(
            sum(c * index**k for k, c in enumerate(self.wavelength_coefficients)), dtype=float
        )


#: A USB2000+ VIS-NIR (grating #2, 25 µm slit): 2048 pixels, ~340–1030 nm, 16-bit ADC saturating
#: at 62 000, masked pixels 6–20.
USB2000PLUS = OceanModel(
    name="USB2000PLUS",
    protocol="ooi",
    product_id=0x101E,
    endpoints_in=(0x81, 0x82, 0x86),
    spectrum_endpoint=0x82,
    pixels=2048,
    wavelength_coefficients=(339.4, 0.3806, -1.55e-5, -1.0e-9),
    dark_pixels=tuple(range(6, 21)),
    max_counts=65535,
    saturation_counts=62000,
    integration_min_us=1000,
    bandwidth_nm=1.5,
    baseline_counts=1500.0,
    peak_responsivity=6.0e5,
    nonlinearity_compression=0.06,
    read_noise_counts=8.0,
    serial="USB2+F12345",
)
#: An STS-VIS: 1024 pixels, ~350–800 nm, 14-bit, no masked pixels.
STS = OceanModel(
    name="STS",
    protocol="obp",
    product_id=0x4000,
    endpoints_in=(0x81,),
    spectrum_endpoint=0x81,
    pixels=1024,
    wavelength_coefficients=(349.2, 0.4652, -1.8e-5, 0.0),
    dark_pixels=(),
    max_counts=16383,
    saturation_counts=16383,
    integration_min_us=10,
    bandwidth_nm=3.0,
    baseline_counts=1000.0,
    peak_responsivity=1.5e5,
    nonlinearity_compression=0.0,
    read_noise_counts=3.0,
    serial="S05678",
)
OCEAN_MODELS = {model.name: model for model in (USB2000PLUS, STS)}


def _responsivity(wavelength_nm: FloatArray, peak: float) -> FloatArray:
    """Counts per ms per unit radiance: silicon under a grating, weak in the blue."""
    shape = 0.08 + 0.92 * np.exp(-0.5 * ((wavelength_nm - 620.0) / 150.0) ** 2)
    return np.asarray(peak * shape, dtype=np.float64)


def ocean_calibration(model: OceanModel) -> tuple[FloatArray, FloatArray]:
    """The exact relative irradiance calibration of ``model``: ``(wavelength_nm, factor)``.

    Counts per ms times ``factor`` gives the radiance the emulator was shown, so the twin's Ocean
    spectrometer reads the lamps as a calibrated instrument would (380–780 nm).
    """
    wavelength = np.arange(380.0, 781.0, 1.0)
    return wavelength, 1.0 / _responsivity(wavelength, model.peak_responsivity)


def _usb_error(kind: str) -> usb.core.USBError:
    codes = {
        "timeout": (-7, errno.ETIMEDOUT, "Operation timed out"),
        "stall": (-9, errno.EPIPE, "Pipe error"),
        "disconnect": (-4, errno.ENODEV, "No such device (it may have been disconnected)"),
        "busy": (-6, errno.EBUSY, "Resource busy"),
    }
    code, errno_value, text = codes[kind]
    if kind == "timeout":
        return usb.core.USBTimeoutError(text, code, errno_value)
    return usb.core.USBError(text, code, errno_value)


@dataclass
class _Reply:
    data: bytes
    fault: Fault | None = None


@dataclass
class _Pending:
    """Answers waiting on the IN endpoints."""

    queues: dict[int, list[_Reply]] = field(default_factory=dict)


class EmulatedOcean:
    """The firmware and detector of one spectrometer.

    Parameters
    ----------
    model
        :data:`USB2000PLUS` or :data:`STS`.
    source
        Spectral radiance the fibre sees (e.g. :meth:`mocks.lamps.LampBank.radiance`).
    seed
        Seed or generator of the noise (the twin replaces :attr:`rng` per step).
    faults
        Fault schedule (labels in the module docstring).
    time_scale
        Fraction of each scan's integration time that passes in wall time.
    bus, address
        Where it sits on the bus.
    """

    def __init__(
        self,
        model: OceanModel,
        source: RadianceSource,
        *,
        seed: int | np.random.Generator | None = 0,
        faults: FaultSchedule | None = None,
        time_scale: float = 1.0,
        bus: int = 1,
        address: int = 9,
    ) -> None:
        self.model = model
        self.faults = faults or FaultSchedule()
        self.time_scale = time_scale
        self.rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self.descriptor = device_descriptor(
            OCEAN_VENDOR_ID,
            model.product_id,
            bus=bus,
            address=address,
            bcdUSB=0x0200,
            bMaxPacketSize0=64,
            iManufacturer=0,
            iProduct=0,
            speed=HIGH_SPEED,
        )
        self.plugged = True
        self.configured = 0
        self.wavelength_nm = model.wavelength_nm()
        self._radiometer = Radiometer(
            RadiometerOptics(
                wavelength_nm=self.wavelength_nm,
                bandwidth_nm=model.bandwidth_nm,
                peak_responsivity=model.peak_responsivity,
                exposure_range_ms=(model.integration_min_us / 1000.0, 65535.0),
            ),
            source,
            self.rng,
        )
        self.responsivity = _responsivity(self.wavelength_nm, model.peak_responsivity)
        self.responsivity[list(model.dark_pixels)] = 0.0
        pattern = np.random.default_rng(model.pixels)
        #: Dark current per pixel, counts per ms (a fixed pattern with a few hot pixels).
        self.dark_rate = 0.02 + 0.01 * pattern.random(model.pixels)
        self.dark_rate[pattern.choice(model.pixels, 3, replace=False)] += 0.5
        self.integration_us = 100_000
        self._requested_us = self.integration_us
        self.pending = _Pending()
        self.commands: list[bytes] = []
        self.scans = 0
        #: How a scan's integration time passes (the backend gives its clock's sleep).
        self.clock_sleep: Callable[[float], None] = WallClock().sleep
        self._lock = threading.RLock()

    # ------------------------------------------------------------------------------ detector

    def nonlinearity_coefficients(self) -> tuple[float, ...]:
        """The polynomial (seabreeze's convention: linear = counts / poly(counts)) the EEPROM holds."""
        if self.model.nonlinearity_compression == 0:
            return (1.0,)
        full = float(self.model.max_counts)
        true = np.linspace(1.0, full, 400)
        measured = self._compress(true)
        fit = np.polynomial.polynomial.polyfit(measured, measured / true, 3)
        return tuple(float(c) for c in fit)

    def _compress(self, counts: FloatArray) -> FloatArray:
        loss = self.model.nonlinearity_compression * counts / self.model.max_counts
        return np.asarray(counts * (1.0 - loss), dtype=np.float64)

    def scan(self) -> FloatArray:
        """One scan's counts as pyseabreeze returns them, at the active integration time.

        The scan uses the integration time set before the previous scan (the stale first scan).
        """
        model = self.model
        integration_ms = self.integration_us / 1000.0
        self.integration_us = self._requested_us
        self.scans += 1
        self._radiometer.rng = self.rng
        light = self._radiometer.band_radiance() * self.responsivity * integration_ms
        above = light + self.dark_rate * integration_ms
        # A pixel fills up at full scale: far beyond it the compression model would turn over.
        above = self._compress(np.minimum(above, 2.0 * model.max_counts))
        variance = np.clip(above, 0.0, None) + model.read_noise_counts**2
        noise = self.rng.standard_normal(model.pixels) * np.sqrt(variance)
        wobble = self.rng.normal(0.0, 3.0)  # common-mode baseline drift, seen by masked pixels too
        counts = model.baseline_counts + wobble + above + noise
        counts = np.clip(np.round(counts), 0, model.saturation_counts)
        return np.asarray(counts, dtype=np.float64)

    def _raw_counts(self) -> FloatArray:
        """The ADC values on the wire (the USB2000+ scales by max/saturation inside pyseabreeze)."""
        counts = self.scan()
        if self.model.protocol == "ooi":
            return np.round(counts * self.model.saturation_counts / self.model.max_counts)
        return counts

    # ------------------------------------------------------------------------------ firmware

    def _queue(self, endpoint: int, data: bytes, fault: Fault | None) -> None:
        self.pending.queues.setdefault(endpoint, []).append(_Reply(data, fault))

    def command(self, data: bytes) -> None:
        """A bulk OUT transfer on endpoint 0x01."""
        with self._lock:
            self.commands.append(bytes(data))
            if self.model.protocol == "ooi":
                self._ooi(data)
            else:
                self._obp(data)

    def _ooi(self, data: bytes) -> None:
        model = self.model
        opcode = data[0] if data else -1
        low = model.endpoints_in[0]
        if opcode == 0x01 and len(data) == 1:
            self._fault("init")
        elif opcode == 0x02 and len(data) == 5:
            self._fault("integration")
            micros = struct.unpack("<I", data[1:])[0]
            if micros >= model.integration_min_us:
                self._requested_us = micros
        elif opcode == 0x05 and len(data) == 2:
            slot = data[1]
            self._queue(
                low, bytes([0x05, slot]) + self._eeprom(slot), self._fault(f"eeprom {slot}")
            )
        elif opcode == 0x6B and len(data) == 2:
            register = data[1]
            value = model.firmware if register == 0x04 else 0
            self._queue(low, struct.pack("<BH", register, value), self._fault(f"fpga {register}"))
        elif opcode == 0xFE and len(data) == 1:
            status = bytearray(16)
            struct.pack_into("<HL", status, 0, model.pixels, self.integration_us)
            status[14] = 0x80
            self._queue(low, bytes(status), self._fault("status"))
        elif opcode == 0x09 and len(data) == 1:
            fault = self._fault("spectrum")
            self._sleep_integration()
            counts = self._raw_counts().astype("<u2").tobytes()
            self._queue(model.spectrum_endpoint, counts + bytes([OOI_SYNC]), fault)
        # Anything else is ignored, as the firmware ignores unknown opcodes.

    def _eeprom(self, slot: int) -> bytes:
        model = self.model
        if slot == 17:
            return b"\x00" * 4 + struct.pack("<H", model.saturation_counts) + b"\x00" * 9
        coefficients = self.nonlinearity_coefficients()
        texts = {0: model.serial, 14: str(len(coefficients) - 1)}
        texts.update({k + 1: f"{c:.6E}" for k, c in enumerate(model.wavelength_coefficients)})
        texts.update({6 + k: f"{c:.6E}" for k, c in enumerate(coefficients)})
        return texts.get(slot, "").encode("ascii")[:15].ljust(15, b"\x00")

    def _obp(self, data: bytes) -> None:
        if len(data) < 64:
            return
        fields = OBP_HEADER.unpack(data[:44])
        message, flags, immediate_length, immediate = fields[4], fields[2], fields[8], fields[9]
        argument = immediate[:immediate_length]
        labels = {
            0x00000101: "serial length",
            0x00000100: "serial",
            0x00180100: "wavelength count",
            0x00110010: "integration",
            0x00101100: "spectrum",
        }
        label = labels.get(message, f"wavelength {argument[0]}" if argument else "wavelength")
        if message not in labels and message != 0x00180101:
            self._reply_obp(message, b"", nack=OBP_UNKNOWN_MESSAGE, fault=None)
            return
        fault = self._fault(label)
        payload: bytes | None = None
        model = self.model
        if message == 0x00000101:
            payload = bytes([len(model.serial)])
        elif message == 0x00000100:
            payload = model.serial.encode("ascii")
        elif message == 0x00180100:
            payload = bytes([len(model.wavelength_coefficients)])
        elif message == 0x00180101:
            index = argument[0] if argument else 255
            if index >= len(model.wavelength_coefficients):
                self._reply_obp(message, b"", nack=OBP_INVALID_PAYLOAD, fault=fault)
                return
            payload = struct.pack("<f", model.wavelength_coefficients[index])
        elif message == 0x00110010:
            micros = struct.unpack("<L", argument)[0]
            if micros < model.integration_min_us:
                self._reply_obp(message, b"", nack=OBP_INVALID_PAYLOAD, fault=fault)
                return
            self._requested_us = micros
        elif message == 0x00101100:
            self._sleep_integration()
            payload = self._raw_counts().astype("<u2").tobytes()
        if payload is not None:
            self._reply_obp(message, payload, fault=fault)
        elif flags & OBP_REQUEST_ACK:
            self._reply_obp(message, b"", ack=True, fault=fault)

    def _reply_obp(
        self, message: int, payload: bytes, *, fault: Fault | None, nack: int = 0, ack: bool = False
    ) -> None:
        if fault is not None and fault.kind is FaultKind.ERROR_CODE:
            nack = int(fault.code) if fault.code else OBP_INVALID_PAYLOAD
            payload, fault = b"", None
        flags = OBP_RESPONSE | (OBP_ACK if ack else 0) | (OBP_NACK if nack else 0)
        immediate = payload if len(payload) <= 16 else b""
        body = b"" if len(payload) <= 16 else payload
        header = OBP_HEADER.pack(
            OBP_START, OBP_VERSION, flags, nack, message, 0, b"", 0,
            len(immediate), immediate, 20 + len(body),
        )  # fmt: skip
        footer = b"\x00" * 16 + struct.pack("<L", OBP_FOOTER)
        self._queue(self.model.endpoints_in[0], header + body + footer, fault)

    def _fault(self, label: str) -> Fault | None:
        fault = self.faults.next_fault(label)
        if fault is not None and fault.kind is FaultKind.DISCONNECT:
            self.plugged = False
            raise _usb_error("disconnect")
        if fault is not None and fault.kind is FaultKind.BUSY:
            raise _usb_error("busy")
        return fault

    def _sleep_integration(self) -> None:
        self.clock_sleep(self.integration_us / 1e6 * self.time_scale)

    def read(self, endpoint: int, size: int, timeout_ms: int, clock: Clock) -> bytes:
        """A bulk IN transfer: the next answer queued on ``endpoint`` (what fits in ``size``)."""
        with self._lock:
            queue = self.pending.queues.get(endpoint, [])
            reply = queue[0] if queue else None
        timeout_s = max(timeout_ms, 1) / 1000.0
        if reply is None:
            clock.sleep(timeout_s)
            raise _usb_error("timeout")
        fault, data = reply.fault, reply.data
        if fault is not None:
            reply.fault = None
            if fault.kind is FaultKind.NO_REPLY or (
                fault.kind is FaultKind.LATE_REPLY and fault.delay_s >= timeout_s
            ):
                with self._lock:
                    queue.pop(0)
                clock.sleep(timeout_s)
                raise _usb_error("timeout")
            if fault.kind is FaultKind.LATE_REPLY:
                clock.sleep(fault.delay_s)
            elif fault.kind is FaultKind.TRUNCATED_REPLY:
                data = fault.kept(data)
            elif fault.kind is FaultKind.GARBLED_REPLY:
                corrupted = bytearray(data)
                if self.model.protocol == "ooi":
                    corrupted[-1] ^= 0xFF
                else:
                    corrupted[0] ^= 0xFF
                data = bytes(corrupted)
            elif fault.kind is FaultKind.ERROR_CODE:
                with self._lock:
                    queue.pop(0)
                raise _usb_error("stall")
            reply.data = data
        with self._lock:
            chunk, rest = data[:size], data[size:]
            if rest:
                reply.data = rest
            else:
                queue.pop(0)
        return chunk


@dataclass
class _Handle:
    device: EmulatedOcean
    claimed: set[int] = field(default_factory=set)


class OceanBackend(usb.backend.IBackend):  # type: ignore[misc]
    """A pyusb backend serving :class:`EmulatedOcean` spectrometers (and nothing else).

    Parameters
    ----------
    devices
        The spectrometers plugged in.
    clock
        Time source of timeouts and delays.
    """

    def __init__(self, devices: list[EmulatedOcean], clock: Clock | None = None) -> None:
        self.devices = list(devices)
        self.clock: Clock = clock or WallClock()
        for device in self.devices:
            device.clock_sleep = self.clock.sleep

    def _check(self, device: EmulatedOcean) -> None:
        if not device.plugged:
            raise _usb_error("disconnect")

    def enumerate_devices(self) -> list[EmulatedOcean]:
        return [device for device in self.devices if device.plugged]

    def get_device_descriptor(self, dev: EmulatedOcean) -> SimpleNamespace:
        return dev.descriptor

    def get_configuration_descriptor(self, dev: EmulatedOcean, config: int) -> SimpleNamespace:
        return SimpleNamespace(
            bLength=9, bDescriptorType=2, wTotalLength=9 + 9 + 7 * (1 + len(dev.model.endpoints_in)),
            bNumInterfaces=1, bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80,
            bMaxPower=250, extra_descriptors=b"",
        )  # fmt: skip

    def get_interface_descriptor(
        self, dev: EmulatedOcean, intf: int, alt: int, config: int
    ) -> SimpleNamespace:
        if intf != 0 or alt != 0:
            raise IndexError(f"no interface {intf} alternate setting {alt}")
        return SimpleNamespace(
            bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0,
            bNumEndpoints=1 + len(dev.model.endpoints_in), bInterfaceClass=0xFF,
            bInterfaceSubClass=0, bInterfaceProtocol=0, iInterface=0, extra_descriptors=b"",
        )  # fmt: skip

    def get_endpoint_descriptor(
        self, dev: EmulatedOcean, ep: int, intf: int, alt: int, config: int
    ) -> SimpleNamespace:
        address = (0x01, *dev.model.endpoints_in)[ep]
        return SimpleNamespace(
            bLength=7, bDescriptorType=5, bEndpointAddress=address, bmAttributes=0x02,
            wMaxPacketSize=64 if address in (0x01, 0x81) else 512, bInterval=0, bRefresh=0,
            bSynchAddress=0, extra_descriptors=b"",
        )  # fmt: skip

    def open_device(self, dev: EmulatedOcean) -> _Handle:
        self._check(dev)
        return _Handle(dev)

    def close_device(self, dev_handle: _Handle) -> None:
        dev_handle.claimed.clear()

    def set_configuration(self, dev_handle: _Handle, config_value: int) -> None:
        self._check(dev_handle.device)
        dev_handle.device.configured = config_value

    def get_configuration(self, dev_handle: _Handle) -> int:
        self._check(dev_handle.device)
        return dev_handle.device.configured

    def claim_interface(self, dev_handle: _Handle, intf: int) -> None:
        self._check(dev_handle.device)
        dev_handle.claimed.add(intf)

    def release_interface(self, dev_handle: _Handle, intf: int) -> None:
        dev_handle.claimed.discard(intf)

    def is_kernel_driver_active(self, dev_handle: _Handle, intf: int) -> bool:
        return False

    def detach_kernel_driver(self, dev_handle: _Handle, intf: int) -> None:
        """No kernel driver binds a vendor-class interface."""

    def attach_kernel_driver(self, dev_handle: _Handle, intf: int) -> None:
        """Nothing to attach."""

    def reset_device(self, dev_handle: _Handle) -> None:
        device = dev_handle.device
        if device.plugged:
            device.pending = _Pending()

    def clear_halt(self, dev_handle: _Handle, ep: int) -> None:
        self._check(dev_handle.device)

    def bulk_write(
        self, dev_handle: _Handle, ep: int, intf: int, data: array.array[int], timeout: int
    ) -> int:
        device = dev_handle.device
        self._check(device)
        device.command(bytes(data))
        return len(data)

    def bulk_read(
        self, dev_handle: _Handle, ep: int, intf: int, buff: array.array[int], timeout: int
    ) -> int:
        device = dev_handle.device
        self._check(device)
        chunk = device.read(ep, len(buff), timeout, self.clock)
        buff[: len(chunk)] = array.array("B", chunk)
        return len(chunk)
