"""Built-in spectral line lists: emission lines of discharge lamps and phosphors, absorption features of
sunlight, their blends at a given resolution, and line spectra rendered from them.

Wavelengths are in air (nm). Sources:

- Atomic lines (Hg I, Ne I, Ar I, Na I, He I, H I, Cd I): NIST Atomic Spectra Database / NIST Handbook of
  Basic Atomic Spectroscopic Data (Sansonetti & Martin 2005, "strong lines", air wavelengths); the
  relative intensities are the Handbook's for an arc or discharge source, used only to weight lines and
  to render a plausible spectrum — a real lamp's ratios differ.
- Phosphor emission of tri-phosphor fluorescent lamps (Tb³⁺ in the green phosphor, Eu³⁺ in Y₂O₃:Eu red):
  the peak wavelengths commonly used to calibrate spectrometers with a compact fluorescent lamp (they
  are crystal-field multiplets, not atomic standards: each line carries an uncertainty of 0.5 nm, and
  the mapping weighs it so). The blue BAM (Eu²⁺) band is a broad band, not a line.
- Solar absorption (Fraunhofer letters, after Rowland's and later atlases) and telluric O₂ bands:
  the centres of the features as they appear at ~0.1–1 nm resolution (a blend's centre, e.g. the G
  band, the O₂ B band's strong part), with the atomic components where the feature is one line. Their
  uncertainty says how much the centre moves with resolution.

A list is looked up by name (:data:`LINE_LISTS`); :func:`blends` groups lines a given resolution
cannot separate (Tb 542.4 + Hg 546.1 at 5 nm, the Mg b triplet at 1 nm) into one feature whose centre is
their intensity-weighted mean; :func:`line_spectrum` renders a list as a :class:`Spectrum`
(Gaussians of each line's own width, at least ``fwhm_nm``) and :func:`builtin_lamp` resolves
``"builtin:NAME[:FWHM_NM]"`` specs (the form ``calib estimate --spectrum`` accepts).

Examples
--------
>>> [b.label for b in blends(line_list("cfl-triphosphor"), 5.0) if "546" in b.label]
['Tb 542.4 + Hg 546.1']
>>> lamp = builtin_lamp("builtin:hg")
>>> abs(float(lamp.wavelength_nm[lamp.values.argmax()]) - 435.83) < 0.05  # the strongest line
True
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import optimize

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.spectra import Spectrum

LineKind = Literal["emission", "absorption"]
NIST = "NIST ASD / Handbook of Basic Atomic Spectroscopic Data (air)"
PHOSPHOR = "tri-phosphor CFL peak (calibration practice; crystal-field multiplet)"
SOLAR = "solar Fraunhofer / telluric feature centre (air)"
#: Range and step of a rendered line spectrum.
RENDER_RANGE_NM = (360.0, 830.0)
RENDER_STEP_NM = 0.05
#: Default rendered width (FWHM, nm) of a line with no width of its own: narrower than any camera
#: resolves, wide enough to be sampled.
DEFAULT_FWHM_NM = 0.2
BUILTIN_PREFIX = "builtin:"


@dataclass(frozen=True)
class Line:
    """One spectral line or feature.

    Attributes
    ----------
    label
        ``"Hg 546.1"``, ``"Fraunhofer D2"``.
    wavelength_nm
        Centre in air.
    strength
        Relative intensity (emission) or depth (absorption) within its list.
    species
        ``"Hg I"``, ``"Tb3+"``, ``"O2 (telluric)"`` …
    kind
        ``"emission"`` or ``"absorption"``.
    width_nm
        Intrinsic FWHM (a phosphor multiplet, a molecular band); 0 for an atomic line.
    uncertainty_nm
        How well the centre is known for this use (atomic lines: 0.005 nm).
    source
        Where the number comes from.
    """

    label: str
    wavelength_nm: float
    strength: float
    species: str
    kind: LineKind = "emission"
    width_nm: float = 0.0
    uncertainty_nm: float = 0.005
    source: str = NIST


def _atomic(species: str, entries: Sequence[tuple[float, float]]) -> tuple[Line, ...]:
    element = species.split()[0]
    return tuple(
        Line(f"{element} {wavelength:.1f}", wavelength, strength, species)
        for wavelength, strength in entries
    )


#: Hg I, visible (air): the lines every fluorescent lamp shows.
MERCURY = _atomic(
    "Hg I",
    (
        (404.6563, 1800.0),
        (407.7837, 150.0),
        (435.8328, 4000.0),
        (491.6068, 80.0),
        (546.0735, 1100.0),
        (576.9598, 240.0),
        (579.0663, 280.0),
    ),
)
NEON = _atomic(
    "Ne I",
    (
        (585.2488, 20000.0),
        (588.1895, 10000.0),
        (594.4834, 5000.0),
        (597.5534, 6000.0),
        (602.9997, 2000.0),
        (607.4338, 10000.0),
        (609.6163, 30000.0),
        (614.3063, 10000.0),
        (616.3594, 10000.0),
        (621.7281, 10000.0),
        (626.6495, 10000.0),
        (630.4789, 1000.0),
        (633.4428, 10000.0),
        (638.2992, 10000.0),
        (640.2248, 20000.0),
        (650.6528, 15000.0),
        (653.2882, 1000.0),
        (659.8953, 10000.0),
        (667.8276, 5000.0),
        (671.7043, 2000.0),
        (692.9467, 100000.0),
        (703.2413, 50000.0),
        (717.3938, 10000.0),
        (724.5167, 10000.0),
        (743.8899, 10000.0),
    ),
)
ARGON = _atomic(
    "Ar I",
    (
        (415.8590, 400.0),
        (420.0674, 400.0),
        (425.9362, 200.0),
        (427.2169, 150.0),
        (430.0101, 100.0),
        (696.5431, 10000.0),
        (706.7218, 10000.0),
        (714.7042, 1000.0),
        (727.2936, 2000.0),
        (738.3980, 10000.0),
        (750.3869, 20000.0),
        (751.4652, 15000.0),
        (763.5106, 25000.0),
        (772.3761, 15000.0),
        (794.8176, 20000.0),
        (800.6157, 20000.0),
        (801.4786, 25000.0),
        (810.3693, 20000.0),
        (811.5311, 35000.0),
    ),
)
SODIUM = _atomic("Na I", ((588.9950, 80000.0), (589.5924, 40000.0)))
HELIUM = _atomic(
    "He I",
    (
        (447.1479, 200.0),
        (471.3146, 30.0),
        (492.1931, 20.0),
        (501.5678, 100.0),
        (587.5621, 500.0),
        (667.8151, 100.0),
        (706.5190, 70.0),
    ),
)
HYDROGEN = (
    Line("H-alpha 656.3", 656.281, 500.0, "H I"),
    Line("H-beta 486.1", 486.133, 180.0, "H I"),
    Line("H-gamma 434.0", 434.047, 90.0, "H I"),
    Line("H-delta 410.2", 410.174, 70.0, "H I"),
)
CADMIUM = _atomic(
    "Cd I", ((467.8149, 200.0), (479.9912, 300.0), (508.5822, 1000.0), (643.8470, 2000.0))
)


def _phosphor(species: str, entries: Sequence[tuple[float, float, float]]) -> tuple[Line, ...]:
    element = species.rstrip("0123456789+").strip()
    return tuple(
        Line(
            f"{element} {wavelength:.1f}",
            wavelength,
            strength,
            species,
            width_nm=width,
            uncertainty_nm=0.5,
            source=PHOSPHOR,
        )
        for wavelength, strength, width in entries
    )


#: Tb³⁺ (green phosphor) and Eu³⁺ (Y₂O₃:Eu red phosphor) peaks of a tri-phosphor lamp, with a
#: typical warm-white lamp's relative heights (Hg 546.1 = 1100 for scale) and multiplet widths.
TERBIUM = _phosphor(
    "Tb3+",
    ((487.7, 600.0, 2.0), (542.4, 1500.0, 2.0), (584.0, 150.0, 2.0), (625.7, 60.0, 2.0)),
)
EUROPIUM = _phosphor(
    "Eu3+",
    (
        (587.6, 120.0, 1.5),
        (593.4, 200.0, 1.5),
        (599.7, 150.0, 1.5),
        (611.6, 3000.0, 1.5),
        (631.1, 250.0, 1.5),
        (650.8, 120.0, 2.0),
        (662.6, 60.0, 2.0),
        (687.7, 60.0, 2.0),
        (707.0, 80.0, 2.0),
        (712.3, 60.0, 2.0),
    ),
)
#: The BAM (BaMgAl₁₀O₁₇:Eu²⁺) blue phosphor: a broad band (for rendering only; not a mapping line).
BLUE_PHOSPHOR_BAND = Line(
    "BAM 450", 450.0, 60.0, "Eu2+", width_nm=50.0, uncertainty_nm=10.0, source=PHOSPHOR
)


def _absorption(
    label: str, wavelength: float, depth: float, species: str, width: float, uncertainty: float
) -> Line:
    return Line(label, wavelength, depth, species, "absorption", width, uncertainty, SOLAR)


#: Fraunhofer lines and telluric bands in sunlight at the ground (depth: a relative weight).
SOLAR_FEATURES = (
    _absorption("Fraunhofer G", 430.78, 0.5, "Fe I + Ca I + CH (G band)", 0.6, 0.15),
    _absorption("Fraunhofer H-gamma", 434.047, 0.3, "H I", 0.2, 0.02),
    _absorption("Fraunhofer d", 466.814, 0.15, "Fe I", 0.0, 0.02),
    _absorption("Fraunhofer F (H-beta)", 486.134, 0.7, "H I", 0.2, 0.02),
    _absorption("Fraunhofer c", 495.761, 0.15, "Fe I", 0.0, 0.02),
    _absorption("Fraunhofer b4", 516.733, 0.35, "Mg I + Fe I", 0.0, 0.02),
    _absorption("Fraunhofer b2", 517.270, 0.6, "Mg I", 0.0, 0.02),
    _absorption("Fraunhofer b1", 518.362, 0.7, "Mg I", 0.0, 0.02),
    _absorption("Fraunhofer E2", 527.039, 0.35, "Fe I", 0.0, 0.02),
    _absorption("Fraunhofer D2", 588.995, 0.8, "Na I", 0.0, 0.01),
    _absorption("Fraunhofer D1", 589.592, 0.7, "Na I", 0.0, 0.01),
    _absorption("Fraunhofer a (O2)", 627.8, 0.3, "O2 (telluric)", 1.5, 0.3),
    _absorption("Fraunhofer C (H-alpha)", 656.281, 0.8, "H I", 0.2, 0.02),
    _absorption("Fraunhofer B (O2)", 687.5, 1.0, "O2 (telluric)", 1.8, 0.3),
    _absorption("water 718", 718.5, 0.4, "H2O (telluric)", 6.0, 1.5),
    _absorption("Fraunhofer A (O2)", 760.5, 1.2, "O2 (telluric)", 2.5, 0.5),
)

#: Every built-in list, by the name ``builtin:NAME`` and :func:`line_list` take.
LINE_LISTS: dict[str, tuple[Line, ...]] = {
    "hg": MERCURY,
    "mercury": MERCURY,
    "ne": NEON,
    "neon": NEON,
    "ar": ARGON,
    "argon": ARGON,
    "hg-ar": MERCURY + ARGON,
    "na": SODIUM,
    "he": HELIUM,
    "h": HYDROGEN,
    "cd": CADMIUM,
    "cfl-triphosphor": MERCURY + TERBIUM + EUROPIUM,
    "solar": SOLAR_FEATURES,
    "fraunhofer": SOLAR_FEATURES,
}


def line_list(name: str) -> tuple[Line, ...]:
    """A built-in list by name (case-insensitive; see :data:`LINE_LISTS`)."""
    key = name.strip().lower()
    if key not in LINE_LISTS:
        raise InputError(
            f"no built-in line list {name!r}; choose from {', '.join(sorted(LINE_LISTS))}",
            source="line list",
        )
    return LINE_LISTS[key]


@dataclass(frozen=True)
class Blend:
    """Lines a resolution cannot separate, seen as one feature.

    Attributes
    ----------
    lines
        The components, by wavelength.
    wavelength_nm
        Their strength-weighted centre (what a feature's centroid measures at this resolution).
    strength
        Summed strength.
    uncertainty_nm
        The components' largest uncertainty.
    """

    lines: tuple[Line, ...]
    wavelength_nm: float
    strength: float
    uncertainty_nm: float

    @property
    def label(self) -> str:
        return " + ".join(line.label for line in self.lines)

    @property
    def reference(self) -> Line:
        """The component whose position a fit reports: the best known, the strongest of those."""
        return min(self.lines, key=lambda line: (line.uncertainty_nm, -line.strength))

    @property
    def kind(self) -> LineKind:
        return self.lines[0].kind


def blends(lines: Sequence[Line], resolution_nm: float) -> list[Blend]:
    """Group lines closer than ``resolution_nm`` (FWHM, chained) into blends, by wavelength.

    A blend's centre is the strength-weighted mean of its components, each component's strength
    spread over its own width: what the centroid of the feature measures when the components are
    not resolved. Lines of different kinds are never blended.
    """
    if not lines:
        return []
    ordered = sorted(lines, key=lambda line: (line.kind, line.wavelength_nm))
    groups: list[list[Line]] = [[ordered[0]]]
    for line in ordered[1:]:
        last = groups[-1][-1]
        gap = line.wavelength_nm - last.wavelength_nm
        reach = max(resolution_nm, 0.5 * (line.width_nm + last.width_nm))
        if line.kind == last.kind and gap < reach:
            groups[-1].append(line)
        else:
            groups.append([line])
    out = []
    for group in groups:
        weights = np.array([line.strength for line in group])
        centres = np.array([line.wavelength_nm for line in group])
        out.append(
            Blend(
                tuple(group),
                float(np.sum(weights * centres) / np.sum(weights)),
                float(weights.sum()),
                max(line.uncertainty_nm for line in group),
            )
        )
    return sorted(out, key=lambda blend: blend.wavelength_nm)


def line_spectrum(
    lines: Sequence[Line],
    *,
    fwhm_nm: float = DEFAULT_FWHM_NM,
    name: str = "line spectrum",
    continuum: float = 0.0,
) -> Spectrum:
    """Render lines as a spectrum: Gaussians of FWHM ``max(fwhm_nm, line width)``, peak ∝ strength.

    Emission lines add to ``continuum`` (relative to the strongest line); absorption features
    multiply a flat continuum of 1 by ``1 − depth``. Sampled every :data:`RENDER_STEP_NM` over
    :data:`RENDER_RANGE_NM`.
    """
    if not (math.isfinite(fwhm_nm) and fwhm_nm > 0):
        raise InputError(f"line width must be > 0 nm, got {fwhm_nm}", source=name)
    axis = np.arange(RENDER_RANGE_NM[0], RENDER_RANGE_NM[1] + 0.5 * RENDER_STEP_NM, RENDER_STEP_NM)
    emission = [line for line in lines if line.kind == "emission"]
    absorption = [line for line in lines if line.kind == "absorption"]
    values: FloatArray
    if emission:
        peak = max(line.strength for line in emission)
        values = np.full(axis.shape, continuum)
        for line in emission:
            values += line.strength / peak * _gaussian(axis, line, fwhm_nm)
    else:
        values = np.ones_like(axis)
    if absorption:
        deepest = max(line.strength for line in absorption)
        for line in absorption:
            values *= 1.0 - 0.9 * line.strength / deepest * _gaussian(axis, line, fwhm_nm)
    return Spectrum(axis, values, name=name)


def _gaussian(axis: FloatArray, line: Line, fwhm_nm: float) -> FloatArray:
    width = max(fwhm_nm, line.width_nm)
    sigma = width / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    return np.asarray(np.exp(-0.5 * ((axis - line.wavelength_nm) / sigma) ** 2), dtype=np.float64)


#: Rendered extras of a built-in lamp beyond its lines (a CFL's blue phosphor band).
_LAMP_EXTRAS: dict[str, tuple[Line, ...]] = {"cfl-triphosphor": (BLUE_PHOSPHOR_BAND,)}


def is_builtin(spec: str) -> bool:
    return spec.strip().lower().startswith(BUILTIN_PREFIX)


def builtin_lamp(spec: str) -> Spectrum:
    """The line spectrum of ``"builtin:NAME"`` or ``"builtin:NAME:FWHM_NM"``.

    The spectrum's name is the spec, so results say which list was used; its lines are
    :func:`builtin_lines` of the same spec.

    Raises
    ------
    InputError
        Not a ``builtin:`` spec, an unknown list, or a bad width.
    """
    name, fwhm = _parse_builtin(spec)
    lines = line_list(name) + _LAMP_EXTRAS.get(name, ())
    return line_spectrum(lines, fwhm_nm=fwhm, name=f"{BUILTIN_PREFIX}{name}")


def builtin_lines(spec: str) -> tuple[Line, ...]:
    """The line list of a ``builtin:`` spec (or of a lamp named like one)."""
    name, _ = _parse_builtin(spec)
    return line_list(name)


def _parse_builtin(spec: str) -> tuple[str, float]:
    text = spec.strip()
    if not is_builtin(text):
        raise InputError(
            f"expected builtin:NAME[:FWHM_NM], e.g. builtin:cfl-triphosphor, got {spec!r}",
            source="spectrum",
        )
    parts = text[len(BUILTIN_PREFIX) :].split(":")
    name = parts[0].lower()
    if not name:
        raise InputError(
            f"builtin: needs a list name, one of {', '.join(sorted(LINE_LISTS))}", source=spec
        )
    line_list(name)
    fwhm = DEFAULT_FWHM_NM
    if len(parts) > 2:
        raise InputError("expected builtin:NAME[:FWHM_NM]", source=spec)
    if len(parts) == 2:
        try:
            fwhm = float(parts[1])
        except ValueError:
            raise InputError(f"width {parts[1]!r} is not a number of nm", source=spec) from None
        if not (math.isfinite(fwhm) and fwhm > 0):
            raise InputError(f"width must be > 0 nm, got {fwhm:g}", source=spec)
    return name, fwhm


#: Hg lines a fluorescent lamp's tabulated spectrum (CIE FL tables, 5 nm steps) holds: 404.7, 435.8,
#: 546.1 and the 577/579 doublet.
TABULATED_MERCURY_NM = (404.6563, 435.8328, 546.0735, 576.9598, 579.0663)
#: Width given to those lines when they are restored (far below what a camera's slit image or a
#: spectroradiometer's slit resolves), and the sampling of the restored spectrum.
RESTORED_LINE_FWHM_NM = 1.0
RESTORED_LINE_STEP_NM = 0.2


def table_bandpass(offset_nm: FloatArray, step_nm: float) -> FloatArray:
    """The weight (1/nm) a table value at ``offset_nm`` from a line gives that line's power: the
    tables' triangular bandpass of FWHM = the step (unit area, zero beyond one step).

    The CIE FL tables were measured through such a bandpass: a line between two 5 nm steps adds
    to both, in proportion to its distance from each. FL1–FL9 bear it out to 1–2 %: the excess
    above the continuum at 440 nm over that at 435 nm is 0.199–0.202 (Hg 435.83: 0.83/4.17 =
    0.199), at 550 over 545 0.261–0.272 (Hg 546.07: 1.07/3.93 = 0.272)."""
    return np.clip(1.0 - np.abs(offset_nm) / step_nm, 0.0, None) / step_nm


def with_narrow_lines(
    spectrum: Spectrum,
    lines_nm: Sequence[float] = TABULATED_MERCURY_NM,
    *,
    fwhm_nm: float = RESTORED_LINE_FWHM_NM,
    step_nm: float = RESTORED_LINE_STEP_NM,
) -> Spectrum:
    """A tabulated line spectrum (CIE FL tables: the lamp through a triangular bandpass as wide as
    the step, :func:`table_bandpass`) with its lines restored as narrow Gaussians at their true
    wavelengths — the lamp a simulation shows a camera and a spectrometer (a real fluorescent
    lamp's mercury lines are ~0.1 nm wide, not 5 nm steps).

    Each line reaches the two table values either side of it. Those values are replaced by the
    continuum interpolated from the nearest values no line reaches; the lines' powers are the
    non-negative least-squares fit of the excess above that continuum by the bandpass (a line
    alone between two steps: the excess summed × the step). So no restored line keeps a shoulder
    one step away (decision 0072). Lines outside the table or without an excess are left out. The
    result, on a ``step_nm`` axis, has the table's total power.

    Examples
    --------
    >>> axis = np.arange(530.0, 565.0, 5.0)
    >>> table = Spectrum(axis, 1.0 + 10.0 * 5.0 * table_bandpass(axis - 546.0735, 5.0))
    >>> lamp = with_narrow_lines(table)
    >>> float(lamp.wavelength_nm[np.argmax(lamp.values)])
    546.0
    >>> round(float(lamp.at(np.array([550.0]))[0]), 3)  # no shoulder: the continuum
    1.0
    >>> round(float(np.trapezoid(lamp.values, lamp.wavelength_nm)), 1)  # 30 nm × 1 + 10 × 5 nm
    80.0
    """
    axis = spectrum.wavelength_nm
    values = spectrum.values
    widths = np.gradient(axis)
    inside = [
        line for line in lines_nm if axis[0] - widths[0] / 2 <= line <= axis[-1] + widths[-1] / 2
    ]
    weights = (
        np.stack(
            [table_bandpass(axis - line, float(np.interp(line, axis, widths))) for line in inside],
            axis=1,
        )
        if inside
        else np.zeros((axis.size, 0))
    )
    reached = np.any(weights > 0, axis=1)
    continuum = np.interp(axis, axis[~reached], values[~reached])
    powers = np.zeros(len(inside))
    if inside:
        excess = (values - continuum)[reached]
        powers = optimize.nnls(weights[reached], excess)[0]
    fine = np.arange(axis[0], axis[-1] + step_nm / 2, step_nm)
    result = np.interp(fine, axis, continuum)
    sigma = fwhm_nm / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    for line, power in zip(inside, powers, strict=True):
        if power > 0:
            profile = np.exp(-0.5 * ((fine - line) / sigma) ** 2) / (sigma * np.sqrt(2 * np.pi))
            result += power * profile
    return Spectrum(fine, result, name=spectrum.name)


#: The mercury features a spectrometer's wavelength scale is checked against
#: (:mod:`calib.core.spectrometer_scale`): the strong visible Hg I lines every fluorescent lamp
#: shows, known to 0.005 nm (NIST), the 576.96/579.07 doublet as one feature (unresolved by slits
#: wider than ~2 nm). 407.78 and 491.60 are too weak to rest a check on; 407.78 is modelled as a
#: neighbour of 404.66.
SCALE_CHECK_FEATURES: tuple[tuple[Line, ...], ...] = (
    (MERCURY[0],),
    (MERCURY[2],),
    (MERCURY[4],),
    (MERCURY[5], MERCURY[6]),
)
#: Every line a fluorescent lamp may show beside those features (Hg I, the tri-phosphors' Tb³⁺ and
#: Eu³⁺ peaks): what a window of the check models with free amplitudes.
CFL_NEIGHBOURS: tuple[Line, ...] = MERCURY + TERBIUM + EUROPIUM
