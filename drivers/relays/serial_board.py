"""What the serial relay boards (LCUS, Numato) share: channel checks, switch-then-verify, close."""

from __future__ import annotations

from drivers.base import DeviceIdentity
from drivers.lifecycle import ClosesOnExit
from drivers.relays import verify_relay_state
from drivers.transport import ByteTransport


class SerialRelayBoard(ClosesOnExit):
    """Base of the serial relay drivers; subclasses say how to switch and how to read the state.

    Parameters
    ----------
    transport
        The byte link to the board.
    channels
        Number of relays, numbered from 1.
    timeout_s
        Deadline of each reply.
    port
        Where the board is connected (reported in its identity).
    """

    def __init__(
        self, transport: ByteTransport, channels: int, *, timeout_s: float, port: str | None
    ) -> None:
        self._transport = transport
        self._channels = channels
        self.timeout_s = timeout_s
        self.port = port
        self._known: tuple[bool, ...] | None = None

    @property
    def channels(self) -> int:
        return self._channels

    @property
    def device(self) -> str:
        return self._transport.device

    def identify(self) -> DeviceIdentity:  # pragma: no cover - every board overrides
        raise NotImplementedError

    def state(self) -> tuple[bool, ...]:  # pragma: no cover - every board overrides
        """Read the relay states from the board (channel 1 first) and remember them."""
        raise NotImplementedError

    def _switch(self, channel: int, on: bool) -> None:  # pragma: no cover
        """Send the board's switching command (no verification)."""
        raise NotImplementedError

    def _check_channel(self, channel: int) -> None:
        if not 1 <= channel <= self._channels:
            raise ValueError(f"{self.device}: channel {channel} is outside 1–{self._channels}")

    def set(self, channel: int, on: bool) -> None:
        """Switch ``channel`` and verify the whole board's state read back.

        The expected state is the last state read back with ``channel`` changed, so a relay that
        did not follow and one that changed on its own both raise.

        Raises
        ------
        StateMismatch
            The board's state after switching is not the one asked for.
        """
        self._check_channel(channel)
        expected = list(self._known if self._known is not None else self.state())
        expected[channel - 1] = on
        self._switch(channel, on)
        verify_relay_state(self.device, expected, self.state())

    def close(self) -> None:
        """Close the port (the relays keep their state)."""
        self._transport.close()
