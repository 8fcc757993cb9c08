"""Relay boards that switch the lamps: HID USBRelay over pyusb, LCUS/CH340 and Numato over serial."""

from __future__ import annotations

from collections.abc import Sequence

from drivers.base import StateMismatch


def verify_relay_state(device: str, expected: Sequence[bool], actual: Sequence[bool]) -> None:
    """Raise :class:`StateMismatch` unless the state read back equals the state asked for.

    Every relay driver calls this after each switch: a relay that did not follow (welded contact,
    lost command, wrong board) must stop the run before a frame is taken under the wrong lamp.
    """
    if tuple(expected) != tuple(actual):

        def show(state: Sequence[bool]) -> str:
            return "".join("1" if on else "0" for on in state)

        raise StateMismatch(
            device,
            "relay state read back after switching differs (channel 1 first)",
            expected=show(expected),
            actual=show(actual),
        )
