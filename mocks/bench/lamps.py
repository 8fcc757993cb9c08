"""The twin's lamps: colour-science spectral distributions behind relay channels, with warm-up drift.

A lamp's settled spectrum is a colour-science illuminant (CIE LED series ``LED-B3`` …, fluorescent
``FL2`` …, ``A``, ``D65``, high-pressure ``HP1`` …) scaled to the configured radiance; the drift
after switch-on is :class:`mocks.lamps.VirtualLamp`'s. The CIE fluorescent tables hold each mercury
line's power in its 5 nm bin; a fluorescent lamp gets its lines back as narrow peaks at their true
wavelengths (:func:`calib.core.line_lists.with_narrow_lines`), as the camera and the spectrometer of a real rig see them —
the pixel→wavelength mapping is found from them.

The camera renders a lamp's light once per *spectral component*: the drifting spectrum
``settled · (1 + g·d) · (1 + k·d·(λ − 550)/100)`` is, at every moment, a combination of two fixed
spectra, ``settled · (λ_max − λ)/(λ_max − λ_min)`` and ``settled · (λ − λ_min)/(λ_max − λ_min)``
(a tilt is linear in λ). :func:`drift_coefficients` finds that combination from the lamp's
radiance itself and says when it does not hold, so the camera falls back to rendering the
spectrum directly rather than trusting a model of the drift.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.colour_data import illuminants
from calib.core.line_lists import with_narrow_lines
from calib.core.observations import LAMP_KINDS, LampKind
from calib.core.spectra import Spectrum
from mocks.bench.colour_cache import cached_table
from mocks.bench.spec import LampSpec, TwinSpecError
from mocks.lamps import Clock, LampBank, VirtualLamp

#: Wavelength range over which a lamp's radiance is normalised to the configured mean.
NORMALISATION_RANGE_NM = (400.0, 700.0)
#: Relative residual above which a lamp's spectrum is not a mix of its two components.
COMPONENT_TOLERANCE = 1e-9


def illuminant_names() -> list[str]:
    """The colour-science illuminants a twin lamp may take its spectrum from."""
    return sorted(illuminants())


def settled_spectrum(lamp: LampSpec) -> Spectrum:
    """The lamp's settled spectral radiance, W/(sr·m²·nm), on the illuminant's own sampling.

    Raises
    ------
    TwinSpecError
        The illuminant is unknown, or has no light in 400–700 nm.
    """

    def from_colour() -> tuple[FloatArray, FloatArray]:
        illuminant = illuminants().get(lamp.spd)  # importing colour costs a second: then cached
        if illuminant is None:
            shown = ", ".join(name for name in illuminant_names() if not name.startswith("ISO"))
            raise TwinSpecError(
                f"devices.relays.lamps.{lamp.name}.spd: {lamp.spd!r} is not a colour-science "
                f"illuminant; name the lamp after one or set spd to one of: {shown}"
            )
        return illuminant.wavelength_nm, illuminant.values

    wavelength_nm, values = cached_table(f"illuminant {lamp.spd}", from_colour)
    spectrum = Spectrum(wavelength_nm, values, name=lamp.name)
    low, high = NORMALISATION_RANGE_NM
    axis = np.arange(low, high + 0.5, 1.0)
    mean = float(np.mean(spectrum.at(axis)))
    if mean <= 0:
        raise TwinSpecError(
            f"devices.relays.lamps.{lamp.name}.spd: {lamp.spd!r} has no light in {low:g}–{high:g} nm"
        )
    return spectrum.scaled(lamp.radiance_w_sr_m2_nm / mean)


def virtual_lamp(lamp: LampSpec) -> VirtualLamp:
    """The lamp as the lamp bank holds it (a fluorescent lamp with narrow mercury lines)."""
    kind: LampKind = next((k for k in LAMP_KINDS if k == lamp.kind), "other")
    settled = settled_spectrum(lamp)
    return VirtualLamp(
        name=lamp.name,
        channel=lamp.channel,
        spectrum=with_narrow_lines(settled) if kind == "fluorescent" else settled,
        kind=kind,
        warmup_tau_s=lamp.drift.tau_s,
        warmup_gain=lamp.drift.gain,
        warmup_tilt=lamp.drift.tilt,
    )


def spectral_components(lamp: VirtualLamp) -> tuple[Spectrum, Spectrum]:
    """The two fixed spectra whose mix is the lamp at any time: settled × falling/rising ramp."""
    settled = lamp.spectrum
    low, high = settled.range_nm
    rising = (settled.wavelength_nm - low) / (high - low)
    return (
        Spectrum(settled.wavelength_nm, settled.values * (1.0 - rising), name=f"{lamp.name}-blue"),
        Spectrum(settled.wavelength_nm, settled.values * rising, name=f"{lamp.name}-red"),
    )


def drift_coefficients(
    lamp: VirtualLamp, components: Sequence[Spectrum], seconds_on: float
) -> FloatArray | None:
    """Weights ``(k,)`` of ``components`` that make the lamp's radiance after ``seconds_on``.

    Returns ``None`` when no mix reproduces the radiance to :data:`COMPONENT_TOLERANCE` (the lamp
    drifts in a way the components do not span).
    """
    axis = lamp.spectrum.wavelength_nm
    radiance = lamp.radiance(axis, seconds_on)
    basis = np.stack([component.at(axis) for component in components], axis=1)
    weights, *_ = np.linalg.lstsq(basis, radiance, rcond=None)
    residual = float(np.linalg.norm(basis @ weights - radiance))
    if residual > COMPONENT_TOLERANCE * max(float(np.linalg.norm(radiance)), 1e-300):
        return None
    return np.asarray(weights, dtype=np.float64)


class PersistentLampBank(LampBank):
    """A lamp bank whose relay channels outlive the process, like a real board's relays.

    Every switch writes the channels to ``state_file`` (``"0100"``: channel 1 first), replacing it
    atomically; :meth:`saved_channels` reads what a previous process left.

    Parameters
    ----------
    lamps, n_channels, clock
        As for :class:`mocks.lamps.LampBank`.
    state_file
        The file; its directory must exist.
    """

    def __init__(
        self,
        lamps: Sequence[VirtualLamp],
        n_channels: int,
        clock: Clock,
        state_file: Path,
        *,
        time_resolution_s: float = 0.0,
    ) -> None:
        super().__init__(lamps, n_channels, clock, time_resolution_s=time_resolution_s)
        self.state_file = state_file

    def saved_channels(self) -> tuple[bool, ...]:
        """The channels a previous process left (all off when there is no file).

        Raises
        ------
        TwinSpecError
            The file holds something else than one ``0``/``1`` per channel.
        """
        try:
            text = self.state_file.read_text(encoding="ascii").strip()
        except FileNotFoundError:
            return (False,) * self.n_channels
        except (OSError, UnicodeDecodeError) as exc:
            raise TwinSpecError(
                f"devices.relays.state_file: cannot read {self.state_file}: {exc}"
            ) from None
        if len(text) != self.n_channels or set(text) - {"0", "1"}:
            raise TwinSpecError(
                f"devices.relays.state_file: {self.state_file} holds {text[:40]!r}, not one 0/1 per "
                f"relay channel ({self.n_channels}); delete it to start with every relay off"
            )
        return tuple(character == "1" for character in text)

    def set_channel(self, channel: int, on: bool) -> None:
        super().set_channel(channel, on)
        text = "".join("1" if state else "0" for state in self.channel_states())
        temporary = self.state_file.with_name(f".{self.state_file.name}.part")
        temporary.write_text(text + "\n", encoding="ascii")
        temporary.replace(self.state_file)
