"""Numato relay module driver: exact exchanges, the module against its emulator, every fault."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import pytest
import serial

from drivers.base import (
    DeviceError,
    DeviceTimeout,
    Disconnected,
    ProtocolError,
    RelayBoard,
    StateMismatch,
)
from drivers.relays.numato import NumatoRelayBoard, mask_digits, open_numato, relay_character
from drivers.transport import ReplyTimeout
from mocks.emulators import NumatoEmulator, start_numato
from mocks.faults import Fault, FaultKind, FaultRule, FaultSchedule
from mocks.lamps import LampBank
from mocks.pty_serial import PtySerialDevice
from tests.drivers.serial_rig import (
    FAST_TIMEOUT_S,
    FAULT_TEST_TIMEOUT_S,
    REPLY_TIMEOUT_S,
    deadline_for,
    two_lamp_bank,
)
from tests.exchange import Exchange, expected_exchange


def answer(command: str, *result: str, end: str = "\n\r") -> bytes:
    """Echo, result lines and prompt, as the module prints them."""
    return (command + end + "".join(line + end for line in result) + ">").encode("ascii")


def exchange(command: str, *result: str, end: str = "\n\r") -> Exchange:
    return (command.encode("ascii") + b"\r", answer(command, *result, end=end))


RESYNC: Exchange = (b"\r", b"\n\r>")


def opening(channels: int = 8, mask: str = "00") -> list[Exchange]:
    return [
        RESYNC,
        exchange("ver", "00000008"),
        exchange("id get", "0000ABCD"),
        exchange("relay readall", mask) if channels > 1 else exchange("relay read 0", "off"),
    ]


@contextmanager
def module(script: Sequence[Exchange], channels: int = 8) -> Iterator[NumatoRelayBoard]:
    """An opened module (resynchronised, identified, state read) on a scripted link."""
    with expected_exchange([*opening(channels, "0" * mask_digits(channels)), *script]) as link:
        board = NumatoRelayBoard(link, channels, port="/dev/ttyACM2")
        board.resync()
        board.identify()
        board.state()
        yield board


# ---------------------------------------------------------------------------- exact exchanges


def test_opening_resynchronises_and_identifies() -> None:
    with module([]) as board:
        identity = board.identify()
    assert (identity.serial, identity.firmware, identity.port) == (
        "0000ABCD",
        "00000008",
        "/dev/ttyACM2",
    )
    assert identity.kind == "relay"
    assert isinstance(board, RelayBoard)


def test_set_switches_relay_n_minus_one_and_verifies() -> None:
    with module([exchange("relay on 2"), exchange("relay readall", "04")]) as board:
        board.set(3, True)


def test_line_end_order_does_not_matter() -> None:
    script = [exchange("relay on 0", end="\r\n"), exchange("relay readall", "01", end="\r\n")]
    with module(script) as board:
        board.set(1, True)


def test_sixteen_relays_use_letters_and_four_hex_digits() -> None:
    script = [exchange("relay on A"), exchange("relay readall", "0400")]
    with module(script, channels=16) as board:
        board.set(11, True)
    assert relay_character(16) == "F" and mask_digits(16) == 4 and mask_digits(4) == 2


def test_a_relay_that_does_not_follow_is_a_state_mismatch() -> None:
    with (
        module([exchange("relay on 1"), exchange("relay readall", "00")]) as board,
        pytest.raises(StateMismatch) as caught,
    ):
        board.set(2, True)
    assert caught.value.expected == "01000000"


def test_all_off_writes_all_relays_at_once() -> None:
    with module([exchange("relay writeall 00"), exchange("relay readall", "00")]) as board:
        board.all_off()


def test_a_one_relay_module_reads_its_relay_directly() -> None:
    script = [
        exchange("relay on 0"),
        exchange("relay read 0", "on"),
        exchange("relay off 0"),
        exchange("relay read 0", "off"),
    ]
    with module(script, channels=1) as board:
        board.set(1, True)
        board.all_off()


def test_read_channel() -> None:
    with module([exchange("relay read 7", "on")]) as board:
        assert board.read_channel(8) is True


def test_a_wrong_echo_is_a_protocol_error_and_the_next_command_resynchronises() -> None:
    script = [
        (b"relay on 0\r", answer("relay on 9")),
        RESYNC,
        exchange("relay readall", "00"),
    ]
    with module(script) as board:
        with pytest.raises(ProtocolError, match="did not echo 'relay on 0'"):
            board.set(1, True)
        assert board.state() == (False,) * 8


def test_a_timeout_resynchronises_before_the_next_command() -> None:
    script = [(b"relay on 0\r", b"relay on 0\n\r"), RESYNC, exchange("relay readall", "01")]
    with module(script) as board:
        with pytest.raises(ReplyTimeout) as caught:
            board.set(1, True)
        assert caught.value.received == b"relay on 0\n\r"
        assert board.state()[0] is True


@pytest.mark.parametrize(
    ("mask", "message"), [("0", "2 hex digits"), ("zz", "2 hex digits"), ("1FF", "2 hex digits")]
)
def test_a_bad_readall_answer_is_a_protocol_error(mask: str, message: str) -> None:
    with (
        module([exchange("relay readall", mask)]) as board,
        pytest.raises(ProtocolError, match=message),
    ):
        board.state()


def test_bits_beyond_the_module_are_a_protocol_error() -> None:
    with (
        module([exchange("relay readall", "10")], channels=4) as board,
        pytest.raises(ProtocolError, match="beyond the 4"),
    ):
        board.state()


def test_a_switch_answered_with_a_result_is_a_protocol_error() -> None:
    with (
        module([exchange("relay on 0", "error")]) as board,
        pytest.raises(ProtocolError, match="result line"),
    ):
        board.set(1, True)


def test_a_garbled_answer_is_a_protocol_error() -> None:
    noisy = answer("relay readall", "00").replace(b"readall", b"rea\xe4all")
    with (
        module([(b"relay readall\r", noisy)]) as board,
        pytest.raises(ProtocolError, match="not printable"),
    ):
        board.state()


def test_bad_channels_are_refused_without_sending() -> None:
    with module([]) as board:
        for channel in (0, 9):
            with pytest.raises(ValueError, match="outside 1–8"):
                board.set(channel, True)
    with expected_exchange([]) as link, pytest.raises(ValueError, match="relays, got 3"):
        NumatoRelayBoard(link, 3)
    with pytest.raises(ValueError, match="relays, got 3"):
        open_numato("/dev/not-opened", 3)


# ------------------------------------------------------------------------ against the emulator


@pytest.fixture
def bank() -> LampBank:
    return two_lamp_bank(8)


def open_fast(
    device: PtySerialDevice, channels: int = 8, timeout_s: float = REPLY_TIMEOUT_S
) -> NumatoRelayBoard:
    return open_numato(device.path, channels, timeout_s=timeout_s)


def test_the_module_switches_the_lamps(bank: LampBank) -> None:
    with start_numato(8, bank) as device, open_fast(device) as board:
        assert board.identify().firmware == "00000008"
        board.set(2, True)
        assert bank.channel_states()[:3] == (False, True, False)
        board.set(1, True)
        board.all_off()
        assert bank.channel_states() == (False,) * 8


def test_a_half_typed_command_is_flushed_on_open(bank: LampBank) -> None:
    with start_numato(8, bank) as device:
        port = serial.Serial(device.path, timeout=0.2)
        port.write(b"relay on")  # a previous program died mid-command
        port.close()
        with open_fast(device) as board:
            assert board.state() == (False,) * 8


def test_a_one_relay_module(bank: LampBank) -> None:
    with start_numato(1) as device, open_fast(device, channels=1) as board:
        board.set(1, True)
        assert board.state() == (True,)
        board.all_off()


# -------------------------------------------------------------------------------------- faults


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
@pytest.mark.parametrize(
    ("fault", "match", "nth", "expected"),
    [
        (Fault(FaultKind.NO_REPLY), "relay on", 1, DeviceTimeout),
        # Late by far more than the deadline: a loaded machine cannot stall the driver past it.
        (Fault(FaultKind.LATE_REPLY, delay_s=6.0), "relay readall", 2, DeviceTimeout),
        (Fault(FaultKind.GARBLED_REPLY), "relay readall", 2, ProtocolError),
        (Fault(FaultKind.TRUNCATED_REPLY), "relay readall", 2, ReplyTimeout),
        (Fault(FaultKind.ERROR_CODE), "relay on", 1, StateMismatch),
        (Fault(FaultKind.DISCONNECT), "relay on", 1, Disconnected),
    ],
    ids=lambda value: value if isinstance(value, str) else getattr(value, "__name__", None),
)
def test_every_fault_on_a_switch_ends_in_its_typed_error(
    bank: LampBank, fault: Fault, match: str, nth: int, expected: type[DeviceError]
) -> None:
    schedule = FaultSchedule.once(fault, match, nth=nth)
    with (
        start_numato(8, bank, faults=schedule) as device,
        open_fast(device, timeout_s=deadline_for(expected)) as board,
        pytest.raises(expected),
    ):
        board.set(1, True)


@pytest.mark.timeout(FAULT_TEST_TIMEOUT_S)
def test_the_module_recovers_after_a_lost_reply(bank: LampBank) -> None:
    schedule = FaultSchedule.once(Fault(FaultKind.NO_REPLY), "relay on")
    with start_numato(8, bank, faults=schedule) as device, open_fast(device) as board:
        board.timeout_s = FAST_TIMEOUT_S  # this reply never comes
        with pytest.raises(DeviceTimeout):
            board.set(1, True)
        board.timeout_s = REPLY_TIMEOUT_S
        assert board.state()[0] is True  # the command was executed, only its reply was lost
        board.set(1, False)
        assert bank.channel_states()[0] is False


def test_busy_cannot_be_injected(bank: LampBank) -> None:
    with pytest.raises(ValueError, match="cannot inject BUSY"):
        NumatoEmulator(8, bank, faults=FaultSchedule([FaultRule(Fault(FaultKind.BUSY))]))
