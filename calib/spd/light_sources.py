"""What a recovered SPD says about the lamp: which source it is, its CCT, and white-balance gains.

Recognition (Alvarez et al. 2014, §6.1) compares the recovered SPD with a library of known sources
by the Euclidean (L2) distance once both are resampled to the same wavelengths and normalised. The
library is colour-science's CIE illuminants and light sources (:func:`colour_library`); sources
whose spectra are identical (e.g. ``A`` and ``SA``) are one entry with aliases. Comparison is made
where the SPD was recovered (the camera's range) ∩ where the entry is defined. ``metric="l2"`` is
the paper's; ``metric="weighted"`` (default) weighs each wavelength by the recovery's inverse
variance, so the noisy ends of the camera's range count less.

CCT: the paper uses McCamy's cubic in ``xy`` (valid ~2000–12500 K); colour-science offers better
methods — Hernández-Andrés et al. 1999 (the paper's [HALR99]), Robertson 1968 and Ohno 2013 (which
also gives ``Duv``, the distance from the Planckian locus: a CCT means little beyond |Duv| ≈ 0.05).

White balance: the gains that make the lamp neutral in the *camera's* raw RGB,
``g_c = G / RGB_c`` with ``RGB_c = ∫ e s_c dλ`` (exact with a calibrated camera), and the paper's
Eq. 14 gains in linear sRGB from the CCT (blackbody at the CCT vs. the D65 white ``(1, 1, 1)``).

References
----------
Alvarez, S., Presa, L., Kunkel, T., Masia, B. (2014). Low Cost Recovery of Spectral Power
Distributions. CEIG. McCamy, C. S. (1992), Color Res. Appl. 17(2). Hernández-Andrés, J., Lee, R. L.,
Romero, J. (1999), Appl. Opt. 38(27). Ohno, Y. (2014), LEUKOS 10(1).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import FloatArray
from calib.core.colour_data import (
    blackbody_linear_srgb,
    correlated_colour_temperature_k,
    emission_xyz,
    illuminants,
    light_sources,
)
from calib.core.errors import InputError
from calib.core.spectra import MultiSpectrum, Spectrum, WavelengthGrid
from calib.spd.alvarez2014 import comparison_grid

Metric = Literal["l2", "weighted"]

#: CCT methods reported, in the order of the paper's (McCamy) then colour-science's better ones.
CCT_METHODS: tuple[str, ...] = ("McCamy 1992", "Hernandez 1999", "Robertson 1968", "Ohno 2013")
#: A relative floor on the recovery's σ when weighting the distance (no wavelength dominates).
SIGMA_FLOOR = 0.01
#: Normalised L2 distance below which two library spectra are one source under two names (tables
#: rounded to a few digits differ by ~1e-5).
ALIAS_DISTANCE = 1e-4
#: Where aliases are looked for: what a camera could ever see.
ALIAS_WINDOW_NM = (380.0, 730.0)
#: Entries this close (same metric) to the best match, as the instrument sees them, cannot be
#: told apart by it: they are reported as equivalent.
EQUIVALENT_DISTANCE = 0.005


# --------------------------------------------------------------------------------------- library


@dataclass(frozen=True, eq=False)
class LibraryEntry:
    """One known source: its name, where it comes from, its spectrum and other names for it."""

    name: str
    collection: str
    spectrum: Spectrum
    aliases: tuple[str, ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        return (self.name, *self.aliases)


@dataclass(frozen=True, eq=False)
class LightSourceLibrary:
    """A set of known sources to recognise recovered SPDs against."""

    entries: tuple[LibraryEntry, ...]

    def __post_init__(self) -> None:
        if not self.entries:
            raise InputError("a light-source library needs at least one entry", source="library")

    @classmethod
    def from_spectra(
        cls, spectra: Sequence[tuple[str, str, Spectrum]], *, step_nm: float = 5.0
    ) -> LightSourceLibrary:
        """Build from ``(name, collection, spectrum)``.

        Spectra identical (up to scale) over the visible window :data:`ALIAS_WINDOW_NM`, and
        defined over the same part of it, become one entry with aliases (``A`` and ``SA`` differ
        only below 380 nm, which no camera sees).
        """
        groups: list[tuple[FloatArray, list[tuple[str, str, Spectrum]]]] = []
        for name, collection, spectrum in spectra:
            lo = max(ALIAS_WINDOW_NM[0], np.ceil(spectrum.range_nm[0] / step_nm) * step_nm)
            hi = min(ALIAS_WINDOW_NM[1], np.floor(spectrum.range_nm[1] / step_nm) * step_nm)
            if hi - lo < 2 * step_nm:
                groups.append((np.array([lo, hi]), [(name, collection, spectrum)]))
                continue
            values = spectrum.resample(WavelengthGrid(lo, hi, step_nm), "interpolate").values
            key = np.concatenate([[lo, hi], values / max(float(np.linalg.norm(values)), 1e-300)])
            for existing, members in groups:
                if existing.shape == key.shape and np.linalg.norm(existing - key) < ALIAS_DISTANCE:
                    members.append((name, collection, spectrum))
                    break
            else:
                groups.append((key, [(name, collection, spectrum)]))
        return cls(
            tuple(
                LibraryEntry(
                    members[0][0],
                    members[0][1],
                    members[0][2],
                    tuple(member[0] for member in members[1:]),
                )
                for _, members in groups
            )
        )

    def entry(self, name: str) -> LibraryEntry:
        """The entry called ``name`` (or having it as an alias)."""
        for entry in self.entries:
            if name in entry.names:
                return entry
        raise InputError(f"no source named {name!r} in the library", source="library")

    def __len__(self) -> int:
        return len(self.entries)


@lru_cache(maxsize=1)
def colour_library() -> LightSourceLibrary:
    """colour-science's CIE illuminants (``SDS_ILLUMINANTS``) and light sources (``SDS_LIGHT_SOURCES``)."""
    return LightSourceLibrary.from_spectra(
        [
            (name, collection, spectrum)
            for collection, table in (
                ("illuminant", illuminants()),
                ("light source", light_sources()),
            )
            for name, spectrum in table.items()
        ]
    )


# ----------------------------------------------------------------------------------- recognition


@dataclass(frozen=True)
class Recognition:
    """The library entry nearest to a recovered SPD.

    Attributes
    ----------
    name, aliases, collection
        The best entry.
    distance
        Its distance (see the module docstring; 0 = same shape).
    margin
        Distance of the nearest entry that is not equivalent minus the best's: how clear the
        decision is.
    equivalents
        Other entries that, as this instrument sees them, differ from the best by less than
        :data:`EQUIVALENT_DISTANCE` (over the compared range): they cannot be told apart.
    ranking
        ``(name, distance)`` of the nearest entries, best first.
    metric
        ``"l2"`` or ``"weighted"``.
    range_nm
        Wavelengths compared.
    instrument_view
        Whether library spectra were compared as the instrument would report them.
    """

    name: str
    aliases: tuple[str, ...]
    collection: str
    distance: float
    margin: float
    equivalents: tuple[str, ...]
    ranking: tuple[tuple[str, float], ...]
    metric: str
    range_nm: tuple[float, float]
    instrument_view: bool = False

    @property
    def names(self) -> tuple[str, ...]:
        """The best entry's names and those of its equivalents."""
        return (self.name, *self.aliases, *self.equivalents)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "aliases": list(self.aliases),
            "collection": self.collection,
            "distance": self.distance,
            "margin": self.margin,
            "equivalents": list(self.equivalents),
            "ranking": [{"name": name, "distance": value} for name, value in self.ranking],
            "metric": self.metric,
            "range_nm": list(self.range_nm),
            "instrument_view": self.instrument_view,
        }


def _distance(
    measured: FloatArray, reference: FloatArray, weights: FloatArray, metric: Metric
) -> float:
    if metric == "l2":
        a = measured / max(float(np.linalg.norm(measured)), 1e-300)
        b = reference / max(float(np.linalg.norm(reference)), 1e-300)
        return float(np.linalg.norm(a - b))
    cross = float(np.sum(weights * measured * reference))
    auto_a = float(np.sum(weights * measured**2))
    auto_b = float(np.sum(weights * reference**2))
    if auto_a <= 0 or auto_b <= 0:
        return float("inf")
    return float(np.sqrt(max(1.0 - cross**2 / (auto_a * auto_b), 0.0)))


@dataclass(frozen=True, eq=False)
class _Candidate:
    entry: LibraryEntry
    values: FloatArray
    covered: NDArray[np.bool_]
    distance: float


def _scored(
    entry: LibraryEntry,
    seen: Spectrum,
    covered: NDArray[np.bool_],
    grid: WavelengthGrid,
    measured: FloatArray,
    weights: FloatArray,
    metric: Metric,
) -> _Candidate:
    values = seen.resample(
        grid, "integrate", out_of_range="error" if seen.covers(grid) else "zero"
    ).values
    distance = _distance(measured[covered], values[covered], weights[covered], metric)
    return _Candidate(entry, values, covered, distance)


def recognise_light_source(
    spd: Spectrum,
    library: LightSourceLibrary | None = None,
    *,
    sigma: Spectrum | None = None,
    metric: Metric = "weighted",
    view: Callable[[Spectrum], Spectrum] | None = None,
    view_top: int = 16,
    range_nm: tuple[float, float] = (380.0, 730.0),
    step_nm: float = 5.0,
    top: int = 5,
) -> Recognition:
    """The library source whose spectrum is nearest to ``spd`` (Alvarez et al. 2014, §6.1).

    Parameters
    ----------
    spd
        The recovered SPD (any scale).
    library
        Known sources; default :func:`colour_library`.
    sigma
        The SPD's standard deviation on the same scale (for ``metric="weighted"``; without it the
        weights are uniform).
    metric
        ``"l2"`` (the paper: normalised vectors, Euclidean distance) or ``"weighted"`` (the sine of
        the inverse-variance-weighted angle between them).
    view
        How the instrument would report a library spectrum (e.g.
        :func:`calib.spd.alvarez2014.instrument_view` bound to the measurement); ``None`` compares the
        library spectra as they are (the paper).
    view_top
        With ``view``: the entries nearest as they are that are compared again through the view.
    range_nm, step_nm
        Compared on the ``step_nm`` grid over ``range_nm`` ∩ the SPD's range ∩ the entry's range;
        both sides are projected on it with hat functions (fair to line spectra).
    top
        How many entries the ranking lists.

    Returns
    -------
    Recognition
    """
    if metric not in ("l2", "weighted"):
        raise InputError(f"metric must be 'l2' or 'weighted', got {metric!r}", source="metric")
    chosen = library if library is not None else colour_library()
    grid = comparison_grid(spd, range_nm, step_nm)
    nodes = grid.wavelength_nm
    # The grid lies inside the SPD's range: end nodes use the covered part of their hat.
    measured = spd.resample(grid, "integrate").values
    if float(measured.max()) <= 0:
        raise InputError("the SPD is zero over the compared range", source=spd.name)
    noise = np.zeros_like(measured)
    if sigma is not None:
        noise = np.interp(nodes, sigma.wavelength_nm, sigma.values)
    floor = SIGMA_FLOOR * float(measured.max())
    weights = 1.0 / (noise**2 + floor**2)
    candidates: list[_Candidate] = []
    for entry in chosen.entries:
        lo, hi = entry.spectrum.range_nm
        covered = (nodes >= lo - 1e-9) & (nodes <= hi + 1e-9)
        if covered.sum() < 3:
            continue
        candidates.append(_scored(entry, entry.spectrum, covered, grid, measured, weights, metric))
    if not candidates:
        raise InputError(
            f"no library source covers {grid.start_nm:g}–{grid.stop_nm:g} nm", source="library"
        )
    if view is not None:
        # The instrument's view changes distances by the blur and the ends of the range, not the
        # order of far-off entries: only the nearest ones are looked at through it.
        candidates.sort(key=lambda candidate: candidate.distance)
        candidates = [
            _scored(c.entry, view(c.entry.spectrum), c.covered, grid, measured, weights, metric)
            for c in candidates[:view_top]
        ]
    candidates.sort(key=lambda candidate: candidate.distance)
    best = candidates[0]
    equivalents: list[str] = []
    runner_up = float("inf")
    for other in candidates[1:]:
        both = best.covered & other.covered
        separation = _distance(best.values[both], other.values[both], weights[both], metric)
        if separation < EQUIVALENT_DISTANCE:
            equivalents.extend(other.entry.names)
        elif runner_up == float("inf"):
            runner_up = other.distance
    return Recognition(
        name=best.entry.name,
        aliases=best.entry.aliases,
        collection=best.entry.collection,
        distance=best.distance,
        margin=runner_up - best.distance,
        equivalents=tuple(equivalents),
        ranking=tuple((c.entry.name, c.distance) for c in candidates[:top]),
        metric=metric,
        range_nm=(grid.start_nm, grid.stop_nm),
        instrument_view=view is not None,
    )


# ------------------------------------------------------------------------------------- colorimetry


@dataclass(frozen=True)
class ColourTemperature:
    """CCT of an SPD by several methods (K), its ``Duv`` (Ohno 2013) and CIE 1931 ``xy``."""

    cct_k: Mapping[str, float]
    duv: float
    xy: tuple[float, float]

    def to_dict(self) -> dict[str, Any]:
        return {"cct_k": dict(self.cct_k), "duv": self.duv, "xy": list(self.xy)}


def tristimulus_xyz(spd: Spectrum) -> FloatArray:
    """CIE 1931 2° ``XYZ`` of an emission spectrum (relative: ``Y`` = 1)."""
    xyz = emission_xyz(spd)
    if not xyz[1] > 0:
        raise InputError("the SPD has no luminance (Y = 0)", source=spd.name)
    return np.asarray(xyz / xyz[1], dtype=np.float64)


def correlated_colour_temperature(
    spd: Spectrum, methods: Sequence[str] = CCT_METHODS
) -> ColourTemperature:
    """CCT of an emission spectrum by each of ``methods`` (colour-science names), with ``Duv``.

    ``xy`` methods (McCamy 1992, Hernandez 1999, Kang 2002, CIE Illuminant D Series) and ``uv``
    methods (Ohno 2013, Robertson 1968, Krystek 1985, Planck 1900) are both accepted. Values
    outside a method's domain are whatever the method returns (colour-science's warnings are
    silenced); check ``Duv``.
    """
    cct_k, duv, xy = correlated_colour_temperature_k(tristimulus_xyz(spd), tuple(methods))
    return ColourTemperature(cct_k, duv, xy)


def camera_white_balance(spd: Spectrum, camera: MultiSpectrum) -> FloatArray:
    """Raw multipliers that make the lamp neutral for this camera, shape ``(3,)``, green = 1.

    ``RGB_c = ∫ e(λ) s_c(λ) dλ`` (what a white reflector lit by the lamp gives), ``g = G / RGB``.
    """
    if camera.values.shape[1] != 3:
        raise InputError(
            f"the camera needs 3 channels, has {camera.values.shape[1]}", source=camera.name
        )
    lo = max(spd.range_nm[0], camera.range_nm[0])
    hi = min(spd.range_nm[1], camera.range_nm[1])
    if hi <= lo:
        raise InputError("the SPD and the camera do not overlap in wavelength", source=spd.name)
    wavelength = np.linspace(lo, hi, int(np.ceil((hi - lo) / 0.5)) + 1)
    rgb = np.array(
        [
            np.trapezoid(
                spd.at(wavelength)
                * np.interp(wavelength, camera.wavelength_nm, camera.values[:, k]),
                wavelength,
            )
            for k in range(3)
        ]
    )
    if np.any(rgb <= 0):
        raise InputError(
            f"the lamp gives no signal in a camera channel (RGB = {rgb.tolist()})", source=spd.name
        )
    return np.asarray(rgb[1] / rgb, dtype=np.float64)


def srgb_white_balance_from_cct(cct_k: float) -> FloatArray:
    """The paper's Eq. 14 gains ``g_i = e_w,i / e_i`` in linear sRGB, shape ``(3,)``, green = 1.

    ``e`` is the linear sRGB colour of a blackbody at ``cct_k`` (no chromatic adaptation, as in the
    blackbody colour table the paper uses) and ``e_w = (1, 1, 1)`` the D65 white.
    """
    if not 500.0 <= cct_k <= 100000.0:
        raise InputError(f"CCT {cct_k:g} K is outside 500–100000 K", source="cct")
    rgb = blackbody_linear_srgb(cct_k)
    rgb = rgb / rgb[1]
    if np.any(rgb <= 0):
        raise InputError(f"a blackbody at {cct_k:g} K lies outside the sRGB gamut", source="cct")
    return np.asarray(1.0 / rgb, dtype=np.float64)


def complete_outside_range(spd: Spectrum, reference: Spectrum) -> Spectrum:
    """``spd`` inside its range, ``reference`` (scaled to it) outside: for colorimetry over 360–830 nm.

    A camera sees ~400–700 nm; colour-matching functions reach further. Outside the measured range
    the best available guess is the recognised source, scaled by least squares to the measurement
    over their common range (the paper computes XYZ from the recognised source altogether).
    """
    lo, hi = spd.range_nm
    inside = spd.wavelength_nm
    scale_axis = inside[(inside >= reference.range_nm[0]) & (inside <= reference.range_nm[1])]
    if scale_axis.size < 2:
        raise InputError("the reference does not overlap the measured SPD", source=reference.name)
    measured = spd.at(scale_axis)
    expected = reference.at(scale_axis)
    scale = float(measured @ expected) / max(float(expected @ expected), 1e-300)
    below = reference.wavelength_nm[reference.wavelength_nm < lo - 1e-9]
    above = reference.wavelength_nm[reference.wavelength_nm > hi + 1e-9]
    wavelength = np.concatenate([below, inside, above])
    values = np.concatenate([scale * reference.at(below), spd.values, scale * reference.at(above)])
    return Spectrum(wavelength, np.clip(values, 0.0, None), name=f"{spd.name} (completed)")
