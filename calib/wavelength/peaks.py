"""Finding a pixel→wavelength mapping from peaks and shapes: emission lines, broadband correlation, ICP.

:func:`mapping_from_peaks` — a fluorescent lamp: emission lines found in the lamp's *measured*
spectrum (weighted by the mean camera ŝ), sub-pixel peaks in the profile, a robust monotonic match
(wrong or missing peaks are outliers), least squares. :func:`coarse_mapping_candidates` — any lamp:
a global search over dispersion and offset by normalised cross-correlation of the profile with
``ŝ ⊙ e`` (the paper's Eq. 15 compares the same two curves with ICP from a flat start).
:func:`refine_mapping` — least squares on ``(a, b, c)`` of any residual function of the mapping,
used with the closed-form solve's own residual by :mod:`calib.methods.makabe2025`.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import FloatArray
from calib.core.errors import EstimationError
from calib.core.mapping import QuadraticMapping, wavelength_rms_from_covariance
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, Spectrum, WavelengthGrid
from calib.model.forward import fine_axis, hat_matrix

#: Known emission lines of fluorescent lamps (nm), used to label peaks found in a measured spectrum.
FLUORESCENT_LINES_NM: Mapping[str, float] = {
    "Hg 404.7": 404.66,
    "Hg 435.8": 435.83,
    "Tb 487.7": 487.7,
    "Tb 542.4": 542.4,
    "Hg 546.1": 546.07,
    "Hg 577.0": 576.96,
    "Hg 579.1": 579.07,
    "Eu 611.6": 611.6,
}


# ------------------------------------------------------------------------------ peak matching


@dataclass(frozen=True)
class Peak:
    """A peak: position (nm or px), height and prominence, with a line label when known."""

    position: float
    height: float
    prominence: float
    label: str | None = None


def _centroid_peak(values: FloatArray, index: int, half_width: int) -> float:
    """Centroid of the samples above half the peak's height, around ``index`` (in samples)."""
    lo = max(index - half_width, 0)
    hi = min(index + half_width + 1, values.size)
    window = values[lo:hi]
    base = float(np.min(window))
    level = base + 0.5 * (values[index] - base)
    weights = np.clip(window - level, 0.0, None)
    # Keep only the connected run around the maximum.
    centre = index - lo
    left = centre
    while left > 0 and weights[left - 1] > 0:
        left -= 1
    right = centre
    while right < weights.size - 1 and weights[right + 1] > 0:
        right += 1
    run = weights[left : right + 1]
    if run.sum() <= 0:
        return float(index)
    return float(lo + left + np.sum(run * np.arange(run.size)) / run.sum())


def _line_excess(values: FloatArray, window: int) -> FloatArray:
    """What rises above a grey opening of ``window`` samples: narrow lines without broad bands."""
    from scipy import ndimage

    size = max(3, window | 1)
    return np.asarray(
        values - ndimage.grey_opening(values, size=size, mode="nearest"), dtype=np.float64
    )


#: The fine axis' step (nm) a lamp's spectrum is interpolated to before its lines are sought.
_FINE_STEP_NM = 0.25


def _fine_spectrum(
    lamp: Spectrum,
    range_nm: tuple[float, float],
    weight: Callable[[FloatArray], FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """``lamp`` (times ``weight``) linearly interpolated every :data:`_FINE_STEP_NM` over
    ``range_nm`` ∩ its own range: the wavelengths and the values."""
    wavelength = np.arange(
        max(range_nm[0], lamp.range_nm[0]), min(range_nm[1], lamp.range_nm[1]), _FINE_STEP_NM
    )
    values = lamp.at(wavelength) * (weight(wavelength) if weight is not None else 1.0)
    return wavelength, np.asarray(values, dtype=np.float64)


def _line_label(position_nm: float) -> str | None:
    """The :data:`FLUORESCENT_LINES_NM` line within 2 nm of ``position_nm``, or ``None``."""
    label = min(
        FLUORESCENT_LINES_NM, key=lambda name: abs(FLUORESCENT_LINES_NM[name] - position_nm)
    )
    return label if abs(FLUORESCENT_LINES_NM[label] - position_nm) <= 2.0 else None


def lamp_lines(
    lamp: Spectrum,
    weight: Callable[[FloatArray], FloatArray] | None = None,
    *,
    min_prominence: float = 0.02,
    max_lines: int = 12,
    range_nm: tuple[float, float] = (380.0, 720.0),
    line_width_nm: float = 20.0,
) -> list[Peak]:
    """Emission lines in a lamp's measured spectrum (optionally weighted, e.g. by ŝ), strongest first.

    The spectrum is interpolated to 0.25 nm (as the renderer and the solve see it), broad bands are
    removed (a grey opening ``line_width_nm`` wide) and each line's position is the centroid of its
    upper half — the same procedure :func:`profile_peaks` applies in pixels, so both sides locate a
    line the same way. Lines within 2 nm of :data:`FLUORESCENT_LINES_NM` are labelled.
    """
    from scipy import signal

    # Resample to a fine axis (linear interpolation, as the renderer and the solve do) so the line
    # shapes, and hence their centroids, are those the profile shows.
    wavelength, values = _fine_spectrum(lamp, range_nm, weight)
    excess = _line_excess(values, int(np.ceil(line_width_nm / _FINE_STEP_NM)))
    if wavelength.size < 3 or float(excess.max()) <= 0:
        raise EstimationError(f"lamp {lamp.name!r} shows no emission lines in {range_nm} nm")
    indices, properties = signal.find_peaks(excess, prominence=min_prominence * float(excess.max()))
    order = np.argsort(properties["prominences"])[::-1][:max_lines]
    peaks: list[Peak] = []
    for k in order:
        index = int(indices[k])
        half_width = int(np.ceil(line_width_nm / _FINE_STEP_NM))
        position = wavelength[0] + _FINE_STEP_NM * _centroid_peak(excess, index, half_width)
        peaks.append(
            Peak(
                float(position),
                float(excess[index]),
                float(properties["prominences"][k]),
                _line_label(position),
            )
        )
    return peaks


#: A lamp's spectrum shows a *narrow* line where a peak is at most this wide (nm, at half its
#: height above its surroundings), or 1.5× the spectrometer's bandwidth when that is more. Judged on
#: colour-science's tables (:func:`narrow_lines`): their Hg lines measure 5–11 nm (one or two 5 nm
#: samples), the narrowest LED band or daylight ripple 15 nm (LED-V1's 415 nm band, D50's 710 nm).
NARROW_LINE_NM = 12.0
#: … standing above its surroundings by at least this multiple of them (the peak at least twice
#: the continuum under it; the tables' Hg 435.8 nm line stands 6–300× above it) …
NARROW_LINE_CONTRAST = 1.0
#: … and by at least this share of the spectrum's maximum (the tables' Hg 435.8 nm line is at least
#: 0.4 of their maximum), and by :data:`PEAK_NOISE_SIGMA` noise σ.
NARROW_LINE_SHARE = 0.1
#: A spectrum measured through a broader slit than this (nm) cannot tell a line from an LED band
#: (a line then measures about the bandwidth, an LED band ≥ √(15² + bandwidth²)).
NARROW_LINE_MAX_BANDWIDTH_NM = 10.0


def narrow_line_width_nm(bandwidth_nm: float | None) -> float | None:
    """The widest peak :func:`narrow_lines` counts as a line for a spectrum measured at
    ``bandwidth_nm`` (``None``: not stated), or ``None`` when the slit is too broad to tell."""
    if bandwidth_nm is None:
        return NARROW_LINE_NM
    if bandwidth_nm > NARROW_LINE_MAX_BANDWIDTH_NM:
        return None
    return max(NARROW_LINE_NM, 1.5 * bandwidth_nm)


def narrow_lines(
    lamp: Spectrum,
    *,
    width_nm: float = NARROW_LINE_NM,
    range_nm: tuple[float, float] = (380.0, 780.0),
) -> list[Peak]:
    """The narrow emission lines of a lamp's spectrum (a fluorescent or gas-discharge lamp's),
    strongest first; none for an LED, an incandescent lamp or daylight.

    A line is a peak of the spectrum (interpolated to 0.25 nm) at most ``width_nm`` wide at half
    its prominence, standing above the higher of the minima beside it by
    :data:`NARROW_LINE_CONTRAST` of that minimum, by :data:`NARROW_LINE_SHARE` of the
    spectrum's maximum and by :data:`PEAK_NOISE_SIGMA` of its noise (from its own samples'
    second differences). An LED's band is at least 15 nm wide, so the rule reads the spectrum
    alone. Lines within 2 nm of :data:`FLUORESCENT_LINES_NM` are labelled.

    Examples
    --------
    >>> from calib.core.lamp_specs import lamp_from_spec
    >>> [peak.label for peak in narrow_lines(lamp_from_spec("FL2"))][:2]
    ['Hg 435.8', 'Hg 546.1']
    >>> narrow_lines(lamp_from_spec("LED-B3"))
    []
    """
    from scipy import signal

    wavelength, values = _fine_spectrum(lamp, range_nm)
    if wavelength.size < 3 or not float(values.max()) > 0:
        return []
    # The noise from the spectrum's own samples (the interpolated ones are correlated).
    own = (lamp.wavelength_nm >= range_nm[0]) & (lamp.wavelength_nm <= range_nm[1])
    noise = second_difference_noise(lamp.values[own])
    threshold = max(NARROW_LINE_SHARE * float(values.max()), PEAK_NOISE_SIGMA * noise)
    indices, properties = signal.find_peaks(values, prominence=threshold)
    prominence = properties["prominences"]
    widths = signal.peak_widths(
        values,
        indices,
        rel_height=0.5,
        prominence_data=(prominence, properties["left_bases"], properties["right_bases"]),
    )[0]
    below = values[indices] - prominence
    narrow = (widths * _FINE_STEP_NM <= width_nm) & (prominence >= NARROW_LINE_CONTRAST * below)
    return [
        Peak(
            float(wavelength[indices[k]]),
            float(values[indices[k]]),
            float(prominence[k]),
            _line_label(float(wavelength[indices[k]])),
        )
        for k in np.argsort(prominence)[::-1]
        if narrow[k]
    ]


#: A peak must stand this many noise σ above its surroundings to count (noise makes no peaks).
PEAK_NOISE_SIGMA = 5.0


def second_difference_noise(values: FloatArray) -> float:
    """White noise σ of ``values`` ``(n,)`` from the median absolute deviation of their second
    differences (a smooth curve and a few sharp peaks hardly move it)."""
    second = np.diff(np.asarray(values, dtype=np.float64), n=2)
    if second.size == 0:
        return 0.0
    return 1.4826 * float(np.median(np.abs(second - np.median(second)))) / math.sqrt(6.0)


def profile_peaks(
    pixel: FloatArray,
    profile: FloatArray,
    *,
    line_width_px: float,
    min_prominence: float = 0.02,
    max_peaks: int = 20,
) -> list[Peak]:
    """Sub-pixel line peaks of a profile ``(n, 3)`` (channels summed, broad bands removed).

    ``line_width_px``: lines narrower than this many pixels are kept (≈ 20 nm at the dispersion).
    A peak must stand out by ``min_prominence`` of the strongest line and by 5 noise σ (estimated
    from the profile's second differences after the same smoothing), so noise makes no peaks.
    """
    from scipy import ndimage, signal

    combined = np.sum(profile, axis=1)
    smoothing = max(line_width_px / 16.0, 0.5)
    smooth = ndimage.gaussian_filter1d(combined, smoothing, mode="nearest")
    excess = _line_excess(smooth, int(np.ceil(line_width_px)))
    if float(excess.max()) <= 0:
        return []
    noise = second_difference_noise(smooth)
    # Smoothing correlates neighbours; the second differences understate σ by about the kernel width.
    noise *= math.sqrt(max(2.0 * math.sqrt(math.pi) * smoothing, 1.0))
    threshold = max(min_prominence * float(excess.max()), PEAK_NOISE_SIGMA * noise)
    indices, properties = signal.find_peaks(excess, prominence=threshold)
    order = np.argsort(properties["prominences"])[::-1][:max_peaks]
    step = np.gradient(pixel)
    peaks = []
    for k in order:
        index = int(indices[k])
        half_width = max(int(line_width_px), 3)
        position = pixel[index] + (_centroid_peak(excess, index, half_width) - index) * step[index]
        peaks.append(
            Peak(float(position), float(excess[index]), float(properties["prominences"][k]))
        )
    return peaks


def nominal_dispersion(
    pixel: FloatArray,
    profile: FloatArray,
    model_nm: FloatArray,
    model: FloatArray,
    level: float = 0.05,
) -> float:
    """nm per pixel-coordinate unit that makes the lit part of the model fit the lit part of the profile.

    The profile is smoothed first (over ~1 % of its length) so that noise does not widen its lit
    extent; "lit" is above ``level`` of the maximum for both curves.
    """
    from scipy import ndimage

    profile_total = np.sum(np.clip(profile, 0, None), axis=1)
    profile_total = ndimage.gaussian_filter1d(
        profile_total, max(profile_total.size / 100.0, 1.0), mode="nearest"
    )
    model_total = np.sum(model, axis=1) if model.ndim == 2 else model
    lit = np.flatnonzero(profile_total > level * float(profile_total.max()))
    model_lit = model_nm[model_total > level * float(model_total.max())]
    if lit.size < 8 or model_lit.size < 2:
        raise EstimationError("the profile or the lamp × camera model has too little signal to map")
    support_px = float(pixel[lit[-1]] - pixel[lit[0]]) + float(np.median(np.diff(pixel)))
    return float(model_lit[-1] - model_lit[0]) / support_px


def _curves_through(
    pixel: FloatArray, wavelength_nm: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(a, b, c)`` ``(K,)`` of the line (two points) or quadratic (three) through each row of
    ``pixel`` ``(K, 2 | 3)`` at ``wavelength_nm`` ``(2 | 3,)``; non-finite where two pixels
    coincide."""
    with np.errstate(divide="ignore", invalid="ignore"):
        if pixel.shape[1] == 2:
            b = (wavelength_nm[1] - wavelength_nm[0]) / (pixel[:, 1] - pixel[:, 0])
            return np.zeros_like(b), b, wavelength_nm[0] - b * pixel[:, 0]
        # Newton's divided differences.
        p0, p1, p2 = pixel[:, 0], pixel[:, 1], pixel[:, 2]
        first = (wavelength_nm[1] - wavelength_nm[0]) / (p1 - p0)
        second = (wavelength_nm[2] - wavelength_nm[1]) / (p2 - p1)
        a = (second - first) / (p2 - p0)
        b = first - a * (p0 + p1)
        return a, b, wavelength_nm[0] - (a * p0 + b) * p0


def match_peak_hypotheses(
    lines: Sequence[Peak],
    peaks: Sequence[Peak],
    *,
    pixel_range: tuple[float, float],
    dispersion_range_nm_per_px: tuple[float, float] = (0.02, 20.0),
    tolerance_nm: float = 1.5,
    allow_reversed: bool = False,
    n_hypotheses: int = 6,
    explain_peaks: bool = False,
) -> list[QuadraticMapping]:
    """Several distinct line↔peak mappings, best scored first (see :func:`match_peaks`).

    Each hypothesis comes from a pair or triple of lines matched to peaks, scored by a soft inlier
    count, then refitted on its inliers with tightening tolerances. Distinct hypotheses (differing by
    more than 3 nm somewhere over ``pixel_range``) let a later fit of the whole profile choose.
    With ``explain_peaks`` the count also asks the profile's strongest peaks to be explained by a
    line (decision 0121: profiles with an arbitrary origin, where no 0th order bounds the mapping).
    Not where a rig's geometry bounds it: a fluorescent lamp's strongest peaks there may be its
    phosphor bands, which no line list holds (a coarse sensor's twin session took the Hg 546.1 line
    1.3 nm off with it).
    """
    if len(lines) < 2 or len(peaks) < 2:
        raise EstimationError(
            f"need ≥ 2 lamp lines and ≥ 2 profile peaks to match, found {len(lines)} lines and "
            f"{len(peaks)} peaks; is this a fluorescent lamp, and is the first order in the profile?"
        )
    line_nm = np.array([line.position for line in lines])
    peak_px = np.array([peak.position for peak in peaks])
    peak_weight = np.array([peak.prominence for peak in peaks])
    line_weight = np.array([line.prominence for line in lines])
    line_weight = line_weight / line_weight.max()
    peak_share = peak_weight / peak_weight.max()
    probe = np.linspace(pixel_range[0], pixel_range[1], 9)

    def inliers(mapping: QuadraticMapping, tolerance: float) -> list[tuple[int, int]]:
        predicted = mapping.wavelength_nm(peak_px)
        pairs: list[tuple[int, int]] = []
        used: set[int] = set()
        for i in np.argsort(line_nm):
            distance = np.abs(predicted - line_nm[i])
            j = int(np.argmin(distance))
            if distance[j] <= tolerance and j not in used:
                pairs.append((int(i), j))
                used.add(j)
        return pairs

    def score(mapping: QuadraticMapping) -> float:
        """Soft inlier count (τ = 2 nm): each line counts by its strength and how close a peak
        lands; with ``explain_peaks`` also each peak by its prominence and how close a line lands.
        A quadratic through
        three lines at three weak peaks scores its three lines as fully as the right match does;
        only the profile's strongest peaks left unexplained tell it apart (decision 0121: the
        validation split's FL2 paper scenes, 55 nm off from such a triple)."""
        predicted = mapping.wavelength_nm(peak_px)
        gap = np.abs(predicted[None, :] - line_nm[:, None])
        lines_found = np.exp(-0.5 * (np.min(gap, axis=1) / 2.0) ** 2)
        peaks_explained = np.exp(-0.5 * (np.min(gap, axis=0) / 2.0) ** 2)
        explained = float(np.sum(peak_share * peaks_explained)) if explain_peaks else 0.0
        return float(np.sum(line_weight * lines_found)) + explained

    def _soft_scores(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
        """:func:`score` of the quadratics ``(a, b, c)`` ``(K,)`` each, at once."""
        predicted = (a[:, None] * peak_px[None, :] + b[:, None]) * peak_px[None, :] + c[:, None]
        gap = np.abs(predicted[:, None, :] - line_nm[None, :, None])
        lines_found = np.exp(-0.5 * (np.min(gap, axis=2) / 2.0) ** 2)
        total = np.sum(line_weight[None, :] * lines_found, axis=1)
        if explain_peaks:
            peaks_explained = np.exp(-0.5 * (np.min(gap, axis=1) / 2.0) ** 2)
            total = total + np.sum(peak_share[None, :] * peaks_explained, axis=1)
        return np.asarray(total, dtype=np.float64)

    def admissible(mapping: QuadraticMapping) -> bool:
        slope = mapping.dispersion_nm_per_px(probe)
        if np.any(slope <= 0) and not allow_reversed:
            return False
        low, high = dispersion_range_nm_per_px
        return bool(np.all((np.abs(slope) >= low) & (np.abs(slope) <= high)))

    def span_nm(pairs: list[tuple[int, int]]) -> float:
        matched = line_nm[[i for i, _ in pairs]]
        return float(matched.max() - matched.min())

    def polish(mapping: QuadraticMapping) -> QuadraticMapping:
        for tolerance in (4 * tolerance_nm, 2 * tolerance_nm, tolerance_nm):
            pairs = inliers(mapping, tolerance)
            if len(pairs) < 2:
                break
            refitted = QuadraticMapping.fit(
                peak_px[[j for _, j in pairs]],
                line_nm[[i for i, _ in pairs]],
                method="fluorescent-peaks",
                degree=2 if len(pairs) >= 3 and span_nm(pairs) >= 150.0 else 1,
            )
            if not admissible(refitted):
                break
            mapping = refitted.with_details(pixel_range=list(pixel_range))
        matched = [
            {"line_nm": float(line_nm[i]), "label": lines[i].label, "pixel": float(peak_px[j])}
            for i, j in inliers(mapping, tolerance_nm)
        ]
        return mapping.with_details(
            details={
                "matched": matched,
                "n_lines": len(lines),
                "n_peaks": len(peaks),
                "score": score(mapping),
            }
        )

    # Every pair and triple of the strongest lines through every ordered pair or triple of the
    # strongest peaks: the curve through them exactly, each line set's placements judged at once.
    low, high = dispersion_range_nm_per_px
    scored: list[tuple[float, QuadraticMapping]] = []
    strongest_lines = sorted(np.argsort(-line_weight)[:6].tolist(), key=lambda i: line_nm[i])
    strongest_peaks = np.argsort(-peak_weight)[:10].tolist()
    for size in (2, 3):
        orders = np.array(list(itertools.permutations(strongest_peaks, size)), dtype=np.intp)
        if orders.size == 0:
            continue
        at = peak_px[orders]
        for line_set in itertools.combinations(strongest_lines, size):
            if line_nm[line_set[-1]] - line_nm[line_set[0]] < 60.0:
                continue  # too short a baseline to extrapolate from
            through = line_nm[list(line_set)]
            a, b, c = _curves_through(at, through)
            slope = 2.0 * a[:, None] * probe[None, :] + b[:, None]
            within = np.all((np.abs(slope) >= low) & (np.abs(slope) <= high), axis=1)
            if not allow_reversed:
                within &= np.all(slope > 0, axis=1)
            within &= np.isfinite(a) & np.isfinite(b) & np.isfinite(c)
            for k, value in zip(
                np.flatnonzero(within).tolist(),
                _soft_scores(a[within], b[within], c[within]).tolist(),
                strict=True,
            ):
                candidate = QuadraticMapping(
                    float(a[k]), float(b[k]), float(c[k]), pixel_range=pixel_range
                )
                scored.append((value, candidate))
    if not scored:
        raise EstimationError(
            "could not match the lamp's lines to the profile's peaks (no consistent pair of lines); "
            "check the lamp spectrum and that the profile holds the first order"
        )
    scored.sort(key=lambda item: -item[0])
    hypotheses: list[QuadraticMapping] = []
    for _, candidate in scored:
        polished = polish(candidate)
        if any(
            np.max(np.abs(polished.wavelength_nm(probe) - other.wavelength_nm(probe))) < 3.0
            for other in hypotheses
        ):
            continue
        hypotheses.append(polished)
        if len(hypotheses) == n_hypotheses:
            break
    return hypotheses


def match_peaks(
    lines: Sequence[Peak],
    peaks: Sequence[Peak],
    *,
    pixel_range: tuple[float, float],
    dispersion_range_nm_per_px: tuple[float, float] = (0.02, 20.0),
    tolerance_nm: float = 1.5,
    allow_reversed: bool = False,
) -> tuple[QuadraticMapping, list[tuple[Peak, Peak]]]:
    """Robustly match lamp lines (nm) to profile peaks (px) and fit the quadratic mapping.

    Pairs and triples of the strongest lines matched to pairs and triples of the strongest peaks
    propose linear and quadratic mappings; each admissible one (monotonic, dispersion in range) is
    scored by a soft inlier count — every line weighted by its strength and by how close a peak lands
    (τ = 2 nm); the best is refitted on its inliers with tolerances tightening to ``tolerance_nm``.
    Spurious or missing peaks only reduce the inlier count. Wavelength increases with the pixel
    coordinate unless ``allow_reversed`` (profiles from :mod:`calib.image.profiles` run away from the
    direct spot, towards longer wavelengths).

    Returns
    -------
    (QuadraticMapping, matches)
        The mapping (``method="fluorescent-peaks"``, covariance from the fit) and the matched pairs.
    """
    best = match_peak_hypotheses(
        lines,
        peaks,
        pixel_range=pixel_range,
        dispersion_range_nm_per_px=dispersion_range_nm_per_px,
        tolerance_nm=tolerance_nm,
        allow_reversed=allow_reversed,
        n_hypotheses=1,
    )[0]
    matched = best.details.get("matched", [])
    if len(matched) < 2:
        raise EstimationError("fewer than 2 lamp lines agree with one mapping")
    by_line = {round(line.position, 9): line for line in lines}
    by_peak = {round(peak.position, 9): peak for peak in peaks}
    matches = [
        (by_line[round(item["line_nm"], 9)], by_peak[round(item["pixel"], 9)]) for item in matched
    ]
    return best, matches


def mapping_from_peaks(
    lamp: Spectrum,
    pixel: FloatArray,
    profile: FloatArray,
    mean_sensitivity: FloatArray,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    tolerance_nm: float = 1.5,
) -> QuadraticMapping:
    """Mapping from a fluorescent lamp: lines of ``ŝ ⊙ e`` matched to the profile's peaks.

    Parameters
    ----------
    lamp
        The lamp's measured spectrum (line positions are taken from it).
    pixel, profile
        Shapes ``(n,)`` and ``(n, 3)``.
    mean_sensitivity
        ``ŝ`` of shape ``(f, 3)`` on ``grid``, to weight the lines as a typical camera sees them and
        to estimate the dispersion from the lit extent of the profile.
    """
    model_nm, model = model_curve_on_fine_axis(lamp, mean_sensitivity, grid)
    dispersion = nominal_dispersion(pixel, profile, model_nm, model)
    total = mean_sensitivity.sum(axis=1)

    def weight(wavelength: FloatArray) -> FloatArray:
        return np.asarray(
            np.interp(wavelength, grid.wavelength_nm, total, 0.0, 0.0), dtype=np.float64
        )

    lines = lamp_lines(lamp, weight, range_nm=(grid.start_nm, grid.stop_nm))
    peaks = profile_peaks(pixel, profile, line_width_px=20.0 / dispersion)
    mapping, _ = match_peaks(
        lines,
        peaks,
        pixel_range=(float(pixel[0]), float(pixel[-1])),
        tolerance_nm=tolerance_nm,
        dispersion_range_nm_per_px=(0.7 * dispersion, 1.4 * dispersion),
    )
    return mapping


# ------------------------------------------------------------------------- broadband search


def _local_maxima(values: FloatArray, order: int) -> NDArray[np.bool_]:
    """Where a value is above each of its ``order`` neighbours on either side along the last
    axis, the ends' neighbours clipped to the ends (:func:`scipy.signal.argrelmax`'s rule, on
    every row at once)."""
    n = values.shape[-1]
    padded = np.concatenate(
        (
            np.repeat(values[..., :1], order, axis=-1),
            values,
            np.repeat(values[..., -1:], order, axis=-1),
        ),
        axis=-1,
    )
    above = np.ones(values.shape, dtype=bool)
    for shift in range(1, order + 1):
        above &= values > padded[..., order + shift : order + shift + n]
        above &= values > padded[..., order - shift : order - shift + n]
    return above


def coarse_mapping_candidates(
    pixel: FloatArray,
    profile: FloatArray,
    model_nm: FloatArray,
    model: FloatArray,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    n_dispersions: int = 48,
    n_candidates: int = 4,
    allow_reversed: bool = False,
    min_model_fraction: float = 0.9,
) -> list[QuadraticMapping]:
    """Global search over linear mappings ``λ = b p + c`` by normalised cross-correlation.

    The profile ``(n, 3)`` is compared, channel by channel, with the expected profile of a typical
    camera, ``model`` ``(n_fine, 3)`` on ``model_nm`` (``ŝ ⊙ e`` per nm, zero outside the grid),
    re-sampled at the trial dispersion; for each dispersion every integer pixel shift is scored at
    once with FFTs. Dispersions span the range in which the model's support fits the profile's;
    only placements that keep at least ``min_model_fraction`` of the model's energy inside the
    profile count (the whole first order must be in the profile).

    Returns
    -------
    list of QuadraticMapping
        Up to ``n_candidates`` distinct linear mappings (``method="led-search"``), best first.
    """
    n = pixel.size
    spacing = float(np.median(np.diff(pixel)))
    nominal = nominal_dispersion(pixel, profile, model_nm, model)
    dispersions = nominal * np.geomspace(0.6, 1.6, n_dispersions)
    centred = profile - profile.mean(axis=0)
    size = 1 << math.ceil(math.log2(4 * n))
    profile_norm = np.linalg.norm(centred, axis=0)
    profile_norm = np.where(profile_norm > 0, profile_norm, 1.0)
    # The model sampled at every dispersion's step (one row each, zero past its own length: the
    # transforms pad with zeros anyway), from a step before the profile's first pixel to past
    # the grid's end; rows too long for the transforms are left out.
    steps_nm = dispersions * spacing
    starts_nm = grid.start_nm - n * steps_nm
    lengths = ((grid.stop_nm - starts_nm) / steps_nm).astype(np.intp) + n + 2
    kept = np.flatnonzero(lengths + n <= size)
    if kept.size == 0:
        raise EstimationError("the broadband mapping search found no candidate")
    dispersions, steps_nm, starts_nm, lengths = (
        dispersions[kept],
        steps_nm[kept],
        starts_nm[kept],
        lengths[kept],
    )
    longest = int(lengths.max())
    index = np.arange(longest)
    samples_nm = starts_nm[:, None] + steps_nm[:, None] * index[None, :]
    inside_row = index[None, :] < lengths[:, None]
    expected = np.stack(
        [
            np.where(
                inside_row,
                np.interp(samples_nm, model_nm, model[:, k], left=0.0, right=0.0),
                0.0,
            )
            for k in range(3)
        ],
        axis=2,
    )
    # corr[s] = Σ_p profile[p] · expected[p + s], every shift s of every dispersion at once;
    # a mirrored placement's (the model reversed) is the model's convolution with the profile.
    expected_fft = np.fft.rfft(expected, size, axis=1)
    correlation = np.fft.irfft(
        expected_fft * np.fft.rfft(centred[::-1], size, axis=0)[None], size, axis=1
    )
    convolution = (
        np.fft.irfft(expected_fft * np.fft.rfft(centred, size, axis=0)[None], size, axis=1)
        if allow_reversed
        else None
    )
    # The n-pixel windows' sums of the model and of its square, by running sums; shift s of a
    # row is admissible up to its own L − n.
    zero = np.zeros((kept.size, 1, 3))
    running = np.cumsum(np.concatenate([zero, expected], axis=1), axis=1)
    running_sq = np.cumsum(np.concatenate([zero, expected**2], axis=1), axis=1)
    shifts = longest - n + 1
    last = lengths - n
    rows = np.arange(kept.size)[:, None]
    sums = running[:, n:] - running[:, :shifts]
    squares = running_sq[:, n:] - running_sq[:, :shifts]
    energy = running_sq[np.arange(kept.size), lengths][:, None, :]
    placed = [(1.0, correlation[:, n - 1 : n - 1 + shifts], sums, squares)]
    if convolution is not None:
        # Mirrored (L samples): its correlation at shift s is the convolution at L − 1 − s, its
        # window at s the forward one at L − n − s.
        mirror = np.clip(last[:, None] - np.arange(shifts)[None, :], 0, shifts - 1)
        placed.append(
            (-1.0, convolution[rows, n - 1 + mirror], sums[rows, mirror], squares[rows, mirror])
        )
    valid = np.arange(shifts)[None, :] <= last[:, None]
    each_row = np.arange(kept.size)
    scored: list[tuple[float, float, float]] = []
    for sign, corr, window_sums, window_squares in placed:
        variance = np.clip(window_squares - window_sums**2 / n, 1e-300, None)
        ncc = corr / (np.sqrt(variance) * profile_norm)
        # Only windows that hold (nearly) the whole modelled first order are admissible.
        inside = np.all(window_squares >= min_model_fraction * energy, axis=2) & valid
        totals = np.where(inside, ncc.mean(axis=2), -np.inf)
        lit = np.any(inside, axis=1)
        # Each row's inadmissible shifts just below its lowest admissible score, and past its
        # own last shift its last value (the local maxima's ends clipped as for one row).
        floor = np.min(np.where(inside, totals, np.inf), axis=1, keepdims=True) - 1
        finite = np.where(inside, totals, floor)
        finite = np.where(valid, finite, finite[each_row, last][:, None])
        peaks_at = _local_maxima(finite, 3) & valid
        peaks_at[each_row, np.argmax(finite, axis=1)] = True
        for row, shift in zip(*np.nonzero(peaks_at & inside & lit[:, None]), strict=True):
            slope = sign * float(dispersions[row])
            nm = samples_nm[row, shift] if sign > 0 else samples_nm[row, last[row] + n - 1 - shift]
            scored.append((float(totals[row, shift]), slope, float(nm - slope * pixel[0])))
    scored.sort(reverse=True)
    pixel_range = (float(pixel[0]), float(pixel[-1]))
    probe = np.linspace(pixel_range[0], pixel_range[1], 16)
    chosen: list[tuple[float, float, float]] = []
    kept_nm = np.empty((0, probe.size))
    for value, slope, offset in scored:
        # (QuadraticMapping.wavelength_nm's own expression, for a = 0.)
        placed_nm = (0.0 * probe + slope) * probe + offset
        if kept_nm.shape[0] and np.min(np.max(np.abs(kept_nm - placed_nm), axis=1)) < 6.0:
            continue
        chosen.append((value, slope, offset))
        kept_nm = np.vstack([kept_nm, placed_nm])
        if len(chosen) == n_candidates:
            break
    candidates = [
        QuadraticMapping(
            0.0, slope, offset, method="led-search", pixel_range=pixel_range, details={"ncc": value}
        )
        for value, slope, offset in chosen
    ]
    if not candidates:
        raise EstimationError("the broadband mapping search found no candidate")
    return candidates


# ------------------------------------------------------------------------------------ refine

ResidualFunction = Callable[[QuadraticMapping], FloatArray]


def refine_mapping(
    mapping: QuadraticMapping,
    residual: ResidualFunction,
    *,
    pixel_range: tuple[float, float],
    method: str,
    max_evaluations: int = 200,
    step_nm: float = 0.02,
    tolerance: float = 1e-8,
) -> tuple[QuadraticMapping, float]:
    """Least-squares refinement of ``(a, b, c)`` minimising ``‖residual(mapping)‖²``.

    The mapping is parameterised by its wavelengths at the two ends and the middle of
    ``pixel_range`` (well conditioned, in nm); derivatives are finite differences of ``step_nm``
    (larger than the kinks that pixel edges crossing the fine axis' nodes put in the residual);
    ``tolerance`` is least squares' ``ftol``/``xtol``/``gtol`` (looser for intermediate stages). The
    covariance of ``(a, b, c)`` comes from the Jacobian at the optimum scaled by the residual
    variance; it gives the mapping's error estimate.

    Returns
    -------
    (QuadraticMapping, float)
        The refined mapping and the final cost ``‖residual‖²``.
    """
    from scipy import optimize

    anchors = np.array([pixel_range[0], 0.5 * (pixel_range[0] + pixel_range[1]), pixel_range[1]])
    to_coefficients = np.linalg.inv(np.stack([anchors**2, anchors, np.ones(3)], axis=1))

    def build(theta: FloatArray) -> QuadraticMapping:
        a, b, c = to_coefficients @ theta
        return QuadraticMapping(
            float(a), float(b), float(c), method=method, pixel_range=pixel_range
        )

    start = mapping.wavelength_nm(anchors)
    solution = optimize.least_squares(
        lambda theta: residual(build(theta)),
        start,
        x_scale=np.ones(3),
        diff_step=step_nm / np.maximum(np.abs(start), 1.0),
        max_nfev=max_evaluations,
        ftol=tolerance,
        xtol=tolerance,
        gtol=tolerance,
    )
    theta_to_anchor = np.eye(3)
    refined = build(solution.x)
    n_residuals = solution.fun.size
    cost = float(np.sum(solution.fun**2))
    variance = cost / max(n_residuals - 3, 1)
    try:
        theta_cov = np.linalg.inv(solution.jac.T @ solution.jac) * variance
        anchor_cov = theta_to_anchor @ theta_cov @ theta_to_anchor.T
        covariance = to_coefficients @ anchor_cov @ to_coefficients.T
        rms = wavelength_rms_from_covariance(covariance, pixel_range)
        covariance_list: list[list[float]] | None = covariance.tolist()
    except np.linalg.LinAlgError:
        covariance_list, rms = None, float("nan")
    details = {
        **dict(mapping.details),
        "refined_from": list(mapping.coefficients),
        "evaluations": int(solution.nfev),
        "cost": cost,
    }
    return refined.with_details(
        covariance=covariance_list, wavelength_rms_nm=rms, details=details
    ), cost


def model_curve_on_fine_axis(
    lamp: Spectrum, mean_sensitivity: FloatArray, grid: WavelengthGrid, step_nm: float = 1.0
) -> tuple[FloatArray, FloatArray]:
    """``ŝ ⊙ e`` per nm on the grid's fine axis: shapes ``(n_fine,)`` and ``(n_fine, 3)``."""
    axis = fine_axis(grid.start_nm, grid.stop_nm, step_nm)
    return axis, lamp.at(axis)[:, None] * (hat_matrix(grid, axis) @ mean_sensitivity)


def icp_mapping(
    observation: Any,
    mean_sensitivity: FloatArray,
    grid: WavelengthGrid = DEFAULT_GRID,
    *,
    iterations: int = 500,
) -> QuadraticMapping:
    """The paper's LED-only mapping: point-to-plane ICP of the profile onto ``ŝ ⊙ e`` (Eq. 15).

    Makabe et al. (2025) §3.2 as printed: ``u = ν(m_dif)`` per channel and ``v = ν(e ⊙ ŝ)`` on the grid
    (``ν`` the L2 normalisation), points ``[g(p_i), u(p_i)]`` against the polyline ``[λ_j, v(λ_j)]``
    with normals from consecutive samples, ``g`` quadratic, 500 iterations from ``a = 0, b = f/n,
    c = 0`` — in grid-index units, as that start implies. One change so the two plots share a vertical
    scale: ``u`` is multiplied by ``√(n/f)`` (``ν`` leaves vectors of different lengths at different
    amplitudes). Kept to reproduce the paper's numbers (``method="icp"`` of
    :func:`calib.wavelength.find_mapping`); the ``"search"`` strategy is the estimator to use.

    Parameters
    ----------
    observation
        A :class:`calib.core.observations.LampObservation` (its spectrum, pixels and profile).
    mean_sensitivity
        ``ŝ`` ``(f, 3)`` on ``grid``.

    Returns
    -------
    QuadraticMapping
        In nanometres, ``method="icp"``.
    """
    pixel = np.asarray(observation.pixel, dtype=np.float64)
    profile = np.asarray(observation.profile, dtype=np.float64)
    n, f = pixel.size, grid.size
    lamp = observation.spectrum.resample(grid, "integrate").values
    index = np.arange(f, dtype=np.float64)
    p = pixel - pixel[0]
    design = np.stack([p**2, p, np.ones_like(p)], axis=1)
    coefficients = np.array([0.0, f / n, 0.0])
    targets = []
    for c in range(3):
        v = lamp * mean_sensitivity[:, c]
        u = profile[:, c]
        if np.linalg.norm(v) <= 0 or np.linalg.norm(u) <= 0:
            continue
        v = v / np.linalg.norm(v)
        u = u / np.linalg.norm(u) * math.sqrt(n / f)
        tangent = np.stack([np.diff(index), np.diff(v)], axis=1)
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.vstack([normal, normal[-1:]])  # the last point takes its segment's normal
        targets.append((u, v, normal))
    if not targets:
        raise EstimationError("the profile or the lamp × mean camera is all zero")
    for _ in range(iterations):
        x = design @ coefficients
        rows, rhs = [], []
        for u, v, normal in targets:
            distance = (x[:, None] - index[None, :]) ** 2 + (u[:, None] - v[None, :]) ** 2
            nearest = np.argmin(distance, axis=1)
            nx, ny = normal[nearest, 0], normal[nearest, 1]
            # ((x − λ_j) n_x + (u − v_j) n_y) with x = design @ coefficients
            rows.append(design * nx[:, None])
            rhs.append(index[nearest] * nx - (u - v[nearest]) * ny)
        update, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
        if np.allclose(update, coefficients, rtol=1e-12, atol=1e-12):
            break
        coefficients = update
    a_idx, b_idx, c_idx = coefficients
    # index → nm: λ = start + step·x, and p = pixel − pixel[0].
    step, start, offset = grid.step_nm, grid.start_nm, pixel[0]
    a = step * a_idx
    b = step * (b_idx - 2 * a_idx * offset)
    c = start + step * (a_idx * offset**2 - b_idx * offset + c_idx)
    return QuadraticMapping(
        float(a), float(b), float(c), method="icp", pixel_range=(float(pixel[0]), float(pixel[-1]))
    )


def lines_and_peaks(
    observation: LampObservation, mean_sensitivity: FloatArray, grid: WavelengthGrid
) -> tuple[list[Peak], list[Peak], float]:
    """A line lamp's lines (nm, :func:`lamp_lines` of its spectrum weighted by ``ŝ``), its
    profile's peaks (px, :func:`profile_peaks`), both strongest first, and the nominal dispersion
    (nm per pixel unit, :func:`nominal_dispersion`) the peaks were found with."""
    model_nm, model = model_curve_on_fine_axis(observation.spectrum, mean_sensitivity, grid)
    dispersion = nominal_dispersion(observation.pixel, observation.profile, model_nm, model)
    total = mean_sensitivity.sum(axis=1)

    def weight(wavelength: FloatArray) -> FloatArray:
        return np.asarray(
            np.interp(wavelength, grid.wavelength_nm, total, 0.0, 0.0), dtype=np.float64
        )

    lines = lamp_lines(observation.spectrum, weight, range_nm=(grid.start_nm, grid.stop_nm))
    peaks = profile_peaks(observation.pixel, observation.profile, line_width_px=20.0 / dispersion)
    return lines, peaks, dispersion


def fluorescent_starts(
    observation: LampObservation,
    mean_sensitivity: FloatArray,
    grid: WavelengthGrid,
    n_candidates: int,
    *,
    explain_peaks: bool = False,
) -> list[QuadraticMapping]:
    """Mappings from matching the lamp's lines to the profile's peaks (several hypotheses;
    ``explain_peaks``: see :func:`match_peak_hypotheses`)."""
    lines, peaks, dispersion = lines_and_peaks(observation, mean_sensitivity, grid)
    return match_peak_hypotheses(
        lines,
        peaks,
        pixel_range=(float(observation.pixel[0]), float(observation.pixel[-1])),
        dispersion_range_nm_per_px=(0.5 * dispersion, 2.0 * dispersion),
        n_hypotheses=n_candidates,
        explain_peaks=explain_peaks,
    )
