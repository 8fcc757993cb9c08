"""Firmware emulator of a Numato Lab USB relay module (ASCII command line over CDC-ACM), device side.

What it implements (facts sheet §2.3):

- commands end with CR (an LF is ignored); the module echoes the command, then for queries the
  result line, then the ``>`` prompt. The echo ends ``\\n\\r`` and result lines end ``\\n\\r``, the order
  numato_controller parses (other firmware uses ``\\r\\n``: the driver must not care);
- relays are numbered from 0 with one character: ``0``–``9``, then ``A``, ``B`` … (16/32-channel
  boards); ``relay on N``, ``relay off N``, ``relay read N`` (→ ``on`` / ``off``),
  ``relay readall`` (→ hex bitmask, two digits per 8 relays, relay 0 in the lowest bit),
  ``relay writeall HH``, ``ver`` (→ 8 characters), ``id get`` (→ 8 characters), ``id set XXXXXXXX``;
- an empty line (a bare CR, which drivers send to flush a half-typed command) gives a prompt;
  an unknown command is echoed and prompted with no result, as the module's shell does.

Relay channel ``c`` of the rig (from 1) is Numato relay ``c - 1``; switching it switches channel ``c``
of the :class:`mocks.lamps.LampBank`.

Fault labels are the command texts (``"relay on 0"``, ``"relay readall"`` …). ``ERROR_CODE`` on a
switch leaves the relay as it was (a stuck contact). ``BUSY`` is not supported.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import ClassVar

from mocks.emulators.serial_base import EmulatorBase, LineSplitter, ReplyPart
from mocks.faults import FaultKind, FaultSchedule
from mocks.lamps import LampBank
from mocks.pty_serial import PtySerialDevice

PROMPT = b">"
LINE_END = b"\n\r"
_RELAY_CHARACTERS = "0123456789ABCDEFGHIJKLMNOPQRSTUV"


class NumatoEmulator(EmulatorBase):
    """A Numato relay module with ``channels`` relays.

    Parameters
    ----------
    channels
        Number of relays (1, 2, 4, 8, 16 or 32 on real modules).
    bank
        Lamps switched by the relays.
    version, module_id
        What ``ver`` and ``id get`` answer (8 characters each).
    faults
        Scheduled misbehaviour.
    """

    SUPPORTED_FAULTS: ClassVar[frozenset[FaultKind]] = frozenset(FaultKind) - {FaultKind.BUSY}
    STRUCTURAL_BYTES: ClassVar[bytes] = b"\r\n>"

    def __init__(
        self,
        channels: int,
        bank: LampBank | None = None,
        *,
        version: str = "00000008",
        module_id: str = "00000001",
        faults: FaultSchedule | None = None,
    ) -> None:
        if channels not in (1, 2, 4, 8, 16, 32):
            raise ValueError(f"Numato modules have 1, 2, 4, 8, 16 or 32 relays, got {channels}")
        if bank is not None and bank.n_channels > channels:
            raise ValueError(
                f"the lamp bank uses {bank.n_channels} channels but the module has {channels}"
            )
        if len(version) != 8 or len(module_id) != 8:
            raise ValueError("the Numato version and id are 8 characters each")
        super().__init__(f"Numato-{channels}", faults=faults)
        self.channels = channels
        self.bank = bank
        self.version = version
        self.module_id = module_id
        self.states = [False] * channels
        self._splitter = LineSplitter(b"\r")

    def receive(self, data: bytes) -> None:
        for line, _ in self._splitter.feed(data.replace(b"\n", b"")):
            self._command(line.decode("ascii", errors="replace"))

    def _command(self, text: str) -> None:
        fault = self.next_fault(text)
        stuck = fault is not None and fault.kind is FaultKind.ERROR_CODE
        result = self._execute(text, apply=not stuck)
        reply = text.encode("ascii", errors="replace") + LINE_END if text else b""
        if result is not None:
            reply += result.encode("ascii") + LINE_END
        self.deliver([ReplyPart(reply + PROMPT)], fault)

    def _relay_index(self, character: str) -> int | None:
        index = _RELAY_CHARACTERS.find(character.upper())
        return index if 0 <= index < self.channels else None

    def _set(self, index: int, on: bool) -> None:
        self.states[index] = on
        channel = index + 1
        if self.bank is not None and channel <= self.bank.n_channels:
            self.bank.set_channel(channel, on)

    def _execute(self, text: str, *, apply: bool) -> str | None:
        """The result line of ``text`` (``None`` for commands without one)."""
        words = text.strip().split()
        if words == ["ver"]:
            return self.version
        if words == ["id", "get"]:
            return self.module_id
        if len(words) == 3 and words[:2] == ["id", "set"] and len(words[2]) == 8:
            self.module_id = words[2]
            return None
        if len(words) == 3 and words[0] == "relay" and words[1] in ("on", "off", "read"):
            index = self._relay_index(words[2]) if len(words[2]) == 1 else None
            if index is None:
                return None
            if words[1] == "read":
                return "on" if self.states[index] else "off"
            if apply:
                self._set(index, words[1] == "on")
            return None
        digits = max(2, self.channels // 4)
        if words == ["relay", "readall"]:
            mask = sum(1 << index for index, on in enumerate(self.states) if on)
            return f"{mask:0{digits}x}"
        if len(words) == 3 and words[:2] == ["relay", "writeall"]:
            if apply and re.fullmatch(rf"[0-9a-fA-F]{{{digits}}}", words[2]):
                mask = int(words[2], 16)
                for index in range(self.channels):
                    self._set(index, bool(mask >> index & 1))
            return None
        return None


def start_numato(
    channels: int,
    bank: LampBank | None = None,
    *,
    faults: FaultSchedule | None = None,
    symlink: str | Path | None = None,
) -> PtySerialDevice:
    """Start a Numato module emulator on a pty; open ``device.path`` with the real driver."""
    emulator = NumatoEmulator(channels, bank, faults=faults)
    return PtySerialDevice(emulator, symlink=symlink).start()
