"""Numato Lab USB relay modules: an ASCII command line over USB CDC-ACM (``ttyACM*``, VID 0x2A19).

The protocol (facts sheet ``protocols.md`` §2.3):

- commands are plain words ending with CR (:data:`COMMAND_TERMINATOR`); the module echoes what it
  receives, then prints any result line, then the prompt ``>``. The reader takes everything up to the
  prompt, checks and drops the echo, and splits the rest into lines on CR and LF in any order (the
  sources disagree on ``\\n\\r`` versus ``\\r\\n``);
- before the first command a bare CR is sent and the answer read up to ``>``, flushing any half-typed
  line; the same resynchronisation follows any timeout or garbled reply;
- relays are numbered from 0 with one character (``0``–``9``, then ``A``, ``B`` …), so rig channel
  ``c`` (from 1) is Numato relay ``c - 1``;
- ``relay on N`` / ``relay off N`` switch (no result line), ``relay readall`` returns the state as a
  hex bitmask (relay 0 in the lowest bit), ``relay writeall HH`` sets all relays at once, ``relay
  read N`` returns ``on``/``off``, ``ver`` and ``id get`` identify the module.

Every switch is verified by reading the state back (:func:`drivers.relays.verify_relay_state`).
"""

from __future__ import annotations

import re

from drivers.base import DeviceIdentity, DeviceTimeout, ProtocolError, TranscriptSink
from drivers.lifecycle import connect_or_close
from drivers.relays import verify_relay_state
from drivers.relays.serial_board import SerialRelayBoard
from drivers.replies import ReplyContext, decode_ascii
from drivers.transport import ByteTransport, Deadline, SerialSettings, ask, open_serial

#: The baud value is nominal on CDC-ACM; libraries use 9600, 19200 or 921600.
SERIAL_SETTINGS = SerialSettings(baudrate=19200)
COMMAND_TERMINATOR = b"\r"
PROMPT = b">"
DEFAULT_TIMEOUT_S = 1.0
CHANNEL_COUNTS = (1, 2, 4, 8, 16, 32)
_RELAY_CHARACTERS = "0123456789ABCDEFGHIJKLMNOPQRSTUV"


def relay_character(channel: int) -> str:
    """The one-character Numato relay number of rig channel ``channel`` (from 1)."""
    if not 1 <= channel <= len(_RELAY_CHARACTERS):
        raise ValueError(f"Numato channel must be 1–{len(_RELAY_CHARACTERS)}, got {channel}")
    return _RELAY_CHARACTERS[channel - 1]


def mask_digits(channels: int) -> int:
    """Hex digits of the ``readall``/``writeall`` bitmask (two per 8 relays, at least two)."""
    return max(2, channels // 4)


def parse_reply(reply: bytes, command: str, context: ReplyContext) -> list[str]:
    """The result lines of ``reply`` (everything up to and including ``>``) to ``command``.

    Raises
    ------
    ProtocolError
        Not ASCII, no prompt at the end, or an echo that is not the command sent.
    """
    text = decode_ascii(reply, context)
    if not text.endswith(">"):
        raise context.error("reply does not end with the '>' prompt", reply)
    lines = [line for line in re.split(r"[\r\n]+", text[:-1]) if line.strip()]
    if command:
        if not lines or lines[0].strip() != command:
            raise context.error(f"the module did not echo {command!r}", reply)
        lines = lines[1:]
    return [line.strip() for line in lines]


def parse_mask(lines: list[str], channels: int, context: ReplyContext) -> tuple[bool, ...]:
    """Relay states (channel 1 first) from the result lines of ``relay readall``."""
    digits = mask_digits(channels)
    if len(lines) != 1 or not re.fullmatch(rf"[0-9A-Fa-f]{{{digits}}}", lines[0]):
        raise context.error(f"readall should answer {digits} hex digits", "\n".join(lines))
    mask = int(lines[0], 16)
    if mask >> channels:
        raise context.error(
            f"readall reports relays beyond the {channels} of this module", lines[0]
        )
    return tuple(bool(mask >> index & 1) for index in range(channels))


def parse_relay_read(lines: list[str], context: ReplyContext) -> bool:
    """One relay's state from the result lines of ``relay read N`` (``on`` / ``off``)."""
    if len(lines) != 1 or lines[0].lower() not in ("on", "off"):
        raise context.error("relay read should answer 'on' or 'off'", "\n".join(lines))
    return lines[0].lower() == "on"


class NumatoRelayBoard(SerialRelayBoard):
    """A Numato relay module; implements :class:`drivers.base.RelayBoard`.

    Parameters
    ----------
    transport
        The byte link to the module.
    channels
        Number of relays (1, 2, 4, 8, 16 or 32).
    timeout_s
        Deadline of each command (up to the prompt).
    port
        Where the module is connected (reported in its identity).
    """

    def __init__(
        self,
        transport: ByteTransport,
        channels: int,
        *,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        port: str | None = None,
    ) -> None:
        if channels not in CHANNEL_COUNTS:
            raise ValueError(f"Numato modules have {CHANNEL_COUNTS} relays, got {channels}")
        super().__init__(transport, channels, timeout_s=timeout_s, port=port)
        self._in_sync = False
        self._identity: DeviceIdentity | None = None

    # ------------------------------------------------------------------------------ exchanges

    def resync(self) -> None:
        """Send a bare CR and read to the prompt, flushing any half-typed command."""
        self._in_sync = False
        reply = ask(
            self._transport, COMMAND_TERMINATOR, terminator=PROMPT, deadline=self._deadline()
        )
        parse_reply(reply, "", ReplyContext(self.device, COMMAND_TERMINATOR))
        self._in_sync = True

    def _deadline(self) -> Deadline:
        return Deadline(self.timeout_s)

    def command(self, text: str) -> list[str]:
        """Send one command line; return its result lines (without echo and prompt)."""
        if not self._in_sync:
            self.resync()
        context = ReplyContext(self.device, text)
        try:
            reply = ask(
                self._transport,
                text.encode("ascii") + COMMAND_TERMINATOR,
                terminator=PROMPT,
                deadline=self._deadline(),
            )
            return parse_reply(reply, text, context)
        except (DeviceTimeout, ProtocolError):
            self._in_sync = False
            raise

    # ------------------------------------------------------------------------------ the board

    def identify(self) -> DeviceIdentity:
        """Firmware version (``ver``) and module id (``id get``); cached."""
        if self._identity is None:
            version = " ".join(self.command("ver"))
            module_id = " ".join(self.command("id get"))
            self._identity = DeviceIdentity(
                kind="relay",
                model=f"Numato {self._channels}-channel relay module",
                serial=module_id or None,
                firmware=version or None,
                port=self.port,
            )
        return self._identity

    def state(self) -> tuple[bool, ...]:
        """Relay states (channel 1 first): ``relay readall``, or ``relay read 0`` on 1-relay
        modules."""
        if self._channels == 1:
            self._known = (self.read_channel(1),)
        else:
            lines = self.command("relay readall")
            self._known = parse_mask(
                lines, self._channels, ReplyContext(self.device, "relay readall")
            )
        return self._known

    def read_channel(self, channel: int) -> bool:
        """One relay's state (``relay read N``)."""
        self._check_channel(channel)
        text = f"relay read {relay_character(channel)}"
        return parse_relay_read(self.command(text), ReplyContext(self.device, text))

    def _expect_no_result(self, text: str) -> None:
        lines = self.command(text)
        if lines:
            raise ReplyContext(self.device, text).error(
                "switching command answered with a result line", " ".join(lines)
            )

    def _switch(self, channel: int, on: bool) -> None:
        self._expect_no_result(f"relay {'on' if on else 'off'} {relay_character(channel)}")

    def all_off(self) -> None:
        """Switch every relay off at once (``relay writeall 00…``) and verify."""
        if self._channels == 1:
            self._expect_no_result(f"relay off {relay_character(1)}")
        else:
            self._expect_no_result(f"relay writeall {0:0{mask_digits(self._channels)}x}")
        verify_relay_state(self.device, [False] * self._channels, self.state())


def open_numato(
    port: str,
    channels: int,
    *,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    transcript: TranscriptSink | None = None,
    baud: int | None = None,
) -> NumatoRelayBoard:
    """Open a Numato module with ``channels`` relays on ``port``, resynchronise and identify it.

    ``baud`` overrides the line speed of :data:`SERIAL_SETTINGS`.

    Raises
    ------
    DeviceNotFound
        No such port.
    DeviceTimeout
        The module does not answer (on Linux, ModemManager may hold a new ``ttyACM`` port for a
        few seconds after plug-in).
    """
    if channels not in CHANNEL_COUNTS:
        raise ValueError(f"Numato modules have {CHANNEL_COUNTS} relays, got {channels}")
    transport = open_serial(
        port,
        SERIAL_SETTINGS.with_baud(baud),
        device=f"Numato {channels}-relay module on {port}",
        transcript=transcript,
    )
    board = NumatoRelayBoard(transport, channels, timeout_s=timeout_s, port=port)

    def connect() -> None:
        board.resync()
        board.identify()
        board.state()

    return connect_or_close(board, connect)
