"""The one seam to colour-science: its data as project types, and the few colorimetric computations used.

Importing colour-science costs about 1.1 s of CPU, more than the rest of ``calib`` together, so no
module of ``calib`` or ``mocks`` imports it: they call the named accessors here, which import it on
first use (:func:`_colour`). Data comes back as :class:`~calib.core.spectra.Spectrum` /
:class:`~calib.core.spectra.MultiSpectrum` (non-negative curves) or as plain arrays where values may
be negative (colour-matching functions, the CIE daylight basis).

Data: the CIE illuminants and light sources (:func:`illuminants`, :func:`light_sources`; a lamp by
name is :func:`calib.core.lamp_specs.colour_lamp`), CIE daylight at a CCT (:func:`cie_daylight`) and its basis
(:func:`cie_daylight_basis`), camera sensitivities (:func:`camera_sensitivities`,
:func:`rawtoaces_sensitivity_path`), ColorChecker reflectances (:func:`colorchecker`), the CIE test
colour samples (:func:`cie_test_colour_samples`), rawtoaces' training reflectances
(:func:`training_reflectances`) and colour-matching functions (:func:`colour_matching_functions`).

Colorimetry: CIE 1931 ``XYZ`` of an emission spectrum (:func:`emission_xyz`), CCT by colour-science's
methods (:func:`cct_methods`, :func:`correlated_colour_temperature_k`) and the linear sRGB colour of a
blackbody (:func:`blackbody_linear_srgb`).
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import InputError, SpectrumError
from calib.core.spectra import MultiSpectrum, Spectrum, WavelengthGrid

#: The ColorChecker data used unless another is named.
DEFAULT_COLORCHECKER = "BabelColor Average"
#: The observer of every colorimetric figure the project reports.
CIE_1931_2_DEGREE = "CIE 1931 2 Degree Standard Observer"
#: The range and step on which an emission spectrum is integrated against the CMFs.
COLORIMETRY_AXIS_NM = (360.0, 830.0, 1.0)


def _colour() -> Any:
    """The colour-science package, imported on first use (about 1.1 s of CPU).

    Importing colour-science switches NumPy's global print options to the 1.13 legacy style; the
    caller's options are put back, so using ``calib`` changes nothing in how a user's arrays print.
    """
    if "colour" in sys.modules:
        return sys.modules["colour"]
    print_options = np.get_printoptions()
    try:
        import colour
    finally:
        np.set_printoptions(**print_options)
    return colour


def _entry(table: Mapping[str, Any], name: str, what: str, source: str) -> Any:
    """``table[name]``, or an :class:`InputError` listing the names colour-science has."""
    if name not in table:
        raise InputError(
            f"colour-science has no {what} {name!r}; choose from {', '.join(sorted(table))}",
            source=source,
        )
    return table[name]


# ------------------------------------------------------------------------------------ light sources


def _spectra(table: Mapping[str, Any]) -> Mapping[str, Spectrum]:
    return MappingProxyType(
        {str(name): Spectrum.from_colour(sd, name=str(name)) for name, sd in table.items()}
    )


@lru_cache(maxsize=1)
def illuminants() -> Mapping[str, Spectrum]:
    """colour-science's CIE illuminants (``SDS_ILLUMINANTS``: ``A``, ``D65``, ``FL2``, ``LED-B3`` …).

    Examples
    --------
    >>> illuminants()["D65"].range_nm
    (300.0, 780.0)
    """
    return _spectra(_colour().SDS_ILLUMINANTS)


@lru_cache(maxsize=1)
def light_sources() -> Mapping[str, Spectrum]:
    """colour-science's measured light sources (``SDS_LIGHT_SOURCES``: ``Kinoton 75P`` …)."""
    return _spectra(_colour().SDS_LIGHT_SOURCES)


SpectralFileFormat = Literal["ies", "xrite", "sekonic", "uprtek"]


@dataclass(frozen=True)
class SpectralFile:
    """A measured spectrum colour-science read from a file: the spectrum, and what the file says
    of it (IES TM-27-14's spectral quantity and bandwidth; ``None`` where it says nothing)."""

    spectrum: Spectrum
    quantity: str | None = None
    bandwidth_nm: float | None = None


def spectral_file(
    path: str | Path, file_format: SpectralFileFormat, sample: str | None = None
) -> SpectralFile:
    """A spectrum from an IES TM-27-14 XML (``ies``), X-Rite (``xrite``: ``sample`` picks one of
    several), Sekonic or UPRtek light-meter export, read by colour-science.

    Raises
    ------
    SpectrumError
        Not readable as that format, or no such sample (the file named).
    """
    colour = _colour()
    source = str(path)
    try:
        if file_format == "ies":
            distribution = colour.SpectralDistribution_IESTM2714(source).read()
        elif file_format == "sekonic":
            distribution = colour.io.SpectralDistribution_Sekonic(source).read()
        elif file_format == "uprtek":
            distribution = colour.io.SpectralDistribution_UPRTek(source).read()
        else:
            samples = colour.io.read_sds_from_xrite_file(source)
            if sample is None and len(samples) != 1:
                raise SpectrumError(
                    f"{len(samples)} samples ({', '.join(samples)}); choose one by name",
                    source=source,
                )
            name = sample if sample is not None else next(iter(samples))
            distribution = _entry(samples, name, "sample", source)
    except (ValueError, KeyError, IndexError, OSError) as exc:
        if isinstance(exc, InputError):
            raise SpectrumError(str(exc).removeprefix(f"{source}: "), source=source) from None
        raise SpectrumError(f"not a readable {file_format} file: {exc}", source=source) from None
    spectrum = Spectrum.from_colour(distribution, name=Path(source).name)
    quantity = getattr(distribution, "spectral_quantity", None) if file_format == "ies" else None
    fwhm = getattr(distribution, "bandwidth_FWHM", None) if file_format == "ies" else None
    return SpectralFile(
        Spectrum(spectrum.wavelength_nm, np.clip(spectrum.values, 0.0, None), name=spectrum.name),
        str(quantity) if quantity else None,
        float(fwhm) if fwhm else None,
    )


def cie_daylight(cct_k: float) -> Spectrum:
    """CIE daylight at a correlated colour temperature (4000–25000 K), 300–830 nm, named ``D65`` …

    Raises
    ------
    InputError
        ``cct_k`` outside the range the CIE defines daylight for.
    """
    if not 4000.0 <= cct_k <= 25000.0:
        raise InputError(f"CIE daylight is defined for 4000–25000 K, got {cct_k:g}", source="cct")
    colour = _colour()
    xy = colour.temperature.CCT_to_xy_CIE_D(cct_k)
    return Spectrum.from_colour(colour.sd_CIE_illuminant_D_series(xy), name=f"D{cct_k / 100:.0f}")


def cie_daylight_basis() -> tuple[FloatArray, FloatArray]:
    """The CIE daylight basis ``S0, S1, S2``: ``(wavelength_nm (n,), values (n, 3))``.

    ``S1`` and ``S2`` change sign, so they are plain curves, not spectra.
    """
    table = _colour().colorimetry.SDS_BASIS_FUNCTIONS_CIE_ILLUMINANT_D_SERIES
    wavelength = np.asarray(table["S0"].wavelengths, dtype=np.float64)
    values = np.stack(
        [
            np.interp(wavelength, table[key].wavelengths, table[key].values)
            for key in ("S0", "S1", "S2")
        ],
        axis=1,
    )
    return wavelength, values


# ---------------------------------------------------------------------------------------- cameras


def camera_sensitivities() -> dict[str, MultiSpectrum]:
    """colour-science's measured cameras (``MSDS_CAMERA_SENSITIVITIES``), as stored (not normalised)."""
    return {
        str(key): MultiSpectrum(
            np.asarray(data.wavelengths, dtype=np.float64),
            np.asarray(data.values, dtype=np.float64),
            name=str(key),
            negative="clip",
        )
        for key, data in _colour().MSDS_CAMERA_SENSITIVITIES.items()
    }


def rawtoaces_sensitivity_path(file_name: str) -> Path:
    """Where a rawtoaces sensitivity CSV that ships inside colour-science lies (it may not exist)."""
    return (
        Path(_colour().__file__).parent / "characterisation" / "datasets" / "rawtoaces" / file_name
    )


# --------------------------------------------------------------------------------- patch spectra


def _patch_set(sds: Mapping[str, Any], channel_names: tuple[str, ...], name: str) -> MultiSpectrum:
    """colour-science spectral distributions as one :class:`MultiSpectrum` on their common range.

    Sets whose members are sampled differently are interpolated to the finest step of the set.
    """
    members = list(sds.values())
    axes = [np.asarray(sd.wavelengths, dtype=np.float64) for sd in members]
    if all(axis.shape == axes[0].shape and np.allclose(axis, axes[0]) for axis in axes):
        wavelength = axes[0]
        values = np.stack([np.asarray(sd.values, dtype=np.float64) for sd in members], axis=1)
    else:
        step = min(float(np.min(np.diff(axis))) for axis in axes)
        start = max(float(axis[0]) for axis in axes)
        stop = min(float(axis[-1]) for axis in axes)
        wavelength = np.arange(start, stop + step / 2, step)
        values = np.stack(
            [
                np.interp(wavelength, axis, np.asarray(sd.values, dtype=np.float64))
                for axis, sd in zip(axes, members, strict=True)
            ],
            axis=1,
        )
    return MultiSpectrum(wavelength, values, channels=channel_names, name=name, negative="clip")


def colorchecker(name: str = DEFAULT_COLORCHECKER) -> MultiSpectrum:
    """The 24 ColorChecker reflectances of colour-science's ``SDS_COLOURCHECKERS[name]``.

    Parameters
    ----------
    name
        ``"BabelColor Average"`` (default), ``"ColorChecker N Ohta"``, ``"ISO 17321-1"`` …

    Returns
    -------
    MultiSpectrum
        Reflectance factors (0–1), one channel per patch in the chart's reading order (dark skin,
        light skin, blue sky, …, black), on the data's own wavelengths.

    Raises
    ------
    InputError
        colour-science has no ColorChecker called ``name`` (the known names are listed).

    Examples
    --------
    >>> chart = colorchecker()
    >>> chart.values.shape, chart.channels[0], chart.range_nm
    ((36, 24), 'dark skin', (380.0, 730.0))
    """
    patches = _entry(_colour().SDS_COLOURCHECKERS, name, "colour checker", "chart")
    return _patch_set(patches, tuple(patches), f"ColorChecker ({name})")


def cie_test_colour_samples(name: str = "CIE 1995") -> MultiSpectrum:
    """The CIE test colour samples (``colour.quality.datasets.SDS_TCS[name]``).

    ``"CIE 1995"`` has the 14 samples of CIE 13.3 (colour rendering index); ``"CIE 2024"`` 15.
    """
    samples = _entry(_colour().quality.datasets.SDS_TCS, name, "test colour samples", "chart")
    return _patch_set(
        samples, tuple(f"{name} {key}" for key in samples), f"test colour samples ({name})"
    )


def training_reflectances() -> MultiSpectrum:
    """The 190 training reflectances of rawtoaces (``read_training_data_rawtoaces_v1``), 380–780 nm."""
    training = _colour().characterisation.read_training_data_rawtoaces_v1()
    return MultiSpectrum(
        np.asarray(training.wavelengths),
        np.asarray(training.values),
        channels=training.labels,
        name="rawtoaces training reflectances",
        negative="clip",  # a few entries are -1e-17
    )


def colour_matching_functions(name: str = CIE_1931_2_DEGREE) -> tuple[FloatArray, FloatArray]:
    """Colour-matching functions (or cone fundamentals) ``MSDS_CMFS[name]``: ``(wavelength_nm, values)``.

    Shapes ``(n,)`` and ``(n, 3)``; RGB colour-matching functions have negative lobes, kept as they are.
    """
    data = _entry(_colour().MSDS_CMFS, name, "colour-matching functions", "cmfs")
    # Copies: a caller may edit its arrays without touching colour-science's tables.
    return np.array(data.wavelengths, dtype=np.float64), np.array(data.values, dtype=np.float64)


# ------------------------------------------------------------------------------------ colorimetry


def emission_xyz(spd: Spectrum) -> FloatArray:
    """CIE 1931 2° ``XYZ`` of an emission spectrum, zero outside its range, shape ``(3,)`` (absolute).

    Integrated on :data:`COLORIMETRY_AXIS_NM` (colour-science's ``sd_to_XYZ``; its warnings silenced).
    """
    colour = _colour()
    start, stop, step = COLORIMETRY_AXIS_NM
    wavelength = np.arange(start, stop + step, step)
    sd = colour.SpectralDistribution(spd.at(wavelength), wavelength, name=spd.name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.asarray(
            colour.sd_to_XYZ(sd, colour.MSDS_CMFS[CIE_1931_2_DEGREE]), dtype=np.float64
        )


def cct_methods() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """colour-science's CCT methods: ``(uv methods, xy methods)``."""
    temperature = _colour().temperature
    return tuple(temperature.UV_TO_CCT_METHODS), tuple(temperature.XY_TO_CCT_METHODS)


def correlated_colour_temperature_k(
    xyz: FloatArray, methods: tuple[str, ...]
) -> tuple[dict[str, float], float, tuple[float, float]]:
    """CCT of ``XYZ`` by each method, ``Duv`` (Ohno 2013) and CIE 1931 ``xy``.

    Raises
    ------
    InputError
        A method colour-science does not offer (the offered ones are listed).
    """
    colour = _colour()
    xy = colour.XYZ_to_xy(xyz)
    uv = colour.UCS_to_uv(colour.XYZ_to_UCS(xyz))
    uv_methods, xy_methods = cct_methods()
    values: dict[str, float] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ohno = np.asarray(colour.uv_to_CCT(uv, method="Ohno 2013"), dtype=np.float64)
        for method in methods:
            if method in uv_methods:
                values[method] = float(np.ravel(colour.uv_to_CCT(uv, method=method))[0])
            elif method in xy_methods:
                values[method] = float(np.ravel(colour.xy_to_CCT(xy, method=method))[0])
            else:
                raise InputError(
                    f"unknown CCT method {method!r}; colour-science offers "
                    f"{sorted(set(uv_methods) | set(xy_methods))}",
                    source="cct",
                )
    return values, float(ohno[1]), (float(xy[0]), float(xy[1]))


def blackbody_linear_srgb(cct_k: float) -> FloatArray:
    """Linear sRGB of a blackbody at ``cct_k`` (360–830 nm, CIE 1931 2°, no adaptation), shape ``(3,)``."""
    colour = _colour()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        body = colour.sd_blackbody(cct_k, colour.SpectralShape(360, 830, 1))
        xyz = colour.sd_to_XYZ(body, colour.MSDS_CMFS[CIE_1931_2_DEGREE])
        return np.asarray(colour.XYZ_to_RGB(xyz, "sRGB"), dtype=np.float64)


# ------------------------------------------------------------------- what a calibrated camera is for

#: The illuminants the camera's uses are computed for, by the names used on the command line.
USE_ILLUMINANTS: tuple[str, ...] = ("D50", "D55", "D65", "A")
#: colour-science's ColorChecker with spectral reflectances to 380–780 nm (Ohta's measurements).
COLORCHECKER_OHTA = "ColorChecker N Ohta"
#: ACES' D55 is the CIE daylight at 5500 K on the 1968 temperature scale (c₂ = 1.4388e-2 m·K).
_DAYLIGHT_C2_RATIO = 1.4388 / 1.4380


def use_illuminant(name: str) -> Spectrum:
    """The relative spectral power of ``D50``, ``D55``, ``D65`` (CIE daylight, 1968 scale) or ``A``.

    Raises
    ------
    InputError
        Any other name, with the names allowed.
    """
    key = name.strip().upper()
    if key == "A":
        return illuminants()["A"]
    if key in ("D50", "D55", "D65"):
        daylight = cie_daylight(float(key[1:]) * 100.0 * _DAYLIGHT_C2_RATIO)
        return Spectrum(daylight.wavelength_nm, daylight.values, name=key)
    raise InputError(
        f"unknown illuminant {name!r}; choose one of {', '.join(USE_ILLUMINANTS)}",
        source="--illuminant",
    )


def cie_1931_observer() -> MultiSpectrum:
    """The CIE 1931 2° colour-matching functions x̄, ȳ, z̄ (360–830 nm, 1 nm)."""
    wavelength, values = colour_matching_functions(CIE_1931_2_DEGREE)
    return MultiSpectrum(wavelength, values, channels=("x", "y", "z"), name="CIE 1931 2°")


def rgb_camera_sensitivities(wavelength_nm: ArrayLike, values: ArrayLike, name: str) -> Any:
    """colour's ``RGB_CameraSensitivities`` of ``values`` ``(f, 3)`` (R, G, B; colour always labels
    them ``red, green, blue``)."""
    return _colour().characterisation.RGB_CameraSensitivities(
        np.asarray(values, dtype=np.float64),
        np.asarray(wavelength_nm, dtype=np.float64),
        name=name,
    )


def xyz_to_lab(xyz: ArrayLike, white_xyz: ArrayLike) -> FloatArray:
    """CIELAB of ``xyz`` ``(..., 3)`` against the reference white ``white_xyz`` ``(3,)`` (Y = 1)."""
    colour = _colour()
    white = np.asarray(white_xyz, dtype=np.float64)
    return np.asarray(
        colour.XYZ_to_Lab(np.asarray(xyz, dtype=np.float64), colour.XYZ_to_xy(white)),
        dtype=np.float64,
    )


def delta_e_2000(lab_a: ArrayLike, lab_b: ArrayLike) -> FloatArray:
    """CIEDE2000 colour difference between CIELAB values ``(..., 3)`` → ``(...)``."""
    return np.asarray(
        _colour().delta_E(
            np.asarray(lab_a, dtype=np.float64), np.asarray(lab_b, dtype=np.float64), "CIE 2000"
        ),
        dtype=np.float64,
    )


def aces_idt_matrix(
    wavelength_nm: ArrayLike, values: ArrayLike, illuminant_spd: Spectrum
) -> tuple[FloatArray, FloatArray]:
    """The ACES IDT matrix (camera RGB → ACES2065-1) and the white-balance multipliers.

    ``colour.matrix_idt`` with its defaults (rawtoaces' 190 training reflectances, CIE 1931
    observer, CAT02 to the ACES white, rawtoaces' optimisation in CIELAB), its objective given
    with its exact gradient (:func:`_rawtoaces_v1_with_gradient`: the same matrix to 10⁻⁵ or closer,
    in a tenth of the time or less). The sensitivities must cover 380–780 nm at 5 nm (rawtoaces'
    range).

    References
    ----------
    The Academy (2015), P-2013-001: Recommended procedures for the creation and use of digital
    camera system input device transforms (IDTs).
    """
    colour = _colour()
    grid = WavelengthGrid(380.0, 780.0, 5.0)
    sensitivities = rgb_camera_sensitivities(wavelength_nm, values, "camera")
    if not np.allclose(sensitivities.wavelengths, grid.wavelength_nm):
        raise InputError(
            "the IDT needs sensitivities on 380–780 nm at 5 nm (the camera files are)",
            source="sensitivities",
        )
    spd = illuminant_spd.resample(grid)
    sd = colour.SpectralDistribution(spd.values, spd.wavelength_nm, name=spd.name)
    matrix, white_balance = colour.matrix_idt(
        sensitivities,
        sd,
        optimisation_factory=_rawtoaces_v1_with_gradient,
        optimisation_kwargs={"jac": True},
    )
    return np.asarray(matrix, dtype=np.float64), np.asarray(white_balance, dtype=np.float64)


#: CIE 1976 L*a*b*'s change of branch in f(t) = t^(1/3), and the slope of its linear part.
_LAB_EPSILON, _LAB_SLOPE = (6.0 / 29.0) ** 3, 841.0 / 108.0


def _rawtoaces_v1_with_gradient() -> tuple[FloatArray, Any, Any, Any]:
    """colour's ``optimisation_factory_rawtoaces_v1`` (the same start, objective and white-preserving
    matrix) with the objective's exact gradient beside its value, in plain NumPy.

    colour's objective goes through its checked colour-model functions and its gradient through
    finite differences: 7 evaluations per BFGS step, 70–100 ms per IDT (``bench/uses_speed.py``),
    three IDTs per estimate's outputs; here one evaluation per step, 8–11 ms per IDT.

    The objective is ‖Lab(A·M·rgb) − Lab_training‖ over the 190 training reflectances, M the 3×3
    matrix whose rows sum to 1 (its first two columns are the 6 unknowns), A the ACES2065-1
    primaries' RGB → XYZ and Lab against the ACES white.
    """
    colour = _colour()
    aces = colour.models.RGB_COLOURSPACE_ACES2065_1
    to_xyz = np.asarray(aces.matrix_RGB_to_XYZ, dtype=np.float64)
    white = np.asarray(colour.xyY_to_XYZ([*aces.whitepoint, 1.0]), dtype=np.float64)

    def finaliser(m: ArrayLike) -> FloatArray:
        first_two = np.reshape(np.asarray(m, dtype=np.float64), (3, 2))
        return np.column_stack([first_two, 1.0 - first_two.sum(axis=1)])

    def lab_and_slope(xyz: FloatArray) -> tuple[FloatArray, FloatArray]:
        t = xyz / white
        cube = t > _LAB_EPSILON
        f = np.where(cube, np.cbrt(np.where(cube, t, 1.0)), _LAB_SLOPE * t + 16.0 / 116.0)
        slope = np.where(cube, 1.0 / (3.0 * np.square(np.where(cube, f, 1.0))), _LAB_SLOPE)
        lab = np.stack(
            [
                116.0 * f[..., 1] - 16.0,
                500.0 * (f[..., 0] - f[..., 1]),
                200.0 * (f[..., 1] - f[..., 2]),
            ],
            axis=-1,
        )
        return lab, slope / white

    def to_lab(xyz: ArrayLike) -> FloatArray:
        return lab_and_slope(np.asarray(xyz, dtype=np.float64))[0]

    def objective(m: FloatArray, rgb: FloatArray, lab: FloatArray) -> tuple[float, FloatArray]:
        matrix = finaliser(m)
        lab_t, slope = lab_and_slope(rgb @ (to_xyz @ matrix).T)
        residual = lab_t - lab
        value = float(np.sqrt(np.sum(np.square(residual))))
        if value == 0.0:
            return value, np.zeros(6)
        r_l, r_a, r_b = residual[:, 0], residual[:, 1], residual[:, 2]
        d_f = np.stack(
            [500.0 * r_a, 116.0 * r_l - 500.0 * r_a + 200.0 * r_b, -200.0 * r_b], axis=-1
        )
        d_matrix = to_xyz.T @ (d_f * slope / value).T @ rgb  # ∂value/∂M, (3, 3)
        return value, (d_matrix[:, :2] - d_matrix[:, 2:]).ravel()

    return np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0]), objective, to_lab, finaliser
