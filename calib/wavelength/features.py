"""The mapping from spectral features: emission lines and absorption dips found in a profile, matched to
a line list, each fitted where it lies, and the mapping fitted through them.

1. **Signal.** Emission: the channels summed, less a baseline that follows everything broader than a
   line (a grey opening). Absorption: the channels summed and divided by their upper envelope (a grey
   closing, smoothed) — the continuum-normalised depth, in which a Fraunhofer line is a dip whatever
   the camera and the source's colour.
2. **Peaks** of that signal above 5 noise σ (noise from the second differences).
3. **Match** the strongest peaks to the list's features at the camera's resolution (:func:`blends`
   of :mod:`calib.core.line_lists`): every pair of peaks against every pair of features proposes a
   line, scored by how much of the peaks' strength it explains (:func:`match_lines`; spurious or
   missing peaks only lower a hypothesis' score), unless a start mapping is given.
4. **Fit every feature where it lies**: the signal in a window around the predicted pixel is a
   linear background plus one Gaussian per component line, the components placed at their
   wavelengths through the current mapping, with a shared width, free heights and one free shift
   per feature — so a blend the camera half-resolves (Tb 542.4 + Hg 546.1, Na D1 + D2, the Mg b
   triplet) is modelled as what it is, not as one line at a wrong centre. Features whose windows
   overlap are fitted together.
5. **Fit the mapping** (its family: the grating equation or the quadratic) through the features'
   pixels (an absorption blend's first moment, at the list's centre: :func:`_point`) by weighted
   least squares — each weighted by its position's σ (through the local
   dispersion) and its wavelength's uncertainty — rejecting outliers beyond 4σ, and repeat 4–5 with
   the new mapping.

The result carries the matched-line table (:meth:`FeatureMatch.row`): line, wavelength, pixel, the
mapping's wavelength there and the residual, for the report.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import EstimationError, InputError
from calib.core.line_lists import Blend, Line, LineKind, blends
from calib.core.mapping import QuadraticMapping, TiltedGrating
from calib.wavelength.families import GratingFamily, QuadraticFamily
from calib.wavelength.least_squares import CONVERGED_DELTA_CHI2, Evaluation, levenberg_marquardt

Family = QuadraticFamily | GratingFamily
ExactMapping = QuadraticMapping | TiltedGrating

#: A channel "sees" an absorption feature where its envelope is at least this fraction of the
#: brightest channel's there (:func:`feature_signal`).
SEEN_FRACTION = 0.15
#: Peaks must stand this many noise σ above their surroundings.
PEAK_SIGMA = 5.0
#: A peak broader than this many line widths (at half its prominence) is not a line.
MAX_PEAK_WIDTH = 4.0
#: Peaks and features whose triples are matched (every triple against every triple).
MATCH_TRIPLE_PEAKS = 10
MATCH_TRIPLE_FEATURES = 12
#: Strongest peaks and features considered when matching without a start.
MATCH_PEAKS = 14
#: A feature's fit window reaches this many FWHM beyond its outermost components …
WINDOW_FWHM = 2.0
#: … and at least this many profile samples: a line under 2.5 samples wide (a 3 px slit image in
#: the 2 px cells of a mosaic's profile) leaves ±2 FWHM too few samples for a quadratic
#: background with the line's height, shift and width, and the feature was dropped (decision 0192).
WINDOW_MIN_SAMPLES = 5.0
#: Position error (nm) the mapping fit adds to every feature (the line model's own approximation).
MODEL_ERROR_NM = 0.01
#: A feature this much weaker than a close neighbour is not fitted (:func:`_measurable`).
WEAK_NEIGHBOUR = 0.15
#: At most this many features are fitted together (a longer chain is cut).
MAX_GROUP = 4
#: Normalised residual beyond which a feature is an outlier.
OUTLIER_SIGMA = 4.0
#: Line-match hypotheses carried through the feature fits.
HYPOTHESES = 6
#: Absorption-line hypotheses: the solar list's dips are many and near-regular, so matches that
#: pair them one dip over are many and close in score; more are carried through the fits (decision
#: 0112: on the spectrograph analog, 6 held no right match for 3 of 88 scenes).
ABSORPTION_HYPOTHESES = 20
#: A dip counts in its match's support by how near the mapping passes it: a Gaussian of the residual
#: with this fraction of the resolution (FWHM) as its σ. A dip fitted where the right mapping puts
#: it is placed to a small fraction of the line spread; a neighbouring dip paired instead leaves
#: the family bent by a good part of one, which a count of the dips kept does not see (decision
#: 0112: iPhone 11 on the spectrograph analog, 8 dips at 0.49 nm RMS kept over the right 10 at 0.21).
DIP_CLOSENESS_FWHM = 0.25
#: A fresh absorption match's runner-up at least this far from it (nm, anywhere on the profile)
#: with a support within :data:`RIVAL_SUPPORT` of its own is a rival the dips do not decide against.
RIVAL_APART_NM = 1.0
RIVAL_SUPPORT = 1.0
#: Refinement rounds (fit features → fit mapping).
ROUNDS = 3
#: Iteration cap of the mapping fit through the features: high enough that the fit converges by
#: its tolerance (the grating family's spacing, focal length and incidence trade off along a flat
#: valley; on the Canon 10D's sunlight the result moves until ~400 iterations and is the same from
#: there to 5000 — 50 and 200 stopped on the way, with 0.43 and 0.41 nm RMS that were the cap's).
#: Its steps bend along the valley (``geodesic``): the same answers in a fraction of the steps.
FIT_ITERATIONS = 1000
#: The mapping fit stops when a step lowers its χ² by less than this fraction (a χ² change of
#: ~1e-8: nothing a σ or a residual shows; 1e-12 let the flattest valleys crawl to the cap with
#: the same printed answers).
FIT_TOLERANCE = 1e-9
#: The mapping fit stops when a step moves no feature by more than this fraction of its σ.
STEP_TOLERANCE = 1e-4
#: Iteration cap of the fit that starts a hypothesis (:func:`_initial_parameters`): only a start
#: (the fits through the features run to convergence from it); a hypothesis the family cannot
#: follow ran this fit to :data:`FIT_ITERATIONS`.
START_ITERATIONS = 100
#: Refits that settle the shared model scatter (:func:`_fit_with_model_scatter`).
SCATTER_ROUNDS = 4
#: σ floor (nm) of a :class:`ProfileAnchor`'s wavelengths: numerical only (a line's own σ is
#: ≥ :data:`MODEL_ERROR_NM`).
ANCHOR_FLOOR_NM = 1e-3
#: A listed line a measured spectrum shows at less than this fraction of the height the list's
#: strengths predict is taken as absent (:func:`lines_shown`): a list's strengths are a typical
#: lamp's, not this one's (:func:`_support`), so a line well below its listed share is still
#: shown; one the lamp lacks fits near zero.
SHOWN_FRACTION = 0.25
#: ... and its blend at the spectrum's resolution stands this many of its σ (from the fit's
#: residual: noise and the background's misfit) above zero: a line the spectrum cannot tell from
#: its band is not shown (the twin's 8 nm PR-655
#: spectra put the absent Hg 491.6 at −0.3 to +0.5 of its listed share, one repeat in 22 above
#: :data:`SHOWN_FRACTION`).
SHOWN_SIGMA = 3.0
#: Half width (in the spectrum's resolutions) of the window each line's height is fitted in.
SHOWN_WINDOW = 2.5
#: Lines a line fit anchored to a whole-profile fit needs (:class:`ProfileAnchor`): two fix the
#: offset and the scale the broadband fit is least sure of; one would only shift it.
MIN_ANCHORED_FEATURES = 2
#: A line match made afresh (no start) is physically implausible when it puts a parameter of the
#: grating further than this many σ from the family's prior (the rig's: EXIF focal length over
#: the pitch, the 0th order at the spot, an incidence near square; :mod:`calib.wavelength.
#: rig_prior`): a Gaussian prior gives a 4σ deviation odds of 6·10⁻⁵, so the lines were matched to
#: the wrong features (an Hg 404.7 too dim to show, and 435.8 taken for it) rather than the rig
#: being that far from what it reports.
PLAUSIBLE_PRIOR_SIGMAS = 4.0
#: ... or when it puts the bluest lit sample of the profile (:func:`lit_extent`) below this
#: wavelength (nm): cameras' UV-cut filters (50 % at 390–410 nm) and glass optics leave less than
#: a twentieth of a camera's peak response below ~380 nm, and a lamp's light there is the lit
#: part's threshold (5 % of the peak) only through them.
LIT_BLUE_LIMIT_NM = 380.0


@dataclass(frozen=True)
class FeatureMatch:
    """One list feature fitted in the profile.

    Attributes
    ----------
    blend
        The feature's component lines; ``reference`` is the strongest, whose pixel is reported.
    pixel, pixel_sigma
        Where the reference line lies, and its σ (profile coordinates).
    fitted_nm
        The mapping's wavelength at ``pixel``.
    sigma_nm
        The feature's total σ in the mapping fit (position through the dispersion, the line's own
        uncertainty, the model error).
    used
        Kept by the mapping fit (not an outlier).
    centre_nm
        The wavelength of the feature's first moment, when the mapping was fitted through that
        (``pixel`` is then the moment's); ``None``: ``pixel`` is the reference line's.
    """

    blend: Blend
    pixel: float
    pixel_sigma: float
    fitted_nm: float
    sigma_nm: float
    used: bool = True
    amplitude: float = 0.0
    centre_nm: float | None = None

    @property
    def reference(self) -> Line:
        return self.blend.reference

    @property
    def wavelength_nm(self) -> float:
        """The wavelength the mapping was fitted to at :attr:`pixel`."""
        return self.reference.wavelength_nm if self.centre_nm is None else self.centre_nm

    @property
    def residual_nm(self) -> float:
        return self.fitted_nm - self.wavelength_nm

    def row(self) -> dict[str, Any]:
        """The matched-line table's row: ``{line, wavelength_nm, pixel, fitted_nm, residual_nm,
        weight}`` (``weight`` is ``1/σ²`` in nm⁻², 0 for a rejected feature; ``wavelength_nm`` is
        the reference line's, or a blend's centre when the feature was fitted at its moment)."""
        return {
            "line": self.blend.label,
            "wavelength_nm": self.wavelength_nm,
            "pixel": self.pixel,
            "fitted_nm": self.fitted_nm,
            "residual_nm": self.residual_nm,
            "weight": 1.0 / self.sigma_nm**2 if self.used else 0.0,
        }


@dataclass(frozen=True)
class FeatureMapping:
    """The mapping through a profile's features.

    Attributes
    ----------
    mapping
        Report form (:class:`calib.core.mapping.QuadraticMapping` over the profile) with the fit's
        covariance and ``wavelength_rms_nm``.
    exact
        The mapping in its family.
    matches
        Every feature fitted, by wavelength.
    details
        How it was found (JSON-safe).
    rival
        A fresh absorption match's runner-up as well supported and elsewhere (or ``None``).
    """

    mapping: QuadraticMapping
    exact: ExactMapping
    matches: tuple[FeatureMatch, ...]
    details: dict[str, Any] = field(default_factory=dict)
    #: A fresh absorption match's runner-up the dips do not decide against (:data:`RIVAL_SUPPORT`).
    rival: FeatureMapping | None = None

    def table(self) -> list[dict[str, Any]]:
        """The matched-line table (see :meth:`FeatureMatch.row`)."""
        return [match.row() for match in self.matches]


@dataclass(frozen=True)
class ProfileAnchor:
    """A whole-profile fit as a Gaussian constraint on a line fit: its wavelengths at the ends and
    middle of the profile with their covariance (the quadratic report's, a Laplace approximation
    of the fit's likelihood). With it, the lines a lamp does show correct the broadband fit where
    they lie and the fit holds the mapping's other degrees of freedom — one mapping fitting both —
    where too few lines would not hold the family on their own (:func:`map_features`).

    Attributes
    ----------
    pixels, wavelength_nm
        ``(3,)``: where the constraint is placed and the fit's wavelengths there.
    covariance_nm2
        ``(3, 3)``: their covariance.
    """

    pixels: FloatArray
    wavelength_nm: FloatArray
    covariance_nm2: FloatArray

    @classmethod
    def from_mapping(
        cls,
        mapping: QuadraticMapping,
        pixel_range: tuple[float, float],
        centre: ExactMapping | None = None,
    ) -> ProfileAnchor:
        """The anchor of a whole-profile fit's report form (it must carry its covariance);
        ``centre``: another basin of the same fit, placed with that covariance."""
        if mapping.covariance is None:
            raise EstimationError(
                "the whole-profile fit carries no covariance to anchor lines with"
            )
        pixels = np.array([pixel_range[0], 0.5 * (pixel_range[0] + pixel_range[1]), pixel_range[1]])
        design = np.stack([pixels**2, pixels, np.ones(3)], axis=1)
        covariance = design @ np.asarray(mapping.covariance, dtype=np.float64) @ design.T
        # A floor far below any line's σ keeps the whitening finite for a fit stated exact.
        covariance = 0.5 * (covariance + covariance.T) + np.eye(3) * ANCHOR_FLOOR_NM**2
        at = (mapping if centre is None else centre).wavelength_nm(pixels)
        return cls(pixels, np.asarray(at, dtype=np.float64), covariance)

    @property
    def rows(self) -> int:
        return int(self.pixels.size)

    @functools.cached_property
    def whitening(self) -> FloatArray:
        """``W`` with ``Wᵀ W = covariance⁻¹`` (rows ``W (λ − λ_fit)`` are unit normal); once per
        anchor, not per iteration of the fits that use it."""
        return np.asarray(np.linalg.inv(np.linalg.cholesky(self.covariance_nm2)), dtype=np.float64)

    def residual(
        self, family: Family, x: FloatArray, with_jacobian: bool
    ) -> tuple[FloatArray, FloatArray | None] | None:
        """The whitened rows at ``x`` and their Jacobian ``(3, P)`` (``None``: ``x`` invalid)."""
        if isinstance(family, GratingFamily):
            evaluated = family.evaluate(self.pixels, x, with_jacobian=with_jacobian)
            if evaluated is None:
                return None
            wavelengths, jacobian = evaluated
        else:
            wavelengths = family.wavelengths(self.pixels, x)
            jacobian = family.jacobian(self.pixels, x) if with_jacobian else None
        whitening = self.whitening
        rows = whitening @ (wavelengths - self.wavelength_nm)
        return rows, None if jacobian is None else whitening @ jacobian


# --------------------------------------------------------------------------------- the signal


def feature_signal(
    profile: FloatArray, kind: LineKind, width_px: float
) -> tuple[FloatArray, float]:
    """The signal in which features are peaks ``(n,)``, and its noise σ (same units).

    Emission: the summed channels less a grey opening ``6·width_px`` wide (what rises above
    everything broader than a line). Absorption: each channel's upper envelope less the channel,
    summed, so a dip counts by its depth times the light around it (where the camera barely sees,
    a relative dip is noise); an envelope is smoothed iteratively over ``3·width_px`` keeping the
    larger of it and the channel, which bridges dips narrower than that and follows the camera's
    broad shape.
    """
    from scipy import ndimage

    channels = np.asarray(profile, dtype=np.float64)
    total = np.sum(channels, axis=1)
    second = np.diff(total, n=2)
    noise = 1.4826 * float(np.median(np.abs(second - np.median(second)))) / math.sqrt(6.0)
    noise = max(noise, 1e-12 * float(np.max(np.abs(total))))
    if kind == "emission":
        size = max(3, int(6 * width_px) | 1)
        signal = total - ndimage.grey_opening(total, size=size, mode="nearest")
    else:
        # Each channel under its own envelope: where two channels cross, their sum dips although
        # neither does — a camera's shape, not the light's.
        envelope = channels.copy()
        for _ in range(8):
            envelope = ndimage.gaussian_filter1d(
                np.maximum(envelope, channels), 3.0 * max(width_px, 1.0), axis=0, mode="nearest"
            )
        # A dip in the light has the same relative depth in every channel that sees it; a dip in
        # one channel's sensitivity has none in the others. The smallest relative depth among the
        # channels with a fair share of the light keeps the first and drops the second.
        relative = (envelope - channels) / np.maximum(envelope, 1e-300)
        seen = envelope >= SEEN_FRACTION * np.max(envelope, axis=1, keepdims=True)
        depth = np.min(np.where(seen, relative, np.inf), axis=1)
        signal = np.where(np.isfinite(depth), depth, 0.0) * np.sum(envelope, axis=1)
    return np.asarray(signal, dtype=np.float64), noise


def signal_peaks(
    pixel: FloatArray, signal: FloatArray, noise: float, width_px: float
) -> list[tuple[float, float]]:
    """``(pixel, prominence)`` of the signal's peaks above :data:`PEAK_SIGMA` noise, strongest first."""
    from scipy import ndimage
    from scipy import signal as sp_signal

    smooth = ndimage.gaussian_filter1d(signal, max(width_px / 4.0, 0.5), mode="nearest")
    indices, properties = sp_signal.find_peaks(
        smooth, prominence=PEAK_SIGMA * noise, distance=max(1, int(width_px / 2))
    )
    order = np.argsort(properties["prominences"])[::-1]
    out = []
    for k in order:
        i = int(indices[k])
        if 0 < i < signal.size - 1:
            # Parabola through the three samples around the maximum.
            left, centre, right = smooth[i - 1], smooth[i], smooth[i + 1]
            curvature = left - 2 * centre + right
            offset = 0.5 * (left - right) / curvature if curvature < 0 else 0.0
            position = float(np.interp(i + np.clip(offset, -1, 1), np.arange(pixel.size), pixel))
        else:
            position = float(pixel[i])
        out.append((position, float(properties["prominences"][k])))
    return out


# ------------------------------------------------------------------------------- feature fits


@dataclass
class _Fitted:
    """A fitted feature: where its reference line lies (``pixel`` ± ``sigma``) and where its light's
    first moment lies (``centroid_px`` ± ``centroid_sigma``: the heights-weighted mean of the fitted
    components — well determined even when the components' split is not)."""

    blend: Blend
    pixel: float
    sigma: float
    amplitude: float
    centroid_px: float = math.nan
    centroid_sigma: float = math.nan


def _absorption_width_px(group: Sequence[Blend], mapping: ExactMapping, fwhm_px: float) -> float:
    """The width a group of features shows: the camera's line spread ``fwhm_px``, widened in
    quadrature by the broadest absorption feature's own width (the list's ``width_nm`` through the
    mapping's dispersion there). A band such as O₂ B (1.8 nm) or the G band (0.6 nm) is several
    times a spectrograph's line spread at 0.2–0.3 nm per pixel (decision 0086): fitted with the
    camera's width alone (×0.5–2 allowed) it was dropped or placed by its sharpest part.
    Emission lines keep the camera's width."""
    widths = [
        line.width_nm
        for blend in group
        for line in blend.lines
        if line.kind == "absorption" and line.width_nm > 0
    ]
    if not widths:
        return fwhm_px
    reference = np.array([group[0].reference.wavelength_nm])
    try:
        at = _pixel_of(mapping, reference)
    except InputError:
        return fwhm_px
    own_px = max(widths) / max(float(_slope(mapping, at)[0]), 1e-12)
    if own_px <= math.sqrt(3.0) * fwhm_px:
        # The fit's shared width (×0.5–2 of the camera's) already reaches hypot(f, √3 f) = 2 f.
        return fwhm_px
    return float(math.hypot(fwhm_px, own_px))


def _fit_group(
    pixel: FloatArray,
    signal: FloatArray,
    noise: float,
    group: Sequence[Blend],
    mapping: ExactMapping,
    fwhm_px: float,
    spacing_px: float,
    *,
    background_order: int = 1,
    restart: bool = False,
) -> list[_Fitted]:
    """Fit overlapping features together (see the module docstring, step 4); ``spacing_px``, the
    profile's sample spacing, sets the window's least reach (:func:`_window_px`).

    Background (a polynomial of ``background_order``), one height per component, one shift per
    feature and a shared width, fitted jointly by Levenberg–Marquardt with the closed-form
    Jacobian, from heights solved linearly at the predicted places; a shift beyond one FWHM of the
    prediction or a width outside ×0.5–2 of the camera's is outside the valid region. Each
    feature's first moment comes with it: the heights-weighted mean of its components (those
    fitted below zero are absent lines) — as exact as the fit for a blend's light (within 0.05 nm
    for a 1 : 2.5 Hg 577/579 doublet at 2–6 px of slit, where its 579.07 line's shift is not).

    With ``restart`` (a measured lamp's few Hg lines placed from its whole-profile fit), a group
    whose fit found no feature is fitted again from half a FWHM to either side (decision 0093).
    """

    fwhm_px = _absorption_width_px(group, mapping, fwhm_px)
    sigma_px = fwhm_px / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    placed = []
    for blend in group:
        at = _pixel_of(mapping, np.array([line.wavelength_nm for line in blend.lines]))
        ref_px = float(_pixel_of(mapping, np.array([blend.reference.wavelength_nm]))[0])
        placed.append((blend, ref_px, at - ref_px))
    reach = _window_px(spacing_px, fwhm_px)
    lo = min(r + float(o.min()) for _, r, o in placed) - reach
    hi = max(r + float(o.max()) for _, r, o in placed) + reach
    inside = (pixel >= lo) & (pixel <= hi)
    n_blends = len(placed)
    n_lines = sum(offsets.size for _, _, offsets in placed)
    if np.count_nonzero(inside) < n_lines + n_blends + 3 + background_order:
        return []
    x = pixel[inside]
    y = signal[inside]
    centre = 0.5 * (lo + hi)
    owner = np.concatenate([np.full(o.size, b) for b, (_, _, o) in enumerate(placed)])
    ownership = (owner[:, None] == np.arange(n_blends)[None, :]).astype(np.float64)  # (lines, F)
    positions = np.concatenate([ref + offsets for _, ref, offsets in placed])

    def gaussians(shifts: FloatArray, width: float) -> tuple[FloatArray, FloatArray]:
        offset = x[:, None] - (positions + shifts[owner])[None, :]
        values = np.exp(-0.5 * (offset / width) ** 2)
        return values, offset

    base = np.stack([((x - centre) / fwhm_px) ** k for k in range(background_order + 1)], axis=1)
    n_base = base.shape[1]
    # Heights and background for the predicted places: the start of the joint fit.
    start_values, _ = gaussians(np.zeros(n_blends), sigma_px)
    linear, *_ = np.linalg.lstsq(np.hstack([base, start_values]), y, rcond=None)
    n_shape = n_blends + 1

    def function(params: FloatArray, with_jacobian: bool) -> Evaluation:
        shifts, width = params[:n_blends], params[n_blends]
        if (np.abs(shifts) > fwhm_px).any() or not (0.5 * sigma_px <= width <= 2.0 * sigma_px):
            return None
        values, offset = gaussians(shifts, width)
        amplitudes = params[n_shape + n_base :]
        model = base @ params[n_shape : n_shape + n_base] + values @ amplitudes
        residual = (model - y) / noise
        if not with_jacobian:
            return residual, None

        def jacobian() -> FloatArray:
            # Deferred: the fit asks for it at the trials it accepts only.
            weighted = values * amplitudes[None, :]
            out = np.empty((x.size, n_shape + n_base + n_lines))
            # Each feature's shift moves its components: their derivatives summed per feature.
            out[:, :n_blends] = (weighted * offset / width**2) @ ownership
            out[:, n_blends] = (weighted * offset**2 / width**3).sum(axis=1)
            out[:, n_shape : n_shape + n_base] = base
            out[:, n_shape + n_base :] = values
            out /= noise
            return out

        return residual, jacobian

    start = np.concatenate([np.zeros(n_blends), [sigma_px], linear])
    # Stopped within a tenth of the fit's own σ: a line is not exactly a Gaussian at this noise
    # (reduced χ² 10³–10⁴ on real profiles), and a shift or width pressing on its limit would
    # otherwise crawl along it to the iteration cap (decision 0195).
    try:
        solution = levenberg_marquardt(
            function,
            start,
            max_iterations=25,
            tolerance=1e-8,
            gain_tolerance=CONVERGED_DELTA_CHI2,
            tempered=True,
            stop_at_bound=True,
        )
    except (ValueError, np.linalg.LinAlgError):
        return []
    heights = solution.x[n_shape + n_base :]
    if restart and float(np.max(heights)) < 3.0 * noise:
        # A feature the predicted place misses by more than a line width starts with
        # its Gaussian off the line: the background takes the line and the fit settles on a dip
        # (a negative height). Started half a FWHM to either side as well, the lowest cost wins.
        for offset in (-0.5 * fwhm_px, 0.5 * fwhm_px):
            shifted = np.full(n_blends, offset)
            values, _ = gaussians(shifted, sigma_px)
            moved, *_ = np.linalg.lstsq(np.hstack([base, values]), y, rcond=None)
            try:
                other = levenberg_marquardt(
                    function,
                    np.concatenate([shifted, [sigma_px], moved]),
                    max_iterations=25,
                    tolerance=1e-8,
                    gain_tolerance=CONVERGED_DELTA_CHI2,
                    tempered=True,
                    stop_at_bound=True,
                )
            except (ValueError, np.linalg.LinAlgError):
                continue
            if other.cost < solution.cost:
                solution = other
        heights = solution.x[n_shape + n_base :]
    dof = max(y.size - start.size, 1)
    variance_scale = max(solution.cost / dof, 1.0)
    try:
        covariance = np.linalg.pinv(solution.jacobian.T @ solution.jacobian) * variance_scale
    except np.linalg.LinAlgError:
        return []
    out = []
    for b, (blend, ref_px, offsets) in enumerate(placed):
        mine = heights[owner == b]
        shift = float(solution.x[b])
        shift_sigma = float(np.sqrt(max(covariance[b, b], 0.0)))
        at_bound = abs(abs(shift) - fwhm_px) < 1e-2 * fwhm_px
        # A feature must stand out: positive, its strongest component above 3 noise σ.
        if at_bound or not math.isfinite(shift_sigma) or float(np.max(mine)) < 3.0 * noise:
            continue
        total = float(np.sum(mine))
        if total <= 0:
            continue
        # The first moment of the fitted components and its σ through the joint covariance
        # (∂c/∂shift = 1, ∂c/∂h_j = (o_j − (c − ref − shift))/Σh).
        # Components fitted below zero are absent lines: no light, no weight.
        weights = np.clip(mine, 0.0, None)
        moment = float(np.dot(weights, offsets)) / float(np.sum(weights))
        gradient = np.zeros(solution.x.size)
        gradient[b] = 1.0
        gradient[n_shape + n_base + np.flatnonzero(owner == b)] = np.where(
            mine > 0, (offsets - moment) / float(np.sum(weights)), 0.0
        )
        centroid_sigma = math.sqrt(max(float(gradient @ covariance @ gradient), 0.0))
        out.append(
            _Fitted(
                blend,
                ref_px + shift,
                shift_sigma,
                total,
                ref_px + shift + moment,
                centroid_sigma,
            )
        )
    return out


#: What the lit part of a profile spans, for a first guess of the dispersion: a camera's response
#: (and most lamps' light) from the violet to the deep red.
LIT_RANGE_NM = (400.0, 680.0)


def lit_extent(pixel: FloatArray, profile: FloatArray) -> tuple[int, int]:
    """The first and last sample of the lit part of a profile (above 5 % of the summed profile's
    peak, smoothed)."""
    from scipy import ndimage

    total = ndimage.gaussian_filter1d(
        np.sum(np.clip(profile, 0.0, None), axis=1), max(pixel.size / 200.0, 1.0)
    )
    lit = np.flatnonzero(total > 0.05 * float(total.max()))
    if lit.size < 2:
        raise EstimationError("the profile has too little signal to find features in")
    return int(lit[0]), int(lit[-1])


def lit_dispersion(pixel: FloatArray, profile: FloatArray) -> float:
    """nm per profile sample if the lit part (:func:`lit_extent`) spans :data:`LIT_RANGE_NM`."""
    first, last = lit_extent(pixel, profile)
    return (LIT_RANGE_NM[1] - LIT_RANGE_NM[0]) / float(last - first)


def implausible(
    family: Family, x: FloatArray, pixel: FloatArray, lit: tuple[int, int]
) -> str | None:
    """Why a fresh line match's mapping (``family`` at ``x``) cannot be the rig's, or ``None``:
    a grating parameter beyond :data:`PLAUSIBLE_PRIOR_SIGMAS` of the family's prior, or the lit
    samples ``lit`` (:func:`lit_extent`) mapped below :data:`LIT_BLUE_LIMIT_NM`."""
    if isinstance(family, GratingFamily) and family.prior.soft():
        deviation = np.abs(family.prior_rows(x)[0])
        worst = int(np.argmax(deviation))
        if deviation[worst] > PLAUSIBLE_PRIOR_SIGMAS:
            soft = family.prior.soft()
            name = [n for n in family.names if n in soft][worst]
            value = float(np.asarray(x)[family.names.index(name)])
            shown = {
                "incidence_deg": f"incidence at {value:+.1f}° (prior {soft[name][0]:+.1f} ± "
                f"{soft[name][1]:g}°)",
                "log_focal": f"focal length at {math.exp(value):.0f} px (prior "
                f"{math.exp(soft[name][0]):.0f} px ± {100 * soft[name][1]:.0f} %)",
                "log_spacing": f"line density at {1e6 / math.exp(value):.0f} lines/mm (prior "
                f"{1e6 / math.exp(soft[name][0]):.0f} ± {100 * soft[name][1]:.0f} %)",
            }.get(name, f"{name} at {value:.4g} (prior {soft[name][0]:.4g} ± {soft[name][1]:.2g})")
            return f"it puts the grating's {shown}, {float(deviation[worst]):.0f}σ off"
    ends = family.mapping(x).wavelength_nm(np.array([pixel[lit[0]], pixel[lit[1]]]))
    bluest = float(np.min(ends))
    if not bluest >= LIT_BLUE_LIMIT_NM:
        return (
            f"it puts the profile's lit part at {bluest:.0f} nm, where cameras see nothing "
            f"(below {LIT_BLUE_LIMIT_NM:g} nm)"
        )
    return None


def match_lines(
    peaks: Sequence[tuple[float, float]],
    features: Sequence[Blend],
    *,
    dispersion_range: tuple[float, float],
    tolerance_nm: float,
    allow_reversed: bool,
    count: int,
) -> list[QuadraticMapping]:
    """Line ↔ peak hypotheses, best first.

    Every triple of the strongest peaks assigned to every triple of the strongest features (in
    order: wavelength rising with the pixel, or falling when allowed) proposes a quadratic — a
    linear guess from two far-apart lines misses a strongly curved first order by more than a
    line's width. Each admissible one (monotonic with a dispersion in range over the peaks' span)
    is scored by how much of the peaks' strength it explains (each peak within a Gaussian
    ``tolerance_nm`` of a feature, weighted by the square root of its prominence); the best are
    refitted through their inliers and scored again (:func:`_agreement`), distinct ones kept.

    All triples are scored at once (vectorised), so the strongest peaks need not be the lines the
    list calls strongest — a real lamp's ratios differ from any list's — and a spurious peak only
    fails to be explained.
    """
    import itertools

    position = np.array([p for p, _ in peaks])[:MATCH_TRIPLE_PEAKS]
    strength = np.sqrt(np.array([h for _, h in peaks]))[:MATCH_TRIPLE_PEAKS]
    strength = strength / strength.sum()
    strongest = sorted(features, key=lambda b: -b.strength)[:MATCH_TRIPLE_FEATURES]
    line_nm = np.sort(np.array([b.wavelength_nm for b in strongest]))
    all_nm = np.array([b.wavelength_nm for b in features])
    sorted_nm = np.sort(all_nm)
    peak_triples = np.array(list(itertools.combinations(np.argsort(position), 3)))
    line_triples = np.array(list(itertools.combinations(range(line_nm.size), 3)))
    if peak_triples.size == 0 or line_triples.size == 0:
        raise EstimationError("too few peaks or lines to match")
    nodes = position[peak_triples]  # (T, 3), ascending
    # Lagrange basis of each peak triple at every peak and its derivative at the span's ends.
    span = np.array([position.min(), position.max()])
    basis = _lagrange(nodes, position)  # (T, n, 3)
    slope_basis = _lagrange_slope(nodes, span)  # (T, 2, 3)
    orders = [line_triples] + ([line_triples[:, ::-1]] if allow_reversed else [])
    # Each candidate: its agreement, its curve and the points it was last fitted through.
    candidates: list[tuple[float, QuadraticMapping, _Points]] = []
    probe = np.linspace(span[0], span[1], 9)
    for assignment in orders:
        values = line_nm[assignment]  # (L, 3)
        predicted = np.einsum("tnm,lm->tln", basis, values)  # (T, L, n)
        slopes = np.einsum("tem,lm->tle", slope_basis, values)  # (T, L, 2)
        magnitude = np.abs(slopes)
        same_sign = np.sign(slopes[..., 0]) == np.sign(slopes[..., 1])
        admissible = (
            same_sign
            & np.all(magnitude >= dispersion_range[0], axis=-1)
            & np.all(magnitude <= dispersion_range[1], axis=-1)
        )
        distance = _nearest_distance(predicted, sorted_nm)  # (T, L, n)
        scores = np.where(
            admissible, (np.exp(-0.5 * (distance / tolerance_nm) ** 2) * strength).sum(-1), -1.0
        )
        best = np.argsort(-scores, axis=None)[: 20 * count]
        for flat in best:
            t, line = np.unravel_index(flat, scores.shape)
            if scores[t, line] <= 0:
                break
            try:
                start = QuadraticMapping.fit(nodes[t], values[line], degree=2)
            except EstimationError:
                continue
            refitted = _refit_through_inliers(start, position, all_nm, tolerance_nm)
            if refitted is None:
                continue
            refined, points = refitted
            candidates.append((_agreement(refined, peaks, features, tolerance_nm), refined, points))
    candidates.sort(key=lambda item: -item[0])
    out: list[QuadraticMapping] = []
    for _, mapping, (pixels, wavelengths, degree) in candidates:
        if all(
            np.max(np.abs(mapping.wavelength_nm(probe) - other.wavelength_nm(probe))) >= 3.0
            for other in out
        ):
            # The same fit with its covariance (the trial fits skipped it).
            out.append(QuadraticMapping.fit(pixels, wavelengths, degree=degree))
        if len(out) == count:
            break
    if not out:
        raise EstimationError("no line ↔ peak match is monotonic with a plausible dispersion")
    return out


def _nearest_distance(values: FloatArray, sorted_nm: FloatArray) -> FloatArray:
    """``min_j |values − sorted_nm[j]|`` elementwise, from the two neighbours in the sorted list.

    Examples
    --------
    >>> _nearest_distance(np.array([0.0, 2.4, 9.0]), np.array([1.0, 2.0, 5.0]))
    array([1. , 0.4, 4. ])
    """
    right = np.clip(np.searchsorted(sorted_nm, values), 1, sorted_nm.size - 1)
    if sorted_nm.size == 1:
        return np.asarray(np.abs(values - sorted_nm[0]), dtype=np.float64)
    return np.asarray(
        np.minimum(np.abs(values - sorted_nm[right - 1]), np.abs(values - sorted_nm[right])),
        dtype=np.float64,
    )


def _lagrange(nodes: FloatArray, at: FloatArray) -> FloatArray:
    """Quadratic Lagrange basis of node triples ``(T, 3)`` at points ``(n,)``: ``(T, n, 3)``."""
    x = at[None, :, None]
    n = nodes[:, None, :]
    out = np.ones((nodes.shape[0], at.size, 3))
    for m in range(3):
        for k in range(3):
            if k != m:
                out[..., m] *= (x[..., 0] - n[..., k]) / (n[..., m] - n[..., k])
    return out


def _lagrange_slope(nodes: FloatArray, at: FloatArray) -> FloatArray:
    """Derivative of :func:`_lagrange`'s basis: ``(T, n, 3)``."""
    x = at[None, :]
    out = np.zeros((nodes.shape[0], at.size, 3))
    for m in range(3):
        others = [k for k in range(3) if k != m]
        denominator = (nodes[:, m] - nodes[:, others[0]]) * (nodes[:, m] - nodes[:, others[1]])
        out[..., m] = (2 * x - nodes[:, others[0], None] - nodes[:, others[1], None]) / denominator[
            :, None
        ]
    return out


#: Points a quadratic was fitted through: pixels, wavelengths, degree.
_Points = tuple[FloatArray, FloatArray, int]


def _refit_through_inliers(
    mapping: QuadraticMapping, position: FloatArray, line_nm: FloatArray, tolerance_nm: float
) -> tuple[QuadraticMapping, _Points] | None:
    """The mapping refitted (twice) through the peaks within ``tolerance_nm`` of a line, and the
    points of its last fit (the curve only: :meth:`QuadraticMapping.fit` without covariance)."""
    points: _Points | None = None
    for _ in range(2):
        predicted = mapping.wavelength_nm(position)
        nearest = np.argmin(np.abs(predicted[:, None] - line_nm[None, :]), axis=1)
        close = np.abs(predicted - line_nm[nearest]) <= tolerance_nm
        if np.count_nonzero(close) < 2:
            return None
        degree = 2 if np.count_nonzero(close) >= 4 else 1
        points = (position[close], line_nm[nearest[close]], degree)
        try:
            mapping = QuadraticMapping.fit(
                points[0], points[1], degree=degree, with_covariance=False
            )
        except EstimationError:
            return None
    slopes = mapping.dispersion_nm_per_px(np.linspace(position.min(), position.max(), 9))
    if points is None or not (np.all(slopes > 0) or np.all(slopes < 0)):
        return None
    return mapping, points


def _agreement(
    mapping: QuadraticMapping,
    peaks: Sequence[tuple[float, float]],
    features: Sequence[Blend],
    tolerance_nm: float,
) -> float:
    """How well a hypothesis explains both sides: every feature by a peak near its wavelength and
    every peak by a feature near its mapped wavelength, each weighted by its relative strength
    (Gaussian in the distance, σ ``tolerance_nm``). A hypothesis that leaves the strongest peaks
    unexplained loses, however many weak lines it matches."""
    if not peaks or not features:
        return 0.0
    peak_nm = mapping.wavelength_nm(np.array([p for p, _ in peaks]))
    peak_weight = np.array([h for _, h in peaks])
    feature_nm = np.array([b.wavelength_nm for b in features])
    feature_weight = np.array([b.strength for b in features])
    distance = np.abs(peak_nm[:, None] - feature_nm[None, :])
    closeness = np.exp(-0.5 * (distance / tolerance_nm) ** 2)
    explained_peaks = float(np.sum(peak_weight / peak_weight.sum() * closeness.max(axis=1)))
    explained_features = float(
        np.sum(feature_weight / feature_weight.sum() * closeness.max(axis=0))
    )
    return explained_peaks + explained_features


def _pixel_of(mapping: ExactMapping, wavelength_nm: FloatArray) -> FloatArray:
    return np.asarray(mapping.pixel_at(wavelength_nm), dtype=np.float64)


def features_at(
    lines: Sequence[Line],
    mapping: ExactMapping,
    fwhm_px: float,
    pixel_range: tuple[float, float],
) -> list[Blend]:
    """The list's features at the resolution a mapping implies (the camera's FWHM times its
    dispersion in the middle of the profile): what blends and what stands alone."""
    middle = 0.5 * (pixel_range[0] + pixel_range[1])
    resolution_nm = fwhm_px * float(_slope(mapping, np.array([middle]))[0])
    return _measurable(blends(lines, resolution_nm), resolution_nm)


def _measurable(features: Sequence[Blend], resolution_nm: float) -> list[Blend]:
    """Features a camera can locate on their own: one weaker than :data:`WEAK_NEIGHBOUR` of a
    neighbour within 1.5 resolutions is left out (its peak is the neighbour's shoulder, and fitting
    it would let it take the neighbour's place)."""
    kept = []
    for blend in features:
        crowded = any(
            other is not blend
            and abs(other.wavelength_nm - blend.wavelength_nm) < 1.5 * resolution_nm
            and blend.strength < WEAK_NEIGHBOUR * other.strength
            for other in features
        )
        if not crowded:
            kept.append(blend)
    return kept


def _window_px(spacing_px: float, fwhm_px: float) -> float:
    """How far (pixel units) a feature's fit window reaches beyond its outermost components:
    :data:`WINDOW_FWHM` FWHM, at least :data:`WINDOW_MIN_SAMPLES` samples ``spacing_px`` apart."""
    return max(WINDOW_FWHM * fwhm_px, WINDOW_MIN_SAMPLES * spacing_px)


def fit_features(
    pixel: FloatArray,
    signal: FloatArray,
    noise: float,
    features: Sequence[Blend],
    mapping: ExactMapping,
    fwhm_px: float,
    *,
    background_order: int = 1,
    restart: bool = False,
) -> list[_Fitted]:
    """Every feature the mapping puts inside the profile, fitted (overlapping ones together;
    ``background_order``, ``restart``: :func:`_fit_group`'s)."""
    lo, hi = float(pixel[0]), float(pixel[-1])
    spacing = abs(float(np.median(np.diff(pixel)))) if pixel.size > 1 else 1.0
    reach = _window_px(spacing, fwhm_px)
    located = []
    for blend in features:
        try:
            at = _pixel_of(mapping, np.array([line.wavelength_nm for line in blend.lines]))
        except InputError:
            continue
        if np.all((at > lo + fwhm_px) & (at < hi - fwhm_px)):
            located.append((float(at.min()), float(at.max()), blend))
    located.sort(key=lambda item: item[0])
    groups: list[list[tuple[float, float, Blend]]] = []
    for item in located:
        near = groups and item[0] - groups[-1][-1][1] < 2 * reach
        if near and len(groups[-1]) < MAX_GROUP:
            groups[-1].append(item)
        else:
            groups.append([item])
    out: list[_Fitted] = []
    for group in groups:
        out += _fit_group(
            pixel,
            signal,
            noise,
            [b for _, _, b in group],
            mapping,
            fwhm_px,
            spacing,
            background_order=background_order,
            restart=restart,
        )
    return out


def spectrum_line_centres(
    wavelength_nm: FloatArray,
    values: FloatArray,
    features: Sequence[Blend],
    resolution_nm: float,
) -> dict[str, tuple[float, float]]:
    """Where a lamp's measured spectrum puts each single line among a camera's ``features``:
    ``{label: (nm, σ nm)}``, the line's centre fitted in the spectrum (:func:`fit_features` on
    the spectrum as a profile whose pixels are nanometres, a quadratic background under it, at
    ``resolution_nm``: the bandwidth, never finer than the sampling). A line the spectrometer
    blends with another one at that resolution, or does not find, is left out.

    A real lamp's lines are where the list says; a tabulated one's (colour-science's 5 nm FL
    tables, which the validation protocol renders) sit at the table's nodes, up to 1.1 nm away —
    and what the camera saw is the lamp, as its spectrum says.
    """
    axis = np.asarray(wavelength_nm, dtype=np.float64)
    spectrum = np.asarray(values, dtype=np.float64)
    if axis.size < 8:
        return {}
    step = float(np.median(np.diff(axis)))
    width = max(float(resolution_nm), step)
    lines = sorted({line for feature in features for line in feature.lines}, key=_line_nm)
    own = {blend.label: blend for blend in blends(lines, width)}
    singles = [f for f in features if len(f.lines) == 1 and f.label in own]
    identity = QuadraticMapping(0.0, 1.0, 0.0, pixel_range=(float(axis[0]), float(axis[-1])))
    _, noise = feature_signal(spectrum[:, None], "emission", width / step)
    return {
        f.blend.label: (f.centroid_px, f.centroid_sigma)
        for f in fit_features(axis, spectrum, noise, singles, identity, width, background_order=2)
        if math.isfinite(f.centroid_px) and math.isfinite(f.centroid_sigma)
    }


def lines_shown(
    wavelength_nm: FloatArray,
    values: FloatArray,
    lines: Sequence[Line],
    resolution_nm: float,
) -> tuple[Line, ...]:
    """The emission ``lines`` a lamp's measured spectrum shows: each line's height fitted at its
    wavelength (a Gaussian of the spectrum's ``resolution_nm``, never finer than its sampling,
    over a quadratic background, by linear least squares; lines whose windows of
    ±:data:`SHOWN_WINDOW` resolutions overlap fitted together), kept when it is at least
    :data:`SHOWN_FRACTION` of what the list's strengths predict from the strongest listed line
    the spectrum holds, and its blend at the spectrum's resolution (lines closer than it) at
    least :data:`SHOWN_SIGMA` of its σ above zero. A line list is every line a species may emit; a lamp need not show them
    all (the twin's FL2 has no Hg 407.8 or 491.6: a camera feature matched to one there is a
    phosphor's shape, not the line).

    Lines outside the spectrum, or with too few samples around them, are kept (nothing says they
    are absent).
    """
    axis = np.asarray(wavelength_nm, dtype=np.float64)
    spectrum = np.asarray(values, dtype=np.float64)
    ordered = sorted(lines, key=_line_nm)
    if axis.size < 8 or not ordered:
        return tuple(ordered)
    step = float(np.median(np.diff(axis)))
    width = max(float(resolution_nm), step)
    sigma = width / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    groups: list[list[Line]] = [[ordered[0]]]
    for line in ordered[1:]:
        if line.wavelength_nm - groups[-1][-1].wavelength_nm < 2.0 * SHOWN_WINDOW * width:
            groups[-1].append(line)
        else:
            groups.append([line])
    heights: dict[str, float] = {}
    significance: dict[str, bool] = {}
    for group in groups:
        lo = group[0].wavelength_nm - SHOWN_WINDOW * width
        hi = group[-1].wavelength_nm + SHOWN_WINDOW * width
        inside = (axis >= lo) & (axis <= hi)
        if lo < axis[0] or hi > axis[-1] or np.count_nonzero(inside) < len(group) + 4:
            continue
        x = axis[inside]
        middle = 0.5 * (lo + hi)
        design = np.column_stack(
            [((x - middle) / width) ** k for k in range(3)]
            + [np.exp(-0.5 * ((x - line.wavelength_nm) / sigma) ** 2) for line in group]
        )
        solution, *_ = np.linalg.lstsq(design, spectrum[inside], rcond=None)
        residual = spectrum[inside] - design @ solution
        dof = max(x.size - design.shape[1], 1)
        covariance = np.linalg.pinv(design.T @ design) * float(residual @ residual) / dof
        heights.update(zip((line.label for line in group), solution[3:].tolist(), strict=True))
        # Lines closer than the resolution are told from the band together (their split is
        # degenerate): each is judged by its blend's summed height against that sum's σ.
        first = 0
        for end in range(1, len(group) + 1):
            if end < len(group) and group[end].wavelength_nm - group[end - 1].wavelength_nm < width:
                continue
            members = slice(3 + first, 3 + end)
            total = float(np.sum(solution[members]))
            total_sigma = math.sqrt(max(float(np.sum(covariance[members, members])), 0.0))
            significant = total >= SHOWN_SIGMA * total_sigma
            significance.update((line.label, significant) for line in group[first:end])
            first = end
    fitted = [line for line in ordered if line.label in heights]
    if not fitted:
        return tuple(ordered)
    reference = max(fitted, key=lambda line: line.strength)
    scale = heights[reference.label] / reference.strength
    if not scale > 0:
        return tuple(ordered)
    return tuple(
        line
        for line in ordered
        if line.label not in heights
        or (
            heights[line.label] >= SHOWN_FRACTION * scale * line.strength
            and significance[line.label]
        )
    )


def _line_nm(line: Line) -> float:
    return line.wavelength_nm


# ------------------------------------------------------------------------------ mapping fit


def fit_mapping_to_points(
    family: Family,
    x0: FloatArray,
    pixels: FloatArray,
    wavelengths_nm: FloatArray,
    sigma_nm: FloatArray,
    max_iterations: int = FIT_ITERATIONS,
    anchor: ProfileAnchor | None = None,
) -> tuple[FloatArray, FloatArray, float]:
    """Weighted least squares of a family through ``(pixel, λ ± σ)`` points (and its prior rows,
    and an ``anchor``'s: a whole-profile fit the points correct).

    Returns the parameters, their covariance (scaled by the reduced χ² when it exceeds 1) and χ²
    (the points' and the anchor's rows).
    """

    span = (float(pixels.min()), float(pixels.max()))
    column_sigma = sigma_nm[:, None]

    def function(x: FloatArray, with_jacobian: bool) -> tuple[FloatArray, FloatArray | None] | None:
        if isinstance(family, GratingFamily):
            evaluated = family.evaluate(pixels, x, span, with_jacobian=with_jacobian)
            if evaluated is None:
                return None
            wavelengths, wavelength_jacobian = evaluated
            rows, row_jacobian = family.prior_rows(x)
        else:
            wavelengths = family.wavelengths(pixels, x)
            wavelength_jacobian = family.jacobian(pixels, x) if with_jacobian else None
            rows, row_jacobian = np.zeros(0), np.zeros((0, x.size))
        anchored: tuple[FloatArray, FloatArray | None] = (np.zeros(0), np.zeros((0, x.size)))
        if anchor is not None:
            evaluated_anchor = anchor.residual(family, x, with_jacobian)
            if evaluated_anchor is None:
                return None
            anchored = evaluated_anchor
        residual = np.concatenate([(wavelengths - wavelengths_nm) / sigma_nm, anchored[0], rows])
        if wavelength_jacobian is None or anchored[1] is None:
            return residual, None
        return residual, np.concatenate(
            [wavelength_jacobian / column_sigma, anchored[1], row_jacobian]
        )

    solution = levenberg_marquardt(
        function,
        x0,
        max_iterations=max_iterations,
        tolerance=FIT_TOLERANCE,
        geodesic=True,
        step_tolerance=STEP_TOLERANCE,
        # Within a tenth of the points' stated σ; not ``stop_at_bound``: the family's soft prior
        # settles its flat valley by many small steps, which move an extrapolated end (0195).
        gain_tolerance=CONVERGED_DELTA_CHI2,
    )
    data_rows = pixels.size + (0 if anchor is None else anchor.rows)
    chi2 = float(np.sum(solution.residual[:data_rows] ** 2))
    dof = max(data_rows - x0.size, 1)
    covariance = solution.covariance(scale_by_fit=False) * max(chi2 / dof, 1.0)
    return solution.x, covariance, chi2


def _initial_parameters(family: Family, mapping: ExactMapping, pixels: FloatArray) -> FloatArray:
    """Family parameters that reproduce ``mapping`` over ``pixels`` (a least-squares fit)."""
    if isinstance(family, QuadraticFamily):
        return family.parameters(mapping)
    if isinstance(mapping, TiltedGrating) and mapping.orientation == family.orientation:
        return family.parameters(mapping)
    targets = mapping.wavelength_nm(pixels)
    means = {name: value[0] for name, value in family.prior.values.items()}
    # Start from the prior (or a generic grating) and fit the family to the mapping's wavelengths.
    guess = {
        "zero_order_px": means.get("zero_order_px", float(pixels[0]) - family.orientation * 0.0),
        "log_spacing": means.get("log_spacing", math.log(1e6 / 600.0)),
        "log_focal": means.get("log_focal", math.log(5000.0)),
        "incidence_deg": means.get("incidence_deg", 0.0),
        "axis_offset_px": family.offset_guess,
    }
    if "zero_order_px" not in family.prior.fixed():
        slope = float(np.polyfit(pixels, targets, 1)[0])
        guess["zero_order_px"] = float(pixels[0] - targets[0] / slope)
        spacing = math.exp(guess["log_spacing"])
        guess["log_focal"] = math.log(max(abs(spacing / slope), 10.0))
    x0 = np.array([guess[name] for name in family.names])
    x, _, _ = fit_mapping_to_points(
        family, x0, pixels, targets, np.full(pixels.size, 0.1), START_ITERATIONS
    )
    return x


def map_features(
    pixel: FloatArray,
    profile: FloatArray,
    lines: Sequence[Line],
    *,
    family: Family,
    fwhm_px: float,
    start: ExactMapping | None = None,
    nominal_dispersion: float | None = None,
    allow_reversed: bool = False,
    kind: LineKind | None = None,
    range_nm: tuple[float, float] = (380.0, 720.0),
    moments: bool = False,
    centres: Mapping[str, tuple[float, float]] | None = None,
    anchor: ProfileAnchor | None = None,
) -> FeatureMapping:
    """The mapping through a profile's features (see the module docstring).

    Parameters
    ----------
    pixel, profile
        ``(n,)`` and ``(n, 3)``.
    lines
        The list to match (emission or absorption, not mixed).
    family
        The mapping family the features are fitted with.
    fwhm_px
        The camera's line width in profile samples (the line spread's FWHM).
    start
        A mapping to start from (skips the matching step).
    nominal_dispersion
        A rough nm per profile sample (bounds the matching's hypotheses to ×0.4–2.5 of it);
        default: the profile's lit extent taken as :data:`LIT_RANGE_NM`.
    allow_reversed
        Let the matching try wavelengths falling with the pixel.
    kind
        Emission or absorption (default: the lines').
    range_nm
        Only features in this range are matched (the camera's and the working grid's).
    moments
        Fit each feature at its first moment (:func:`_point`), on the summed profile itself with a
        quadratic background — for a lamp whose line strengths nobody listed (a measured
        fluorescent lamp's Hg lines: its 577.0/579.1 split is its own) — and let a physical
        family's soft prior count as an equation (a start is given: no matching to guard).
    centres
        With ``moments``: ``{label: (nm, σ nm)}`` of single lines placed by the lamp's measured
        spectrum (:func:`spectrum_line_centres`), used instead of the list's wavelengths.
    anchor
        A whole-profile fit (with ``start``, its mapping) that the features correct: fitted
        jointly with them, so :data:`MIN_ANCHORED_FEATURES` features suffice
        (:class:`ProfileAnchor`).
    """
    if anchor is not None and start is None:
        raise InputError("an anchored line fit starts from its whole-profile fit", source="start")
    if not lines:
        raise InputError("no lines to match", source="line list")
    kind = kind or lines[0].kind
    spacing = float(np.median(np.diff(pixel)))
    # Dispersion in nm per pixel unit (not per sample), from the start or the lit extent.
    if start is not None:
        ends = start.wavelength_nm(np.array([pixel[0], pixel[-1]]))
        dispersion_guess = abs(float(ends[1] - ends[0])) / max(float(pixel[-1] - pixel[0]), 1e-9)
    else:
        dispersion_guess = nominal_dispersion or lit_dispersion(pixel, profile) / spacing
    resolution_nm = fwhm_px * dispersion_guess
    chosen = [
        line
        for line in lines
        if line.kind == kind and range_nm[0] <= line.wavelength_nm <= range_nm[1]
    ]
    features = _measurable(blends(chosen, resolution_nm), resolution_nm)
    signal, noise = feature_signal(profile, kind, fwhm_px / spacing)
    if moments and kind == "emission":
        # On the light itself, a quadratic background under each feature: the baseline's opening
        # leaves a broad band's shoulder under a line on a steep flank, which moves its moment.
        signal = np.sum(np.asarray(profile, dtype=np.float64), axis=1)
    pixel_range = (float(pixel[0]), float(pixel[-1]))
    hypotheses: list[ExactMapping]
    if start is None:
        peaks = signal_peaks(pixel, signal, noise, fwhm_px / spacing)[:MATCH_PEAKS]
        if len(peaks) < 3:
            raise EstimationError(
                f"found {len(peaks)} {kind} feature(s) in the profile; the mapping needs several "
                "(is the lamp the one named, and the first order whole?)"
            )
        # The lit extent is a rough guess (a line lamp lights less than a camera sees).
        hypotheses = list(
            match_lines(
                peaks,
                features,
                dispersion_range=(0.4 * dispersion_guess, 2.5 * dispersion_guess),
                tolerance_nm=max(2.0, 0.5 * resolution_nm),
                allow_reversed=allow_reversed,
                count=ABSORPTION_HYPOTHESES if kind == "absorption" else HYPOTHESES,
            )
        )
    else:
        hypotheses = [start]
    # Every hypothesis is carried through the feature fits; the one whose mapping explains the
    # most (and strongest) features wins — a match by peaks alone is fooled by a camera's own
    # narrow structure, which a feature fit through the list does not line up with.
    outcomes = []
    for hypothesis in hypotheses:
        try:
            outcomes.append(
                _refine(
                    family,
                    hypothesis,
                    pixel,
                    signal,
                    noise,
                    features_at(chosen, hypothesis, fwhm_px, pixel_range),
                    fwhm_px,
                    pixel_range,
                    moments,
                    centres or {},
                    anchor,
                )
            )
        except (EstimationError, ValueError, np.linalg.LinAlgError):
            continue
    if not outcomes:
        raise EstimationError(
            f"none of {len(hypotheses)} line matches held when the {kind} features were fitted "
            "(is the lamp the one named, and the first order whole?)"
        )
    refused = 0
    if start is None and kind == "emission":
        # A fresh match must be a grating the rig can be (lines alone: nothing else checks it).
        lit = lit_extent(pixel, profile)
        reasons = [implausible(family, outcome[0], pixel, lit) for outcome in outcomes]
        plausible = [o for o, why in zip(outcomes, reasons, strict=True) if why is None]
        refused = len(outcomes) - len(plausible)
        if not plausible:
            best = max(range(len(outcomes)), key=lambda k: _support(outcomes[k]))
            raise EstimationError(
                f"the best of {len(outcomes)} {kind} line matches is not physically plausible: "
                f"{reasons[best]} — its lines were matched to the wrong features (a line too dim "
                "or missing?)"
            )
        outcomes = plausible
    ranked = sorted(outcomes, key=_support, reverse=True)
    found = _feature_mapping(ranked[0], family, pixel_range, kind, moments, centres, refused)
    if start is None and kind == "absorption":
        # A runner-up as well supported and elsewhere: the dips do not decide (the caller warns).
        probe = np.linspace(pixel_range[0], pixel_range[1], 64)
        kept_nm = found.exact.wavelength_nm(probe)
        for other in ranked[1:]:
            if _support(other) < _support(ranked[0]) - RIVAL_SUPPORT:
                break
            apart = np.max(np.abs(family.mapping(other[0]).wavelength_nm(probe) - kept_nm))
            if float(apart) >= RIVAL_APART_NM:
                rival = _feature_mapping(other, family, pixel_range, kind, moments, centres, 0)
                return replace(found, rival=rival)
    return found


def _feature_mapping(
    outcome: _Outcome,
    family: Family,
    pixel_range: tuple[float, float],
    kind: LineKind,
    moments: bool,
    centres: Mapping[str, tuple[float, float]] | None,
    refused: int,
) -> FeatureMapping:
    """One outcome of :func:`_refine` as a :class:`FeatureMapping`."""
    x, covariance, fitted, sigma, used, _, _ = outcome
    exact = family.mapping(x)
    matches = tuple(
        FeatureMatch(
            f.blend,
            position,
            position_sigma,
            float(exact.wavelength_nm(np.array([position]))[0]),
            float(s),
            bool(u),
            f.amplitude,
            centre,
        )
        for f, s, u in zip(fitted, sigma, used, strict=True)
        for position, position_sigma, centre, _ in [_point(f, moments, centres or {})]
    )
    report = _report(exact, family, x, covariance, pixel_range)
    kept = [m for m in matches if m.used]
    residuals = np.array([m.residual_nm for m in kept])
    details: dict[str, Any] = {
        "origin": f"{kind} features",
        "family": "grating" if isinstance(family, GratingFamily) else "quadratic",
        "n_features": len(matches),
        "n_used": len(kept),
        "residual_rms_nm": float(np.sqrt(np.mean(residuals**2))) if kept else None,
        "matched_lines": [m.row() for m in matches],
    }
    if refused:
        details["implausible_matches"] = refused
    if isinstance(exact, TiltedGrating):
        details["grating"] = exact.to_dict()
    mapping_out = report.with_details(details={**dict(report.details), **details})
    return FeatureMapping(mapping_out, exact, matches, details)


_Outcome = tuple[FloatArray, FloatArray, list[_Fitted], FloatArray, FloatArray, float, FloatArray]


def _support(outcome: _Outcome) -> float:
    """The features a mapping keeps, less half those it puts inside the profile but could not fit
    or rejected — each counted by the fourth root of its listed strength: a list's strengths are
    a typical lamp's, not this one's (a CFL's Hg 404.7 may be faint, its Tb peak strong), so they
    only mildly favour strong lines. A mapping that predicts lines where there are none loses.
    A dip counts by how near the mapping passes it, too (:data:`DIP_CLOSENESS_FWHM`; emission
    lines fully)."""
    _, _, fitted, _, used = outcome[:5]
    expected = outcome[5]
    closeness = outcome[6]
    kept = sum(_weight(f.blend) * c for f, u, c in zip(fitted, used, closeness, strict=True) if u)
    return float(kept - 0.5 * (expected - kept))


def _weight(blend: Blend) -> float:
    return float(blend.strength**0.25)


def _point(
    fitted: _Fitted, moments: bool, centres: Mapping[str, tuple[float, float]]
) -> tuple[float, float, float | None, float]:
    """A fitted feature as a point of the mapping fit: ``(pixel, σ px, nm or None, σ nm)``.

    By default the reference line's pixel, the list's wavelength (``None``) and uncertainty. With
    ``moments``, the feature's first moment: a single line at its list wavelength, a blend at the
    list's strength-weighted centre with σ for a split nobody measured (uniform between its
    components: their span/√12 — the Hg 576.96/579.07 doublet's share varies with the lamp; fitted
    as two components at the list's places, the twin's put 579.07 1.1 nm off). A single line
    that ``centres`` holds is placed there instead (where the lamp's own spectrum puts it).

    An absorption blend (Na D2 + D1, the Mg b triplet: lines the camera does not resolve) is
    always placed so, with or without ``moments``: its components' heights, fitted freely at a
    resolution that cannot split them, trade with its shift, and the reference line's pixel
    follows the trade while the moment does not (decision 0095: on the spectrograph analog the
    mapping's error at D fell from 0.14 to 0.11 nm RMS, at Mg b from 0.065 to 0.053; the Sun's
    equivalent widths are not the list's weights, so the split's σ stays the uniform one)."""
    blend = fitted.blend
    absorbed = len(blend.lines) > 1 and blend.reference.kind == "absorption"
    if (not moments and not absorbed) or not math.isfinite(fitted.centroid_px):
        return fitted.pixel, fitted.sigma, None, blend.uncertainty_nm
    if len(blend.lines) == 1:
        measured = centres.get(blend.label)
        if measured is not None:
            return fitted.centroid_px, fitted.centroid_sigma, measured[0], measured[1]
        return fitted.centroid_px, fitted.centroid_sigma, None, blend.uncertainty_nm
    wavelengths = [line.wavelength_nm for line in blend.lines]
    split_nm = math.hypot(
        (max(wavelengths) - min(wavelengths)) / math.sqrt(12.0), blend.uncertainty_nm
    )
    return fitted.centroid_px, fitted.centroid_sigma, blend.wavelength_nm, split_nm


def _refine(
    family: Family,
    mapping: ExactMapping,
    pixel: FloatArray,
    signal: FloatArray,
    noise: float,
    features: Sequence[Blend],
    fwhm_px: float,
    pixel_range: tuple[float, float],
    moments: bool = False,
    centres: Mapping[str, tuple[float, float]] | None = None,
    anchor: ProfileAnchor | None = None,
) -> _Outcome:
    """Fit the features where ``mapping`` puts them, the mapping through them (and ``anchor``'s
    whole-profile fit, when given); :data:`ROUNDS`."""
    # The family starts where the hypothesis is supported (between the features it predicts
    # inside the profile): a quadratic through a few lines says little beyond them.
    inside = []
    for blend in features:
        try:
            at = float(_pixel_of(mapping, np.array([blend.wavelength_nm]))[0])
        except InputError:
            continue
        if pixel_range[0] <= at <= pixel_range[1]:
            inside.append(at)
    span = (min(inside), max(inside)) if len(inside) >= 2 else pixel_range
    x = _initial_parameters(family, mapping, np.linspace(*span, 64))
    # Dips, too, are fitted again from ±½ FWHM when missed (decision 0095: at a coarse resolution
    # a mapping pulled by its blends put Hα 2.2 px from its dip at a 3 px FWHM, and it was lost).
    absorption = bool(features) and features[0].reference.kind == "absorption"
    covariance = np.zeros((x.size, x.size))
    fitted: list[_Fitted] = []
    sigma = np.zeros(0)
    used = np.zeros(0, dtype=bool)
    for _ in range(ROUNDS):
        current = family.mapping(x)
        fitted = fit_features(
            pixel,
            signal,
            noise,
            features,
            current,
            fwhm_px,
            background_order=2 if moments else 1,
            restart=moments or absorption,
        )
        # From a given start, a physical family's soft prior (an incidence near 0) is one more
        # equation.
        prior_row = moments and isinstance(family, GratingFamily) and bool(family.prior.soft())
        needed = x.size + (0 if prior_row else 1)
        if anchor is not None:
            # The whole-profile fit holds the family; the features correct it.
            needed = MIN_ANCHORED_FEATURES
        if len(fitted) < needed:
            raise EstimationError(
                f"only {len(fitted)} of the list's features were found in the profile; the mapping "
                f"needs at least {needed} (is the lamp the one named, and the first order whole?)"
            )
        points = [_point(f, moments, centres or {}) for f in fitted]
        pixels = np.array([p[0] for p in points])
        references = np.array(
            [
                f.blend.reference.wavelength_nm if p[2] is None else p[2]
                for f, p in zip(fitted, points, strict=True)
            ]
        )
        sigma = np.sqrt(
            (np.array([p[1] for p in points]) * _slope(current, pixels)) ** 2
            + np.array([p[3] for p in points]) ** 2
            + MODEL_ERROR_NM**2
        )
        used = np.ones(len(fitted), dtype=bool)
        stated = sigma
        while True:
            x, covariance, sigma = _fit_with_model_scatter(
                family, x, pixels, references, stated, used, anchor
            )
            normalised = np.abs(family.wavelengths(pixels, x) - references) / sigma
            worst = int(np.argmax(np.where(used, normalised, -1.0)))
            if normalised[worst] <= OUTLIER_SIGMA or used.sum() <= needed:
                break
            used[worst] = False
    final = family.mapping(x)
    closeness = np.ones(len(fitted))
    if absorption:
        # How near the mapping passes each dip (:data:`DIP_CLOSENESS_FWHM`, :func:`_support`).
        residual = family.wavelengths(pixels, x) - references
        scale_nm = DIP_CLOSENESS_FWHM * fwhm_px * float(np.median(_slope(final, pixels)))
        closeness = np.exp(-0.5 * (residual / scale_nm) ** 2)
    expected = 0.0
    for blend in features:
        try:
            where = float(_pixel_of(final, np.array([blend.wavelength_nm]))[0])
        except InputError:
            continue
        if pixel_range[0] + fwhm_px < where < pixel_range[1] - fwhm_px:
            expected += _weight(blend)
    return x, covariance, fitted, sigma, used, expected, closeness


def _fit_with_model_scatter(
    family: Family,
    x: FloatArray,
    pixels: FloatArray,
    references: FloatArray,
    stated_nm: FloatArray,
    used: FloatArray,
    anchor: ProfileAnchor | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The family through the ``used`` points, their σ widened where the fit says they are short.

    When the family cannot pass within the features' stated σ, two explanations compete, each
    with one parameter settled so the fit's χ² equals its degrees of freedom: the *list* is
    short (every σ scaled by one factor, the weights kept: a tri-phosphor lamp's listed peaks are
    its phosphors' typical ones) or the *model* is (one scatter added in quadrature to every σ:
    a spectrograph's field curvature or a lens' distortion the family lacks, which the sharpest
    features feel as much as the others). The one with the higher Gaussian likelihood of the
    residuals is kept, so the sharpest features no longer drag the mapping through themselves at
    the others' cost where the model is what misfits, and an outlier is judged against the
    scatter the family actually leaves. Returns the parameters, their covariance and the widened
    σ of every point.

    With an ``anchor`` (a whole-profile fit the points correct) its rows count as data, and only
    the first explanation is weighed: the family's misfit is then the anchor's as much as the
    points', and the covariance is already scaled by the whole χ² (:func:`fit_mapping_to_points`).
    """
    extra_rows = 0 if anchor is None else anchor.rows
    dof = max(int(used.sum()) + extra_rows - x.size, 1)
    x_list, covariance_list, _ = fit_mapping_to_points(
        family, x, pixels[used], references[used], stated_nm[used], anchor=anchor
    )
    residual = (family.wavelengths(pixels, x_list) - references)[used]
    factor = max(float(np.sqrt(np.sum((residual / stated_nm[used]) ** 2) / dof)), 1.0)
    best = (x_list, covariance_list, stated_nm * factor)
    if factor == 1.0 or anchor is not None:
        return best
    best_likelihood = _log_likelihood(residual, stated_nm[used] * factor)
    scatter_nm, x_model, covariance_model = 0.0, x_list, covariance_list
    for _ in range(SCATTER_ROUNDS):
        sigma = np.hypot(stated_nm, scatter_nm)
        x_model, covariance_model, _ = fit_mapping_to_points(
            family, x_model, pixels[used], references[used], sigma[used]
        )
        residual = (family.wavelengths(pixels, x_model) - references)[used]
        widened = _scatter_for_chi2(residual, stated_nm[used], dof)
        settled = abs(widened - scatter_nm) <= 0.01 * max(widened, 1e-3)
        scatter_nm = widened
        if settled:
            break
    sigma = np.hypot(stated_nm, scatter_nm)
    if _log_likelihood(residual, sigma[used]) > best_likelihood:
        return x_model, covariance_model, sigma
    return best


def _log_likelihood(residual: FloatArray, sigma: FloatArray) -> float:
    return float(-0.5 * np.sum((residual / sigma) ** 2 + 2.0 * np.log(sigma)))


def _scatter_for_chi2(residual: FloatArray, sigma: FloatArray, dof: int) -> float:
    """The ``s ≥ 0`` with ``Σ r² / (σ² + s²) = dof`` (0 when the stated σ already give less)."""
    if float(np.sum((residual / sigma) ** 2)) <= dof:
        return 0.0
    from scipy.optimize import brentq  # deferred, as the module's other scipy uses

    def excess(scatter: float) -> float:
        return float(np.sum(residual**2 / (sigma**2 + scatter**2))) - dof

    # Σ r²/(σ² + s²) falls with s; at this bound it is below n·max r²/s² = dof.
    high = float(np.max(np.abs(residual))) * math.sqrt(residual.size / dof) + float(np.max(sigma))
    return float(brentq(excess, 0.0, high, xtol=1e-12))


def _slope(mapping: ExactMapping, pixels: FloatArray) -> FloatArray:
    if isinstance(mapping, TiltedGrating):
        return np.abs(mapping.dispersion_at(pixels))
    return np.abs(mapping.dispersion_nm_per_px(pixels))


def _report(
    exact: ExactMapping,
    family: Family,
    x: FloatArray,
    covariance: FloatArray,
    pixel_range: tuple[float, float],
) -> QuadraticMapping:
    pixels = np.linspace(pixel_range[0], pixel_range[1], 256)
    fitted = QuadraticMapping.fit(pixels, exact.wavelength_nm(pixels))
    jacobian = family.jacobian(pixels, x)
    design = np.stack([pixels**2, pixels, np.ones_like(pixels)], axis=1)
    projection = np.linalg.pinv(design)
    coefficient_covariance = projection @ jacobian @ covariance @ jacobian.T @ projection.T
    variance = np.einsum("ij,jk,ik->i", jacobian, covariance, jacobian)
    details: dict[str, Any] = {}
    if isinstance(exact, TiltedGrating):
        details["quadratic_max_error_nm"] = float(
            np.max(np.abs(fitted.wavelength_nm(pixels) - exact.wavelength_nm(pixels)))
        )
    return QuadraticMapping(
        fitted.a,
        fitted.b,
        fitted.c,
        method="features",
        pixel_range=pixel_range,
        covariance=tuple((float(r[0]), float(r[1]), float(r[2])) for r in coefficient_covariance),
        wavelength_rms_nm=float(np.sqrt(np.mean(np.clip(variance, 0.0, None)))),
        details=details,
        model=exact if isinstance(exact, TiltedGrating) else None,
    )
