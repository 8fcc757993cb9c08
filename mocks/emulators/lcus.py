"""Firmware emulator of an LCUS-type CH340 serial relay board (LCUS-1/2/4/8), device side.

What it implements (facts sheet §2.2):

- switching frames of four bytes ``A0 <channel> <state> <checksum>``, channel from 1, state 00 off /
  01 on, checksum = low byte of the sum of the first three; a frame with a bad checksum, channel or
  state is ignored, as the boards do; switching frames get no reply;
- the status query, the single byte ``FF``, answered by one fixed-length line per channel,
  ``CH1: ON \\r\\n`` / ``CH2: OFF\\r\\n`` (boards built with ``answers_status=False`` stay silent, like
  many single-channel boards);
- any other byte between frames is dropped (the receiver resynchronises on ``A0`` / ``FF``).

Switching a channel switches it on the :class:`mocks.lamps.LampBank` (when one is given), so the
spectrometer emulators see the lamp.

Fault labels: ``"on <n>"``, ``"off <n>"``, ``"status"``. ``ERROR_CODE`` on a switch leaves the relay
as it was (a stuck contact), which the driver's read-back catches. ``BUSY`` is not supported (the
board has no way to say it).
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

from mocks.emulators.serial_base import EmulatorBase, ReplyPart
from mocks.faults import FaultKind, FaultSchedule
from mocks.lamps import LampBank
from mocks.pty_serial import PtySerialDevice

FRAME_START = 0xA0
STATUS_QUERY = 0xFF
FRAME_LENGTH = 4


class LcusEmulator(EmulatorBase):
    """An LCUS board with ``channels`` relays.

    Parameters
    ----------
    channels
        Number of relays (1, 2, 4 or 8 on real boards).
    bank
        Lamps switched by the relays (channels beyond the bank's are relays with nothing on them).
    answers_status
        Whether the board answers the ``FF`` status query.
    faults
        Scheduled misbehaviour.
    """

    SUPPORTED_FAULTS: ClassVar[frozenset[FaultKind]] = frozenset(FaultKind) - {FaultKind.BUSY}

    def __init__(
        self,
        channels: int,
        bank: LampBank | None = None,
        *,
        answers_status: bool = True,
        faults: FaultSchedule | None = None,
    ) -> None:
        if not 1 <= channels <= 8:
            raise ValueError(f"LCUS boards have 1 to 8 channels, got {channels}")
        if bank is not None and bank.n_channels > channels:
            raise ValueError(
                f"the lamp bank uses {bank.n_channels} channels but the board has {channels}"
            )
        super().__init__(f"LCUS-{channels}", faults=faults)
        self.channels = channels
        self.bank = bank
        self.answers_status = answers_status
        self.states = [False] * channels
        self._frame = bytearray()

    def receive(self, data: bytes) -> None:
        for byte in data:
            if not self._frame:
                if byte == STATUS_QUERY:
                    self._status()
                elif byte == FRAME_START:
                    self._frame.append(byte)
                continue
            self._frame.append(byte)
            if len(self._frame) == FRAME_LENGTH:
                frame = bytes(self._frame)
                self._frame.clear()
                self._switch(frame)

    def _switch(self, frame: bytes) -> None:
        _, channel, state, checksum = frame
        if checksum != sum(frame[:3]) & 0xFF or state not in (0, 1):
            return
        if not 1 <= channel <= self.channels:
            return
        fault = self.next_fault(f"{'on' if state else 'off'} {channel}")
        if fault is None or fault.kind is not FaultKind.ERROR_CODE:
            self.states[channel - 1] = bool(state)
            if self.bank is not None and channel <= self.bank.n_channels:
                self.bank.set_channel(channel, bool(state))
        self.deliver([], fault)

    def _status(self) -> None:
        fault = self.next_fault("status")
        if not self.answers_status:
            self.deliver([], fault)
            return
        reply = b"".join(
            f"CH{index}: {'ON ' if on else 'OFF'}\r\n".encode("ascii")
            for index, on in enumerate(self.states, start=1)
        )
        self.deliver([ReplyPart(reply)], fault)


def start_lcus(
    channels: int,
    bank: LampBank | None = None,
    *,
    answers_status: bool = True,
    faults: FaultSchedule | None = None,
    symlink: str | Path | None = None,
) -> PtySerialDevice:
    """Start an LCUS board emulator on a pty; open ``device.path`` with the real driver."""
    emulator = LcusEmulator(channels, bank, answers_status=answers_status, faults=faults)
    return PtySerialDevice(emulator, symlink=symlink).start()
