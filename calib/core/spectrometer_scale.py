"""The spectrometer's wavelength scale checked against the mercury lines of a lamp it measured.

A spectroradiometer's wavelength scale is off by up to its stated tolerance (±0.5 nm,
:mod:`calib.core.spectrometer_tolerance`): the pixel it reports as ``λ`` sees the light of
``λ + δ(λ)``. Every estimate's lamp spectra carry that ``δ``, and the σ budget carries the tolerance
(decision 0044). A lab checks its spectrometer against mercury lines, and every session with a
fluorescent lamp already holds such a measurement: the spectrometer's own spectrum of the lamp
shows Hg 404.66, 435.83, 546.07 and the 576.96/579.07 doublet, known to 0.01 nm (NIST).

:func:`check_spectrometer_scale` fits ``δ`` from those lines (decision 0069):

1. *One window per Hg feature* (:data:`calib.core.line_lists.SCALE_CHECK_FEATURES`), ±2 slit
   FWHM around it. The model in the window is every line of the tri-phosphor CFL list
   (:data:`calib.core.line_lists.CFL_NEIGHBOURS`: Hg, Tb³⁺, Eu³⁺) that reaches into it, each a
   Gaussian of the slit (the stated FWHM × a free factor, in quadrature with the line's own width)
   with a free amplitude, on a polynomial background, all moved by one shift ``δ``. So a blend
   is modelled, not ignored: where the slit cannot separate Tb 542.4 from Hg 546.1 (or the two
   lines of the doublet) the free amplitudes make the shift poorly determined and the fit's
   covariance says so; a phosphor line's peak (known to 0.5 nm) gets its own displacement with a
   Gaussian prior of that σ, so it informs ``δ`` only as far as its position is known.
   *Coarse sampling* (decision 0072; a PR-655 reports every 4 nm through its 8 nm slit: 9–10
   samples per window): the background's degree is lowered as far as a straight line
   (:data:`MIN_BACKGROUND_DEGREE`) until the window holds three samples more than parameters, and
   a window so lowered that models a neighbour closer than :data:`RESOLVED_FWHM` slit widths
   (404.7 beside Hg 407.8, 546.1 beside Tb 542.4) holds the slit factor at the one its resolved
   windows measured (one instrument, one slit): with so few samples a free width trades with
   the blended neighbour's amplitude and moves the centre (on the twin's FL2 at 7 nm, 404.7 by
   0.7–0.9 nm with a free width, 0.1 nm held).
2. *A window counts* when its mercury line is there: amplitude ≥ :data:`MIN_LINE_SNR` of its σ,
   the slit factor and the shift inside their search ranges (not at a bound), and ``δ``'s σ below
   :data:`MAX_LINE_SIGMA_NM`. Otherwise it is left out (the reason recorded).
3. *The scale*: ``δ(λ) = a + b (λ − λ_r)`` from the windows' shifts, weighted by their σ. The
   offset ``a`` takes no prior (the data decide it, so an instrument out of its specification is
   seen as such); the slope ``b`` takes the in-spec instrument's prior: the error at 380 and at
   780 nm each within ±tolerance (σ = tolerance/√3), independent, straight between — the twin's
   model (decision 0038), ``σ_b = √2 · 0.289 / 400 nm``. The data fit it only when the windows span
   :data:`MIN_SLOPE_SPAN_NM`; otherwise it stays its prior and the σ grows away from the lines.
   At least :data:`MIN_FEATURES` windows must count (one line cannot test itself).
   When the windows disagree (reduced χ² > 1) the covariance is inflated by it; beyond
   :data:`MAX_CONSISTENCY_CHI2` they are taken as not mercury's and no check is made.
4. *The σ*: ``σ(λ)² = [1, λ − λ_r] Σ [1, λ − λ_r]ᵀ``, stated as its RMS over the working range
   (:attr:`ScaleCheck.sigma_nm`): the spectrometer scale σ the mapping and the budget use in place
   of the tolerance.

No check is made (the reason is returned) when fewer than two windows count (no Hg lines: an LED,
a halogen lamp; lines too blended or too coarsely sampled at this slit; a poor fit), when they
disagree, or when the result is no better than the tolerance: the tolerance stays.

:func:`checked_observations` applies it to an estimate's lamps: the first line lamp whose spectrum a
spectrometer measured (a stated bandwidth, not a built-in or tabulated spectrum) is checked, and
every lamp measured by *the same instrument* is corrected. One estimate's lamp spectra are taken
as one instrument's when they state the same bandwidth: a rig session records one spectrometer
for all its lamps, and ``calib estimate`` states one ``--bandwidth`` (or each CSV its own). A lamp
whose spectrum states another bandwidth (or ``metadata["spectrometer"]`` another instrument) keeps
its spectrum and the tolerance. Where the isolated lines measured the slit more than
:data:`SLIT_CORRECTION_SIGMAS` of its σ away from the stated one, every corrected lamp's bandwidth
becomes the measured slit (the stated one kept under :data:`SLIT_CORRECTION_KEY`), so the mapping
and the solve match the spectra at the slit the instrument has, and the σ budget's bandwidth
component is the measurement's own σ (decision 0176).

Examples
--------
>>> from calib.core.line_lists import line_list, line_spectrum
>>> lamp = line_spectrum(line_list("hg"), fwhm_nm=3.0, continuum=0.02)
>>> moved = Spectrum(lamp.wavelength_nm - 0.3, lamp.values)  # reports λ for the light of λ + 0.3
>>> sampled = Spectrum(np.arange(380.0, 781.0), moved.at(np.arange(380.0, 781.0)))
>>> check = check_spectrometer_scale(sampled, 3.0)  # a ScaleCheck, or why there is none
>>> round(check.offset_nm, 2), check.sigma_nm < 0.05
(0.3, True)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.line_lists import CFL_NEIGHBOURS, SCALE_CHECK_FEATURES, Line, is_builtin
from calib.core.observations import LampObservation
from calib.core.result import json_safe
from calib.core.spectra import Spectrum
from calib.core.spectrometer_tolerance import IN_SPEC_TOLERANCE_SIGMA, WAVELENGTH_SCALE_NM

#: ``LampObservation.metadata`` key of a corrected lamp: the check's record (:meth:`ScaleCheck.to_dict`).
SCALE_CHECK_KEY = "spectrometer_scale_check"
#: ``LampObservation.metadata`` key: the one-σ wavelength-scale error (nm) of the lamp's spectrum
#: after the check, used by the mapping and the budget in place of the tolerance.
SCALE_SIGMA_KEY = "wavelength_scale_sigma_nm"
#: ``LampObservation.metadata`` key of a lamp whose stated bandwidth the check corrected to the
#: measured slit: the stated FWHM (nm) (:func:`checked_observations`; the factor and its σ are the
#: check's record's).
SLIT_CORRECTION_KEY = "stated_bandwidth_nm"
#: The measured slit replaces the stated one when they differ by more than this many σ of the
#: measured factor (:attr:`ScaleCheck.slit_factor`): the stated slit is then contradicted by the
#: instrument's own spectrum (decision 0176). A significance level, not a tuned number.
SLIT_CORRECTION_SIGMAS = 2.0

#: Search range of the shift (nm): the PR-655's stated ±2 nm and a margin, so an instrument out of
#: its ±0.5 nm class is still measured (and flagged), not refused.
SEARCH_SHIFT_NM = 3.0
#: Search range of the slit factor (true FWHM / stated): the stated ±25 % (decision 0038) widened by
#: the lines' own width (a lamp's Hg lines as simulations restore them: 1 nm) and the sampling.
SLIT_FACTOR_RANGE = (0.6, 1.8)
#: A window's half-width in slit FWHMs: a Gaussian is at 1/65 of its peak at 2 FWHM, so the window
#: holds the line and enough background on each side to fit it.
WINDOW_FWHM = 2.0
#: A mercury line counts when its amplitude is this many σ of the fit (its blend partners' free
#: amplitudes included): a clear detection, not a bump of the background. Whether its centre is
#: well enough determined is :data:`MAX_LINE_SIGMA_NM`'s to say.
MIN_LINE_SNR = 8.0
#: A window whose shift is less well determined than this (nm) adds nothing against the ±0.5 nm
#: tolerance (σ 0.29 nm) and is left out.
MAX_LINE_SIGMA_NM = 0.25
#: A check rests on at least this many mercury features, so that their agreement tests the model:
#: one line's centre can be pulled by structure under it (a phosphor band's edge, a neighbour the
#: list lacks) that nothing else reveals. On the validation protocol's spectrometer draws (FL2,
#: slits 8–10 nm) the single-line checks held their ±2σ for 11 % of draws (decision 0069).
MIN_FEATURES = 2
#: The features must span at least this (nm) for the data to fit a slope: over a shorter lever a
#: window's error is amplified by (working range / span) ≥ 3 at the range's far end (404.7 and
#: 435.8 nm alone: 10×). Below it the slope keeps its in-spec prior (zero, σ_b) and the offset is
#: the weighted mean of the windows; 435.8 with 546.1 (110 nm) or 578 (142 nm) fits one.
MIN_SLOPE_SPAN_NM = 100.0
#: Windows whose shifts disagree beyond this reduced χ² are not mercury's lines as the list has them
#: (a lamp of another gas, a mislabelled spectrum): nothing is returned. About p = 10⁻³ for 1–3
#: degrees of freedom is χ²/dof of 5–11; 9 keeps the refusal to gross disagreement.
MAX_CONSISTENCY_CHI2 = 9.0
#: The scale error's range in the in-spec model (the twin's, decision 0038): its ends each within
#: ±tolerance, independent, straight between.
SCALE_MODEL_RANGE_NM = (380.0, 780.0)
#: Where the offset ``a`` of ``δ(λ) = a + b (λ − λ_r)`` is stated (the middle of the model range).
REFERENCE_NM = 580.0
#: A line known better than this (nm) is an atomic standard and moves with the scale alone; a
#: less well known one (a phosphor multiplet, 0.5 nm) gets its own displacement with that prior.
ATOMIC_UNCERTAINTY_NM = 0.05
#: A neighbour farther than this many stated slit FWHM from a mercury feature is resolved from it:
#: two Gaussian lines one FWHM apart already show a dip between them, and the true slit may be
#: 25 % wider than stated (decision 0038), so 1.5 stated FWHM is ≥ 1.2 true ones.
RESOLVED_FWHM = 1.5
#: Degree of the polynomial background of a window.
BACKGROUND_DEGREE = 3
#: The lowest degree it is lowered to when a window has too few samples for a cubic: a straight
#: line (a phosphor continuum's slope under the line must be fitted; its curvature over ±2 FWHM
#: moves the centre far less than the slope would).
MIN_BACKGROUND_DEGREE = 1
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
#: The slit factor's model error (relative), in quadrature under the fit's own σ
#: (:attr:`ScaleCheck.slit_factor`): the window models an isolated mercury line as a Gaussian of
#: the slit alone (an atomic line's own width is 0), so a line that reaches the spectrometer with
#: a width of its own (a spectrum restored or resampled at some resolution: the simulations'
#: lamps give their Hg lines ≈ 1 nm) reads as a slit wider by ``√(1 + (w / s)²) − 1``: large at
#: narrow slits, nothing at wide ones (:func:`slit_factor_floor`). ``w`` here is that width, not
#: known to the check. Judged on the VALIDATION split only (decision 0160, ``python
#: bench/spectrometer_scale_check.py --split validation --data-dir DIR``; the protocol's
#: instrument has the slit it states, so the factor's truth is 1): the 40 measured factors are off
#: by +0.077…+0.088 at 2.4–2.5 nm slits, +0.02 at 4–5 nm and ≤ +0.010 at 8–10 nm; each scene's
#: excess read as such a width gives 0.93–1.10 nm at 2–5 nm slits, the least-squares width over
#: all 40 is 1.01 nm (residual RMS 0.004), and this form at 1.0 nm matches every 2 nm band's RMS
#: (0.066 / 0.022 / 0.011 / 0.006 against 0.067 / 0.023 / 0.013 / 0.006). Decision 0099's constant
#: 0.07 was the 2–4 nm band's, 7–10× the error at the twins' 7–8 nm slits.
SLIT_LINE_WIDTH_NM = 1.0


def slit_factor_floor(bandwidth_nm: float) -> float:
    """The slit factor's model error at a stated slit FWHM (:data:`SLIT_LINE_WIDTH_NM`):
    ``√(1 + (w / s)²) − 1``, the relative widening a line's own width ``w`` adds to a slit ``s``.

    >>> round(slit_factor_floor(2.5), 4), round(slit_factor_floor(8.0), 4)
    (0.077, 0.0078)
    """
    return math.hypot(1.0, SLIT_LINE_WIDTH_NM / bandwidth_nm) - 1.0


@dataclass(frozen=True)
class LineShift:
    """One window's fit: the shift of its mercury feature and its σ."""

    label: str
    wavelength_nm: float
    shift_nm: float
    sigma_nm: float
    snr: float
    slit_factor: float
    #: σ of :attr:`slit_factor` where the window fitted it (an isolated line, the factor free);
    #: ``None`` where the factor was held or a neighbour shares the window (its width is not the
    #: slit's alone).
    slit_factor_sigma: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class ScaleCheck:
    """The spectrometer's wavelength-scale error as the mercury lines measure it (module docstring).

    ``δ(λ) = offset_nm + slope · (λ − reference_nm)``: the pixel the instrument reports as ``λ``
    sees the light of ``λ + δ(λ)``; the corrected spectrum puts each value at ``λ + δ(λ)``.

    Attributes
    ----------
    lamp
        The lamp whose spectrum was checked.
    bandwidth_nm
        Its stated slit FWHM.
    offset_nm, slope
        The fitted scale error.
    covariance
        ``(2, 2)`` covariance of ``(offset_nm, slope)``.
    sigma_nm
        RMS of the correction's σ over ``range_nm``: the scale σ left after the correction.
    range_nm
        The working range that RMS is taken over.
    lines
        The windows that counted.
    left_out
        The windows that did not, with why.
    reduced_chi2
        The windows' agreement with the straight line (``None`` with one window).
    tolerance_nm
        The instrument's stated tolerance the check is compared with.
    """

    lamp: str
    bandwidth_nm: float
    offset_nm: float
    slope: float
    covariance: FloatArray
    sigma_nm: float
    range_nm: tuple[float, float]
    lines: tuple[LineShift, ...]
    left_out: tuple[str, ...] = ()
    reduced_chi2: float | None = None
    tolerance_nm: float = WAVELENGTH_SCALE_NM
    reference_nm: float = REFERENCE_NM

    def correction_nm(self, wavelength_nm: FloatArray) -> FloatArray:
        """``δ(λ)`` at the reported wavelengths (same shape)."""
        x = np.asarray(wavelength_nm, dtype=np.float64) - self.reference_nm
        return np.asarray(self.offset_nm + self.slope * x, dtype=np.float64)

    def sigma_at(self, wavelength_nm: FloatArray) -> FloatArray:
        """σ of ``δ(λ)`` (same shape)."""
        x = np.asarray(wavelength_nm, dtype=np.float64) - self.reference_nm
        c = self.covariance
        variance = c[0, 0] + 2.0 * c[0, 1] * x + c[1, 1] * x * x
        return np.asarray(np.sqrt(np.clip(variance, 0.0, None)), dtype=np.float64)

    def _range_axis(self) -> FloatArray:
        return np.linspace(self.range_nm[0], self.range_nm[1], 61)

    @property
    def mean_offset_nm(self) -> float:
        """``δ`` averaged over :attr:`range_nm` (what a constant offset over the range would be)."""
        return float(np.mean(self.correction_nm(self._range_axis())))

    @property
    def out_of_spec(self) -> bool:
        """Whether ``|δ|`` exceeds the tolerance by more than 2σ somewhere in :attr:`range_nm`
        (the instrument is out of its specification)."""
        axis = self._range_axis()
        beyond = np.abs(self.correction_nm(axis)) - 2.0 * self.sigma_at(axis)
        return bool(np.any(beyond > self.tolerance_nm))

    def note(self) -> str:
        """One line for the result and the report."""
        lines = ", ".join(line.label for line in self.lines)
        slope = (
            f", slope {100 * self.slope:+.2f} ± {100 * math.sqrt(self.covariance[1, 1]):.2f} nm per "
            "100 nm"
        )
        return (
            f"spectrometer scale checked against Hg lines ({lines} of {self.lamp}): offset "
            f"{self.mean_offset_nm:+.2f} ± {self.sigma_nm:.2f} nm over "
            f"{self.range_nm[0]:g}–{self.range_nm[1]:g} nm{slope}, corrected"
        )

    @property
    def slit_factor(self) -> tuple[float, float] | None:
        """The slit's FWHM over the stated one as the isolated lines measured it, and its σ: their
        inverse-variance mean, its σ inflated by the lines' disagreement (reduced χ² > 1) and
        :func:`slit_factor_floor` at the stated slit in quadrature; ``None`` when no isolated line
        fitted it."""
        measured = [
            (line.slit_factor, line.slit_factor_sigma)
            for line in self.lines
            if line.slit_factor_sigma is not None and line.slit_factor_sigma > 0
        ]
        if not measured:
            return None
        factors = np.array([value for value, _ in measured])
        weights = 1.0 / np.array([sigma for _, sigma in measured]) ** 2
        mean = float(np.sum(weights * factors) / weights.sum())
        variance = 1.0 / float(weights.sum())
        if len(measured) > 1:
            chi2 = float(np.sum(weights * (factors - mean) ** 2)) / (len(measured) - 1)
            variance *= max(1.0, chi2)
        return mean, math.sqrt(variance + slit_factor_floor(self.bandwidth_nm) ** 2)

    def to_dict(self) -> dict[str, Any]:
        """Its fields as plain JSON data, with the derived figures the report and the σ budget
        use (the slit factor: :func:`measured_slit`)."""
        slit = self.slit_factor
        return {
            **json_safe(asdict(self)),
            "mean_offset_nm": self.mean_offset_nm,
            "out_of_spec": self.out_of_spec,
            "slit_factor": None if slit is None else slit[0],
            "slit_factor_sigma": None if slit is None else slit[1],
        }


def _gaussians(
    x: FloatArray, centres: FloatArray, fwhm: FloatArray
) -> FloatArray:  # (..., n, k), peak 1, for centres (..., k)
    sigma = fwhm / FWHM_PER_SIGMA
    offsets = x[:, None] - centres[..., None, :]
    return np.asarray(np.exp(-0.5 * (offsets / sigma) ** 2))


@dataclass(frozen=True)
class _Window:
    label: str
    wavelength_nm: float  # strength-weighted centre of its mercury lines
    x: FloatArray
    y: FloatArray
    lines: tuple[Line, ...]
    reference: tuple[bool, ...]  # which components are the feature's mercury lines
    degree: int
    bandwidth_nm: float

    @property
    def isolated(self) -> bool:
        """Whether the feature is resolved from every neighbour the window models (none within
        :data:`RESOLVED_FWHM` stated slit widths), so its width measures the slit."""
        feature = [line for line, ref in zip(self.lines, self.reference, strict=True) if ref]
        return all(
            abs(line.wavelength_nm - own.wavelength_nm) > RESOLVED_FWHM * self.bandwidth_nm
            for line, ref in zip(self.lines, self.reference, strict=True)
            if not ref
            for own in feature
        )

    def design(self, shift_nm: float, factor: float, moved: Sequence[float] = ()) -> FloatArray:
        return np.asarray(self.designs(np.array([shift_nm]), factor, moved)[0])

    def designs(
        self, shifts_nm: FloatArray, factor: float, moved: Sequence[float] = ()
    ) -> FloatArray:
        """The design matrices at every shift of ``shifts_nm`` at once, ``(shifts, n, k)``: the
        lines' Gaussians, then the background's powers."""
        listed = np.array([line.wavelength_nm for line in self.lines])
        positions = listed[None, :] - np.asarray(shifts_nm, dtype=np.float64)[:, None]
        if moved:
            positions = positions + np.asarray(moved)
        widths = np.hypot(factor * self.bandwidth_nm, [line.width_nm for line in self.lines])
        peaks = _gaussians(self.x, positions, widths)
        centre = self.wavelength_nm
        scale = max(float(np.ptp(self.x)) / 2.0, 1.0)
        background = np.stack([((self.x - centre) / scale) ** j for j in range(self.degree + 1)], 1)
        background = np.broadcast_to(background, (*peaks.shape[:-1], background.shape[1]))
        return np.concatenate([peaks, background], axis=-1)

    def residual(
        self, shift_nm: float, factor: float, moved: Sequence[float] = ()
    ) -> tuple[FloatArray, FloatArray]:
        design = self.design(shift_nm, factor, moved)
        coefficients, *_ = np.linalg.lstsq(design, self.y, rcond=None)
        return np.asarray(self.y - design @ coefficients), np.asarray(coefficients)

    def costs(self, shifts_nm: FloatArray, factor: float) -> FloatArray:
        """The residual sum of squares at every shift of ``shifts_nm`` (the linear parameters
        projected out), as :meth:`residual` finds it shift by shift, in batched calls.

        The background's columns do not move with the shift: they are projected out of the data
        and of every shift's Gaussians once, and the Gaussians left are fitted by one batched SVD.
        Both keep the singular vectors ``lstsq`` keeps (singular values above ``eps · max(n, k)``
        of the largest, its ``rcond=None``), so a rank-deficient design (a line listed twice) is
        fitted as it fits it."""
        design = self.designs(shifts_nm, factor)
        lines = len(self.lines)
        rcond = np.finfo(np.float64).eps * max(design.shape[-2:])
        flat, singular, _ = np.linalg.svd(design[0, :, lines:], full_matrices=False)
        flat = flat[:, singular > rcond * singular[0]]
        peaks = design[:, :, :lines] - flat @ np.einsum("nb,snk->sbk", flat, design[:, :, :lines])
        y = self.y - flat @ (flat.T @ self.y)
        left, singular, _ = np.linalg.svd(peaks, full_matrices=False)
        kept = singular > rcond * singular[:, :1]
        projections = np.einsum("snk,n->sk", left, y) * kept
        residual = y[None, :] - np.einsum("snk,sk->sn", left, projections)
        return np.asarray(np.einsum("sn,sn->s", residual, residual))


def _windows(spectrum: Spectrum, bandwidth_nm: float) -> tuple[list[_Window], list[str]]:
    wavelength = np.asarray(spectrum.wavelength_nm, dtype=np.float64)
    values = np.asarray(spectrum.values, dtype=np.float64)
    windows: list[_Window] = []
    left_out: list[str] = []
    for feature in SCALE_CHECK_FEATURES:
        label = " + ".join(line.label for line in feature)
        strengths = np.array([line.strength for line in feature])
        centre = float(
            np.sum(strengths * [line.wavelength_nm for line in feature]) / strengths.sum()
        )
        span = max(line.wavelength_nm for line in feature) - min(
            line.wavelength_nm for line in feature
        )
        half = WINDOW_FWHM * bandwidth_nm + 0.5 * span + SEARCH_SHIFT_NM
        inside = (wavelength >= centre - half) & (wavelength <= centre + half)
        if wavelength[0] > centre - half or wavelength[-1] < centre + half:
            left_out.append(f"{label}: outside the spectrum's range")
            continue
        reach = half + bandwidth_nm
        neighbours = [
            line
            for line in CFL_NEIGHBOURS
            if abs(line.wavelength_nm - centre) <= reach and line.kind == "emission"
        ]
        lines = tuple(sorted(set(neighbours) | set(feature), key=lambda line: line.wavelength_nm))
        reference = tuple(line in feature for line in lines)
        n = int(inside.sum())
        nonlinear = 2
        # The background's degree as the samples allow (coarse sampling: a PR-655's 4 nm steps
        # through an 8 nm slit give 9–10 samples per window), never below a straight line.
        degree = BACKGROUND_DEGREE
        while degree > MIN_BACKGROUND_DEGREE and n < nonlinear + len(lines) + degree + 1 + 3:
            degree -= 1
        parameters = nonlinear + len(lines) + degree + 1
        if n < parameters + 3:
            left_out.append(
                f"{label}: {n} samples in the window, too few for {parameters} parameters"
            )
            continue
        windows.append(
            _Window(
                label,
                centre,
                wavelength[inside],
                values[inside],
                lines,
                reference,
                degree,
                bandwidth_nm,
            )
        )
    return windows, left_out


def _fit_window(
    window: _Window, step_nm: float, held_factor: float | None = None
) -> LineShift | str:
    """The window's shift and its σ, or why it does not count.

    Nonlinear parameters: the shift, the slit factor (unless ``held_factor`` holds it: the slit
    measured on another window of the same spectrum) and, for each phosphor line (a multiplet whose
    peak is known to its ``uncertainty_nm`` only), its own displacement with a Gaussian prior of
    that σ; the amplitudes and the background are projected out. So a strong phosphor neighbour
    (Tb 542.4 beside Hg 546.1) informs the shift only as far as its listed position is known."""
    low, high = SLIT_FACTOR_RANGE
    phosphor = [
        index
        for index, line in enumerate(window.lines)
        if not window.reference[index] and line.uncertainty_nm > ATOMIC_UNCERTAINTY_NM
    ]
    prior_sigma = np.array([window.lines[index].uncertainty_nm for index in phosphor])

    def moved(values: FloatArray) -> list[float]:
        out = [0.0] * len(window.lines)
        for index, value in zip(phosphor, values, strict=True):
            out[index] = float(value)
        return out

    held = held_factor is not None
    free = 1 if held else 2  # the shift, and the slit factor unless held

    def full(values: FloatArray) -> FloatArray:
        # (shift, factor, displacements…) from the free parameters.
        if not held:
            return values
        return np.concatenate([[values[0], held_factor], values[1:]])

    shift_step = min(0.1, 0.25 * step_nm, window.bandwidth_nm / 20.0)
    shifts = np.arange(-SEARCH_SHIFT_NM, SEARCH_SHIFT_NM + shift_step / 2, shift_step)
    factors = np.array([held_factor]) if held_factor is not None else np.linspace(low, high, 13)
    # The grid's costs, factor by factor, every shift of one factor in one call; the first smallest
    # in factor-then-shift order (a cost that is not a number never counts), its cost then
    # recomputed by the fit itself, so the noise the refinement whitens with is the fit's.
    costs = np.stack([window.costs(shifts, float(factor)) for factor in factors])
    costs = np.where(np.isnan(costs), math.inf, costs)
    first = int(np.argmin(costs))
    best = (math.inf, 0.0, 1.0)
    if costs.flat[first] < math.inf:
        row, column = divmod(first, shifts.size)
        shift, factor = float(shifts[column]), float(factors[row])
        residual, _ = window.residual(shift, factor)
        best = (float(residual @ residual), shift, factor)
    n = window.x.size
    k = len(window.lines) + window.degree + 1
    dof = n - k - free
    noise = math.sqrt(max(best[0], 1e-300) / dof)
    parameters = np.concatenate([[best[1], best[2]][:free], np.zeros(len(phosphor))])

    def whitened(values: FloatArray) -> FloatArray:
        every = full(values)
        residual, _ = window.residual(every[0], every[1], moved(every[2:]))
        return np.concatenate([residual / noise, every[2:] / prior_sigma])

    # Gauss–Newton, the linear parameters projected out at each step.
    limits = np.concatenate([[0.5, 0.1][:free], 0.5 * prior_sigma])
    for _ in range(40):
        residual = whitened(parameters)
        jacobian = np.empty((residual.size, parameters.size))
        for j in range(parameters.size):
            probe = parameters.copy()
            probe[j] += 1e-4
            jacobian[:, j] = (whitened(probe) - residual) / 1e-4
        step, *_ = np.linalg.lstsq(jacobian, -residual, rcond=None)
        step = np.clip(step, -limits, limits)
        parameters = parameters + step
        if abs(step[0]) < 1e-5 and (held or abs(step[1]) < 1e-6):
            break
    parameters = full(parameters)
    shift, factor = float(parameters[0]), float(parameters[1])
    if not (-SEARCH_SHIFT_NM < shift < SEARCH_SHIFT_NM):
        return f"{window.label}: no line within ±{SEARCH_SHIFT_NM:g} nm"
    if not held and not (low < factor < high):
        return (
            f"{window.label}: its width is not the slit's ({factor:.2f} × the stated "
            f"{window.bandwidth_nm:g} nm)"
        )
    displaced = moved(parameters[2:])
    residual, coefficients = window.residual(shift, factor, displaced)
    noise = math.sqrt(float(residual @ residual) / dof)
    # The whitened Jacobian of everything (shift, factor, displacements, linear coefficients) at
    # the solution, the displacements' priors as rows of their own.
    design = window.design(shift, factor, displaced)
    model = design @ coefficients
    columns = []
    for j in range(parameters.size):
        if held and j == 1:
            continue
        probe = parameters.copy()
        probe[j] += 1e-4
        changed = window.design(probe[0], probe[1], moved(probe[2:])) @ coefficients
        columns.append((changed - model) / 1e-4)
    data_rows = np.concatenate([np.stack(columns, axis=1), design], axis=1) / noise
    prior_rows = np.zeros((len(phosphor), data_rows.shape[1]))
    for row, sigma_u in enumerate(prior_sigma):
        prior_rows[row, free + row] = 1.0 / sigma_u
    jacobian = np.concatenate([data_rows, prior_rows], axis=0)
    covariance = np.linalg.pinv(jacobian.T @ jacobian)
    sigma = math.sqrt(max(float(covariance[0, 0]), 0.0))
    first = parameters.size - (1 if held else 0)
    amplitudes = [first + i for i, is_ref in enumerate(window.reference) if is_ref]
    amplitude = float(sum(coefficients[i - first] for i in amplitudes))
    amplitude_sigma = math.sqrt(
        max(float(sum(covariance[i, j] for i in amplitudes for j in amplitudes)), 1e-300)
    )
    snr = amplitude / amplitude_sigma
    if not snr >= MIN_LINE_SNR:
        return f"{window.label}: no mercury line above the noise ({snr:.1f} σ)"
    if not sigma <= MAX_LINE_SIGMA_NM:
        return f"{window.label}: blended at this slit, its shift is known to ±{sigma:.2f} nm only"
    factor_sigma = (
        None if held or not window.isolated else math.sqrt(max(float(covariance[1, 1]), 0.0))
    )
    return LineShift(window.label, window.wavelength_nm, shift, sigma, snr, factor, factor_sigma)


def slope_prior_sigma(tolerance_nm: float = WAVELENGTH_SCALE_NM) -> float:
    """σ of the scale error's slope (nm/nm) of an in-spec instrument: its ends each within
    ±tolerance (σ tolerance/√3), independent, over :data:`SCALE_MODEL_RANGE_NM`."""
    low, high = SCALE_MODEL_RANGE_NM
    return math.sqrt(2.0) * tolerance_nm * IN_SPEC_TOLERANCE_SIGMA / (high - low)


def check_spectrometer_scale(
    spectrum: Spectrum,
    bandwidth_nm: float,
    *,
    lamp: str = "",
    range_nm: tuple[float, float] = (400.0, 700.0),
    tolerance_nm: float = WAVELENGTH_SCALE_NM,
) -> ScaleCheck | str:
    """The spectrometer's wavelength-scale error from the Hg lines of ``spectrum`` (module
    docstring), or the reason the lines cannot decide it (a one-line string).

    Parameters
    ----------
    spectrum
        A lamp's spectrum as the spectrometer reported it.
    bandwidth_nm
        The spectrometer's stated slit FWHM.
    lamp
        The lamp's name (for the record).
    range_nm
        The working range the stated σ is the RMS over.
    tolerance_nm
        The instrument's stated wavelength tolerance (:attr:`ScaleCheck.out_of_spec`).
    """
    if not (math.isfinite(bandwidth_nm) and bandwidth_nm > 0):
        return "no stated bandwidth"
    wavelength = np.asarray(spectrum.wavelength_nm, dtype=np.float64)
    step = float(np.median(np.diff(wavelength))) if wavelength.size > 1 else math.inf
    windows, left_out = _windows(spectrum, bandwidth_nm)
    # Windows sampled too coarsely for the full background (a PR-655's 4 nm steps through an 8 nm
    # slit) that model neighbours are fitted after the isolated ones, with the slit held at the
    # width the isolated lines measured: with few samples a free width trades with a blended
    # neighbour's amplitude and moves the centre (decision 0072). One instrument, one slit.
    coarse = [w for w in windows if w.degree < BACKGROUND_DEGREE and not w.isolated]
    lines: list[LineShift] = []
    slits: list[float] = []
    for window in windows:
        if any(window is other for other in coarse):
            continue
        outcome = _fit_window(window, step)
        if isinstance(outcome, str):
            left_out.append(outcome)
            continue
        lines.append(outcome)
        if window.isolated:
            slits.append(outcome.slit_factor)
    for window in coarse:
        if not slits:
            left_out.append(
                f"{window.label}: too few samples to fit the slit beside its neighbours, and no "
                "resolved line measured it"
            )
            continue
        outcome = _fit_window(window, step, held_factor=float(np.median(slits)))
        if isinstance(outcome, str):
            left_out.append(outcome)
        else:
            lines.append(outcome)
    lines.sort(key=lambda line: line.wavelength_nm)
    if len(lines) < MIN_FEATURES:
        measured = f" (only {lines[0].label})" if lines else ""
        return f"fewer than {MIN_FEATURES} mercury features measured{measured}: " + "; ".join(
            left_out
        )
    x = np.array([line.wavelength_nm - REFERENCE_NM for line in lines])
    d = np.array([line.shift_nm for line in lines])
    weight = 1.0 / np.array([line.sigma_nm for line in lines]) ** 2
    prior = 1.0 / slope_prior_sigma(tolerance_nm) ** 2
    span = float(np.ptp(x))
    if span >= MIN_SLOPE_SPAN_NM:
        normal = np.array(
            [
                [weight.sum(), (weight * x).sum()],
                [(weight * x).sum(), (weight * x * x).sum() + prior],
            ]
        )
        covariance = np.linalg.inv(normal)
        offset, slope = covariance @ np.array([(weight * d).sum(), (weight * x * d).sum()])
    else:
        # Too short a lever for a slope: an offset at the lines' weighted centre, the slope its
        # prior (zero, σ_b) — the σ grows away from the lines.
        centre = float(np.sum(weight * x) / weight.sum())
        at_centre = float(np.sum(weight * d) / weight.sum())
        slope = 0.0
        offset = at_centre - slope * centre
        variance_b = 1.0 / prior
        covariance = np.array(
            [
                [1.0 / weight.sum() + centre**2 * variance_b, -centre * variance_b],
                [-centre * variance_b, variance_b],
            ]
        )
    chi2: float | None = None
    if len(lines) >= 2:
        # The windows' agreement, the slope's prior counted as one more observation (zero slope).
        residual = d - offset - slope * x
        chi2 = float((np.sum(weight * residual**2) + prior * slope**2) / (len(lines) - 1))
        if chi2 > MAX_CONSISTENCY_CHI2:
            return (
                "the mercury lines disagree on the scale (reduced χ² "
                f"{chi2:.3g}): not mercury's lines as listed, or a poor fit"
            )
        covariance = covariance * max(1.0, chi2)
    check = ScaleCheck(
        lamp=lamp or spectrum.name,
        bandwidth_nm=bandwidth_nm,
        offset_nm=float(offset),
        slope=float(slope),
        covariance=covariance,
        sigma_nm=0.0,
        range_nm=(float(range_nm[0]), float(range_nm[1])),
        lines=tuple(lines),
        left_out=tuple(left_out),
        reduced_chi2=chi2,
        tolerance_nm=tolerance_nm,
    )
    axis = check._range_axis()
    sigma = float(np.sqrt(np.mean(check.sigma_at(axis) ** 2)))
    if sigma >= tolerance_nm * IN_SPEC_TOLERANCE_SIGMA:
        return (
            f"the lines determine the scale to ±{sigma:.2f} nm only, no better than its tolerance "
            f"(σ {tolerance_nm * IN_SPEC_TOLERANCE_SIGMA:.2f} nm)"
        )
    return replace(check, sigma_nm=sigma)


def corrected_spectrum(spectrum: Spectrum, check: ScaleCheck) -> Spectrum:
    """``spectrum`` with each value put at the wavelength it was measured at, ``λ + δ(λ)``."""
    axis = np.asarray(spectrum.wavelength_nm, dtype=np.float64)
    return Spectrum(axis + check.correction_nm(axis), spectrum.values, name=spectrum.name)


#: Lamp kinds whose spectrum may show mercury lines.
MERCURY_LAMP_KINDS = ("fluorescent",)


def measured_spectrum(observation: LampObservation) -> bool:
    """Whether the lamp's spectrum was measured by a spectrometer: it states a bandwidth, it is not
    a built-in line list, and nobody said it stands in for one not measured."""
    return (
        observation.spectrum_bandwidth_nm is not None
        and not is_builtin(observation.spectrum.name or "")
        and observation.metadata.get("spectrum_known") is not False
    )


def same_instrument(observation: LampObservation, checked: LampObservation) -> bool:
    """Whether ``observation``'s spectrum was measured by the instrument that measured ``checked``'s
    (module docstring): both measured, the same stated bandwidth, and no different
    ``metadata["spectrometer"]``."""
    if not (measured_spectrum(observation) and measured_spectrum(checked)):
        return False
    assert observation.spectrum_bandwidth_nm is not None
    assert checked.spectrum_bandwidth_nm is not None
    if not math.isclose(
        observation.spectrum_bandwidth_nm, checked.spectrum_bandwidth_nm, rel_tol=1e-9
    ):
        return False
    mine, theirs = observation.metadata.get("spectrometer"), checked.metadata.get("spectrometer")
    return mine is None or theirs is None or mine == theirs


@dataclass(frozen=True)
class ScaleCheckOutcome:
    """What :func:`checked_observations` did: the check (``None``: none made), the lamps corrected,
    and notes (why not, which lamps kept the tolerance)."""

    check: ScaleCheck | None
    corrected: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "check": None if self.check is None else self.check.to_dict(),
            "corrected": list(self.corrected),
            "notes": list(self.notes),
        }


def checked_observations(
    observations: Sequence[Any], *, range_nm: tuple[float, float] = (400.0, 700.0)
) -> tuple[list[Any], ScaleCheckOutcome]:
    """``observations`` with the lamp spectra of the checked instrument corrected (module
    docstring: the scale, and the bandwidth where the measured slit contradicts the stated one),
    and what was done. Lamps already checked are left as they are."""
    items = list(observations)
    lamps = [item for item in items if isinstance(item, LampObservation)]
    if any(SCALE_CHECK_KEY in lamp.metadata for lamp in lamps):
        return items, ScaleCheckOutcome(None, notes=("the lamp spectra were checked already",))
    candidates = [
        lamp for lamp in lamps if lamp.kind in MERCURY_LAMP_KINDS and measured_spectrum(lamp)
    ]
    if not candidates:
        return items, ScaleCheckOutcome(None)
    reasons: list[str] = []
    for lamp in candidates:
        assert lamp.spectrum_bandwidth_nm is not None
        outcome = check_spectrometer_scale(
            lamp.spectrum, lamp.spectrum_bandwidth_nm, lamp=lamp.name, range_nm=range_nm
        )
        if isinstance(outcome, str):
            reasons.append(f"{lamp.name}: {outcome}")
            continue
        record = outcome.to_dict()
        slit = outcome.slit_factor
        if slit is not None and abs(slit[0] - 1.0) <= SLIT_CORRECTION_SIGMAS * slit[1]:
            slit = None  # the stated slit agrees with the measured one: it stays
        corrected: list[str] = []
        kept: list[str] = []
        out: list[Any] = []
        for item in items:
            if isinstance(item, LampObservation) and same_instrument(item, lamp):
                metadata = {
                    **item.metadata,
                    SCALE_CHECK_KEY: record,
                    SCALE_SIGMA_KEY: outcome.sigma_nm,
                }
                bandwidth = item.spectrum_bandwidth_nm
                if slit is not None and bandwidth is not None:
                    metadata[SLIT_CORRECTION_KEY] = bandwidth
                    bandwidth = bandwidth * slit[0]
                out.append(
                    replace(
                        item,
                        spectrum=corrected_spectrum(item.spectrum, outcome),
                        spectrum_bandwidth_nm=bandwidth,
                        metadata=metadata,
                    )
                )
                corrected.append(item.name)
            else:
                if isinstance(item, LampObservation) and measured_spectrum(item):
                    kept.append(item.name)
                out.append(item)
        notes = [outcome.note()]
        if slit is not None and lamp.spectrum_bandwidth_nm is not None:
            notes.append(
                f"spectrometer slit measured ×{slit[0]:.3f} ± {slit[1]:.3f} of the stated "
                f"{lamp.spectrum_bandwidth_nm:g} nm (the Hg lines' widths): the spectra are taken "
                f"at {lamp.spectrum_bandwidth_nm * slit[0]:.3g} nm"
            )
        if kept:
            notes.append(
                f"{', '.join(kept)}: measured by another instrument (another stated bandwidth): "
                "not corrected, the scale tolerance stays"
            )
        return out, ScaleCheckOutcome(outcome, tuple(corrected), tuple(notes + reasons))
    return items, ScaleCheckOutcome(
        None,
        notes=tuple(
            "spectrometer scale not checked (" + why + "): the tolerance stays" for why in reasons
        ),
    )


def measured_slit(observation: LampObservation) -> tuple[float, float] | None:
    """The slit factor (true FWHM / stated) and its σ that the Hg-line check of this lamp's
    instrument measured (:attr:`ScaleCheck.slit_factor`), ``None`` when its spectrum was not checked
    or no isolated line measured the slit. Of a lamp whose bandwidth :func:`checked_observations`
    corrected to the measured slit: ``1`` and the factor's σ relative to the corrected bandwidth."""
    record = observation.metadata.get(SCALE_CHECK_KEY)
    if not isinstance(record, Mapping):
        return None
    factor, sigma = record.get("slit_factor"), record.get("slit_factor_sigma")
    if not isinstance(factor, int | float) or not isinstance(sigma, int | float):
        return None
    if not (math.isfinite(factor) and factor > 0 and math.isfinite(sigma) and sigma >= 0):
        return None
    if SLIT_CORRECTION_KEY in observation.metadata:
        # The bandwidth was corrected to the measured slit: what is left of the slit's error is
        # the measurement's own σ, relative to the corrected bandwidth.
        return 1.0, float(sigma) / float(factor)
    return float(factor), float(sigma)


def scale_sigma_nm(observation: LampObservation) -> float | None:
    """The one-σ scale error (nm) of a checked lamp's spectrum, ``None`` when it was not checked."""
    value = observation.metadata.get(SCALE_SIGMA_KEY)
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else None
