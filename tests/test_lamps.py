"""mocks.lamps: the relay-channel lamp bank the emulators share."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from calib.core.spectra import Spectrum
from drivers.base import StateMismatch
from drivers.relays import verify_relay_state
from mocks.lamps import LampBank, SimulatedClock, VirtualLamp


def _bank() -> tuple[LampBank, SimulatedClock]:
    clock = SimulatedClock()
    led = VirtualLamp(
        "LED-B3", 1, Spectrum.from_colour(colour.SDS_ILLUMINANTS["LED-B3"]), warmup_tau_s=10.0
    )
    fl = VirtualLamp(
        "FL2",
        2,
        Spectrum.from_colour(colour.SDS_ILLUMINANTS["FL2"]),
        kind="fluorescent",
        warmup_gain=-0.3,
    )
    return LampBank([led, fl], n_channels=4, clock=clock), clock


def test_radiance_follows_the_relays_and_settles() -> None:
    bank, clock = _bank()
    wavelengths = np.arange(400.0, 701.0, 5.0)
    np.testing.assert_array_equal(bank.radiance(wavelengths), 0.0)
    bank.set_channel(1, True)
    assert bank.channel_states() == (True, False, False, False)
    early = bank.radiance(wavelengths)
    clock.advance(200.0)
    settled = bank.radiance(wavelengths)
    led = bank.lamps[0].spectrum.at(wavelengths)
    np.testing.assert_allclose(settled, led, rtol=1e-6)
    assert np.abs(early / np.where(led > 0, led, 1) - 1).max() > 0.03
    bank.set_channel(2, True)
    clock.advance(1000.0)
    np.testing.assert_allclose(
        bank.radiance(wavelengths), led + bank.lamps[1].spectrum.at(wavelengths), rtol=1e-6
    )
    bank.set_channel(1, False)
    bank.set_channel(2, False)
    np.testing.assert_array_equal(bank.radiance(wavelengths), 0.0)


def test_bank_rejects_bad_channels() -> None:
    bank, _ = _bank()
    with pytest.raises(ValueError, match=r"outside 1\.\.4"):
        bank.set_channel(5, True)
    with pytest.raises(ValueError, match="share a relay channel"):
        LampBank([bank.lamps[0], bank.lamps[0]], n_channels=4)


def test_verify_relay_state() -> None:
    verify_relay_state("board", [True, False], (True, False))
    with pytest.raises(StateMismatch, match="expected '10', read back '00'"):
        verify_relay_state("board", [True, False], [False, False])
