"""A Ctrl-C noted when it arrives, so ``rig`` ends as interrupted whatever error a library made of it.

A library may catch the ``KeyboardInterrupt`` and raise its own error instead (pydantic-core turns
one raised while it builds a validator into a ``SchemaError``). :func:`note_interrupts` installs a
SIGINT handler that records the signal, then interrupts as Python's default handler does;
:func:`rig.cli.main` asks :func:`interrupt_seen` before calling an error internal.
"""

from __future__ import annotations

import signal
from types import FrameType

INTERRUPTED_EXIT_CODE = 130

_seen: list[int] = []


def interrupt_seen() -> bool:
    """Whether a Ctrl-C reached this process through the handler :func:`note_interrupts` installs."""
    return bool(_seen)


def note_interrupts() -> None:
    """Install the noting handler in place of Python's default one (never over another's)."""
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _note_and_interrupt)


def _note_and_interrupt(signum: int, frame: FrameType | None) -> None:
    _seen.append(signum)
    signal.default_int_handler(signum, frame)
