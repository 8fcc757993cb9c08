"""LCUS relay board driver: exact exchanges, the board against its emulator, every fault."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np
import pytest

from drivers.base import (
    DeviceError,
    DeviceTimeout,
    Disconnected,
    ListTranscript,
    ProtocolError,
    RelayBoard,
    StateMismatch,
)
from drivers.relays.lcus import LcusRelayBoard, encode_switch_frame, open_lcus
from drivers.spectrometer.pr6xx import open_pr6xx
from drivers.transport import NO_PACING, ReplyTimeout
from mocks.emulators import LcusEmulator, start_lcus, start_pr655
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
    two_lamp_bank,
)
from tests.exchange import Exchange, expected_exchange

QUERY = b"\xff"


def status(*states: bool) -> bytes:
    return b"".join(
        f"CH{index}: {'ON ' if on else 'OFF'}\r\n".encode("ascii")
        for index, on in enumerate(states, start=1)
    )


OFF4 = status(False, False, False, False)


def queries(answer: bytes, stale: bytes | None = None) -> list[Exchange]:
    """The driver's status read: the query twice, the second answer counts."""
    return [(QUERY, stale if stale is not None else answer), (QUERY, answer)]


@contextmanager
def board4(script: Sequence[Exchange]) -> Iterator[LcusRelayBoard]:
    """A 4-channel board whose state has been read once (all off)."""
    with expected_exchange([*queries(OFF4), *script]) as link:
        board = LcusRelayBoard(link, 4, port="/dev/ttyUSB0")
        board.state()
        yield board


# ---------------------------------------------------------------------------- exact exchanges


@pytest.mark.parametrize(
    ("channel", "on", "frame"),
    [
        (1, True, "A0 01 01 A2"),
        (1, False, "A0 01 00 A1"),
        (2, True, "A0 02 01 A3"),
        (8, False, "A0 08 00 A8"),
    ],
)
def test_switch_frames_carry_the_checksum(channel: int, on: bool, frame: str) -> None:
    assert encode_switch_frame(channel, on) == bytes.fromhex(frame)


def test_the_second_status_answer_is_the_one_used() -> None:
    stale = status(True, False, False, False)
    with expected_exchange(queries(OFF4, stale)) as link:
        assert LcusRelayBoard(link, 4).state() == (False, False, False, False)


def test_set_switches_and_verifies_the_whole_board() -> None:
    script = [(bytes.fromhex("A0 02 01 A3"), None), *queries(status(False, True, False, False))]
    with board4(script) as board:
        board.set(2, True)
    assert isinstance(board, RelayBoard)
    assert board.identify().model == "LCUS-4" and board.identify().port == "/dev/ttyUSB0"


def test_a_relay_that_does_not_follow_is_a_state_mismatch() -> None:
    with (
        board4([(bytes.fromhex("A0 03 01 A4"), None), *queries(OFF4)]) as board,
        pytest.raises(StateMismatch) as caught,
    ):
        board.set(3, True)
    assert (caught.value.expected, caught.value.actual) == ("0010", "0000")


def test_another_channel_changing_is_also_a_state_mismatch() -> None:
    script = [(bytes.fromhex("A0 01 01 A2"), None), *queries(status(True, False, False, True))]
    with board4(script) as board, pytest.raises(StateMismatch):
        board.set(1, True)


def test_all_off_switches_channel_by_channel_then_verifies() -> None:
    frames: list[Exchange] = [
        (encode_switch_frame(channel, False), None) for channel in (1, 2, 3, 4)
    ]
    with board4([*frames, *queries(OFF4)]) as board:
        board.all_off()


@pytest.mark.parametrize(
    ("answer", "message"),
    [
        (status(False, False, False, False).replace(b"CH3", b"CH4"), "status line 3"),
        (b"CH1: ON \r\nCH2: OFF\r\nCH3: OF\xff\r\nCH4: OFF\r\n", "not printable"),
        (b"CH1: ON \r\nCH2: OFF\r\nCH3: OFF\r\nCH4: MAYBE", "4 CR LF lines"),
    ],
)
def test_a_bad_status_answer_is_a_protocol_error(answer: bytes, message: str) -> None:
    with (
        expected_exchange([(QUERY, answer)]) as link,
        pytest.raises(ProtocolError, match=message),
    ):
        LcusRelayBoard(link, 4).state()


def test_a_malformed_first_answer_is_not_ignored() -> None:
    noisy = OFF4.replace(b"CH2", b"\x92H2")
    with expected_exchange([(QUERY, noisy)]) as link, pytest.raises(ProtocolError):
        LcusRelayBoard(link, 4).state()


def test_a_board_that_does_not_answer_the_status_query_times_out() -> None:
    with expected_exchange([(QUERY, None)]) as link, pytest.raises(ReplyTimeout):
        LcusRelayBoard(link, 4).state()


def test_a_channel_outside_the_board_is_refused_without_sending() -> None:
    with board4([]) as board:
        for channel in (0, 5):
            with pytest.raises(ValueError, match="outside 1–4"):
                board.set(channel, True)


@pytest.mark.parametrize("channels", [0, 9])
def test_impossible_channel_counts_are_refused(channels: int) -> None:
    with expected_exchange([]) as link, pytest.raises(ValueError, match="1–8 channels"):
        LcusRelayBoard(link, channels)
    with pytest.raises(ValueError, match="1–8 channels"):
        open_lcus("/dev/not-opened", channels)


def test_close_closes_the_link() -> None:
    with board4([]) as board:
        board.close()
    assert board._transport.closed  # type: ignore[attr-defined]


# ------------------------------------------------------------------------ against the emulator


@pytest.fixture
def bank() -> LampBank:
    return two_lamp_bank()


def open_fast(device: PtySerialDevice, timeout_s: float = REPLY_TIMEOUT_S) -> LcusRelayBoard:
    return open_lcus(device.path, 4, timeout_s=timeout_s, pacing=NO_PACING)


def test_the_relays_decide_what_the_spectrometer_sees(bank: LampBank) -> None:
    transcript = ListTranscript()
    with (
        start_lcus(4, bank) as relays,
        start_pr655(bank.radiance, seed=4, time_scale=TIME_SCALE) as spectrometer,
    ):
        board = open_lcus(relays.path, 4, transcript=transcript)  # default pacing
        pr = open_pr6xx("PR-655", spectrometer.path, timeout_s=1.0, pacing=NO_PACING)
        try:
            peaks = []
            for channel in (1, 2):
                board.set(channel, True)
                reading = pr.measure()
                peaks.append(reading.wavelength_nm[np.argmax(reading.values)])
                board.set(channel, False)
            assert board.state() == (False, False, False, False)
        finally:
            pr.close()
            board.close()
    assert abs(peaks[0] - BLUE_PEAK_NM) <= 4 and abs(peaks[1] - RED_PEAK_NM) <= 4
    sent = [entry for entry in transcript.entries if entry.direction == "tx"]
    gaps = np.diff([entry.monotonic_s for entry in sent])
    assert gaps.min() >= 0.1 - 1e-3  # frames are paced


def test_the_emulator_ignores_a_frame_with_a_bad_checksum(bank: LampBank) -> None:
    with start_lcus(4, bank) as relays, open_fast(relays) as board:
        board._transport.write(bytes.fromhex("A0 01 01 A3"))
        assert board.state() == (False, False, False, False)
        board.set(2, True)
        assert bank.channel_states() == (False, True, False, False)


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
def test_a_mute_board_is_refused_when_opened(bank: LampBank) -> None:
    with start_lcus(1, answers_status=False) as relays, pytest.raises(DeviceTimeout):
        open_lcus(relays.path, 1, timeout_s=FAST_TIMEOUT_S, pacing=NO_PACING)


# -------------------------------------------------------------------------------------- faults


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
@pytest.mark.parametrize(
    ("fault", "match", "expected"),
    [
        (Fault(FaultKind.NO_REPLY), "status", DeviceTimeout),
        # Late by far more than the deadline: a loaded machine cannot stall the driver past it.
        (Fault(FaultKind.LATE_REPLY, delay_s=6.0), "status", DeviceTimeout),
        (Fault(FaultKind.GARBLED_REPLY), "status", ProtocolError),
        (Fault(FaultKind.TRUNCATED_REPLY), "status", ReplyTimeout),
        (Fault(FaultKind.ERROR_CODE), "on 2", StateMismatch),
        (Fault(FaultKind.DISCONNECT), "on 2", Disconnected),
    ],
    ids=lambda value: value if isinstance(value, str) else getattr(value, "__name__", None),
)
def test_every_fault_on_a_switch_ends_in_its_typed_error(
    bank: LampBank, fault: Fault, match: str, expected: type[DeviceError]
) -> None:
    # The first two status queries are the ones made when the board is opened.
    nth = 3 if match == "status" else 1
    schedule = FaultSchedule.once(fault, match, nth=nth)
    with (
        start_lcus(4, bank, faults=schedule) as relays,
        open_fast(relays, timeout_s=deadline_for(expected)) as board,
        pytest.raises(expected),
    ):
        board.set(2, True)


def test_busy_cannot_be_injected(bank: LampBank) -> None:
    with pytest.raises(ValueError, match="cannot inject BUSY"):
        LcusEmulator(4, bank, faults=FaultSchedule([FaultRule(Fault(FaultKind.BUSY))]))


def test_the_emulator_refuses_a_bank_larger_than_the_board() -> None:
    with pytest.raises(ValueError, match="uses 4 channels but the board has 2"):
        LcusEmulator(2, two_lamp_bank(4))
