"""The serial transport: deadlines, no silent short reads, pacing, error mapping, transcript."""

from __future__ import annotations

import math
import os
import termios
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from drivers.base import (
    DeviceBusy,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    ListTranscript,
    ProtocolError,
)
from drivers.transport import (
    ByteTransport,
    Deadline,
    Pacing,
    ReplyTimeout,
    SerialSettings,
    SerialTransport,
    ask,
    open_serial,
)
from mocks.pty_serial import DeviceLink, PtySerialDevice

SHORT = 0.05


@pytest.fixture
def transcript() -> ListTranscript:
    return ListTranscript()


@pytest.fixture
def loop(transcript: ListTranscript) -> Iterator[SerialTransport]:
    """A transport on pyserial's ``loop://`` (what is written can be read back)."""
    transport = open_serial("loop://", SerialSettings(), device="loop", transcript=transcript)
    yield transport
    transport.close()


class FakePort:
    """A :class:`drivers.transport.SerialPort` stand-in that records writes and can fail."""

    def __init__(self, incoming: bytes = b"") -> None:
        self.port: str | None = "fake0"
        self.timeout: float | None = None
        self.write_timeout: float | None = 1.0
        self.buffer = bytearray(incoming)
        self.writes: list[bytes] = []
        self.flushes = 0
        self.read_error: Exception | None = None
        self.write_error: Exception | None = None
        self.closed = False

    @property
    def in_waiting(self) -> int:
        return len(self.buffer)

    def read(self, size: int = 1) -> bytes:
        if self.read_error is not None:
            raise self.read_error
        if not self.buffer:
            time.sleep(min(self.timeout or 0.0, 0.01))
        chunk = bytes(self.buffer[:size])
        del self.buffer[:size]
        return chunk

    def write(self, data: bytes, /) -> int:
        if self.write_error is not None:
            raise self.write_error
        self.writes.append(bytes(data))
        return len(data)

    def flush(self) -> None:
        self.flushes += 1

    def reset_input_buffer(self) -> None:
        self.buffer.clear()

    def close(self) -> None:
        self.closed = True


class FakeTime:
    """A clock that only moves when ``sleep`` is called."""

    def __init__(self) -> None:
        self.now_s = 100.0
        self.sleeps: list[float] = []

    def clock(self) -> float:
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now_s += seconds


def test_the_serial_transport_is_a_byte_transport(loop: SerialTransport) -> None:
    assert isinstance(loop, ByteTransport)


def test_round_trip_is_recorded_in_the_transcript(
    loop: SerialTransport, transcript: ListTranscript
) -> None:
    loop.write(b"D111\r\n")
    assert loop.read_until(b"\r\n", deadline=Deadline(1.0)) == b"D111\r\n"
    directions = [(entry.direction, entry.payload) for entry in transcript.entries]
    assert directions[0][0] == "event" and b"loop://" in directions[0][1]
    assert directions[1:] == [("tx", b"D111\r\n"), ("rx", b"D111\r\n")]
    times = [entry.monotonic_s for entry in transcript.entries]
    assert times == sorted(times)
    assert {entry.device for entry in transcript.entries} == {"loop"}


def test_bytes_after_the_terminator_wait_for_the_next_read(loop: SerialTransport) -> None:
    loop.write(b"OK00,003\nOK00\n")
    assert loop.read_until(b"\n", deadline=Deadline(1.0)) == b"OK00,003\n"
    assert loop.read_until(b"\n", deadline=Deadline(1.0)) == b"OK00\n"


def test_an_incomplete_reply_raises_with_the_partial_bytes(
    loop: SerialTransport, transcript: ListTranscript
) -> None:
    loop.write(b"00000,PR-6")
    with pytest.raises(ReplyTimeout) as caught:
        loop.read_until(b"\r\n", deadline=Deadline(SHORT))
    assert caught.value.received == b"00000,PR-6"
    assert caught.value.command == b"00000,PR-6"
    assert caught.value.timeout_s == SHORT
    assert isinstance(caught.value, DeviceTimeout) and caught.value.retryable
    assert "00000,PR-6" in str(caught.value)
    assert ("rx", b"00000,PR-6") in [(e.direction, e.payload) for e in transcript.entries]
    assert b"timeout" in transcript.entries[-1].payload
    # The partial bytes were consumed by the error: nothing stale is left behind.
    loop.write(b"next\r\n")
    assert loop.read_until(b"\r\n", deadline=Deadline(1.0)) == b"next\r\n"


def test_a_silent_device_times_out_with_nothing_received(loop: SerialTransport) -> None:
    with pytest.raises(ReplyTimeout) as caught:
        loop.read_until(b"\n", deadline=Deadline(SHORT))
    assert caught.value.received == b""
    assert "nothing received" in str(caught.value)


def test_read_exact_returns_exactly_the_size_or_raises(loop: SerialTransport) -> None:
    loop.write(b"\x01\x02\x03")
    assert loop.read_exact(2, deadline=Deadline(1.0)) == b"\x01\x02"
    with pytest.raises(ReplyTimeout) as caught:
        loop.read_exact(2, deadline=Deadline(SHORT))
    assert caught.value.received == b"\x03"


def test_a_reply_without_terminator_beyond_the_limit_is_a_protocol_error(
    loop: SerialTransport,
) -> None:
    loop.write(b"x" * 64)
    with pytest.raises(ProtocolError, match="exceeds 16 bytes"):
        loop.read_until(b"\n", deadline=Deadline(1.0), max_bytes=16)


def test_discard_input_drops_stale_bytes_and_records_them(
    loop: SerialTransport, transcript: ListTranscript
) -> None:
    loop.write(b"late reply\r\n")  # loop:// has it to read at once
    assert loop.discard_input() == b"late reply\r\n"
    assert b"discarded 12 stale input bytes" in transcript.entries[-1].payload
    assert loop.discard_input() == b""


def test_ask_drops_stale_input_before_sending(loop: SerialTransport) -> None:
    loop.write(b"stale\n")
    assert ask(loop, b"fresh\n", terminator=b"\n", deadline=Deadline(1.0)) == b"fresh\n"


def test_pacing_writes_one_character_at_a_time_and_spaces_commands() -> None:
    port = FakePort()
    fake_time = FakeTime()
    transcript = ListTranscript()
    transport = SerialTransport(
        port,
        device="paced",
        transcript=transcript,
        pacing=Pacing(char_delay_s=0.01, command_gap_s=0.05),
        clock=fake_time.clock,
        sleep=fake_time.sleep,
    )
    transport.write(b"M5\r")
    assert port.writes == [b"M", b"5", b"\r"]
    assert port.flushes == 3
    assert fake_time.sleeps == [0.01, 0.01, 0.01]
    transport.write(b"Q")
    assert fake_time.sleeps[3] == pytest.approx(0.05)
    assert port.writes[-1] == b"Q"
    # The transcript has one entry per command, not per paced character.
    assert [e.payload for e in transcript.entries if e.direction == "tx"] == [b"M5\r", b"Q"]


def test_no_gap_is_added_when_the_commands_are_already_far_apart() -> None:
    port = FakePort()
    fake_time = FakeTime()
    transport = SerialTransport(
        port,
        device="paced",
        pacing=Pacing(command_gap_s=0.05),
        clock=fake_time.clock,
        sleep=fake_time.sleep,
    )
    transport.write(b"\xff")
    fake_time.now_s += 1.0
    transport.write(b"\xff")
    assert fake_time.sleeps == []
    assert port.writes == [b"\xff", b"\xff"]


def test_negative_pacing_is_refused() -> None:
    with pytest.raises(ValueError, match=">= 0"):
        Pacing(char_delay_s=-0.01)


def test_a_write_that_flow_control_holds_off_is_a_timeout() -> None:
    port = FakePort()
    port.write_error = serial.SerialTimeoutException("Write timeout")
    transport = SerialTransport(port, device="held off")
    with pytest.raises(DeviceTimeout, match="flow control") as caught:
        transport.write(b"MEAS,1\n")
    assert not isinstance(caught.value, ReplyTimeout)
    assert caught.value.command == b"MEAS,1\n"


@pytest.mark.parametrize(
    "error", [serial.SerialException("device reports readiness"), OSError(5, "EIO")]
)
def test_a_failing_read_is_a_disconnect_and_the_transport_stays_broken(error: Exception) -> None:
    port = FakePort()
    port.read_error = error
    transport = SerialTransport(port, device="flaky")
    with pytest.raises(Disconnected, match="during read") as caught:
        transport.read_until(b"\n", deadline=Deadline(1.0))
    with pytest.raises(Disconnected) as again:
        transport.write(b"x")
    assert again.value is caught.value
    assert port.writes == []


def test_a_failing_write_is_a_disconnect() -> None:
    port = FakePort()
    port.write_error = OSError(19, "No such device")
    transport = SerialTransport(port, device="gone")
    with pytest.raises(Disconnected, match="during write"):
        transport.write(b"x")


def test_a_flush_failing_with_a_termios_error_is_a_disconnect() -> None:
    class VanishedTty(FakePort):
        def flush(self) -> None:
            raise termios.error(5, "Input/output error")

    with pytest.raises(Disconnected, match="Input/output error"):
        SerialTransport(VanishedTty(), device="vanished").write(b"\xa0\x02\x01\xa3")


def test_close_is_idempotent_and_later_use_is_an_error(
    loop: SerialTransport, transcript: ListTranscript
) -> None:
    loop.close()
    loop.close()
    assert [e.payload for e in transcript.entries].count(b"closed loop://") == 1
    with pytest.raises(Disconnected, match="closed"):
        loop.write(b"x")
    with pytest.raises(Disconnected, match="closed"):
        loop.read_until(b"\n", deadline=Deadline(1.0))


def test_close_of_a_port_that_fails_to_close_does_not_raise() -> None:
    class BadClose(FakePort):
        def close(self) -> None:
            raise OSError(5, "EIO")

    transcript = ListTranscript()
    SerialTransport(BadClose(), device="bad", transcript=transcript).close()
    assert b"close failed" in transcript.entries[0].payload


def test_opening_a_missing_port_says_which_and_what_to_do(tmp_path: Path) -> None:
    missing = str(tmp_path / "ttyACM9")
    with pytest.raises(DeviceNotFound, match=r"ttyACM9.*does not exist.*rig devices"):
        open_serial(missing, SerialSettings(), device="PR-655 on ttyACM9")


def test_opening_a_bad_url_is_device_not_found() -> None:
    with pytest.raises(DeviceNotFound, match="cannot open serial port"):
        open_serial("nosuchscheme://x", SerialSettings(), device="bad url")


def test_a_port_held_by_another_program_is_busy() -> None:
    master, slave = os.openpty()
    tty.setraw(master)
    path = os.ttyname(slave)
    try:
        first = open_serial(path, SerialSettings(), device="first")
        try:
            with pytest.raises(DeviceBusy, match="in use"):
                open_serial(path, SerialSettings(), device="second")
        finally:
            first.close()
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("timeout_s", [-1.0, math.inf, math.nan])
def test_a_deadline_needs_a_finite_non_negative_timeout(timeout_s: float) -> None:
    with pytest.raises(ValueError, match="finite timeout"):
        Deadline(timeout_s)


def test_a_deadline_counts_down_to_zero() -> None:
    fake_time = FakeTime()
    deadline = Deadline(2.0, clock=fake_time.clock)
    assert deadline.remaining_s() == 2.0 and not deadline.expired()
    fake_time.sleep(1.5)
    assert deadline.remaining_s() == pytest.approx(0.5)
    fake_time.sleep(1.0)
    assert deadline.remaining_s() == 0.0 and deadline.expired()


class _Trickle:
    """An emulator that answers anything with one byte every 0.1 s for 4 s, never a line end."""

    name = "trickle"
    length = 40

    def attach(self, link: DeviceLink) -> None:
        self.link = link

    def receive(self, data: bytes) -> None:
        for index in range(self.length):
            self.link.send(b"x", delay_s=0.1 * index)


class _Silent:
    name = "silent"

    def attach(self, link: DeviceLink) -> None:
        pass

    def receive(self, data: bytes) -> None:
        pass


def test_the_deadline_is_total_even_while_bytes_keep_trickling_in() -> None:
    with PtySerialDevice(_Trickle()) as device:
        transport = open_serial(device.path, SerialSettings(), device="trickle")
        try:
            transport.write(b"go\r")
            # The first byte is due at once: waited for without a tight deadline.
            assert transport.read_exact(1, deadline=Deadline(10.0)) == b"x"
            with pytest.raises(ReplyTimeout) as caught:
                transport.read_until(b"\r", deadline=Deadline(0.2))
        finally:
            transport.close()
    assert caught.value.timeout_s == 0.2
    # One total deadline, not one per byte (pyserial readline): the read ended long before the
    # trickle did (a per-byte deadline reads every byte, each 0.1 s after the last).
    assert len(caught.value.received) < _Trickle.length - 1


def test_a_device_unplugged_during_a_read_is_a_disconnect() -> None:
    with PtySerialDevice(_Silent()) as device:
        transport = open_serial(device.path, SerialSettings(), device="unplugged")
        timer = threading.Timer(0.05, device.unplug)
        timer.start()
        try:
            with pytest.raises(Disconnected):
                transport.read_until(b"\n", deadline=Deadline(2.0))
        finally:
            timer.join()
            transport.close()
