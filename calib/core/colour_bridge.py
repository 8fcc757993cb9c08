"""Every colour-science call the outputs and the camera's uses make, in one place.

colour is imported inside each function (importing it costs about a second). Everything else in
:mod:`calib.use` and :mod:`calib.pipeline` works on plain arrays and the project's spectra, and
reaches colour only through this module: illuminants, the CIE 1931 observer, the ColorChecker
reflectances, CIELAB and ΔE2000, the ACES IDT solve (``colour.matrix_idt``), and the conversion to
colour's ``RGB_CameraSensitivities``.

References
----------
Mansencal, T. et al. colour-science (colour.characterisation.matrix_idt; colour.difference.
delta_E_CIE2000). The Academy (2015), P-2013-001: Recommended procedures for the creation and use of
digital camera system input device transforms (IDTs).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.spectra import MultiSpectrum, Spectrum, WavelengthGrid

#: The illuminants the camera's uses are computed for, by the names used on the command line.
ILLUMINANTS: tuple[str, ...] = ("D50", "D55", "D65", "A")
#: colour-science's ColorChecker with spectral reflectances (Ohta's measurements, 380–780/5 nm).
COLORCHECKER = "ColorChecker N Ohta"
#: ACES' D55 is the CIE daylight at 5500 K on the 1968 temperature scale (c₂ = 1.4388e-2 m·K).
_DAYLIGHT_C2_RATIO = 1.4388 / 1.4380


def camera_sensitivities(wavelength_nm: ArrayLike, values: ArrayLike, name: str) -> Any:
    """colour's ``RGB_CameraSensitivities`` of ``values`` ``(f, 3)`` (R, G, B; colour always labels
    them ``red, green, blue``)."""
    import colour

    return colour.characterisation.RGB_CameraSensitivities(
        np.asarray(values, dtype=np.float64),
        np.asarray(wavelength_nm, dtype=np.float64),
        name=name,
    )


def illuminant(name: str) -> Spectrum:
    """The relative spectral power of ``D50``, ``D55``, ``D65`` (CIE daylight) or ``A`` (CIE).

    Raises
    ------
    InputError
        Any other name, with the names allowed.
    """
    import colour

    key = name.strip().upper()
    if key == "A":
        sd = colour.SDS_ILLUMINANTS["A"]
    elif key in ("D50", "D55", "D65"):
        cct_k = float(key[1:]) * 100.0 * _DAYLIGHT_C2_RATIO
        sd = colour.sd_CIE_illuminant_D_series(colour.temperature.CCT_to_xy_CIE_D(cct_k))
    else:
        raise InputError(
            f"unknown illuminant {name!r}; choose one of {', '.join(ILLUMINANTS)}",
            source="--illuminant",
        )
    return Spectrum.from_colour(sd, name=key)


def cie_1931_observer() -> MultiSpectrum:
    """The CIE 1931 2° colour-matching functions x̄, ȳ, z̄ (360–830 nm, 1 nm)."""
    import colour

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    return MultiSpectrum(
        np.asarray(cmfs.wavelengths, dtype=np.float64),
        np.asarray(cmfs.values, dtype=np.float64),
        channels=("x", "y", "z"),
        name="CIE 1931 2°",
    )


def colorchecker_reflectances() -> MultiSpectrum:
    """The 24 ColorChecker patches' spectral reflectances (:data:`COLORCHECKER`), row by row."""
    import colour

    patches = colour.SDS_COLOURCHECKERS[COLORCHECKER]
    names = tuple(patches)
    first = patches[names[0]]
    return MultiSpectrum(
        np.asarray(first.wavelengths, dtype=np.float64),
        np.stack([np.asarray(patches[n].values, dtype=np.float64) for n in names], axis=1),
        channels=names,
        name=COLORCHECKER,
        negative="clip",
    )


def training_reflectances() -> MultiSpectrum:
    """rawtoaces' 190 training reflectances (as colour-science ships them, 380–780/5 nm)."""
    import colour

    data = colour.characterisation.read_training_data_rawtoaces_v1()
    return MultiSpectrum(
        np.asarray(data.wavelengths, dtype=np.float64),
        np.asarray(data.values, dtype=np.float64),
        channels=tuple(str(label) for label in data.labels),
        name="rawtoaces training data (190)",
        negative="clip",
    )


def xyz_to_lab(xyz: ArrayLike, white_xyz: ArrayLike) -> FloatArray:
    """CIELAB of ``xyz`` ``(..., 3)`` against the reference white ``white_xyz`` ``(3,)`` (Y = 1)."""
    import colour

    white = np.asarray(white_xyz, dtype=np.float64)
    return np.asarray(
        colour.XYZ_to_Lab(np.asarray(xyz, dtype=np.float64), colour.XYZ_to_xy(white)),
        dtype=np.float64,
    )


def delta_e_2000(lab_a: ArrayLike, lab_b: ArrayLike) -> FloatArray:
    """CIEDE2000 colour difference between CIELAB values ``(..., 3)`` → ``(...)``."""
    import colour

    return np.asarray(
        colour.delta_E(
            np.asarray(lab_a, dtype=np.float64), np.asarray(lab_b, dtype=np.float64), "CIE 2000"
        ),
        dtype=np.float64,
    )


def aces_idt_matrix(
    wavelength_nm: ArrayLike, values: ArrayLike, illuminant_spd: Spectrum
) -> tuple[FloatArray, FloatArray]:
    """The ACES IDT matrix (camera RGB → ACES2065-1) and the white-balance multipliers.

    ``colour.matrix_idt`` with its defaults (rawtoaces' 190 training reflectances, CIE 1931
    observer, CAT02 to the ACES white, rawtoaces' optimisation in CIELAB). The sensitivities must
    cover 380–780 nm (rawtoaces' range).
    """
    import colour

    grid = WavelengthGrid(380.0, 780.0, 5.0)
    sensitivities = camera_sensitivities(wavelength_nm, values, "camera")
    if not np.allclose(sensitivities.wavelengths, grid.wavelength_nm):
        raise InputError(
            "the IDT needs sensitivities on 380–780 nm at 5 nm (the camera files are)",
            source="sensitivities",
        )
    spd = illuminant_spd.resample(grid)
    sd = colour.SpectralDistribution(spd.values, spd.wavelength_nm, name=spd.name)
    matrix, white_balance = colour.matrix_idt(sensitivities, sd)
    return np.asarray(matrix, dtype=np.float64), np.asarray(white_balance, dtype=np.float64)
