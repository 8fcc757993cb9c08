"""Virtual lamps behind relay channels: the shared state the emulators read and write.

Relay emulators switch channels on a :class:`LampBank`; spectrometer emulators and the twin's camera
ask it for the light that is on *now*. Lamps warm up after switch-on: output and spectral tilt drift
exponentially toward their settled values, so a rig that measures too early sees a different
spectrum. Time comes from a :class:`Clock`, which the twin replaces by a simulated clock so that a
warm-up of minutes takes no wall time.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.core.observations import LampKind
from calib.core.spectra import Spectrum


class Clock(Protocol):
    """A source of time in seconds; ``sleep`` advances it (really or virtually)."""

    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class WallClock:
    """Real time (:func:`time.monotonic`)."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))


class SimulatedClock:
    """Virtual time: ``sleep`` advances it instantly. Thread-safe."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._now = start_s
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._now

    def sleep(self, seconds: float) -> None:
        self.advance(seconds)

    def advance(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError(f"cannot advance a clock by {seconds} s")
        with self._lock:
            self._now += seconds


@dataclass(frozen=True)
class VirtualLamp:
    """A lamp on a relay channel.

    Parameters
    ----------
    name
        Lamp name, e.g. ``"LED-B3"``.
    channel
        Relay channel (from 1).
    spectrum
        Settled spectral radiance, W/(sr·m²·nm).
    kind
        LED, fluorescent, …
    warmup_tau_s
        Time constant of the warm-up drift.
    warmup_gain
        Relative output excess at switch-on (LEDs start brighter and dim as the junction heats:
        positive; fluorescent tubes start dim: negative).
    warmup_tilt
        Relative spectral tilt at switch-on, per 100 nm away from 550 nm.
    """

    name: str
    channel: int
    spectrum: Spectrum
    kind: LampKind = "led"
    warmup_tau_s: float = 30.0
    warmup_gain: float = 0.05
    warmup_tilt: float = 0.02

    def radiance(
        self, wavelength_nm: NDArray[np.float64], seconds_on: float
    ) -> NDArray[np.float64]:
        """Spectral radiance ``(n,)`` at ``wavelength_nm`` after being on for ``seconds_on``."""
        settled = self.spectrum.at(wavelength_nm)
        if self.warmup_tau_s <= 0:
            return settled
        decay = float(np.exp(-max(seconds_on, 0.0) / self.warmup_tau_s))
        tilt = 1.0 + self.warmup_tilt * decay * (wavelength_nm - 550.0) / 100.0
        return np.clip(settled * (1.0 + self.warmup_gain * decay) * tilt, 0.0, None)


class LampBank:
    """Relay channels with lamps on some of them; thread-safe.

    Parameters
    ----------
    lamps
        The lamps; their channels must be distinct and within ``1..n_channels``.
    n_channels
        Number of relay channels on the board.
    clock
        Time source for warm-up.
    time_resolution_s
        How long a lamp has been on is rounded to this (0: not rounded). The twin rounds to 1 µs so
        that a lamp's timeline rebuilt in another process (resume) gives the same light to the bit,
        whatever the float rounding of the absolute clock values.
    """

    def __init__(
        self,
        lamps: Sequence[VirtualLamp],
        n_channels: int,
        clock: Clock | None = None,
        *,
        time_resolution_s: float = 0.0,
    ) -> None:
        channels = [lamp.channel for lamp in lamps]
        if len(set(channels)) != len(channels):
            raise ValueError(f"two lamps share a relay channel: {channels}")
        if any(not 1 <= c <= n_channels for c in channels):
            raise ValueError(f"lamp channels {channels} outside 1..{n_channels}")
        self.lamps = tuple(lamps)
        self.n_channels = n_channels
        self.clock: Clock = clock or WallClock()
        self.time_resolution_s = time_resolution_s
        self._switched_on_at: dict[int, float] = {}
        self._lock = threading.Lock()

    def set_channel(self, channel: int, on: bool) -> None:
        if not 1 <= channel <= self.n_channels:
            raise ValueError(f"channel {channel} outside 1..{self.n_channels}")
        with self._lock:
            if on and channel not in self._switched_on_at:
                self._switched_on_at[channel] = self.clock.now()
            elif not on:
                self._switched_on_at.pop(channel, None)

    def channel_states(self) -> tuple[bool, ...]:
        with self._lock:
            return tuple(c in self._switched_on_at for c in range(1, self.n_channels + 1))

    def lit(self) -> list[tuple[VirtualLamp, float]]:
        """Lamps that are on, with how long each has been on (s)."""
        now = self.clock.now()
        with self._lock:
            on = dict(self._switched_on_at)
        resolution = self.time_resolution_s
        return [
            (
                lamp,
                round((now - on[lamp.channel]) / resolution) * resolution
                if resolution
                else now - on[lamp.channel],
            )
            for lamp in self.lamps
            if lamp.channel in on
        ]

    def radiance(self, wavelength_nm: ArrayLike) -> NDArray[np.float64]:
        """Total spectral radiance of the lit lamps at ``wavelength_nm`` (zeros when all are off)."""
        axis = np.asarray(wavelength_nm, dtype=np.float64)
        total = np.zeros_like(axis)
        for lamp, seconds_on in self.lit():
            total += lamp.radiance(axis, seconds_on)
        return total
