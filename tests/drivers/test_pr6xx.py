"""PR-655 / PR-670 driver: exact exchanges for every command, then the driver against its emulator."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np
import pytest
from numpy.typing import NDArray

from drivers.base import (
    DeviceError,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    InstrumentError,
    ListTranscript,
    ProtocolError,
    Spectrometer,
)
from drivers.spectrometer import MeasurementConditionError, open_spectrometer
from drivers.spectrometer.pr6xx import Pr6xx, open_pr6xx
from drivers.transport import NO_PACING, ReplyTimeout
from mocks.emulators import PR655, PR670, Pr6xxEmulator, start_pr655, start_pr670
from mocks.faults import Fault, FaultKind, FaultRule, FaultSchedule
from mocks.lamps import LampBank
from mocks.pty_serial import PtySerialDevice
from tests.drivers.serial_rig import (
    BLUE_PEAK_NM,
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


def line(text: str) -> bytes:
    return text.encode("ascii") + b"\r\n"


def connect_script(
    model: str = "PR-655", grid: tuple[int, int, int] = (380, 780, 4)
) -> list[Exchange]:
    start, stop, step = grid
    points = (stop - start) // step + 1
    return [
        (b"PHOTO", b"REMOTE MODE\r\n"),
        (b"D110\r", line("00000,65061234")),
        (b"D111\r", line(f"00000,{model}")),
        (b"D114\r", line("00000,1.25")),
        (b"D120\r", line(f"00000,{points},0.00,{start},{stop},{step},256,7,247")),
    ]


def spectrum_reply(
    values: Sequence[float] | NDArray[np.float64], grid: tuple[int, int, int] = (380, 780, 4)
) -> bytes:
    start, stop, step = grid
    lines = [line("00000,0,5.560e+02,1.827e-01,5.147e+01")]
    lines += [
        line(f"{wavelength},{value:.4e}")
        for wavelength, value in zip(range(start, stop + 1, step), values, strict=True)
    ]
    return b"".join(lines)


@contextmanager
def connected(script: Sequence[Exchange], model: str = "PR-655") -> Iterator[Pr6xx]:
    """A connected driver on a scripted link; the rest of the script must be used in the block."""
    with expected_exchange([*connect_script(model), *script]) as link:
        instrument = Pr6xx(link, model=model)
        instrument.connect()
        yield instrument


VALUES = [1e-3 * (index + 1) for index in range(101)]


# ---------------------------------------------------------------------------- exact exchanges


def test_connect_enters_remote_mode_and_reads_identity_and_grid() -> None:
    with expected_exchange(connect_script()) as link:
        instrument = Pr6xx(link, model="PR-655", port="/dev/ttyACM0")
        instrument.connect()
        identity = instrument.identify()  # cached: no second exchange
        grid = instrument.spectral_grid()
    assert (identity.model, identity.serial, identity.firmware) == ("PR-655", "65061234", "1.25")
    assert identity.port == "/dev/ttyACM0" and identity.kind == "spectrometer"
    assert (grid.points, grid.start_nm, grid.stop_nm, grid.step_nm) == (101, 380, 780, 4)
    assert isinstance(instrument, Spectrometer)


def test_measure_reads_the_spectrum_and_the_exposure_used() -> None:
    with connected(
        [(b"M5\r", spectrum_reply(VALUES)), (b"D13\r", line("00000,Normal,250 msec"))]
    ) as instrument:
        reading = instrument.measure()
    np.testing.assert_array_equal(reading.wavelength_nm, np.arange(380, 781, 4))
    np.testing.assert_allclose(reading.values, VALUES, rtol=1e-4)
    assert reading.exposure_ms == 250.0
    assert reading.units == "W/(sr·m²·nm)"
    assert reading.extra["peak_wavelength_nm"] == "556"
    assert reading.extra["integrated_radiance"] == "0.1827"


def test_the_pr670_grid_comes_from_d120() -> None:
    grid = (380, 780, 2)
    script = [
        *connect_script("PR-670", grid),
        (b"M5\r", spectrum_reply(np.linspace(0, 1, 201), grid)),
        (b"D13\r", line("00000,Normal,40 msec")),
    ]
    with expected_exchange(script) as link:
        instrument = Pr6xx(link, model="PR-670")
        instrument.connect()
        reading = instrument.measure()
    assert reading.wavelength_nm.shape == (201,)
    assert reading.wavelength_nm[1] - reading.wavelength_nm[0] == 2.0


def test_last_spectrum_reads_again_without_measuring() -> None:
    with connected(
        [(b"D5\r", spectrum_reply(VALUES)), (b"D13\r", line("00000,Normal,250 msec"))]
    ) as instrument:
        reading = instrument.last_spectrum()
    assert reading.extra["command"] == "D5"
    assert reading.values.shape == (101,)


def test_last_exposure() -> None:
    with connected([(b"D13\r", line("00000,Normal,1250 msec"))]) as instrument:
        assert instrument.last_exposure_ms() == 1250.0


@pytest.mark.parametrize(
    ("exposure_ms", "command"), [(250, b"SE250\r"), (249.6, b"SE250\r"), (None, b"SE0\r")]
)
def test_set_exposure(exposure_ms: float | None, command: bytes) -> None:
    with connected([(command, line("00000"))]) as instrument:
        instrument.set_exposure(exposure_ms)


@pytest.mark.parametrize(("model", "exposure_ms"), [("PR-655", 2), ("PR-655", 6001), ("PR-670", 5)])
def test_an_exposure_outside_the_model_range_is_refused_before_sending(
    model: str, exposure_ms: float
) -> None:
    with (
        connected([], model) as instrument,
        pytest.raises(ValueError, match=f"{model} exposure must be"),
    ):
        instrument.set_exposure(exposure_ms)


def test_an_exposure_the_instrument_refuses_is_an_instrument_error() -> None:
    with (
        connected([(b"SE100\r", line("-1010"))]) as instrument,
        pytest.raises(InstrumentError, match="bad exposure value") as caught,
    ):
        instrument.set_exposure(100)
    assert caught.value.code == "-1010"
    assert caught.value.command == "SE100"


def test_set_averages() -> None:
    with connected([(b"SN5\r", line("00000"))]) as instrument:
        instrument.set_averages(5)
        assert instrument.averages == 5
        with pytest.raises(ValueError, match="1–99"):
            instrument.set_averages(100)


def test_weak_light_is_an_instrument_error_and_no_data_lines_are_awaited() -> None:
    with (
        connected([(b"M5\r", line("-0008"))]) as instrument,
        pytest.raises(InstrumentError, match="weak light") as caught,
    ):
        instrument.measure()
    assert caught.value.code == "-8"
    assert not caught.value.retryable


@pytest.mark.parametrize("code", ["-0001", "-0009", "-0012"])
def test_unstable_light_and_sync_errors_are_retryable(code: str) -> None:
    with (
        connected([(b"M5\r", line(code))]) as instrument,
        pytest.raises(MeasurementConditionError) as caught,
    ):
        instrument.measure()
    assert caught.value.retryable


def test_an_unknown_status_code_is_still_typed() -> None:
    with (
        connected([(b"D13\r", line("-0077"))]) as instrument,
        pytest.raises(InstrumentError, match="unknown status code") as caught,
    ):
        instrument.last_exposure_ms()
    assert caught.value.code == "-77"


def test_a_spectral_line_off_the_grid_is_a_protocol_error() -> None:
    reply = spectrum_reply(VALUES).replace(b"\r\n384,", b"\r\n385,")
    with (
        connected([(b"M5\r", reply)]) as instrument,
        pytest.raises(ProtocolError, match="385 nm, the D120 grid says 384 nm"),
    ):
        instrument.measure()


def test_a_spectrum_cut_short_times_out_with_what_arrived() -> None:
    reply = spectrum_reply(VALUES)[:500]
    with connected([(b"M5\r", reply)]) as instrument, pytest.raises(ReplyTimeout) as caught:
        instrument.measure()
    assert caught.value.received and reply.endswith(caught.value.received)


def test_a_d13_reply_without_an_exposure_is_a_protocol_error() -> None:
    with (
        connected([(b"D13\r", line("00000,0,5.560e+02"))]) as instrument,
        pytest.raises(ProtocolError, match="names no exposure"),
    ):
        instrument.last_exposure_ms()


def test_a_wrong_model_on_the_port_is_device_not_found() -> None:
    with expected_exchange(connect_script("PR-670")[:4]) as link:
        instrument = Pr6xx(link, model="PR-655")
        with pytest.raises(DeviceNotFound, match=r"reports model 'PR-670'.*config says 'PR-655'"):
            instrument.connect()


def test_a_missing_remote_mode_confirmation_is_a_protocol_error() -> None:
    with (
        expected_exchange([(b"PHOTO", b"-1000\r\n")]) as link,
        pytest.raises(ProtocolError, match="did not confirm remote mode"),
    ):
        Pr6xx(link, model="PR-655").enter_remote_mode()


def test_close_leaves_remote_mode_once() -> None:
    with connected([(b"Q", None)]) as instrument:
        instrument.close()
        instrument.close()


def test_close_without_remote_mode_sends_nothing() -> None:
    with expected_exchange([]) as link:
        Pr6xx(link, model="PR-655").close()
    assert link.closed


def test_close_of_a_vanished_instrument_does_not_raise() -> None:
    with connected([]) as instrument:
        instrument._transport.close()  # the port died under the driver
        instrument.close()


def test_an_unknown_model_is_refused() -> None:
    with expected_exchange([]) as link, pytest.raises(ValueError, match="PR-999"):
        Pr6xx(link, model="PR-999")


# ------------------------------------------------------------------------ against the emulator


def open_fast(
    device: PtySerialDevice,
    model: str = "PR-655",
    *,
    measure_timeout_s: float = REPLY_TIMEOUT_S,
    timeout_s: float = REPLY_TIMEOUT_S,
    transcript: ListTranscript | None = None,
) -> Pr6xx:
    """The driver on an emulator, with no pacing (a test expecting a timeout shortens a deadline)."""
    return open_pr6xx(
        model,
        device.path,
        timeout_s=timeout_s,
        measure_timeout_s=measure_timeout_s,
        pacing=NO_PACING,
        transcript=transcript,
    )


@pytest.fixture
def bank() -> LampBank:
    return two_lamp_bank()


def test_the_spectrum_follows_the_lamp_that_is_on(bank: LampBank) -> None:
    transcript = ListTranscript()
    with start_pr655(bank.radiance, seed=1, time_scale=TIME_SCALE) as device:
        # The factory the rig uses, with the real (paced) link.
        instrument = open_spectrometer("pr655", device.path, timeout_s=2.0, transcript=transcript)
        try:
            bank.set_channel(1, True)
            blue = instrument.measure()
            bank.set_channel(1, False)
            bank.set_channel(2, True)
            red = instrument.measure()
        finally:
            instrument.close()
        assert settled(lambda: not device.emulator.remote)  # type: ignore[attr-defined]
    assert abs(blue.wavelength_nm[np.argmax(blue.values)] - BLUE_PEAK_NM) <= 4
    assert abs(red.wavelength_nm[np.argmax(red.values)] - RED_PEAK_NM) <= 4
    assert blue.exposure_ms is not None and blue.exposure_ms > 0
    sent = [entry.payload for entry in transcript.entries if entry.direction == "tx"]
    assert sent[:2] == [b"PHOTO", b"D110\r"] and sent[-1] == b"Q"
    assert sent.count(b"M5\r") == 2


def test_a_pr670_reports_its_own_grid(bank: LampBank) -> None:
    bank.set_channel(2, True)
    with (
        start_pr670(bank.radiance, seed=2, time_scale=TIME_SCALE) as device,
        open_fast(device, "PR-670") as instrument,
    ):
        reading = instrument.measure()
    np.testing.assert_array_equal(reading.wavelength_nm, PR670.wavelength_nm)
    assert reading.wavelength_nm.shape == (201,) != PR655.wavelength_nm.shape


def test_the_measurement_is_close_to_the_truth_with_realistic_noise(bank: LampBank) -> None:
    bank.set_channel(1, True)
    with start_pr655(bank.radiance, seed=3, time_scale=TIME_SCALE) as device:
        truth = device.emulator.radiometer.band_radiance()  # type: ignore[attr-defined]
        with open_fast(device) as instrument:
            first, second = instrument.measure(), instrument.measure()
    peak = int(np.argmax(truth))
    assert first.values[peak] == pytest.approx(truth[peak], rel=0.02)
    assert not np.array_equal(first.values, second.values)  # noise
    relative = np.abs(first.values - second.values)[peak] / truth[peak]
    assert 0 < relative < 0.02


def test_the_same_seed_gives_the_same_measurements(bank: LampBank) -> None:
    bank.set_channel(2, True)
    readings = []
    for _ in range(2):
        with (
            start_pr655(bank.radiance, seed=7, time_scale=TIME_SCALE) as device,
            open_fast(device) as instrument,
        ):
            readings.append(instrument.measure().values)
    np.testing.assert_array_equal(readings[0], readings[1])


def test_darkness_is_weak_light(bank: LampBank) -> None:
    with (
        start_pr655(bank.radiance, time_scale=TIME_SCALE) as device,
        open_fast(device) as instrument,
        pytest.raises(InstrumentError, match="weak light"),
    ):
        instrument.measure()


def test_a_fixed_exposure_that_saturates_is_an_overload(bank: LampBank) -> None:
    bank.set_channel(1, True)
    with (
        start_pr655(bank.radiance, time_scale=TIME_SCALE) as device,
        open_fast(device) as instrument,
    ):
        instrument.set_exposure(6000)
        with pytest.raises(InstrumentError, match="overload"):
            instrument.measure()
        instrument.set_exposure(20)
        assert instrument.measure().exposure_ms == 20.0


# -------------------------------------------------------------------------------------- faults


def start_faulty(bank: LampBank, fault: Fault, match: str, nth: int = 1) -> PtySerialDevice:
    bank.set_channel(1, True)
    schedule = FaultSchedule.once(fault, match, nth=nth)
    return start_pr655(bank.radiance, seed=5, faults=schedule, time_scale=TIME_SCALE)


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
@pytest.mark.parametrize(
    ("fault", "expected"),
    [
        (Fault(FaultKind.NO_REPLY), DeviceTimeout),
        # Late by far more than the deadline: a loaded machine cannot stall the driver past it.
        (Fault(FaultKind.LATE_REPLY, delay_s=6.0), DeviceTimeout),
        (Fault(FaultKind.GARBLED_REPLY, garbled_bytes=5), ProtocolError),
        (Fault(FaultKind.TRUNCATED_REPLY), ReplyTimeout),
        (Fault(FaultKind.ERROR_CODE), InstrumentError),
        (Fault(FaultKind.ERROR_CODE, code="-1"), MeasurementConditionError),
        (Fault(FaultKind.DISCONNECT), Disconnected),
    ],
    ids=lambda value: value.kind.name if isinstance(value, Fault) else value.__name__,
)
def test_every_fault_on_a_measurement_ends_in_its_typed_error(
    bank: LampBank, fault: Fault, expected: type[DeviceError]
) -> None:
    with (
        start_faulty(bank, fault, "M5") as device,
        open_fast(
            device, timeout_s=deadline_for(expected), measure_timeout_s=deadline_for(expected)
        ) as instrument,
        pytest.raises(expected) as caught,
    ):
        instrument.measure()
    if isinstance(caught.value, DeviceTimeout):
        # It gave up at the measurement's deadline, which the transport keeps in total (see
        # test_transport), not a longer one; a hang is ended by the test's own timeout.
        assert caught.value.timeout_s == instrument.measure_timeout_s


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
def test_a_late_reply_is_discarded_and_the_next_measurement_succeeds(bank: LampBank) -> None:
    # The reply comes 1.2 s late, four times the 0.3 s deadline: a loaded machine that stalls the
    # driver past a late reply's arrival would let it read the reply in time.
    late = Fault(FaultKind.LATE_REPLY, delay_s=1.2)
    transcript = ListTranscript()
    with (
        start_faulty(bank, late, "M5") as device,
        open_fast(device, measure_timeout_s=0.3, transcript=transcript) as pr,
    ):
        with pytest.raises(DeviceTimeout):
            pr.measure()
        pr.measure_timeout_s = REPLY_TIMEOUT_S  # the next reply is due
        # The runner backs off before a retry; here the late reply is waited for until it is on the
        # line, so that the next measurement must drop it rather than take it for its own.
        assert settled(lambda: pr._transport._port.in_waiting > 0)  # type: ignore[attr-defined]
        reading = pr.measure()
        # Dropped before the measurement's command, not left for closing to drop.
        events = [entry.payload for entry in transcript.entries if entry.direction == "event"]
    assert any("stale input bytes" in str(event) for event in events)
    assert abs(reading.wavelength_nm[np.argmax(reading.values)] - BLUE_PEAK_NM) <= 4


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
def test_only_the_scheduled_command_fails(bank: LampBank) -> None:
    with start_faulty(bank, Fault(FaultKind.NO_REPLY), "M5", nth=2) as device:
        with open_fast(device) as instrument:
            instrument.measure()
            instrument.measure_timeout_s = FAST_TIMEOUT_S  # this reply never comes
            with pytest.raises(DeviceTimeout):
                instrument.measure()
            instrument.measure_timeout_s = REPLY_TIMEOUT_S
            instrument.measure()
        injected = device.emulator.faults.injected  # type: ignore[attr-defined]
    assert [(fault.label, fault.fault.kind) for fault in injected] == [("M5", FaultKind.NO_REPLY)]


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
def test_an_instrument_that_ignores_photo_fails_to_open_and_releases_the_port(
    bank: LampBank,
) -> None:
    with start_faulty(bank, Fault(FaultKind.NO_REPLY), "PHOTO") as device:
        with pytest.raises(DeviceTimeout):
            open_fast(device, timeout_s=FAST_TIMEOUT_S)
        with open_fast(device) as instrument:  # the port was released: it can be opened again
            assert instrument.identify().model == "PR-655"


def test_busy_cannot_be_injected_into_a_protocol_without_a_busy_reply(bank: LampBank) -> None:
    schedule = FaultSchedule([FaultRule(Fault(FaultKind.BUSY))])
    with pytest.raises(ValueError, match="cannot inject BUSY"):
        Pr6xxEmulator(PR655, bank.radiance, faults=schedule)
