"""CS-2000 driver: exact exchanges for every command, then the driver against its emulator."""

from __future__ import annotations

import logging
import struct
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np
import pytest
import serial

from drivers.base import (
    DeviceBusy,
    DeviceError,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    InstrumentError,
    ProtocolError,
    Spectrometer,
    StateMismatch,
)
from drivers.spectrometer import longest_measure_s, open_spectrometer
from drivers.spectrometer.cs2000 import Cs2000, SpeedSetting, open_cs2000
from drivers.transport import ReplyTimeout
from mocks.emulators import start_cs2000
from mocks.faults import Fault, FaultKind, FaultSchedule
from mocks.lamps import LampBank
from mocks.pty_serial import PtySerialDevice
from tests.drivers.serial_rig import (
    FAST_TIMEOUT_S,
    FAULT_TEST_TIMEOUT_S,
    RED_PEAK_NM,
    REPLY_TIMEOUT_S,
    TIME_SCALE,
    deadline_for,
    settled,
    two_lamp_bank,
)
from tests.exchange import Exchange, expected_exchange

CONNECT: list[Exchange] = [
    (b"RMTS,2\n", b"OK00\n"),
    (b"IDDR\n", b"OK00,CS-2000  ,1,1000123\n"),
]
VALUES = np.linspace(1e-4, 2e-2, 401).astype(np.float32).astype(np.float64)


def hex_values(values: Sequence[float] | np.ndarray) -> list[str]:
    return [struct.pack(">f", float(value)).hex().upper() for value in values]


def block_reply(values: Sequence[float] | np.ndarray) -> bytes:
    return ("OK00," + ",".join(hex_values(values)) + "\n").encode("ascii")


def data_script(values: np.ndarray = VALUES, integration_us: int = 250_000) -> list[Exchange]:
    """Conditions and the four spectral blocks."""
    script: list[Exchange] = [
        (b"MEDR,0,0,1\n", f"OK00,0,0,{integration_us:09d},2,0,0,0,0\n".encode("ascii")),
    ]
    for block, (start, stop) in enumerate([(0, 100), (100, 200), (200, 300), (300, 401)], 1):
        script.append((f"MEDR,1,1,{block}\n".encode("ascii"), block_reply(values[start:stop])))
    return script


MEASURE: list[Exchange] = [(b"MEAS,1\n", b"OK00,003\n"), (None, b"OK00\n"), *data_script()]


@contextmanager
def connected(script: Sequence[Exchange], **options: str) -> Iterator[Cs2000]:
    """A connected driver on a scripted link; the rest of the script must be used in the block."""
    with expected_exchange([*CONNECT, *script]) as link:
        instrument = Cs2000(link, port="/dev/ttyACM1", **options)  # type: ignore[arg-type]
        instrument.connect()
        yield instrument


# ---------------------------------------------------------------------------- exact exchanges


def test_connect_enters_remote_mode_without_flash_writes_and_identifies() -> None:
    with connected([]) as instrument:
        identity = instrument.identify()
    assert (identity.model, identity.serial, identity.port) == (
        "CS-2000",
        "1000123",
        "/dev/ttyACM1",
    )
    assert isinstance(instrument, Spectrometer)


def test_a_cs2000a_is_recognised_by_its_variation() -> None:
    script = [(b"RMTS,2\n", b"OK00\n"), (b"IDDR\n", b"OK00,CS-2000A ,2,1000456\n")]
    with expected_exchange(script) as link:
        instrument = Cs2000(link, model="CS-2000A")
        instrument.connect()
    assert instrument.identify().model == "CS-2000A"


def test_the_other_variation_on_the_port_is_device_not_found() -> None:
    script = [(b"RMTS,2\n", b"OK00\n"), (b"IDDR\n", b"OK00,CS-2000A ,2,1000456\n")]
    with (
        expected_exchange(script) as link,
        pytest.raises(DeviceNotFound, match=r"is a CS-2000A, the config says CS-2000"),
    ):
        Cs2000(link).connect()


def test_old_firmware_refusing_rmts2_is_explained() -> None:
    with (
        expected_exchange([(b"RMTS,2\n", b"ER00\n")]) as link,
        pytest.raises(InstrumentError, match=r"3\.00\.9301") as caught,
    ):
        Cs2000(link).connect()
    assert caught.value.code == "ER00"


def test_measure_waits_for_completion_and_decodes_the_four_blocks() -> None:
    with connected(MEASURE) as instrument:
        reading = instrument.measure()
    np.testing.assert_array_equal(reading.wavelength_nm, np.arange(380.0, 781.0))
    np.testing.assert_array_equal(reading.values, VALUES)  # float32 round trip is exact
    assert reading.exposure_ms == 250.0
    assert reading.units == "W/(sr·m²·nm)"
    assert reading.extra == {
        "speed_mode": "Normal",
        "internal_nd": "2",
        "announced_measurement_s": "3",
    }


@pytest.mark.parametrize(
    ("exposure_ms", "nd", "command", "readback"),
    [
        (None, "auto", b"SPMS,0,2\n", b"OK00,0,2\n"),
        (250, "auto", b"SPMS,3,000250000,2\n", b"OK00,3,000250000,2\n"),
        (12.5, "off", b"SPMS,3,000012500,0\n", b"OK00,3,000012500,0\n"),
        (120_000, "on", b"SPMS,3,120000000,1\n", b"OK00,3,120000000,1\n"),
    ],
)
def test_set_exposure_and_read_it_back(
    exposure_ms: float | None, nd: str, command: bytes, readback: bytes
) -> None:
    with connected([(command, b"OK00\n"), (b"SPMR\n", readback)], internal_nd=nd) as instrument:
        instrument.set_exposure(exposure_ms)


def test_a_setting_that_does_not_read_back_is_a_state_mismatch() -> None:
    script = [(b"SPMS,3,000250000,2\n", b"OK00\n"), (b"SPMR\n", b"OK00,0,2\n")]
    with connected(script) as instrument, pytest.raises(StateMismatch) as caught:
        instrument.set_exposure(250)
    assert caught.value.actual == SpeedSetting(mode=0, internal_nd=2)


@pytest.mark.parametrize("exposure_ms", [4.9, 120_001])
def test_an_exposure_out_of_range_is_refused_before_sending(exposure_ms: float) -> None:
    with connected([]) as instrument, pytest.raises(ValueError, match="5–120000 ms"):
        instrument.set_exposure(exposure_ms)


def test_speed_setting_reads_every_mode() -> None:
    script = [(b"SPMR\n", b"OK00,2,05,1\n"), (b"SPMR\n", b"OK00,1,0\n")]
    with connected(script) as instrument:
        assert instrument.speed_setting() == SpeedSetting(2, 1, multi_integration_s=5)
        assert instrument.speed_setting() == SpeedSetting(1, 0)


@pytest.mark.parametrize("part", ["ack", "completion"])
def test_over_range_is_an_instrument_error(part: str) -> None:
    if part == "ack":
        script: list[Exchange] = [(b"MEAS,1\n", b"ER10\n")]
    else:
        script = [(b"MEAS,1\n", b"OK00,003\n"), (None, b"ER10\n")]
    with connected(script) as instrument, pytest.raises(InstrumentError, match="over range") as e:
        instrument.measure()
    assert e.value.code == "ER10"


def test_measurement_in_progress_is_busy_and_retryable() -> None:
    with (
        connected([(b"MEAS,1\n", b"ER02\n")]) as instrument,
        pytest.raises(DeviceBusy, match="measurement in progress") as caught,
    ):
        instrument.measure()
    assert caught.value.retryable


def test_a_lost_completion_cancels_the_measurement_then_raises() -> None:
    script = [(b"MEAS,1\n", b"OK00,003\n"), (b"MEAS,0\n", b"OK00\n")]
    with connected(script) as instrument, pytest.raises(DeviceTimeout) as caught:
        instrument.measure()
    assert caught.value.timeout_s == 3 + instrument.completion_margin_s


def test_an_announced_time_beyond_the_instrument_s_range_is_refused_and_cancelled() -> None:
    script = [(b"MEAS,1\n", b"OK00,999\n"), (b"MEAS,0\n", b"OK00\n")]
    with (
        connected(script) as instrument,
        pytest.raises(ProtocolError, match="beyond the instrument's 242 s"),
    ):
        instrument.measure()


@pytest.mark.parametrize(
    ("model", "options", "longest"),
    [
        ("PR-655", {}, 60.0 + 10.0),
        ("pr670", {"timeout_s": 2.0, "measure_timeout_s": 5.0}, 7.0),
        ("CS-2000", {}, 15.0 + 242.0 + 10.0 + 5 * 15.0),
        ("cs2000a", {"timeout_s": 1.0, "measure_timeout_s": 2.0}, 1.0 + 242.0 + 2.0 + 5.0),
    ],
)
def test_the_longest_measurement_covers_every_deadline_of_the_call(
    model: str, options: dict[str, float], longest: float
) -> None:
    assert longest_measure_s(model, **options) == pytest.approx(longest)


def test_a_failed_cancel_does_not_hide_the_timeout(caplog: pytest.LogCaptureFixture) -> None:
    script = [(b"MEAS,1\n", b"OK00,003\n"), (b"MEAS,0\n", None)]
    with (
        caplog.at_level(logging.WARNING),
        connected(script) as instrument,
        pytest.raises(DeviceTimeout, match="waiting for b'\\\\n'"),
    ):
        instrument.measure()
    assert "could not cancel the measurement" in caplog.text


def test_a_value_the_instrument_could_not_calculate_is_an_instrument_error() -> None:
    fields = hex_values(VALUES[300:401])
    fields[5] = "D1BA43B6"
    script = [*MEASURE[:-1], (b"MEDR,1,1,4\n", ("OK00," + ",".join(fields) + "\n").encode())]
    with connected(script) as instrument, pytest.raises(InstrumentError, match="685 nm") as e:
        instrument.measure()
    assert e.value.code == "D1BA43B6"


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda f: f[:-1], "has 100 parameters, expected 101"),
        (lambda f: [*f[:3], "3A7G0000", *f[4:]], "not 8 hex digits"),
        (lambda f: [*f[:3], "7FC00000", *f[4:]], "not finite"),
    ],
)
def test_a_damaged_block_is_a_protocol_error(damage: object, message: str) -> None:
    fields = damage(hex_values(VALUES[300:401]))  # type: ignore[operator]
    script = [*MEASURE[:-1], (b"MEDR,1,1,4\n", ("OK00," + ",".join(fields) + "\n").encode())]
    with connected(script) as instrument, pytest.raises(ProtocolError, match=message):
        instrument.measure()


def test_a_reply_that_is_neither_ok_nor_error_is_a_protocol_error() -> None:
    with connected([(b"SPMR\n", b"XX00,0,2\n")]) as instrument, pytest.raises(ProtocolError):
        instrument.speed_setting()


def test_close_leaves_remote_mode() -> None:
    with connected([(b"RMTS,0\n", b"OK00\n")]) as instrument:
        instrument.close()
        instrument.close()


def test_close_swallows_a_refusal(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING), connected([(b"RMTS,0\n", b"ER00\n")]) as instrument:
        instrument.close()
    assert "could not leave remote mode" in caplog.text


@pytest.mark.parametrize(
    ("options", "message"), [({"model": "CS-100"}, "CS-100"), ({"internal_nd": "half"}, "half")]
)
def test_bad_options_are_refused(options: dict[str, str], message: str) -> None:
    with expected_exchange([]) as link, pytest.raises(ValueError, match=message):
        Cs2000(link, **options)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=message):
        open_cs2000("/dev/null-not-opened", **options)  # type: ignore[arg-type]


# ------------------------------------------------------------------------ against the emulator


def open_fast(
    device: PtySerialDevice, timeout_s: float = REPLY_TIMEOUT_S, **options: str
) -> Cs2000:
    return open_cs2000(
        device.path,
        timeout_s=timeout_s,
        completion_margin_s=0.3,
        **options,  # type: ignore[arg-type]
    )


@pytest.fixture
def bank() -> LampBank:
    return two_lamp_bank()


def test_the_factory_opens_a_cs2000_that_measures_the_lit_lamp(bank: LampBank) -> None:
    bank.set_channel(2, True)
    with start_cs2000(bank.radiance, seed=1, time_scale=TIME_SCALE) as device:
        truth = device.emulator.radiometer.band_radiance()  # type: ignore[attr-defined]
        instrument = open_spectrometer("CS-2000", device.path, timeout_s=1.0, measure_timeout_s=1.0)
        try:
            reading = instrument.measure()
        finally:
            instrument.close()
        assert settled(lambda: not device.emulator.remote)  # type: ignore[attr-defined]
    assert reading.wavelength_nm[np.argmax(reading.values)] == pytest.approx(RED_PEAK_NM, abs=2)
    peak = int(np.argmax(truth))
    assert reading.values[peak] == pytest.approx(truth[peak], rel=0.02)
    assert reading.exposure_ms is not None and 5 <= reading.exposure_ms <= 5000


def test_a_cs2000a_emulator_opens_as_a_cs2000a(bank: LampBank) -> None:
    with start_cs2000(bank.radiance, variation=2, time_scale=TIME_SCALE) as device:
        with open_fast(device, model="CS-2000A") as instrument:
            assert instrument.identify().model == "CS-2000A"
        with pytest.raises(DeviceNotFound):
            open_fast(device, model="CS-2000")


def test_a_manual_exposure_is_used_and_darkness_gives_noise(bank: LampBank) -> None:
    with (
        start_cs2000(bank.radiance, seed=2, time_scale=TIME_SCALE) as device,
        open_fast(device, internal_nd="off") as instrument,
    ):
        instrument.set_exposure(40.0)
        reading = instrument.measure()
    assert reading.exposure_ms == 40.0
    noise = float(np.std(reading.values))
    assert 0 < noise < 1e-4  # far below the lamps' 2e-2
    assert abs(float(np.mean(reading.values))) < noise


def test_a_manual_exposure_that_saturates_is_over_range(bank: LampBank) -> None:
    bank.set_channel(1, True)
    with (
        start_cs2000(bank.radiance, time_scale=TIME_SCALE) as device,
        open_fast(device, internal_nd="off") as instrument,
    ):
        instrument.set_exposure(2000.0)
        with pytest.raises(InstrumentError, match="over range"):
            instrument.measure()


def test_the_emulator_answers_with_the_delimiter_used_and_clears_data_once_read(
    bank: LampBank,
) -> None:
    bank.set_channel(1, True)
    # Slow enough that the measurement is certainly still running when MEDR follows MEAS.
    with start_cs2000(bank.radiance, time_scale=0.5) as device:
        port = serial.Serial(device.path, 115200, rtscts=True, timeout=3.0)
        try:
            port.write(b"IDDR\r")
            assert port.read_until(b"\r") == b"ER00\r"  # not in remote mode yet
            port.write(b"RMTS,2\r\n")
            assert port.read_until(b"\n") == b"OK00\r\n"
            port.write(b"MEAS,1\n")
            assert port.read_until(b"\n").startswith(b"OK00,")
            port.write(b"MEDR,1,1,1\n")
            assert port.read_until(b"\n") == b"ER02\n"  # still measuring
            assert port.read_until(b"\n") == b"OK00\n"  # completion
            for block in (1, 2, 3, 4):
                port.write(f"MEDR,1,0,{block}\n".encode())
                assert port.read_until(b"\n").startswith(b"OK00,")
            port.write(b"MEDR,1,1,1\n")
            assert port.read_until(b"\n") == b"ER20\n"  # measure key enabled: data cleared
        finally:
            port.close()


# -------------------------------------------------------------------------------------- faults


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
@pytest.mark.parametrize(
    ("fault", "match", "expected"),
    [
        (Fault(FaultKind.NO_REPLY), "MEAS,1", DeviceTimeout),
        (Fault(FaultKind.NO_REPLY, part=1), "MEAS,1", DeviceTimeout),
        # Late by far more than the deadline: a loaded machine cannot stall the driver past it.
        (Fault(FaultKind.LATE_REPLY, delay_s=6.0), "MEDR,0", DeviceTimeout),
        (Fault(FaultKind.GARBLED_REPLY, garbled_bytes=6), "MEDR,1,1,2", ProtocolError),
        (Fault(FaultKind.TRUNCATED_REPLY), "MEDR,1,1,4", ReplyTimeout),
        (Fault(FaultKind.ERROR_CODE), "MEAS,1", InstrumentError),
        (Fault(FaultKind.ERROR_CODE, part=1), "MEAS,1", InstrumentError),
        (Fault(FaultKind.ERROR_CODE, code="ER51"), "MEDR,1,1,3", InstrumentError),
        (Fault(FaultKind.BUSY), "MEAS,1", DeviceBusy),
        (Fault(FaultKind.DISCONNECT), "MEDR,1,1,1", Disconnected),
        (Fault(FaultKind.DISCONNECT, part=1), "MEAS,1", Disconnected),
    ],
    ids=lambda value: value if isinstance(value, str) else getattr(value, "__name__", None),
)
def test_every_fault_on_a_measurement_ends_in_its_typed_error(
    bank: LampBank, fault: Fault, match: str, expected: type[DeviceError]
) -> None:
    bank.set_channel(2, True)
    schedule = FaultSchedule.once(fault, match)
    with start_cs2000(bank.radiance, faults=schedule, time_scale=TIME_SCALE) as device:
        instrument = open_fast(device, timeout_s=deadline_for(expected))
        try:
            with pytest.raises(expected) as caught:
                instrument.measure()
        finally:
            instrument.close()
    if isinstance(caught.value, DeviceTimeout):
        # It gave up at a command's deadline or, for the completion, the measurement's time (1 s
        # here) and its margin, which the transport keeps in total (see test_transport), not at a
        # longer one; a hang is ended by the test's own timeout.
        assert caught.value.timeout_s in (
            pytest.approx(instrument.timeout_s),
            pytest.approx(1.0 + instrument.completion_margin_s),
        )


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
def test_a_lost_completion_cancels_the_measurement_on_the_instrument(bank: LampBank) -> None:
    bank.set_channel(2, True)
    schedule = FaultSchedule.once(Fault(FaultKind.NO_REPLY, part=1), "MEAS,1")
    with start_cs2000(bank.radiance, faults=schedule, time_scale=TIME_SCALE) as device:
        with open_fast(device) as instrument:
            with pytest.raises(DeviceTimeout):
                instrument.measure()
            reading = instrument.measure()  # the instrument accepts commands again
        commands = device.emulator.commands  # type: ignore[attr-defined]
    assert commands.index("MEAS,0") == commands.index("MEAS,1") + 1
    assert reading.values.shape == (401,)


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
def test_an_instrument_slow_to_identify_fails_to_open(bank: LampBank) -> None:
    # Late by far more than the deadline: a loaded machine cannot stall the driver past it.
    schedule = FaultSchedule.once(Fault(FaultKind.LATE_REPLY, delay_s=6.0), "IDDR")
    with (
        start_cs2000(bank.radiance, faults=schedule, time_scale=TIME_SCALE) as device,
        pytest.raises(DeviceTimeout),
    ):
        open_fast(device, timeout_s=FAST_TIMEOUT_S)
