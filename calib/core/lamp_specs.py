"""Lamp spectra named on a command line: colour-science names, Gaussian LEDs, CSV files.

``"LED-B3"`` or ``"FL2"`` — a colour-science illuminant or light source; ``"gauss:630:25"`` — a
narrow-band LED modelled as a Gaussian with its centre and full width at half maximum in nm; anything
else is read as a spectrum CSV (:func:`calib.core.spectra.read_spectrum_csv`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from calib.core.colour_data import illuminants, light_sources
from calib.core.errors import InputError
from calib.core.spectra import Spectrum, read_spectrum_csv

#: Range of a Gaussian LED's tabulated spectrum (covers every working grid of the project).
GAUSSIAN_RANGE_NM = (360.0, 830.0)
#: A Gaussian LED's floor relative to its peak: real LEDs leak a little light everywhere (and the
#: response fit needs some light at every wavelength to say anything there).
GAUSSIAN_FLOOR = 1e-4
#: Blue, green and red narrow-band LEDs (Gaussians): the synthetic protocol's coloured LEDs and
#: ``calib plan-lamps``'s default candidates.
RGB_LEDS: tuple[str, ...] = ("gauss:455:25", "gauss:530:35", "gauss:630:20")


def gaussian_lamp(centre_nm: float, fwhm_nm: float, *, name: str | None = None) -> Spectrum:
    """A narrow-band LED: a Gaussian of ``fwhm_nm`` at ``centre_nm`` (peak 1, 1 nm samples).

    Examples
    --------
    >>> lamp = gaussian_lamp(630.0, 20.0)
    >>> round(float(lamp.at(np.array([640.0]))[0]), 3)  # half maximum at ±10 nm (+ the 1e-4 floor)
    0.5
    """
    if not (math.isfinite(centre_nm) and math.isfinite(fwhm_nm)) or fwhm_nm <= 0:
        raise InputError(
            f"a Gaussian LED needs a finite centre and a width > 0 nm, got {centre_nm:g}, {fwhm_nm:g}",
            source=name or "gauss",
        )
    axis = np.arange(GAUSSIAN_RANGE_NM[0], GAUSSIAN_RANGE_NM[1] + 0.5, 1.0)
    sigma = fwhm_nm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    values = np.exp(-0.5 * ((axis - centre_nm) / sigma) ** 2) + GAUSSIAN_FLOOR
    return Spectrum(axis, values, name=name or f"gauss:{centre_nm:g}:{fwhm_nm:g}")


def colour_lamp(name: str) -> Spectrum:
    """A colour-science illuminant (``SDS_ILLUMINANTS``) or light source (``SDS_LIGHT_SOURCES``)."""
    for table in (illuminants(), light_sources()):
        if name in table:
            return table[name]
    raise InputError(
        f"colour-science has no illuminant or light source named {name!r}", source="lamp"
    )


def lamp_from_spec(spec: str) -> Spectrum:
    """A lamp from ``gauss:CENTRE:FWHM``, a CSV path, or a colour-science name (in that order).

    Raises
    ------
    InputError
        A malformed ``gauss:`` spec, an unreadable CSV, or an unknown name (the spec is named).
    """
    text = spec.strip()
    if text.lower().startswith("gauss:"):
        parts = text.split(":")
        try:
            centre, width = (float(part) for part in parts[1:])
        except ValueError:
            raise InputError(
                "expected gauss:CENTRE_NM:FWHM_NM, e.g. gauss:630:20", source=spec
            ) from None
        return gaussian_lamp(centre, width, name=text)
    path = Path(text)
    if path.suffix.lower() in (".csv", ".txt") or path.is_file():
        return read_spectrum_csv(path)
    return colour_lamp(text)
