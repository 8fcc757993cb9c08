"""The lens and the grating's tilt measured from both first orders (decision 0197).

With a broadband lamp alone, the competing basins of the +1 profile's likelihood differ in the
grating's incidence far more than in its dispersion (decision 0196: a median 16° on the validation
split), and within one basin the incidence and the focal length trade against each other: the same
+1 mapping comes from many geometries. The −1 order, when it is in the frame, is the same light
through the same grating with the incidence's sign turned
(:meth:`calib.core.mapping.TiltedGrating.other_order`). A wavelength leaving the grating at
``sin(θ + a₊) − sin θ = λ/d`` on the +1 side leaves at ``sin θ − sin(θ − a₋) = λ/d`` on the other,
so the pixel ``u₋ = F tan a₋`` that shows what ``u₊ = F tan a₊`` shows depends on the focal length
``F`` and the incidence ``θ`` alone — the groove spacing cancels. Carried through the right
``(F, θ)``, the −1 profile is the +1 profile times one smooth ratio common to the three channels
(the two orders' efficiency ratio ``η₋₁/η₊₁`` — 1 for a thin sinusoidal grating, smaller and shaped
for a blazed one — and their dispersion ratio); through a wrong one the channels' ratios disagree
wherever the profile's colour changes.

:func:`other_order_geometry` finds that ``(F, θ)`` — a scan over a grid of both on the profiles
smoothed, the best point refined on them as measured — and states its σ from the fit's curvature
(tempered by its reduced χ² above 1, widened by :data:`SIGMA_SCALE`).
:func:`calib.wavelength.locate.locate_mapping` reports it with an LED-only mapping; it does not
join the grating prior (decision 0197: measured, on the test split that left mappings pulled by a
camera unlike the prior unwarned). A fit the ratio model does not describe, or a second valley the
scan cannot rule out, says so (:attr:`OtherOrderGeometry.refused`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.polynomial import legendre
from numpy.typing import NDArray

from calib.core.arrays import FloatArray
from calib.core.observations import LampObservation, OrderProfile

#: Degree of the smooth ratio ``−1 / +1`` (a Legendre polynomial in the +1 pixel): the orders'
#: efficiency ratio and dispersion ratio (a blazed grating's −1/+1 ratio, sinc²(λ_B/λ + 1) over
#: sinc²(λ_B/λ − 1), is the most shaped of the protocol's gratings).
RATIO_DEGREE = 4
#: Fewest shared samples per fitted coefficient for a fit to count.
SAMPLES_PER_TERM = 4
#: The scan: incidences (degrees: from, to, step) and focal lengths (from, to, in units of the
#: profile's far end, and the step of its logarithm: a first order's far end lies 5–50° from the
#: 0th order, F = u / tan(angle)). The −1 order's features move by about 7 px per degree against
#: the +1 order's at a typical focal length; smoothed by :data:`SCAN_SMOOTHING_PX` a half-degree
#: step keeps within the valley.
INCIDENCE_SCAN_DEG = (-30.0, 30.0, 0.5)
FOCAL_SCAN = (0.8, 12.0, 0.05)
#: A geometry must carry this share of the −1 profile's lit samples (any channel above
#: :data:`LIT_SIGMAS` of its σ) into the +1 profile's reach: the light of one order is the other's.
LIT_SHARE = 0.9
LIT_SIGMAS = 5.0
#: The scan's smoothing of both profiles (Gaussian σ, sensor pixels).
SCAN_SMOOTHING_PX = 8.0
#: A second valley of the scan (a separate minimum over incidence) within this Δχ² (tempered) of
#: the best one, more than :data:`DISTINCT_DEG` away, leaves the geometry unmeasured. Chosen on
#: the validation split (decision 0197): of the 49 scenes of 144 with a second valley within
#: Δχ² 25, the best was the true geometry in every one (within 2.2°, most within 0.5°); this bar
#: keeps the check for a tie.
AMBIGUITY_DELTA_CHI2 = 1.0
DISTINCT_DEG = 2.0
#: A −1 fit whose reduced χ² is above this is not described by the ratio model (another light on
#: that side, a band cut by the frame): its geometry is not used.
MISFIT_REDUCED_CHI2 = 4.0
#: The refined fit's curvature σ is short (the ratio model's own misfit: the slit's image is the
#: same in pixels on both sides, not in nanometres): the stated covariance is widened by this.
#: Chosen on the validation split (decision 0197): over the 133 geometries of its 144 LED-only
#: scenes that it measured and used, the 95th percentile of |error|/σ was 5.4 for the incidence
#: and 5.3 for the focal length; widened by 2.7 the ±2σ band holds 95 %.
SIGMA_SCALE = 2.7


@dataclass(frozen=True)
class OtherOrderGeometry:
    """What the two first orders measured together.

    Attributes
    ----------
    incidence_deg, incidence_sigma_deg
        ``θ`` and its σ (the fit's, widened by :data:`SIGMA_SCALE`).
    log_focal, log_focal_sigma
        ``ln F`` (``F`` in sensor pixels) and its σ (likewise).
    reduced_chi2
        Of the −1 profile about the ratio model at that geometry.
    samples
        −1 samples the +1 profile reaches there.
    covariance
        Of ``(θ, ln F)`` (tempered by the reduced χ² above 1, widened by :data:`SIGMA_SCALE`): the
        −1 order holds one combination of the two far better than either.
    runner_up
        The scan's best valley more than :data:`DISTINCT_DEG` from it: ``(θ, Δχ²)`` (tempered),
        or ``None``.
    refused
        Why the geometry is not used (``None``: it is).
    """

    incidence_deg: float
    incidence_sigma_deg: float
    log_focal: float
    log_focal_sigma: float
    reduced_chi2: float
    samples: int
    covariance: tuple[tuple[float, float], tuple[float, float]]
    runner_up: tuple[float, float] | None
    refused: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """For ``result.json``: a σ the fit could not state (a flat valley) is ``None``."""

        def finite(value: float) -> float | None:
            return value if math.isfinite(value) else None

        spread = self.covariance[0][0] * self.covariance[1][1]
        return {
            "incidence_deg": self.incidence_deg,
            "incidence_sigma_deg": finite(self.incidence_sigma_deg),
            "focal_length_px": math.exp(self.log_focal),
            "log_focal_sigma": finite(self.log_focal_sigma),
            "correlation": finite(self.covariance[0][1] / math.sqrt(spread))
            if math.isfinite(spread) and spread > 0
            else None,
            "reduced_chi2": self.reduced_chi2,
            "samples": self.samples,
            "runner_up": None
            if self.runner_up is None
            else {"incidence_deg": self.runner_up[0], "delta_chi2": self.runner_up[1]},
            "refused": self.refused,
        }


def corresponding_pixel(
    other_pixel: FloatArray, focal_px: FloatArray, incidence_deg: FloatArray
) -> FloatArray:
    """The +1 pixel (distance from the spot) showing what ``other_pixel`` on the −1 side shows,
    for each ``(F, θ)`` (broadcast: ``focal_px`` and ``incidence_deg`` of shape ``(K, 1)`` give
    ``(K, n)``); NaN where the wavelength has no +1 order."""
    theta = np.radians(incidence_deg)
    angle = np.arctan(np.asarray(other_pixel, dtype=np.float64) / focal_px)
    # λ/d from the −1 side, then the +1 side's angle for it.
    ratio = np.sin(theta) - np.sin(theta - angle)
    sine = np.sin(theta) + ratio
    with np.errstate(invalid="ignore"):
        plus = np.arcsin(np.where(np.abs(sine) < 1.0, sine, np.nan)) - theta
    return np.asarray(focal_px * np.tan(plus), dtype=np.float64)


def _smoothed(order: OrderProfile, sigma_px: float) -> OrderProfile:
    from scipy.ndimage import gaussian_filter1d  # deferred: slow to import

    spacing = float(np.median(np.diff(order.pixel)))
    return replace(
        order,
        profile=gaussian_filter1d(np.asarray(order.profile), sigma_px / spacing, axis=0),
    )


def _misfit(
    first: OrderProfile,
    other: OrderProfile,
    carried: FloatArray,
    degree: int,
    lit: NDArray[np.bool_],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """For each row of ``carried`` ``(K, n)`` (the +1 pixel of each −1 sample; NaN: unused): the
    χ² of the −1 profile about ``r(u₊) × (+1 profile there)`` with ``r`` a Legendre polynomial of
    ``degree`` in the +1 pixel over ``first``'s range (weighted least squares, the +1 profile's σ
    carried through a first pass's ratio), the samples used and the weighted residuals
    ``(K, n, 3)`` (0 where unused). Rows with too few samples, or that leave more than
    1 − :data:`LIT_SHARE` of the ``lit`` samples out: χ² ∞."""
    carried = np.atleast_2d(carried)
    low, high = float(first.pixel[0]), float(first.pixel[-1])
    used = np.isfinite(carried) & (carried >= low) & (carried <= high)
    at = np.where(used, carried, low)
    plus = np.stack([np.interp(at, first.pixel, first.profile[:, c]) for c in range(3)], axis=-1)
    plus_sigma = np.stack(
        [np.interp(at, first.pixel, first.profile_sigma[:, c]) for c in range(3)], axis=-1
    )
    minus = np.broadcast_to(other.profile, plus.shape)
    minus_sigma = np.broadcast_to(other.profile_sigma, plus.shape)
    basis = legendre.legvander((2.0 * at - (low + high)) / (high - low), degree)  # (K, n, T)
    mask = used[..., None]
    ratio: FloatArray = np.zeros(at.shape)
    for _ in range(2):
        variance = minus_sigma**2 + (ratio[..., None] * plus_sigma) ** 2
        weight = np.where(mask, 1.0 / np.maximum(variance, 1e-300), 0.0)  # (K, n, 3)
        # Normal equations of Σ_c w (m − (B·c) p)²: (K, T, T) and (K, T), the channels summed
        # first and the rest as batched products.
        transposed = basis.transpose(0, 2, 1)
        normal = transposed @ (basis * np.sum(weight * plus**2, axis=-1)[..., None])
        right = (transposed @ np.sum(weight * plus * minus, axis=-1)[..., None])[..., 0]
        # A row without samples (or nearly so) stays solvable; its χ² is set to ∞ below.
        trace = np.trace(normal, axis1=1, axis2=2)[:, None, None]
        normal += (1e-12 * trace + (trace == 0)) * np.eye(degree + 1)
        coefficients = np.linalg.solve(normal, right[..., None])[..., 0]
        ratio = np.asarray((basis @ coefficients[..., None])[..., 0], dtype=np.float64)
    variance = minus_sigma**2 + (ratio[..., None] * plus_sigma) ** 2
    residual = np.where(mask, (minus - ratio[..., None] * plus) / np.sqrt(variance), 0.0)
    chi2 = np.sum(residual**2, axis=(1, 2))
    count = used.sum(axis=1)
    covered = (used & lit).sum(axis=1) >= LIT_SHARE * max(int(np.count_nonzero(lit)), 1)
    chi2 = np.where((count >= SAMPLES_PER_TERM * (degree + 1)) & covered, chi2, np.inf)
    return chi2, count, residual


def other_order_geometry(
    lamp: LampObservation, degree: int = RATIO_DEGREE
) -> OtherOrderGeometry | None:
    """``(F, θ)`` from ``lamp``'s two first orders (module docstring); ``None`` when it has no
    other order or the two share too few samples anywhere on the scan."""
    from scipy.optimize import least_squares  # deferred: slow to import

    other = lamp.other_order
    if other is None or lamp.profile_sigma is None:
        return None
    first = OrderProfile(lamp.pixel, lamp.profile, lamp.profile_sigma)
    reach = float(max(first.pixel[-1], other.pixel[-1]))
    low, high, step = INCIDENCE_SCAN_DEG
    incidences = np.arange(low, high + step / 2, step)
    near, far, log_step = FOCAL_SCAN
    logs = np.arange(math.log(near * reach), math.log(far * reach) + log_step / 2, log_step)
    theta, log_focal = (grid.reshape(-1, 1) for grid in np.meshgrid(incidences, logs))
    # The scan on both profiles smoothed, the −1 samples thinned to half the smoothing.
    blurred = (_smoothed(first, SCAN_SMOOTHING_PX), _smoothed(other, SCAN_SMOOTHING_PX))
    every = max(1, round(SCAN_SMOOTHING_PX / 2 / float(np.median(np.diff(other.pixel)))))
    thinned = OrderProfile(
        blurred[1].pixel[::every], blurred[1].profile[::every], blurred[1].profile_sigma[::every]
    )
    lit = np.any(np.asarray(other.profile) > LIT_SIGMAS * np.asarray(other.profile_sigma), axis=1)
    chi2 = np.empty(theta.shape[0])
    shared = np.empty(theta.shape[0])
    for rows in np.array_split(np.arange(theta.shape[0]), max(1, theta.shape[0] // 512)):
        carried = corresponding_pixel(thinned.pixel, np.exp(log_focal[rows]), theta[rows])
        chi2[rows], shared[rows], _ = _misfit(blurred[0], thinned, carried, degree, lit[::every])
    if not np.any(np.isfinite(chi2)):
        return None
    surface = chi2.reshape(logs.size, incidences.size)
    best = int(np.argmin(chi2))
    # Another valley: the lowest other local minimum of each incidence's best (over the focal
    # length) more than DISTINCT_DEG away. The −1 order holds one combination of F and θ well
    # and the other loosely, so one valley runs across incidences; only a separate minimum along
    # it is another answer.
    by_incidence = surface.min(axis=0)
    padded = np.concatenate([[np.inf], by_incidence, [np.inf]])
    minima = np.flatnonzero(
        (by_incidence <= padded[:-2]) & (by_incidence <= padded[2:]) & np.isfinite(by_incidence)
    )
    minima = minima[np.abs(incidences[minima] - float(theta[best, 0])) > DISTINCT_DEG]
    second = int(minima[np.argmin(by_incidence[minima])]) if minima.size else None

    start = np.array([float(theta[best, 0]), float(log_focal[best, 0])])
    # The refinement on the samples the scan's best point shares.
    at_start = corresponding_pixel(other.pixel, np.exp(start[1]), start[0])
    with np.errstate(invalid="ignore"):
        used = np.isfinite(at_start) & (at_start >= first.pixel[0]) & (at_start <= first.pixel[-1])
    count = int(used.sum())
    if count < SAMPLES_PER_TERM * (degree + 1):
        return None

    def residuals(x: FloatArray) -> FloatArray:
        carried = corresponding_pixel(other.pixel, np.exp(x[1]), x[0])
        if not np.all(np.isfinite(carried[used])):
            return np.full(3 * count, 1e3)
        return _residuals(first, other, carried, used, degree)

    # Within the scan's ranges: at normal incidence the two orders are mirror images for every
    # focal length, and a free fit walks along that flat valley to focal lengths where the
    # incidence too stops mattering.
    bounds = (
        [low, math.log(near * reach)],
        [high, math.log(far * reach)],
    )
    start = np.clip(start, bounds[0], bounds[1])
    solved = least_squares(
        residuals, start, x_scale=np.array([0.05, 0.01]), bounds=bounds, max_nfev=100
    )
    dof = 3 * count - (degree + 1) - 2
    reduced = float(2.0 * solved.cost / max(dof, 1))
    temper = max(1.0, reduced)
    try:
        covariance = np.linalg.inv(solved.jac.T @ solved.jac) * temper * SIGMA_SCALE**2
    except np.linalg.LinAlgError:
        covariance = np.diag([np.inf, np.inf])
    if not np.all(np.isfinite(covariance)):
        covariance = np.diag([np.inf, np.inf])
    sigmas = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    runner_up = None
    refused = None
    if second is not None and math.isfinite(by_incidence[second]):
        # On the smoothed scan, tempered by its best point's own reduced χ² (over the thinned
        # samples that point shares).
        scan_dof = max(3 * int(shared[best]) - (degree + 1) - 2, 1)
        scan_temper = max(1.0, float(chi2[best]) / scan_dof)
        delta = (float(by_incidence[second]) - float(chi2[best])) / scan_temper
        runner_up = (float(incidences[second]), delta)
        if delta < AMBIGUITY_DELTA_CHI2:
            refused = (
                f"a second geometry fits the two orders nearly as well (incidence "
                f"{incidences[second]:.1f}° against {solved.x[0]:.1f}°, Δχ² {delta:.1f})"
            )
    if reduced > MISFIT_REDUCED_CHI2:
        refused = (
            f"the −1 profile is not the +1 profile's shape through any geometry (reduced χ² "
            f"{reduced:.1f}, above {MISFIT_REDUCED_CHI2:g}): other light on that side, or the "
            "band cut by the frame"
        )
    return OtherOrderGeometry(
        float(solved.x[0]),
        float(sigmas[0]),
        float(solved.x[1]),
        float(sigmas[1]),
        reduced,
        count,
        (
            (float(covariance[0, 0]), float(covariance[0, 1])),
            (float(covariance[1, 0]), float(covariance[1, 1])),
        ),
        runner_up,
        refused,
    )


def _residuals(
    first: OrderProfile,
    other: OrderProfile,
    carried: FloatArray,
    used: NDArray[np.bool_],
    degree: int,
) -> FloatArray:
    """:func:`_misfit`'s weighted residuals for one ``carried`` over the ``used`` samples (a fixed
    set, so a refinement's residual vector keeps its length; one that leaves the +1 profile's
    reach counts 0)."""
    kept = np.where(used, carried, np.nan)
    _, _, residual = _misfit(first, other, kept, degree, np.zeros(used.shape, dtype=bool))
    return np.asarray(residual[0][used].reshape(-1))
