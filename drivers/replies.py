"""Strict decoding of instrument replies: every malformed reply becomes a :class:`ProtocolError`.

Reply parsers in the drivers are pure functions built from these helpers, so a parser fed arbitrary
bytes raises :class:`drivers.base.ProtocolError` (or the instrument's own typed error) and nothing
else: no ``ValueError``, ``IndexError`` or ``UnicodeDecodeError`` escapes to the rig.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.base import ProtocolError


@dataclass(frozen=True)
class ReplyContext:
    """Who answered what: the device label and the command the reply belongs to."""

    device: str
    command: bytes | str

    def error(self, message: str, reply: bytes | str | None) -> ProtocolError:
        return ProtocolError(self.device, message, command=self.command, reply=reply)


def decode_ascii(reply: bytes, context: ReplyContext) -> str:
    """``reply`` as text; bytes outside printable ASCII (plus CR, LF, TAB) are a protocol error."""
    if any(byte > 0x7E or (byte < 0x20 and byte not in b"\r\n\t") for byte in reply):
        raise context.error(
            "reply contains bytes that are not printable ASCII (line noise?)", reply
        )
    return reply.decode("ascii")


def parse_int(text: str, what: str, context: ReplyContext, reply: bytes | str) -> int:
    """``text`` as a (signed, decimal) integer, or a protocol error naming ``what``."""
    stripped = text.strip()
    body = stripped[1:] if stripped[:1] in "+-" else stripped
    if not body.isdigit() or not body.isascii():
        raise context.error(f"{what} should be an integer, got {text!r}", reply)
    return int(stripped)


def parse_float(text: str, what: str, context: ReplyContext, reply: bytes | str) -> float:
    """``text`` as a finite float, or a protocol error naming ``what``."""
    stripped = text.strip()
    try:
        value = float(stripped)
    except ValueError:
        raise context.error(f"{what} should be a number, got {text!r}", reply) from None
    if not math.isfinite(value) or "_" in stripped:
        raise context.error(f"{what} should be a finite number, got {text!r}", reply)
    return value
