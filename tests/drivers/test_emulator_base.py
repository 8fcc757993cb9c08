"""The emulator base: how command lines are split and how faults reach the wire."""

from __future__ import annotations

import pytest

from mocks.emulators.serial_base import EmulatorBase, LineSplitter, ReplyPart
from mocks.faults import Fault, FaultKind, FaultSchedule
from mocks.pty_serial import ScheduledOutput


class RecordingLink:
    """A :class:`mocks.pty_serial.DeviceLink` that records instead of sending."""

    def __init__(self) -> None:
        self.sent: list[tuple[bytes, float]] = []
        self.hang_ups: list[float] = []

    def send(self, data: bytes, *, delay_s: float = 0.0) -> ScheduledOutput:
        self.sent.append((data, delay_s))
        return ScheduledOutput(data, delay_s)

    def hang_up(self, *, delay_s: float = 0.0) -> None:
        self.hang_ups.append(delay_s)


def emulator(fault: Fault | None = None) -> tuple[EmulatorBase, RecordingLink]:
    faults = FaultSchedule.once(fault) if fault is not None else None
    base = EmulatorBase("test", faults=faults)
    link = RecordingLink()
    base.attach(link)
    return base, link


TWO_PARTS = [ReplyPart(b"OK00,003\n", 0.1), ReplyPart(b"OK00\n", 3.1)]


def deliver(fault: Fault | None) -> RecordingLink:
    base, link = emulator(fault)
    base.deliver(TWO_PARTS, base.next_fault("MEAS,1"))
    return link


def test_without_a_fault_every_part_goes_out_on_time() -> None:
    link = deliver(None)
    assert [data for data, _ in link.sent] == [b"OK00,003\n", b"OK00\n"]
    assert [delay for _, delay in link.sent] == pytest.approx([0.1, 3.1], abs=1e-3)


def test_no_reply_on_the_second_part_keeps_the_first() -> None:
    link = deliver(Fault(FaultKind.NO_REPLY, part=1))
    assert [data for data, _ in link.sent] == [b"OK00,003\n"]


def test_a_late_part_delays_the_parts_after_it() -> None:
    link = deliver(Fault(FaultKind.LATE_REPLY, delay_s=2.0))
    assert [delay for _, delay in link.sent] == pytest.approx([2.1, 5.1], abs=1e-3)


def test_truncation_and_disconnect_stop_the_reply() -> None:
    truncated = deliver(Fault(FaultKind.TRUNCATED_REPLY, part=1))
    assert [data for data, _ in truncated.sent] == [b"OK00,003\n", b"OK"]
    assert truncated.hang_ups == []
    dropped = deliver(Fault(FaultKind.DISCONNECT))
    assert [data for data, _ in dropped.sent] == [b"OK00"]
    assert len(dropped.hang_ups) == 1 and dropped.hang_ups[0] > 0.1


def test_a_disconnect_on_a_command_without_reply_still_hangs_up() -> None:
    base, link = emulator(Fault(FaultKind.DISCONNECT))
    base.deliver([], base.next_fault("A0 01 01 A2"))
    assert link.sent == [] and len(link.hang_ups) == 1


def test_garbling_keeps_line_ends() -> None:
    link = deliver(Fault(FaultKind.GARBLED_REPLY, garbled_bytes=3))
    first = link.sent[0][0]
    assert first.endswith(b"\n") and first != b"OK00,003\n" and len(first) == 9
    assert link.sent[1][0] == b"OK00\n"


def test_a_sequential_device_answers_the_next_command_after_the_previous_one() -> None:
    base, link = emulator()
    base.deliver([ReplyPart(b"slow\r\n", 0.5)], None)
    base.deliver([ReplyPart(b"fast\r\n", 0.0)], None)
    assert link.sent[1][1] == pytest.approx(0.5, abs=0.05)


def test_time_scale_must_be_positive() -> None:
    with pytest.raises(ValueError, match="time_scale"):
        EmulatorBase("test", time_scale=0.0)


def test_lines_split_on_cr_lf_and_crlf_even_across_chunks() -> None:
    splitter = LineSplitter()
    lines = list(splitter.feed(b"RMTS,2\r"))
    lines += list(splitter.feed(b"\nIDDR\nSPMR\r\nMEAS"))
    assert lines == [(b"RMTS,2", b"\r"), (b"IDDR", b"\n"), (b"SPMR", b"\r\n")]
    assert splitter.pending == b"MEAS"
    assert list(splitter.feed(b",1\r")) == [(b"MEAS,1", b"\r")]
