"""LCUS-type CH340 serial relay boards (LCUS-1/2/4/8, "LC Technology"), binary frames.

The protocol (facts sheet ``protocols.md`` §2.2):

- 9600 8N1, no flow control; the board appears as ``ttyUSB*`` (CH340, VID 0x1A86 / PID 0x7523);
- a switch is the four bytes ``A0 <channel> <state> <checksum>`` (channel from 1, state 00 off /
  01 on, checksum = low byte of the sum of the first three), and gets no reply; there is no "all"
  frame, so :meth:`LcusRelayBoard.all_off` switches channel by channel;
- the status query is the single byte ``FF``; the board answers one fixed-length line per channel,
  ``CH1: ON \\r\\n`` or ``CH1: OFF\\r\\n``. The first answer is often stale, so the query is sent
  :data:`STATUS_QUERY_REPEATS` times; every answer must be well formed, the last one is used;
- frames are spaced by :data:`DEFAULT_PACING` (implementations use 50–100 ms).

Every switch is verified by reading the state back (:func:`drivers.relays.verify_relay_state`). A
board that does not answer the status query (many single-channel boards) cannot be verified and is
refused when it is opened.
"""

from __future__ import annotations

import re

from drivers.base import DeviceIdentity, TranscriptSink
from drivers.lifecycle import connect_or_close
from drivers.relays import verify_relay_state
from drivers.relays.serial_board import SerialRelayBoard
from drivers.replies import ReplyContext, decode_ascii
from drivers.transport import ByteTransport, Deadline, Pacing, SerialSettings, open_serial

SERIAL_SETTINGS = SerialSettings(baudrate=9600)
DEFAULT_PACING = Pacing(command_gap_s=0.1)
FRAME_START = 0xA0
STATUS_QUERY = b"\xff"
#: [?] bmrzycki/lcus_relay found the first answer stale and keeps the second.
STATUS_QUERY_REPEATS = 2
#: ``CH1: ON \r\n`` and ``CH1: OFF\r\n`` are both this long ("ON" is padded).
STATUS_LINE_BYTES = 10
DEFAULT_TIMEOUT_S = 1.0
MAX_CHANNELS = 8


def encode_switch_frame(channel: int, on: bool) -> bytes:
    """The four-byte frame switching ``channel`` (from 1) on or off."""
    if not 1 <= channel <= 0xFF:
        raise ValueError(f"LCUS channel must be 1–255, got {channel}")
    head = bytes([FRAME_START, channel, 1 if on else 0])
    return head + bytes([sum(head) & 0xFF])


def parse_status(reply: bytes, channels: int, context: ReplyContext) -> tuple[bool, ...]:
    """Channel states (channel 1 first) from a status answer of ``channels`` lines.

    Raises
    ------
    ProtocolError
        Not ASCII, a line that is not ``CHn: ON`` / ``CHn: OFF``, or channels out of order.
    """
    text = decode_ascii(reply, context)
    lines = text.split("\r\n")
    if lines[-1] != "" or len(lines) != channels + 1:
        raise context.error(f"status answer should be {channels} CR LF lines", reply)
    states = []
    for expected, line in enumerate(lines[:-1], start=1):
        match = re.fullmatch(r"CH(\d+): (ON |OFF)", line)
        if match is None or int(match.group(1)) != expected:
            raise context.error(
                f"status line {expected} is {line!r}, expected 'CH{expected}: …'", reply
            )
        states.append(match.group(2) == "ON ")
    return tuple(states)


class LcusRelayBoard(SerialRelayBoard):
    """An LCUS board; implements :class:`drivers.base.RelayBoard`.

    Parameters
    ----------
    transport
        The byte link to the board.
    channels
        Number of relays (1–8).
    timeout_s
        Deadline of each status answer.
    port
        Where the board is connected (reported in its identity).
    """

    def __init__(
        self,
        transport: ByteTransport,
        channels: int,
        *,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        port: str | None = None,
    ) -> None:
        if not 1 <= channels <= MAX_CHANNELS:
            raise ValueError(f"LCUS boards have 1–{MAX_CHANNELS} channels, got {channels}")
        super().__init__(transport, channels, timeout_s=timeout_s, port=port)

    def identify(self) -> DeviceIdentity:
        """The board reports nothing about itself; this is what the config says it is."""
        return DeviceIdentity(kind="relay", model=f"LCUS-{self._channels}", port=self.port)

    def state(self) -> tuple[bool, ...]:
        """Channel states as the board reports them (channel 1 first)."""
        self._transport.discard_input()
        context = ReplyContext(self.device, STATUS_QUERY)
        for _ in range(STATUS_QUERY_REPEATS):
            self._transport.write(STATUS_QUERY)
            reply = self._transport.read_exact(
                STATUS_LINE_BYTES * self._channels, deadline=Deadline(self.timeout_s)
            )
            # Every answer must be well formed (line noise shows here); the last one counts.
            self._known = parse_status(reply, self._channels, context)
        assert self._known is not None
        return self._known

    def _switch(self, channel: int, on: bool) -> None:
        self._transport.write(encode_switch_frame(channel, on))

    def all_off(self) -> None:
        """Switch every channel off (one frame each) and verify."""
        for channel in range(1, self._channels + 1):
            self._transport.write(encode_switch_frame(channel, False))
        verify_relay_state(self.device, [False] * self._channels, self.state())


def open_lcus(
    port: str,
    channels: int,
    *,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    transcript: TranscriptSink | None = None,
    pacing: Pacing = DEFAULT_PACING,
    baud: int | None = None,
) -> LcusRelayBoard:
    """Open an LCUS board with ``channels`` relays on ``port`` and read its state.

    ``baud`` overrides the line speed of :data:`SERIAL_SETTINGS`.

    Raises
    ------
    DeviceNotFound
        No such port.
    DeviceTimeout
        The board does not answer the status query (then its switching cannot be verified).
    """
    if not 1 <= channels <= MAX_CHANNELS:
        raise ValueError(f"LCUS boards have 1–{MAX_CHANNELS} channels, got {channels}")
    transport = open_serial(
        port,
        SERIAL_SETTINGS.with_baud(baud),
        device=f"LCUS-{channels} relay board on {port}",
        transcript=transcript,
        pacing=pacing,
    )
    board = LcusRelayBoard(transport, channels, timeout_s=timeout_s, port=port)
    return connect_or_close(board, board.state)
