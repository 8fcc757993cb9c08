"""The pixel→wavelength mapping of one geometry's lamps, from whatever they offer — physics first.

:func:`locate_mapping` decides what the lamps can tell and combines the ways this package has:

1. **The rig's prior** (:mod:`calib.wavelength.rig_prior`): with pixels measured from the direct spot,
   the grating equation through the lens is the model, and what the capture reports (EXIF focal
   length and pitch, the spot's place on the sensor), the rig's line density and a grating file of
   the same rig become its prior.
2. **Lines, when there are lines** (:mod:`calib.wavelength.features`): a lamp whose spectrum is a
   built-in line list (``builtin:cfl-triphosphor`` — a lamp nobody measured) is mapped through its
   lines; a measured source that resolves Fraunhofer or telluric dips (sunlight at ≤ 1 nm) is
   refined through them from the whole-profile start. A measured fluorescent lamp keeps the
   whole-profile fit, and its Hg lines, fitted where that mapping puts them, say how well (a 5 nm
   table biases the fit by most of a nanometre: the warning suggests ``builtin:cfl-triphosphor``).
   The matched-line table goes with the result.
3. **Otherwise the whole profiles** (:func:`calib.wavelength.profile_search.search_profiles`): the
   lamps times a response under the camera prior, with batched scans, analytic Jacobians and the
   basins' profile likelihoods — ambiguity stated, never hidden.

Either orientation is tried when the profile's origin is arbitrary (a 1-D export may be mirrored);
the result is monotonic or an error.

The result's :class:`calib.core.mapping.QuadraticMapping` (the report format) carries in its
``details``: ``family`` and ``grating`` (the physical parameters), ``matched_lines`` (rows
``{line, wavelength_nm, pixel, fitted_nm, residual_nm, weight}``), ``candidates`` (every basin
with its mapping and likelihood), ``ambiguous`` (competing basins, or one held loosely at an
end), ``warnings`` (sentences for the user) with their ``warning_codes`` (one quality code each),
and ``rig_prior`` (what the physics rested on).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import EstimationError, InputError
from calib.core.line_lists import Line, builtin_lines, is_builtin, line_list
from calib.core.mapping import (
    LineReach,
    QuadraticMapping,
    TiltedGrating,
    wavelength_rms_from_covariance,
)
from calib.core.observations import LampObservation
from calib.core.result import MAPPING_FAILURE_NM
from calib.core.spectra import WavelengthGrid
from calib.model.bases import CameraPrior
from calib.model.resolution import COARSE_SLIT_NM, FWHM_PER_SIGMA, camera_kernel
from calib.wavelength.families import GratingFamily, GratingPrior, QuadraticFamily
from calib.wavelength.features import FeatureMapping, ProfileAnchor, map_features
from calib.wavelength.other_order import other_order_geometry
from calib.wavelength.profile_search import (
    AMBIGUITY_DELTA_CHI2,
    BASIN_TEMPER,
    BROADBAND_AMBIGUITY_DELTA_CHI2,
    GLOBAL_BIN_NM,
    HOPELESS_DELTA_CHI2,
    LOCAL_SIGMA_SCALE,
    Candidate,
    MappingSearch,
    Orientation,
    _report,
    basin_sigma,
    coarse_spectrum,
    deciding_shot,
    lines_unplaced,
    prior_misfit_sigma_nm,
    search_profiles,
    spectrometer_scale_sigma_nm,
    stated_covariance,
)
from calib.wavelength.quadratic_view import FinalVerdict, final_verdict, quadratic_coarse_view
from calib.wavelength.rig_prior import (
    RigGeometry,
    default_prior,
    optics_from_observation,
    rig_prior,
)

ExactMapping = QuadraticMapping | TiltedGrating

#: Absorption features of the built-in solar list that must be found in a measured spectrum for
#: the dips to be used (sunlight, or a lamp behind an absorbing filter).
MIN_SPECTRUM_DIPS = 3
#: A measured spectrum resolves absorption dips when sampled at least this finely (nm).
DIP_SAMPLING_NM = 1.0
#: A known Hg line this far (nm) from where the whole-profile mapping puts it is reported.
KNOWN_LINE_WARNING_NM = 0.3
#: Line width (FWHM, profile samples) assumed when neither a line spread nor the profile tells.
DEFAULT_FWHM_PX = 4.0
#: Narrowest line width (FWHM, profile samples) taken from a line spread or a profile: a line
#: narrower than two samples has one sample above half its maximum, whatever its true width
#: (1–2 samples), and a feature fit a sample wide has too few samples to fit (the twin's D40:
#: a 0.19/0.60/0.19 spread, FWHM ≈ 1.5 samples, counted 1).
MIN_FWHM_PX = 1.5
#: A line-based mapping this far (RMS, nm) from the whole-profile start it was refined from is
#: reported (the two sources disagree: a wrong line list or a wrong lamp).
DISAGREEMENT_NM = 2.0


@dataclass(frozen=True)
class MappingSolution:
    """The mapping and how it was found.

    Attributes
    ----------
    mapping
        The report form (see the module docstring for its ``details``).
    exact
        The mapping in its family (:class:`calib.core.mapping.TiltedGrating` for the physical one).
    warnings
        Sentences for the user.
    """

    mapping: QuadraticMapping
    exact: ExactMapping
    warnings: tuple[str, ...] = ()
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def matched_lines(self) -> list[dict[str, Any]]:
        rows = self.details.get("matched_lines")
        return list(rows) if isinstance(rows, list) else []

    @property
    def ambiguous(self) -> bool:
        return bool(self.details.get("ambiguous", False))


def lamp_lines(observation: LampObservation) -> tuple[Line, ...] | None:
    """The built-in line list a lamp's spectrum was rendered from (``builtin:NAME``), or ``None``."""
    name = observation.spectrum.name
    return builtin_lines(name) if is_builtin(name) else None


def fwhm_px(observation: LampObservation, kind: str = "emission") -> float:
    """The camera's line width in profile samples: the measured line spread's FWHM, else the
    narrowest of the profile's strong lines (or dips), else :data:`DEFAULT_FWHM_PX`."""
    if observation.line_spread is not None and observation.line_spread.size > 1:
        spread = observation.line_spread
        above = np.flatnonzero(spread >= 0.5 * float(spread.max()))
        return float(max(above[-1] - above[0] + 1, MIN_FWHM_PX))
    from scipy import ndimage, signal

    total = np.sum(observation.profile, axis=1)
    if kind == "emission":
        # Lines stand on broad bands: a baseline far wider than any line (a twentieth).
        baseline = ndimage.grey_opening(total, size=max(3, (total.size // 20) | 1), mode="nearest")
        values = total - baseline
    else:
        from calib.wavelength.features import feature_signal

        # Dips under the channels' envelopes, found with a provisional width of a few samples.
        values, _ = feature_signal(observation.profile, "absorption", DEFAULT_FWHM_PX)
    peaks, properties = signal.find_peaks(values, prominence=0.05 * float(np.ptp(values)))
    if peaks.size == 0:
        return DEFAULT_FWHM_PX
    widths = signal.peak_widths(values, peaks, rel_height=0.5)[0]
    strongest = np.argsort(properties["prominences"])[::-1][:5]
    # The narrowest of the strong ones: others are blends or bands.
    return float(max(np.min(widths[strongest]), MIN_FWHM_PX))


def _grating_prior_for(
    lead: LampObservation,
    *,
    geometry: GratingPrior | None,
    grooves_per_mm: float | None,
    stored: RigGeometry | None,
) -> tuple[GratingPrior | None, str]:
    """The physical family's prior: given, else from the rig (spot profiles), else none."""
    if geometry is not None:
        return geometry, geometry.source
    from_spot = lead.pixel_origin == "direct_spot"
    optics = optics_from_observation(lead)
    prior, why = rig_prior(
        optics, grooves_per_mm=grooves_per_mm, stored=stored, from_spot=from_spot
    )
    if prior is None and from_spot:
        return default_prior(True), "defaults"
    return prior, why


def _feature_family(
    lead: LampObservation, prior: GratingPrior | None, orientation: int
) -> GratingFamily:
    """The physical family for a line fit: the rig's prior, or weak plausibility bounds when the
    0th order's position is unknown (a 1-D export)."""
    if prior is not None:
        return GratingFamily(prior, orientation=orientation, axis_offset_px=prior.axis_offset_px)
    # 300–1800 lines/mm, a focal length of 500–50000 px, incidence within ±40°: broad enough
    # for any rig, narrow enough to keep the four parameters out of degenerate corners.
    loose = GratingPrior(
        {
            "log_spacing": (math.log(1e6 / 750.0), 0.6),
            "log_focal": (math.log(5000.0), 1.2),
            "incidence_deg": (0.0, 20.0),
        },
        "plausible gratings (nothing known of the rig)",
    )
    return GratingFamily(loose, orientation=orientation)


def _map_lines(
    lamp: LampObservation,
    lines: Sequence[Line],
    prior: GratingPrior | None,
    *,
    start: ExactMapping | None,
    directions: Sequence[int],
    grid: WavelengthGrid,
    dispersion_nm_per_px: float | None = None,
    moments: bool = False,
    centres: dict[str, tuple[float, float]] | None = None,
    anchor: ProfileAnchor | None = None,
) -> FeatureMapping:
    """Lines of one lamp through the physical family, in each allowed direction; the better kept.

    ``dispersion_nm_per_px`` (a whole-profile fit's) narrows the line matching when there is no
    ``start`` to follow; ``moments``, ``centres`` and ``anchor``:
    :func:`calib.wavelength.features.map_features`'."""
    if not lines:
        # Nothing of the list shows in this lamp's spectrum and grid: the caller's fallback (the
        # profile fit, another basin) decides, as for lines that could not be matched.
        raise EstimationError(f"lamp {lamp.name!r}: none of its listed lines shows to be matched")
    kind = lines[0].kind
    width = fwhm_px(lamp, kind)
    outcomes = []
    errors = []
    for direction in directions:
        family = _feature_family(lamp, prior, direction)
        try:
            outcomes.append(
                map_features(
                    lamp.pixel,
                    lamp.profile,
                    lines,
                    family=family,
                    fwhm_px=width * float(np.median(np.diff(lamp.pixel))),
                    start=start,
                    nominal_dispersion=dispersion_nm_per_px,
                    allow_reversed=direction < 0,
                    kind=kind,
                    range_nm=(grid.start_nm - 30.0, grid.stop_nm + 30.0),
                    moments=moments,
                    centres=centres,
                    anchor=anchor,
                )
            )
        except (EstimationError, ValueError) as exc:
            errors.append(str(exc))
    if not outcomes:
        raise EstimationError(
            f"lamp {lamp.name!r}: its {kind} lines could not be matched ({'; '.join(errors)})"
        )
    return max(outcomes, key=lambda o: sum(m.blend.strength for m in o.matches if m.used))


def _spectrum_dips(observation: LampObservation) -> tuple[Line, ...]:
    """Solar-list features that show as dips in a lamp's measured spectrum (≥ 3, else none)."""
    from scipy import ndimage, signal

    spectrum = observation.spectrum
    axis = np.arange(max(spectrum.range_nm[0], 380.0), min(spectrum.range_nm[1], 760.0), 0.25)
    if axis.size < 20:
        return ()
    values = spectrum.at(axis)
    envelope = values.copy()
    for _ in range(6):
        envelope = ndimage.gaussian_filter1d(np.maximum(envelope, values), 24.0)
    depth = 1.0 - values / np.maximum(envelope, 1e-300)
    peaks, _ = signal.find_peaks(depth, prominence=0.02)
    found_nm = axis[peaks]
    step = float(np.median(np.diff(spectrum.wavelength_nm)))
    tolerance = max(1.0, step)
    solar = line_list("solar")
    shown = [
        line
        for line in solar
        if found_nm.size and float(np.min(np.abs(found_nm - line.wavelength_nm))) <= tolerance
    ]
    # Lines closer than the spectrum's sampling merge into one of its dips: a line within that of
    # one shown is shown too (at 1 nm, Na D2 beside D1; without it D1 alone is fitted where the
    # pair's blend lies, 0.3 nm off — decision 0086).
    present = tuple(
        line
        for line in solar
        if any(abs(line.wavelength_nm - other.wavelength_nm) <= tolerance for other in shown)
    )
    # The partners are no evidence of dips: the count is of those found.
    return present if len(shown) >= MIN_SPECTRUM_DIPS else ()


def _dips_near_profile_fit(
    features: FeatureMapping | None,
    lamp: LampObservation,
    dips: Sequence[Line],
    prior: GratingPrior | None,
    profile_fit: ExactMapping,
    profile_sigma_nm: float | None,
    lead: LampObservation,
    grid: WavelengthGrid,
) -> tuple[FeatureMapping, FeatureMapping | None]:
    """The dips' mapping where the whole-profile fit is: a match made afresh (``features``; ``None``
    when none held) that lies further from it than :data:`DISAGREEMENT_NM` (RMS) and three of its
    stated σ (``profile_sigma_nm``: a fit that states 10 nm cannot overrule the dips) paired the
    dips with the wrong features (the solar list has many near-regular dips: on the validation
    analog, ``bench/solar_validate.py``, 4 of 44 cameras were 22–240 nm off with the profile fit
    within 1 nm, and one matched nothing), so the dips are fitted again from the profile fit
    itself; if that still lies beyond :data:`LINE_FIT_MAX_DISTANCE_NM`, an
    :class:`EstimationError` (the profile fit stands).

    When the fresh match explains the dips better than the refit (:func:`_dominates`), the
    profile fit is the one in the wrong basin (decision 0091: the 5D Mk II, Kawakami, without
    optics — the fit 14 nm off with σ 3.5 nm, its refit 4 dips to 517 nm at 0.35 nm, the fresh
    match 10 dips to 656 nm at 0.10 nm and right): the fresh match is returned with the refit as
    its competitor (the second element; ``None`` when there is none)."""
    probe = np.linspace(lead.pixel[0], lead.pixel[-1], 64)

    def apart(mapping: ExactMapping) -> float:
        difference = mapping.wavelength_nm(probe) - profile_fit.wavelength_nm(probe)
        return float(np.sqrt(np.mean(difference**2)))

    allowed = max(DISAGREEMENT_NM, 3.0 * (profile_sigma_nm or 0.0))
    if features is not None and apart(features.exact) <= allowed:
        # A runner-up of the dips' own match as well supported, which the profile fit does not
        # exclude either, is its competitor (decision 0112).
        rival = features.rival
        return features, rival if rival is not None and apart(rival.exact) <= allowed else None
    refitted = _map_lines(
        lamp,
        dips,
        prior,
        start=profile_fit,
        directions=(_direction(profile_fit, lead),),
        grid=grid,
    )
    distance = apart(refitted.exact)
    if distance > LINE_FIT_MAX_DISTANCE_NM:
        raise EstimationError(
            f"the dips, fitted from the whole-profile fit, lie {distance:.1f} nm (RMS) from it"
        )
    if features is not None and _dominates(features, refitted):
        # The dips, not the profile fit, decide between the two: the fresh match stands, the
        # refit is its competitor.
        return features, refitted
    return refitted, None


def _dominates(one: FeatureMapping, other: FeatureMapping) -> bool:
    """Whether ``one`` explains the dips better than ``other``: more of them used, fitted at most
    as far off (residual RMS). A wrong pairing of the solar list's near-regular dips can use more
    of them only by fitting them worse (the 10D, Kawakami, on the validation analog: 9 dips at
    2.0 nm against the right 7 at 0.76)."""
    residual, other_residual = (mapping.details.get("residual_rms_nm") for mapping in (one, other))
    if residual is None or other_residual is None:
        return False
    return _dips_used(one) > _dips_used(other) and float(residual) <= float(other_residual)


def _spanning(
    mapping: QuadraticMapping, other: QuadraticMapping, pixel_range: tuple[float, float]
) -> QuadraticMapping:
    """``mapping`` with a covariance that reaches ``other`` at every pixel: the coefficients'
    difference ``d`` added as ``d dᵀ`` (σ(p) ≥ |other(p) − mapping(p)|, the two candidates one σ
    apart wherever they differ — at the blue end when the dips there were paired differently)."""
    if mapping.covariance is None:
        return mapping
    difference = np.array([other.a - mapping.a, other.b - mapping.b, other.c - mapping.c])
    covariance = np.asarray(mapping.covariance, dtype=np.float64) + np.outer(difference, difference)
    return mapping.with_details(
        covariance=[[float(v) for v in row] for row in covariance],
        wavelength_rms_nm=wavelength_rms_from_covariance(covariance, pixel_range),
    )


def _dips_used(features: FeatureMapping) -> int:
    """How many of the dips a match used (its line fit's count)."""
    return sum(1 for match in features.matches if match.used)


def _hg_lines_shown(
    lamp: LampObservation, mapping: ExactMapping, grid: WavelengthGrid
) -> tuple[tuple[Line, ...], float, float]:
    """The built-in Hg lines near ``grid`` that a measured fluorescent lamp's spectrum shows
    (:func:`~calib.wavelength.features.lines_shown`), with the spectrum's resolution and the
    camera's (nm, FWHM; the camera's through ``mapping`` at the profile's middle).

    A camera feature where the list has a line the lamp lacks is a phosphor band's shape (the
    twin's FL2 has no 491.6, matched 1.0–1.5 nm off, nor 407.8, which moved the 404.7 blend's
    centre by 0.24 nm). A spectrum more than :data:`JUDGING_RESOLUTION` times coarser than the
    camera cannot tell: every line is kept then."""
    from calib.wavelength.features import lines_shown

    lines = tuple(
        line
        for line in line_list("hg")
        if grid.start_nm - 30.0 <= line.wavelength_nm <= grid.stop_nm + 30.0
    )
    width = fwhm_px(lamp) * float(np.median(np.diff(lamp.pixel)))
    middle = np.array([0.5 * (float(lamp.pixel[0]) + float(lamp.pixel[-1]))])
    camera_nm = width * abs(float(_local_dispersion(mapping, middle)[0]))
    spectrum = lamp.spectrum
    resolution_nm = max(
        lamp.spectrum_bandwidth_nm or 0.0, float(np.median(np.diff(spectrum.wavelength_nm)))
    )
    if resolution_nm <= JUDGING_RESOLUTION * camera_nm:
        lines = lines_shown(spectrum.wavelength_nm, spectrum.values, lines, resolution_nm)
    return lines, resolution_nm, camera_nm


def _known_line_table(
    lamp: LampObservation, mapping: ExactMapping, grid: WavelengthGrid
) -> tuple[list[dict[str, Any]], str | None]:
    """The built-in Hg lines fitted where ``mapping`` puts them (the mapping held): the matched-line
    table of a measured fluorescent lamp, and a note when they sit off by more than
    :data:`KNOWN_LINE_WARNING_NM` (a spectrum too coarse for its lines, or a wrong mapping).

    Only the lines the lamp's spectrum shows (:func:`~calib.wavelength.features.lines_shown`),
    where it resolves within :data:`JUDGING_RESOLUTION` of the camera (:func:`_measured_lines`'
    rule): a "line" the lamp lacks is a phosphor band's shape."""
    from calib.wavelength.features import feature_signal, features_at, fit_features

    width = fwhm_px(lamp)
    spacing = float(np.median(np.diff(lamp.pixel)))
    signal, noise = feature_signal(lamp.profile, "emission", width)
    pixel_range = (float(lamp.pixel[0]), float(lamp.pixel[-1]))
    lines, _, _ = _hg_lines_shown(lamp, mapping, grid)
    blends = features_at(lines, mapping, width * spacing, pixel_range)
    rows: list[dict[str, Any]] = []
    for fitted in fit_features(lamp.pixel, signal, noise, blends, mapping, width * spacing):
        reference = fitted.blend.reference
        at = float(mapping.wavelength_nm(np.array([fitted.pixel]))[0])
        rows.append(
            {
                "line": fitted.blend.label,
                "wavelength_nm": reference.wavelength_nm,
                "pixel": fitted.pixel,
                "fitted_nm": at,
                "residual_nm": at - reference.wavelength_nm,
                "weight": 0.0,  # not used by the mapping (the whole-profile fit is)
            }
        )
    off = [row for row in rows if abs(float(row["residual_nm"])) > KNOWN_LINE_WARNING_NM]
    note = None
    if off:
        worst = max(off, key=lambda row: abs(float(row["residual_nm"])))
        note = (
            f"its {worst['line']} line sits {float(worst['residual_nm']):+.2f} nm from where the "
            "mapping puts it: a lamp spectrum coarser than its lines biases the fit "
            "(--spectrum builtin:cfl-triphosphor, or a finer measurement, avoids it)"
        )
    return rows, note


#: Half width (nm) of the window around each strong Hg line in which the camera's profile and the
#: lamp's spectrum must each show one peak for :func:`_line_misplacement_nm` (a fit several nm off
#: still has the line inside; a second line or a phosphor peak inside makes the line unusable).
MISPLACEMENT_WINDOW_NM = 8.0
#: A second peak this prominent (fraction of the window's strongest) makes a window ambiguous.
SECOND_PEAK = 0.2


def _single_peak(values: FloatArray) -> float | None:
    """The sub-sample position (3-point parabola) of the one prominent peak of ``values``, or
    ``None`` when there is none or a second one at least :data:`SECOND_PEAK` as prominent."""
    from scipy import signal

    peaks, properties = signal.find_peaks(values, prominence=0.0)
    if peaks.size == 0:
        return None
    prominence = properties["prominences"]
    order = np.argsort(prominence)[::-1]
    if peaks.size > 1 and prominence[order[1]] >= SECOND_PEAK * prominence[order[0]]:
        return None
    top = int(peaks[order[0]])
    if top == 0 or top == values.size - 1:
        return None
    left, middle, right = values[top - 1 : top + 2]
    curvature = left - 2.0 * middle + right
    return float(top + (0.5 * (left - right) / curvature if curvature < 0 else 0.0))


def _line_misplacement_nm(
    lamp: LampObservation, mapping: ExactMapping, grid: WavelengthGrid
) -> float | None:
    """How far ``mapping`` puts a measured fluorescent lamp's strong Hg lines from where they are
    (RMS nm over the lines the camera shows alone within :data:`MISPLACEMENT_WINDOW_NM`), or
    ``None`` when no line qualifies.

    Where the lamp's spectrum resolves about as finely as the camera (the rule of
    :func:`_measured_lines`), a line is where the spectrum has it — the mapping's error at the line
    whatever the spectrum's scale or its table's nodes (the camera saw the lamp its spectrum
    describes); a coarser spectrum's centre sits on the phosphor band, and the list's wavelength is
    used (a tabulated lamp's lines are up to 1.1 nm from it: an upper bound then). A whole-profile
    fit that the lines could not correct states at least this (:func:`locate_mapping`)."""
    from calib.wavelength.features import feature_signal

    width = fwhm_px(lamp)
    spacing = float(np.median(np.diff(lamp.pixel)))
    pixel_range = (float(lamp.pixel[0]), float(lamp.pixel[-1]))
    middle = np.array([0.5 * (pixel_range[0] + pixel_range[1])])
    camera_nm = width * spacing * abs(float(_local_dispersion(mapping, middle)[0]))
    spectrum = lamp.spectrum
    axis = np.asarray(spectrum.wavelength_nm, dtype=np.float64)
    values = np.asarray(spectrum.values, dtype=np.float64)
    resolution_nm = max(lamp.spectrum_bandwidth_nm or 0.0, float(np.median(np.diff(axis))))
    judged = resolution_nm <= JUDGING_RESOLUTION * camera_nm
    profile_signal, _ = feature_signal(lamp.profile, "emission", width)
    at_nm = np.asarray(mapping.wavelength_nm(lamp.pixel), dtype=np.float64)
    misplaced = []
    for line in line_list("hg"):
        centre = line.wavelength_nm
        if line.strength < STRONG_LINE or not grid.start_nm <= centre <= grid.stop_nm:
            continue
        near_camera = np.flatnonzero(np.abs(at_nm - centre) <= MISPLACEMENT_WINDOW_NM)
        in_camera = _single_peak(profile_signal[near_camera]) if near_camera.size >= 3 else None
        if in_camera is None:
            continue
        spectrum_nm = centre
        if judged:
            near_spectrum = np.flatnonzero(np.abs(axis - centre) <= MISPLACEMENT_WINDOW_NM)
            in_spectrum = _single_peak(values[near_spectrum]) if near_spectrum.size >= 3 else None
            if in_spectrum is None:
                continue
            spectrum_nm = float(
                np.interp(in_spectrum, np.arange(near_spectrum.size), axis[near_spectrum])
            )
        camera_px = float(
            np.interp(in_camera, np.arange(near_camera.size), lamp.pixel[near_camera])
        )
        camera_nm_at = float(mapping.wavelength_nm(np.array([camera_px]))[0])
        misplaced.append(camera_nm_at - spectrum_nm)
    return float(np.sqrt(np.mean(np.square(misplaced)))) if misplaced else None


def _hg_reach_nm(
    lamp: LampObservation, mapping: ExactMapping, grid: WavelengthGrid
) -> tuple[float, float] | None:
    """The bluest and reddest Hg lines a measured fluorescent lamp shows inside ``grid``
    (:func:`_hg_lines_shown`) — how far its lines hold a whole-profile fit they did not correct
    (decision 0122) — or ``None`` with fewer than two."""
    lines, _, _ = _hg_lines_shown(lamp, mapping, grid)
    inside = [
        line.wavelength_nm for line in lines if grid.start_nm <= line.wavelength_nm <= grid.stop_nm
    ]
    return (min(inside), max(inside)) if len(inside) >= 2 else None


def _line_reach(
    reach_nm: tuple[float, float], exact: ExactMapping, lead: LampObservation
) -> LineReach:
    """The :class:`~calib.core.mapping.LineReach` of lines spanning ``reach_nm`` under ``exact``:
    in the quadratic family its curvature is the fit's own ``|a|`` (the departure from the
    straight continuation at the outermost line, decision 0122); in the physical family 0 (the
    grating equation, pinned by the 0th order, carries the mapping past the lines, and its
    covariance states how well)."""
    pixel = np.asarray(lead.pixel, dtype=np.float64)
    at_nm = np.asarray(exact.wavelength_nm(pixel), dtype=np.float64)
    order = np.argsort(at_nm)
    ends = np.interp(np.asarray(reach_nm), at_nm[order], pixel[order])
    curvature = abs(exact.a) if isinstance(exact, QuadraticMapping) else 0.0
    return LineReach(
        (float(min(ends)), float(max(ends))),
        (float(reach_nm[0]), float(reach_nm[1])),
        float(curvature),
    )


def _directions(lead: LampObservation, orientation: Orientation) -> tuple[int, ...]:
    if lead.pixel_origin == "direct_spot" or orientation == "rising":
        return (1,)
    if orientation == "falling":
        return (-1,)
    return (1, -1)


def locate_mapping(
    observations: LampObservation | Sequence[LampObservation],
    prior: CameraPrior,
    grid: WavelengthGrid,
    *,
    geometry: GratingPrior | None = None,
    grooves_per_mm: float | None = None,
    stored: RigGeometry | None = None,
    starts: Sequence[QuadraticMapping] | None = None,
    kernel: FloatArray | None = None,
    orientation: Orientation = "auto",
) -> MappingSolution:
    """The mapping shared by one geometry's lamps (see the module docstring).

    Parameters
    ----------
    observations
        The lamps, in one pixel frame.
    prior
        The camera prior on ``grid``.
    grid
        The working grid (the mapping must cover it).
    geometry
        A grating prior to use as is (else it is built from the rig: :func:`calib.wavelength.
        rig_prior.rig_prior`).
    grooves_per_mm
        The grating's nominal line density, when the rig's configuration gives it.
    stored
        The geometry of a grating file of the same rig.
    starts
        Starting mappings for the whole-profile search.
    kernel
        The camera's line spread in profile samples (default: the lamps').
    orientation
        ``"auto"`` tries both directions when the profiles' origin is arbitrary.

    Returns
    -------
    MappingSolution
    """
    lamps = [observations] if isinstance(observations, LampObservation) else list(observations)
    if not lamps:
        raise InputError("no lamp observations to find the mapping with", source="observations")
    lead = lamps[0]
    grating_prior, prior_source = _grating_prior_for(
        lead, geometry=geometry, grooves_per_mm=grooves_per_mm, stored=stored
    )
    directions = _directions(lead, orientation)
    warnings: list[str] = []
    line_lamps = [(lamp, lamp_lines(lamp)) for lamp in lamps]
    listed = [(lamp, lines) for lamp, lines in line_lamps if lines]
    measured = [lamp for lamp, lines in line_lamps if not lines]
    details: dict[str, Any] = {"rig_prior": prior_source}
    if lead.other_order is not None:
        # The −1 order in the frame measures the lens's focal length and the grating's tilt; it
        # is reported, not joined to the mapping's prior (decision 0197: on the test split that
        # left LED-only mappings pulled by a camera unlike the prior unwarned).
        other = other_order_geometry(lead)
        details["other_order"] = (
            {"refused": "the two first orders share too few lit samples to measure them"}
            if other is None
            else other.to_dict()
        )

    search = None
    # σ of a whole-profile fit that a measured lamp's lines could not correct, from how far it
    # misplaces them (when larger than the fit's own).
    fallback_sigma_nm: float | None = None
    # How far (nm) the lamp lines that hold the mapping reach (decision 0127).
    reach_nm: tuple[float, float] | None = None

    def profile_search() -> MappingSearch:
        return search_profiles(
            measured,
            prior,
            grid,
            geometry=grating_prior
            if grating_prior is not None and lead.pixel_origin == "direct_spot"
            else geometry,
            starts=starts,
            kernel=kernel if kernel is not None else camera_kernel(lamps),
            orientation=orientation,
        )

    if measured and not listed:
        search = profile_search()

    features: FeatureMapping | None = None
    # The dips' match near the profile fit when one that explains them better was kept.
    dips_competitor: FeatureMapping | None = None
    if listed:
        lamp, lines = max(listed, key=lambda item: len(item[1] or ()))
        assert lines is not None
        # The lines decide: a broadband lamp's whole-profile fit is not needed (nor trusted) to
        # start them.
        try:
            features = _map_lines(
                lamp, lines, grating_prior, start=None, directions=directions, grid=grid
            )
            details["line_source"] = f"{lamp.spectrum.name} (built-in list)"
        except EstimationError as alone:
            if not measured:
                raise
            # Too few of its lines above the noise to hold the family alone (a dim Hg 404.7:
            # 435.8, 546.1 and the 577/579 blend): the measured lamps' whole-profile fit holds
            # it, and the lines the lamp does show correct that fit — one fit of both.
            search = profile_search()
            features = _anchored_lines(lamp, lines, search, grating_prior, grid, lead, alone)
            details["line_source"] = (
                f"{lamp.spectrum.name} (built-in list) anchored to the whole-profile fit of "
                + ", ".join(other.name for other in measured)
            )
    elif search is not None:
        # A measured source that resolves absorption dips (sunlight at ≤ 1 nm) is refined
        # through them; a table coarser than its dips (D65's) would put them at its nodes.
        dipped = [
            (lamp, _spectrum_dips(lamp))
            for lamp in measured
            if lamp.kind != "fluorescent" and not coarse_spectrum(lamp, DIP_SAMPLING_NM)
        ]
        dipped = [(lamp, dips) for lamp, dips in dipped if dips]
        if dipped:
            lamp, dips = dipped[0]
            # The dips are matched afresh, in the fit's direction and near its dispersion: a
            # broadband fit can be a few nanometres off, more than a dip's width.
            middle = np.array([0.5 * (lead.pixel[0] + lead.pixel[-1])])
            try:
                fresh: FeatureMapping | None
                try:
                    fresh = _map_lines(
                        lamp,
                        dips,
                        grating_prior,
                        start=None,
                        directions=(_direction(search.exact, lead),),
                        grid=grid,
                        dispersion_nm_per_px=abs(float(_local_dispersion(search.exact, middle)[0])),
                    )
                except EstimationError:
                    fresh = None
                try:
                    features, competitor = _dips_near_profile_fit(
                        fresh,
                        lamp,
                        dips,
                        grating_prior,
                        search.exact,
                        search.mapping.wavelength_rms_nm,
                        lead,
                        grid,
                    )
                except EstimationError as refit_failed:
                    if fresh is None:
                        raise
                    # Nothing near the profile fit explains the dips (the validation analog's
                    # 5D Mk II with optics: the fit 13.5 nm off, the dips' own match 0.1 nm):
                    # their own match stands, and the disagreement with the fit is warned below.
                    features, competitor = fresh, None
                    warnings.append(
                        "the absorption dips match nothing near the whole-profile fit "
                        f"({refit_failed}): their own match stands"
                    )
                # The dips sit at the solar list's wavelengths, which the spectrum's scale does
                # not move (it only says which dips are there, to ≥ 1 nm).
                features.details["line_centres_from_spectrum"] = []
                details["line_source"] = f"absorption features of {lamp.name}"
                if competitor is not None:
                    dips_competitor = competitor
            except EstimationError as exc:
                warnings.append(f"the absorption refinement failed ({exc}); the profile fit stands")
        else:
            fluorescent = [lamp for lamp in measured if lamp.kind == "fluorescent"]
            if fluorescent:
                # A measured line lamp: its Hg lines decide, from the profile fit (decision
                # 0030). A coarse table nobody measured (no bandwidth: colour-science's 5 nm FL
                # tables) holds its lines at its nodes, not their wavelengths: the fit stands.
                lamp = fluorescent[0]
                try:
                    if lines_unplaced(lamp):
                        raise EstimationError(
                            "a coarse tabulated spectrum: the lines are its nodes"
                        )
                    features, start = _lines_from_basins(lamp, search, grating_prior, grid, lead)
                    details["line_source"] = f"Hg lines of {lamp.name} (measured lamp)"
                    try:
                        _check_line_fit(features, start, grating_prior, lead)
                        details["measured_lines"] = True
                    except EstimationError as refused:
                        # The lines still decide: on the validation split a line fit its checks
                        # refuse is nearer the truth than the profile fit (mapping mean 0.18 vs
                        # 0.28 nm, sensitivity RE 5.37 vs 5.53 ×10⁻²); the refusal is recorded.
                        details["line_checks_failed"] = str(refused)
                except EstimationError as exc:
                    # The profile fit stands; its known lines say how well (a note, not a
                    # warning — a rendered lamp table's lines sit at its nodes).
                    table, note = _known_line_table(lamp, search.exact, grid)
                    misplaced_nm = _line_misplacement_nm(lamp, search.exact, grid)
                    details["matched_lines"] = table
                    details["measured_lines_failed"] = str(exc)
                    stated_nm = search.mapping.wavelength_rms_nm
                    if misplaced_nm is not None and stated_nm is not None:
                        # The lines were not used, but they still say how far off the fit is
                        # at them: its σ is at least that (never 0.2 nm for a 4 nm error).
                        details["line_misplacement_nm"] = misplaced_nm
                        if misplaced_nm > stated_nm:
                            fallback_sigma_nm = misplaced_nm
                    if note:
                        details["known_lines_note"] = f"lamp {lamp.name!r}: {note}"
                    if isinstance(search.exact, QuadraticMapping) and stated_nm is not None:
                        # The quadratic family: past the lines the lamp shows the fit's
                        # curvature is held by nothing (the mapping's line reach, decision
                        # 0127); a grating family's is its geometry's (the 0th order pins it).
                        reach_nm = _hg_reach_nm(lamp, search.exact, grid)
                    slit_nm = max(other.spectrum_bandwidth_nm or 0.0 for other in measured)
                    if slit_nm > COARSE_SLIT_NM:
                        # Nothing corrects a whole-profile fit through a broad slit: its model
                        # drops the slit's second-order terms, which at 25 nm are the size of
                        # the camera's flanks, and the fit stretches the mapping for them (the
                        # twin's i1Pro in standard bands: 4–14 nm off at the red end). Its σ is
                        # at least the slit's own σ, and the user is told.
                        slit_sigma_nm = slit_nm / FWHM_PER_SIGMA
                        fallback_sigma_nm = max(
                            fallback_sigma_nm or 0.0, stated_nm or 0.0, slit_sigma_nm
                        )
                        warnings.append(
                            f"the mapping rests on the whole-profile fit alone: {lamp.name}'s "
                            f"lines could not be matched, and its spectrum's {slit_nm:g} nm slit "
                            f"leaves that fit several nm uncertain (σ {slit_sigma_nm:.1f} nm, "
                            "most at the red end); measure the lamps through a finer slit "
                            "(spotread -H, high_resolution: true, or a spectrometer of ≤ "
                            f"{COARSE_SLIT_NM:g} nm)"
                        )

    extrapolated: list[str] = []
    ambiguity_warnings: list[str] = []
    imprecise_warnings: list[str] = []
    if features is not None:
        mapping, exact = features.mapping, features.exact
        details.update(features.details)
        details["ambiguous"] = False
        if search is not None and search.warnings:
            # The lines decided: the whole-profile fit's competing basins only started them, so
            # they are recorded, not warned about (the warning would ask for the line lamp used).
            details["profile_fit_warnings"] = list(search.warnings)
        # A measured spectrum's scale moves what it placed (its dips, its line centres), not the
        # Hg lines the list places (decision 0050: on the twin's PR-655 every line was the list's,
        # and the scale made the stated σ 2.2× the actual error).
        by_spectrum = features.details.get("line_centres_from_spectrum", True)
        if by_spectrum:
            # Lines placed by a measured spectrum carry its wavelength scale (a common offset).
            offset_nm = (
                spectrometer_scale_sigma_nm(lamps, placed_by_features=True)
                if search is not None
                else 0.0
            )
            offset_key = "spectrometer_scale_sigma_nm"
        else:
            # The list's lines as the camera sees them are off by a little more than the fit
            # states (decision 0050): a common floor, judged on the validation split.
            offset_nm = LISTED_LINES_FLOOR_NM if search is not None else 0.0
            offset_key = "listed_lines_floor_nm"
        if offset_nm > 0 and mapping.wavelength_rms_nm is not None:
            mapping = stated_covariance(
                mapping,
                math.hypot(mapping.wavelength_rms_nm, offset_nm),
                offset_nm,
                (float(lead.pixel[0]), float(lead.pixel[-1])),
            )
            details[offset_key] = offset_nm
        if dips_competitor is not None:
            # Two assignments of the dips, the profile fit against the better one: ambiguous, the
            # other in the result and the stated σ reaching it (never 2 nm for a 14 nm error).
            probe = np.linspace(lead.pixel[0], lead.pixel[-1], 64)
            competing_nm = float(
                np.sqrt(
                    np.mean(
                        (exact.wavelength_nm(probe) - dips_competitor.exact.wavelength_nm(probe))
                        ** 2
                    )
                )
            )
            mapping = _spanning(
                mapping, dips_competitor.mapping, (float(lead.pixel[0]), float(lead.pixel[-1]))
            )
            stated_nm = mapping.wavelength_rms_nm or competing_nm
            details["ambiguous"] = True
            details["dips_competitor"] = {
                "mapping": dips_competitor.mapping.to_dict(),
                "distance_nm": competing_nm,
                "dips_used": _dips_used(dips_competitor),
                "dips_used_kept": _dips_used(features),
            }
            ambiguity_warnings.append(
                f"the mapping is ambiguous: the absorption dips also match {competing_nm:.1f} nm "
                f"away (RMS) ({_dips_used(dips_competitor)} of them "
                f"against the {_dips_used(features)} used); both are in the result and the stated "
                f"σ ({stated_nm:.1f} nm) spans them. "
                + deciding_shot(lamps)
                + " So does the camera's optics (EXIF focal length)."
            )
        used = [m.wavelength_nm for m in features.matches if m.used]
        if used:
            reach_nm = (min(used), max(used))
        if search is not None:
            probe = np.linspace(lead.pixel[0], lead.pixel[-1], 64)
            apart = float(
                np.sqrt(
                    np.mean((exact.wavelength_nm(probe) - search.exact.wavelength_nm(probe)) ** 2)
                )
            )
            details["profile_fit_distance_nm"] = apart
            details["profile_fit"] = search.mapping.to_dict()
            # A measured lamp's profile fit is only the lines' start: its distance is recorded.
            if apart > DISAGREEMENT_NM and "measured_lines" not in details:
                warnings.append(
                    f"the lines and the whole-profile fit disagree by {apart:.1f} nm (RMS); the "
                    "lines are used — check that the lamp spectra are the lamps'"
                )
    else:
        assert search is not None
        mapping, exact = search.mapping, search.exact
        details.update(search.details)
        warnings += list(search.warnings)
        if fallback_sigma_nm is not None:
            mapping = stated_covariance(
                mapping,
                fallback_sigma_nm,
                float(search.details.get("spectrometer_scale_sigma_nm", 0.0)),
                (float(lead.pixel[0]), float(lead.pixel[-1])),
            )
            details["profile_fit_sigma_nm"] = search.mapping.wavelength_rms_nm
            details["wavelength_rms_from"] = "the measured lamp's lines, misplaced by the fit"
        if (
            stored is None
            and geometry is None
            and all(lamp.kind != "fluorescent" for lamp in measured)
        ):
            # Judged with the rig's own incidence prior only (a grating file's reused incidence
            # has a σ of a fraction of a degree: not judged).
            conflict = _incidence_conflict(
                search, mapping, (float(lead.pixel[0]), float(lead.pixel[-1]))
            )
            if conflict is not None:
                mapping, text = conflict
                details["ambiguous"] = True
                details["incidence_conflict_sigmas"] = _incidence_sigmas(search)
                ambiguity_warnings.append(text)
        if (
            isinstance(search.exact, QuadraticMapping)
            and search.exact.model is None
            and all(lamp.kind != "fluorescent" for lamp in measured)
        ):
            mapping, exact = _quadratic_coarse_check(
                search,
                mapping,
                measured,
                prior,
                grid,
                kernel if kernel is not None else camera_kernel(lamps),
                details,
                ambiguity_warnings,
            )
            if not details.get("ambiguous") and all(lamp.kind != "fluorescent" for lamp in lamps):
                # One basin, but the likelihood holds an end too loosely for the 3 nm
                # (decision 0158).
                imprecise = _imprecise_end(mapping, lead, grid)
                details["imprecise_end"] = imprecise
                if imprecise is not None:
                    details["ambiguous"] = True
                    imprecise_warnings.append(_imprecise_warning(imprecise, lamps, grid))
    _check_monotonic(exact, lead)
    if reach_nm is not None:
        # One σ past the lines for every consumer: the mapping carries it (decision 0127).
        mapping = mapping.with_line_reach(_line_reach(reach_nm, exact, lead))
        red_end, note = _red_end(mapping, grid)
        details["red_end"] = red_end
        if note:
            extrapolated.append(note)
    # The quality code of each warning (calib.core.result.QUALITY_CODES): the profile search warns
    # only of competing basins; this function's own warnings are about the lines against the fit,
    # and about a mapping extrapolated beyond its lines.
    warnings += ambiguity_warnings
    ambiguity = set(search.warnings) if search is not None else set()
    ambiguity |= set(ambiguity_warnings)
    details["warning_codes"] = (
        [
            "mapping_ambiguous" if text in ambiguity else "mapping_line_residuals"
            for text in warnings
        ]
        + ["mapping_imprecise"] * len(imprecise_warnings)
        + ["mapping_extrapolated"] * len(extrapolated)
    )
    warnings += imprecise_warnings + extrapolated
    details["warnings"] = warnings
    mapping = mapping.with_details(details={**dict(mapping.details), **details})
    return MappingSolution(mapping, exact, tuple(warnings), details)


#: A broadband-only mapping whose grating incidence lies further than this many of the rig prior's
#: σ from its mean conflicts with the prior (the prior, 0 ± 5° without a grating file, is what a rig
#: that faces the grating to the lens holds: :data:`calib.wavelength.rig_prior.INCIDENCE_PRIOR_DEG`).
#: Five σ is the conventional bar for a prior–data conflict, not a tuned value. Without EXIF the
#: incidence and focal length trade against each other along the profile, and a camera prior that
#: does not describe the camera's red cut-off uses that freedom to bend the red end (decision 0118:
#: the validation split's two silent wrong LED-only mappings, 5–6 nm off at the red end, sat at
#: −29° and −33°; of the right ones of the 44 leave-one-body-out and 100 predicted cameras, with or
#: without EXIF, none unwarned beyond 19°, one already warned at 28–31°). The result is then
#: ambiguous and its σ reaches the nearest other basin.
INCIDENCE_CONFLICT_SIGMAS = 5.0


def _incidence_sigmas(search: MappingSearch) -> float | None:
    """How many of the rig prior's σ the search's grating incidence lies from the prior's mean
    (``None`` for a quadratic mapping or a prior without an incidence)."""
    exact = search.exact
    values = search.details.get("grating_prior", {}).get("values", {})
    incidence = values.get("incidence_deg")
    if not isinstance(exact, TiltedGrating) or incidence is None or not incidence[1] > 0:
        return None
    return abs(exact.incidence_deg - float(incidence[0])) / float(incidence[1])


def _incidence_conflict(
    search: MappingSearch, mapping: QuadraticMapping, pixel_range: tuple[float, float]
) -> tuple[QuadraticMapping, str] | None:
    """A broadband-only search's mapping whose incidence conflicts with the rig's prior
    (:data:`INCIDENCE_CONFLICT_SIGMAS`), not already warned of: the mapping with its σ reaching
    half-way to the nearest other basin (the search's candidates, all in the result) and the
    warning; ``None`` when there is no conflict."""
    sigmas = _incidence_sigmas(search)
    if sigmas is None or sigmas <= INCIDENCE_CONFLICT_SIGMAS or search.ambiguous:
        return None
    assert isinstance(search.exact, TiltedGrating)
    others = [c.distance_nm for c in search.candidates[1:]]
    stated = mapping.wavelength_rms_nm or 0.0
    widened = "no other basin was found"
    if others:
        nearest = min(others)
        stated = max(stated, 0.5 * nearest)
        mapping = stated_covariance(
            mapping,
            stated,
            float(search.details.get("spectrometer_scale_sigma_nm", 0.0)),
            pixel_range,
        )
        widened = (
            f"the nearest other basin, {nearest:.1f} nm away (RMS), is among the result's "
            f"candidates and the stated σ ({stated:.1f} nm) reaches half-way to it"
        )
    return mapping, (
        f"the mapping is ambiguous: its grating incidence ({search.exact.incidence_deg:+.0f}°) "
        f"lies {sigmas:.1f}σ from the rig's prior — with a broadband lamp alone the camera "
        f"prior's shape bends the red end where the camera is unlike it; {widened}. "
        + deciding_shot(())  # broadband lamps alone (its caller's condition)
    )


def _quadratic_coarse_check(
    search: MappingSearch,
    mapping: QuadraticMapping,
    lamps: Sequence[LampObservation],
    prior: CameraPrior,
    grid: WavelengthGrid,
    kernel: FloatArray | None,
    details: dict[str, Any],
    ambiguity_warnings: list[str],
) -> tuple[QuadraticMapping, ExactMapping]:
    """A broadband-only quadratic answer, not already warned of, that the coarse view rejects
    (:mod:`calib.wavelength.quadratic_view`, decision 0133). The coarse view's basin is weighed on
    the search's final stage (:func:`~calib.wavelength.quadratic_view.final_verdict`, decision
    0139): when that stage prefers it by the search's bar, it is the answer (:func:`_adopted`);
    else the answer is ambiguous, the basin a candidate (``coarse_view_delta_chi2``,
    ``rms_distance_nm``) and the stated σ reaching half-way to it. The verdicts are in
    ``details["quadratic_coarse_view"]``. Returns the mapping (σ widened, replaced, or as it was)
    and its exact form. An answer warned already is not asked (its σ reaches its rival)."""
    assert isinstance(search.exact, QuadraticMapping)
    if details.get("ambiguous"):
        return mapping, search.exact
    view, evaluations = quadratic_coarse_view(lamps, prior, grid, search.exact, kernel=kernel)
    if view is None:
        return mapping, search.exact
    details["quadratic_coarse_view"] = {
        "delta_chi2": view.delta_chi2,
        "distance_nm": view.distance_nm,
        "rejects": view.rejects,
        "evaluations": evaluations,
        "adopted": False,
    }
    if not view.rejects:
        return mapping, search.exact
    verdict = final_verdict(lamps, prior, grid, search.exact, view.x, kernel=kernel)
    if verdict is not None:
        details["quadratic_coarse_view"].update(
            final_delta_chi2=verdict.delta_chi2,
            final_temper=verdict.temper,
            evaluations=evaluations + verdict.evaluations,
        )
        if verdict.adopts:
            return _adopted(search, verdict, lamps, view.delta_chi2, details, ambiguity_warnings)
    pixel_range = (float(lamps[0].pixel[0]), float(lamps[0].pixel[-1]))
    family = QuadraticFamily(pixel_range)
    other = family.mapping(view.x)
    stated = max(mapping.wavelength_rms_nm or 0.0, 0.5 * view.distance_nm)
    mapping = stated_covariance(
        mapping,
        stated,
        float(search.details.get("spectrometer_scale_sigma_nm", 0.0)),
        pixel_range,
    )
    details["ambiguous"] = True
    probe = np.linspace(pixel_range[0], pixel_range[1], 5)
    details["candidates"] = [
        *details.get("candidates", []),
        {
            "mapping": other.to_dict(),
            "coarse_view_delta_chi2": view.delta_chi2,
            "rms_distance_nm": view.distance_nm,
            "wavelength_at_pixels_nm": {
                f"{p:g}": float(w) for p, w in zip(probe, other.wavelength_nm(probe), strict=True)
            },
        },
    ]
    ambiguity_warnings.append(
        f"the mapping is ambiguous: on the coarser profile ({GLOBAL_BIN_NM:g} nm bins) where the "
        f"search found its basins, the same model has a basin {view.distance_nm:.1f} nm away "
        f"(RMS) that puts this answer Δχ² {view.delta_chi2:.0f} behind it (above "
        f"{AMBIGUITY_DELTA_CHI2:g}); it is among the result's candidates and the stated σ "
        f"({stated:.1f} nm) reaches half-way to it. " + deciding_shot(lamps)
    )
    return mapping, search.exact


#: A broadband-only mapping whose stated ±2σ exceeds the bar for a wrong mapping
#: (:data:`calib.core.result.MAPPING_FAILURE_NM`) somewhere on the working grid is not one a user
#: can take as right: it warns even when no other basin competes (decision 0158), under its own
#: quality code ``mapping_imprecise`` (decision 0166).
#: Pixels (over the lead profile) at which the stated σ is read for :func:`_imprecise_end`.
IMPRECISE_PROBE_PIXELS = 129


def _imprecise_end(
    mapping: QuadraticMapping, lead: LampObservation, grid: WavelengthGrid
) -> dict[str, float] | None:
    """Where on the working grid the mapping's stated ±2σ is widest, when it exceeds
    :data:`MAPPING_FAILURE_NM`: ``{"wavelength_nm", "sigma_nm", "pixel"}``, else ``None``
    (or when the mapping states no per-pixel σ). Only the profile's pixels the mapping puts on
    the grid are read: beyond the profile nothing is measured."""
    pixel = np.linspace(float(lead.pixel[0]), float(lead.pixel[-1]), IMPRECISE_PROBE_PIXELS)
    sigma = mapping.sigma_nm(pixel)
    if sigma is None:
        return None
    wavelength = mapping.wavelength_nm(pixel)
    on_grid = (wavelength >= grid.start_nm) & (wavelength <= grid.stop_nm)
    if not on_grid.any():
        return None
    k = int(np.argmax(np.where(on_grid, sigma, -np.inf)))
    if 2.0 * float(sigma[k]) <= MAPPING_FAILURE_NM:
        return None
    return {
        "wavelength_nm": float(wavelength[k]),
        "sigma_nm": float(sigma[k]),
        "pixel": float(pixel[k]),
    }


def _imprecise_warning(
    imprecise: dict[str, float], lamps: Sequence[LampObservation], grid: WavelengthGrid
) -> str:
    """The user's sentence for :func:`_imprecise_end`'s finding, naming the end (the half of the
    working grid it lies in)."""
    wavelength = imprecise["wavelength_nm"]
    where = "blue" if wavelength < 0.5 * (grid.start_nm + grid.stop_nm) else "red"
    return (
        f"the mapping is imprecise at its {where} end: its stated σ there is "
        f"{imprecise['sigma_nm']:.1f} "
        f"nm (at {wavelength:.0f} nm), so ±2σ spans more than {MAPPING_FAILURE_NM:g} nm either "
        f"way: with {lamps[0].name}'s light alone the likelihood holds that end only loosely, and "
        "the sensitivity's flanks there may be shifted by as much. " + deciding_shot(lamps)
    )


def _adopted(
    search: MappingSearch,
    verdict: FinalVerdict,
    lamps: Sequence[LampObservation],
    coarse_delta_chi2: float,
    details: dict[str, Any],
    ambiguity_warnings: list[str],
) -> tuple[QuadraticMapping, QuadraticMapping]:
    """The coarse view's basin as the answer, the final stage preferring it (decision 0139): its
    report form, curvature and stated σ as the search states its own answer's
    (:func:`~calib.wavelength.profile_search.basin_sigma` over the two basins, weighed on the final
    stage with its temper; the camera prior's pull from that temper), the search's answer the
    second candidate. Ambiguous (warned, σ half-way to it) when the search's first answer stays
    within the search's ambiguity bar (``details["ambiguity_delta_chi2"]``) of it. The search's
    other candidates follow, their distances to the new answer, their Δχ² as the search stated
    them (behind its first answer on the deciding stage: none within its bar and > 1 nm away,
    or it would have warned)."""
    assert isinstance(search.exact, QuadraticMapping)
    pixel_range = (float(lamps[0].pixel[0]), float(lamps[0].pixel[-1]))
    family = QuadraticFamily(pixel_range)
    solution = verdict.rival
    exact = family.mapping(solution.x)
    mapping, local_rms = _report(
        exact,
        family,
        solution.x,
        solution.covariance(),
        pixel_range,
        str(details.get("origin", "")),
    )
    probe = np.linspace(pixel_range[0], pixel_range[1], 64)
    exact_probe = exact.wavelength_nm(probe)

    def distance(other: ExactMapping) -> float:
        return float(np.sqrt(np.mean((other.wavelength_nm(probe) - exact_probe) ** 2)))

    first = Candidate(
        search.exact,
        verdict.answer_cost,
        verdict.delta_chi2,
        float(math.exp(-0.5 * verdict.delta_chi2 / BASIN_TEMPER)),
        distance(search.exact),
    )
    candidates = [Candidate(exact, verdict.rival_cost, 0.0, 1.0, 0.0), first]
    scale_nm = float(search.details.get("spectrometer_scale_sigma_nm", 0.0))
    bar = float(details.get("ambiguity_delta_chi2", BROADBAND_AMBIGUITY_DELTA_CHI2))
    sigma = basin_sigma(
        candidates,
        local_nm=LOCAL_SIGMA_SCALE * local_rms,
        scale_nm=scale_nm,
        misfit_nm=prior_misfit_sigma_nm(verdict.temper, local_rms),
        ambiguity_delta_chi2=bar,
    )
    mapping = stated_covariance(mapping, sigma.stated_nm, scale_nm, pixel_range)
    others = []
    for candidate in search.candidates[1:]:
        entry = candidate.to_dict(pixel_range)
        entry["rms_distance_nm"] = distance(candidate.mapping)
        entry["delta_chi2_behind"] = "the search's first answer, on its deciding stage"
        others.append(entry)
    details.update(
        candidates=[c.to_dict(pixel_range) for c in candidates] + others,
        final_cost=verdict.rival_cost,
        reduced_chi2=verdict.rival_cost / solution.dof,
        temper=verdict.temper,
        basin_spread_nm=sigma.spread_nm,
        local_rms_nm=local_rms,
        prior_misfit_sigma_nm=sigma.misfit_nm,
        ambiguous=sigma.competing is not None,
        profile_fit=search.mapping.to_dict(),
    )
    details["quadratic_coarse_view"]["adopted"] = True
    if sigma.competing is not None:
        ambiguity_warnings.append(
            f"the mapping is ambiguous: the search's basin, {first.distance_nm:.1f} nm away (RMS), "
            f"stood Δχ² {coarse_delta_chi2:.0f} behind this one on the coarser profile "
            f"({GLOBAL_BIN_NM:g} nm bins) where the search found its basins, and this one fits "
            f"the full-resolution profile better by Δχ² {verdict.delta_chi2:.0f} (tempered; "
            f"ambiguous below {bar:g}); both are in the result and the stated σ "
            f"({sigma.stated_nm:.1f} nm) spans them. " + deciding_shot(lamps)
        )
    return mapping, exact


#: A measured spectrum's single Hg line this far (nm, beyond twice its σ) from its wavelength means
#: the spectrum is not a real lamp's on a right scale (compact spectrometers: ±0.5 nm).
LINE_SCALE_TOLERANCE_NM = 0.5
#: Listed strength (:data:`calib.core.line_lists.MERCURY`) of the Hg lines a spectrum judges.
STRONG_LINE = 1000.0
#: ... judged only by a spectrum at most this many times the camera's resolution (FWHM, nm).
JUDGING_RESOLUTION = 2.0


def _lines_from_basins(
    lamp: LampObservation,
    search: MappingSearch,
    prior: GratingPrior | None,
    grid: WavelengthGrid,
    lead: LampObservation,
) -> tuple[FeatureMapping, ExactMapping]:
    """:func:`_measured_lines` from the whole-profile fit, else from each of its other basins in
    order of fit. The fit only starts the lines, and a broad slit biases it: the twin's i1Pro in
    standard bands (25 nm) put its best basin 4 nm off at 550 nm (14 nm at the red end), too far
    for the lines to match, the next one 2 nm. A line fit from another basin is kept only when it
    passes :func:`_check_line_fit` against that basin (the best basin's is kept as before, its
    refusal recorded), and only from a basin the profiles do not rule out: one more than
    :data:`~calib.wavelength.profile_search.HOPELESS_DELTA_CHI2` behind (tempered, its closest
    Δχ²; decision 0065: none came back) matches a few lines to the wrong features (decision
    0066: Hg 491.6 and the 577/579 pair, 13.7 nm off, from a basin 15 000 behind). Returns the
    line fit and the start it came from; the best basin's error when none matches."""
    try:
        return _measured_lines(lamp, search.exact, prior, grid), search.exact
    except EstimationError as first:
        for candidate in search.candidates[1:]:
            if candidate.delta_chi2 > HOPELESS_DELTA_CHI2:
                continue
            try:
                features = _measured_lines(lamp, candidate.mapping, prior, grid)
                _check_line_fit(features, candidate.mapping, prior, lead)
            except EstimationError:
                continue
            return features, candidate.mapping
        raise first


def _anchored_lines(
    lamp: LampObservation,
    lines: Sequence[Line],
    search: MappingSearch,
    prior: GratingPrior | None,
    grid: WavelengthGrid,
    lead: LampObservation,
    alone: EstimationError,
) -> FeatureMapping:
    """A listed lamp's lines fitted jointly with the measured lamps' whole-profile fit
    (:class:`~calib.wavelength.features.ProfileAnchor`): from the fit's best basin, else from
    each other basin the profiles do not rule out (:func:`_lines_from_basins`' rule). ``alone``
    is why the lines could not hold the mapping by themselves (raised with the joint fit's error
    when that fails too)."""
    pixel_range = (float(lead.pixel[0]), float(lead.pixel[-1]))
    # Another basin is placed with the best one's covariance (the search states only that).
    starts = [search.exact] + [
        candidate.mapping
        for candidate in search.candidates[1:]
        if candidate.delta_chi2 <= HOPELESS_DELTA_CHI2
    ]
    errors: list[str] = []
    for start in starts:
        try:
            return _map_lines(
                lamp,
                lines,
                prior,
                start=start,
                directions=(_direction(start, lead),),
                grid=grid,
                anchor=ProfileAnchor.from_mapping(search.mapping, pixel_range, start),
            )
        except EstimationError as exc:
            errors.append(str(exc))
    raise EstimationError(
        f"{alone}; anchored to the whole-profile fit: {'; '.join(errors) or 'no fit with a σ'}"
    )


def _measured_lines(
    lamp: LampObservation,
    start: ExactMapping,
    prior: GratingPrior | None,
    grid: WavelengthGrid,
) -> FeatureMapping:
    """A measured fluorescent lamp's Hg lines through the physical family, from ``start`` (the
    whole-profile fit), each feature at its first moment (decision 0030).

    Every fluorescent lamp has the Hg lines, at wavelengths the physics fixes; the whole-profile
    fit, which the camera prior's misfit bends by nanometres, only starts them. The camera finds
    them (only those it finds are used) and the list places them: a single line at its
    wavelength, a blend the camera cannot resolve (577.0 + 579.1) at its list centre with σ for
    the split nobody listed (span/√12). Where the lamp's measured spectrum resolves at least as
    finely as the camera, it places the single lines instead (a tabulated lamp's sit at its
    nodes); a coarser one's centre of a line on a phosphor band's flank was 0.4–0.8 nm off on
    the twin's PR-655, and the blends' it measured (578.19 nm for the twin's doublet, right) met a
    camera moment 0.3 nm off: those stay with the list."""
    from calib.wavelength.features import features_at, spectrum_line_centres

    width = fwhm_px(lamp) * float(np.median(np.diff(lamp.pixel)))
    pixel_range = (float(lamp.pixel[0]), float(lamp.pixel[-1]))
    lines, resolution_nm, camera_nm = _hg_lines_shown(lamp, start, grid)
    spectrum = lamp.spectrum
    measured = spectrum_line_centres(
        spectrum.wavelength_nm,
        spectrum.values,
        features_at(lines, start, width, pixel_range),
        resolution_nm,
    )
    listed = {line.label: line.wavelength_nm for line in lines}
    # Only the strong lines every fluorescent lamp shows (404.7, 435.8, 546.1): a weak one's
    # "centre" in a spectrum without it is the band's.
    strong = {line.label for line in lines if line.strength >= STRONG_LINE}
    measured = {label: value for label, value in measured.items() if label in strong}
    # A spectrum blurred far more than the camera's profile cannot judge (the i1Pro's 15 nm put
    # 546.1 on the halophosphate band 3.8 nm off).
    judged = measured if resolution_nm <= JUDGING_RESOLUTION * camera_nm else {}
    for label, (centre_nm, sigma_nm) in judged.items():
        # A lamp whose spectrum does not put its lines where mercury has them (a tabulated lamp's
        # nodes: colour-science's FL tables, the validation protocol's; a wrong scale) is not
        # placed by the list: the profile fit, which matches the spectrum, stands.
        if abs(centre_nm - listed[label]) > LINE_SCALE_TOLERANCE_NM + 2.0 * sigma_nm:
            raise EstimationError(
                f"its spectrum puts {label} at {centre_nm:.2f} nm, not where mercury has it "
                f"({listed[label]:.2f} nm): a tabulated lamp or a shifted scale"
            )
    centres = measured if resolution_nm <= camera_nm else {}
    features = _map_lines(
        lamp,
        lines,
        prior,
        start=start,
        directions=(_direction(start, lamp),),
        grid=grid,
        moments=True,
        centres=centres,
    )
    # Lines the list places sit where mercury has them, whatever the spectrometer's scale: only
    # centres read off the measured spectrum carry it (the mapping's σ, decision 0050).
    features.details["line_centres_from_spectrum"] = sorted(centres)
    return features


#: σ (nm, a common offset) added to a measured fluorescent lamp's mapping whose Hg lines the list
#: placed: without it the stated σ held 73.9 % of the validation split's LED+FL mapping errors at
#: ±2σ (actual/stated median 0.78); with 0.05 nm 93.5 % (0.75), with 0.1 nm 98.9 % (0.67)
#: (decision 0050; 40 of 44 scenes list-placed).
LISTED_LINES_FLOOR_NM = 0.05


#: A measured lamp's line fit is kept only with its incidence within this many σ of the rig's prior
#: and within this RMS distance (nm) of the whole-profile fit it started from. Chosen on the
#: validation split's LED+FL scenes (their FL2 is a 5 nm table, whose lines sit at its nodes: with
#: three lines a fit reached −44° and 6 nm at the red end, another matched a line 6 nm off and was
#: 10 nm from the profile fit) and the twin (its profile fits 2.1–3.3 nm away, lines within 2σ).
LINE_FIT_INCIDENCE_SIGMAS = 2.0
LINE_FIT_MAX_DISTANCE_NM = 5.0


def _check_line_fit(
    features: FeatureMapping,
    start: ExactMapping,
    prior: GratingPrior | None,
    lead: LampObservation,
) -> None:
    """An :class:`EstimationError` when a measured lamp's line fit is not physically plausible
    (incidence beyond :data:`LINE_FIT_INCIDENCE_SIGMAS` of the prior) or lies further than
    :data:`LINE_FIT_MAX_DISTANCE_NM` (RMS) from the whole-profile fit: too few or wrong lines."""
    exact = features.exact
    incidence = None if prior is None else prior.values.get("incidence_deg")
    if isinstance(exact, TiltedGrating) and incidence is not None and incidence[1] > 0:
        deviation = abs(exact.incidence_deg - incidence[0]) / incidence[1]
        if deviation > LINE_FIT_INCIDENCE_SIGMAS:
            raise EstimationError(
                f"the line fit's incidence {exact.incidence_deg:+.1f}° is {deviation:.1f}σ from "
                "the rig's prior (too few lines to hold the grating)"
            )
    probe = np.linspace(lead.pixel[0], lead.pixel[-1], 64)
    apart = float(np.sqrt(np.mean((exact.wavelength_nm(probe) - start.wavelength_nm(probe)) ** 2)))
    if apart > LINE_FIT_MAX_DISTANCE_NM:
        raise EstimationError(
            f"the line fit lies {apart:.1f} nm (RMS) from the whole-profile fit (a line matched "
            "to the wrong feature)"
        )


#: σ (nm) of a mapping's extrapolation past its lamp's reddest line, at the working grid's red
#: end, beyond which it is reported (a 1 nm shift moves a camera's steep flanks by several per
#: cent).
EXTRAPOLATED_SIGMA_NM = 1.0


def _red_end(mapping: QuadraticMapping, grid: WavelengthGrid) -> tuple[dict[str, Any], str | None]:
    """How far the lines reach and the mapping's stated σ (:meth:`~calib.core.mapping.
    QuadraticMapping.sigma_nm`: the covariance's and the extrapolation past the lines) at the
    grid's ends; a note when what carries the mapping past its reddest line leaves it uncertain
    by more than :data:`EXTRAPOLATED_SIGMA_NM` at the grid's red end: in the quadratic family the
    line reach's term (the curvature nothing holds there), in the physical family the grating
    equation, whose σ there is its covariance's (the reach's term is 0)."""
    reach = mapping.line_reach
    if reach is None or mapping.covariance is None:
        return {}, None
    lines = reach.wavelength_range_nm
    ends = np.array([grid.start_nm, grid.stop_nm])
    try:
        pixel = np.asarray(mapping.pixel_at(ends), dtype=np.float64)
    except InputError:
        pixel = np.full(2, np.nan)
    stated = mapping.sigma_nm(pixel)
    assert stated is not None
    sigma = [float(v) for v in stated]
    extrapolation = [float(v) for v in reach.sigma_nm(pixel)]
    quadratic = reach.curvature_nm_per_px2 > 0
    carried_nm = extrapolation[1] if quadratic else sigma[1]
    record = {
        "lines_reach_nm": list(lines),
        "sigma_at_grid_ends_nm": sigma,
        "extrapolation_at_grid_ends_nm": extrapolation,
        "grid_ends_nm": [float(v) for v in ends],
    }
    if not (carried_nm > EXTRAPOLATED_SIGMA_NM and grid.stop_nm > lines[1]):
        return record, None
    if quadratic:
        how = f"by the quadratic fit, whose curvature no line holds there (σ {carried_nm:.1f} nm)"
        pins = "or the 0th order in the frame (the grating equation then carries it)"
    else:
        how = "by the grating equation"
        pins = "as does the grating's known line density"
    return record, (
        f"beyond its reddest line ({lines[1]:.0f} nm) the mapping is extrapolated {how}: "
        f"σ {sigma[1]:.1f} nm at {grid.stop_nm:g} nm. A lamp with red lines in the same geometry "
        f"pins it — a tri-phosphor CFL (Eu 611 nm) or a neon lamp — {pins}"
    )


def _local_dispersion(mapping: ExactMapping, pixel: FloatArray) -> FloatArray:
    if isinstance(mapping, TiltedGrating):
        return mapping.dispersion_at(pixel)
    return mapping.dispersion_nm_per_px(pixel)


def _direction(mapping: ExactMapping, lead: LampObservation) -> int:
    ends = mapping.wavelength_nm(np.array([lead.pixel[0], lead.pixel[-1]]))
    return 1 if ends[1] >= ends[0] else -1


def _check_monotonic(mapping: ExactMapping, lead: LampObservation) -> None:
    """A mapping that folds back over the profile is an error, never a result."""
    wavelengths = mapping.wavelength_nm(np.linspace(lead.pixel[0], lead.pixel[-1], 257))
    steps = np.diff(wavelengths)
    if not (np.all(steps > 0) or np.all(steps < 0)) or not np.all(np.isfinite(wavelengths)):
        raise EstimationError(
            "the mapping found folds back over the profile (not monotonic); the profile may hold "
            "more than one order or a reversed part — crop it to one first order"
        )


__all__ = ["MappingSolution", "fwhm_px", "lamp_lines", "locate_mapping"]
