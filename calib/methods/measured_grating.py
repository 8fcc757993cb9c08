"""The grating's efficiency measured with a spectroradiometer in its beams (decision 0032).

A spot spectroradiometer aimed at the slit without the grating sheet (the *direct* beam), through
the sheet straight on (the 0th order) and turned to the slit's 1st-order image (one band of
wavelengths per aim) measures the lamp's spectrum in each. Where the slit's image lies wholly inside
its measuring field, the power it collects at ``λ`` is the order's share of the slit's:

    η₀(λ) = order0(λ) / direct(λ),        η₁(λ) = order1(λ) / direct(λ),

the instrument's own calibration, the lamp's spectrum and the fraction of the field the slit fills
cancelling in each ratio (same instrument, same focus, same slit). An aim at the 1st order sees a
band ``d cos θ · field`` wide; its edges are blurred by the instrument's bandwidth and by how much
of the slit's image is inside, so only its core is kept (:func:`band_core`): the half-maximum
region around the band's peak less one bandwidth and :data:`EDGE_MARGIN_NM` on each side.

η₁ on the working grid is a physical model (:mod:`calib.model.gratings`: a thin sinusoidal phase
sheet ``T·J₁²(φ₀·550/λ)`` or a blazed grating ``T·sinc²(λ_B/λ − 1)``, ``T`` a free scale — a
sheet's substrate loses light to both orders) fitted to the measured points by weighted least
squares, the family with the smaller χ² chosen (both have two parameters, so the smaller χ² is also
the smaller ``C_L``). The model fills the gaps between the bands' cores and the range beyond the
aims; σ is the fit's covariance, inflated by the reduced χ² where above 1, the shape parameter's
never below the wavelength scale's share (:data:`calib.methods.grating_models.WAVELENGTH_SCALE_SIGMA`).
η₀ is measured at every wavelength with light and kept as measured (averaged onto the grid): a
flat or a physical η₀ both come out as they are.

Why the known-grating path and not a prior on the direct equations: the ratio measures η₁ itself,
free of everything that limits the direct equations (the exposure ratio between the spot and the
band, the spot's extraction, saturation; decision 0028's χ² of ~4 there), and of the camera basis;
``s = q̂/η₁`` then needs nothing else. A prior would let the worse-conditioned equations pull the
measured curve.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from calib.core.arrays import BoolArray, FloatArray
from calib.core.errors import InputError
from calib.core.grating_file import GratingEfficiency
from calib.core.spectra import WavelengthGrid
from calib.methods.grating_models import WAVELENGTH_SCALE_SIGMA
from calib.model.gratings import (
    PHYSICAL_KINDS,
    PHYSICAL_PARAMETER_NAMES,
    PHYSICAL_PARAMETER_RANGES,
    PhysicalKind,
    physical_grating,
)

#: Kept clear of a band's half-maximum edges beyond the instrument's bandwidth (nm): the slit's
#: own image (a few nm in the 1st order) and the instrument's wavelength steps.
EDGE_MARGIN_NM = 4.0
#: Bandwidth assumed when the instrument did not say (nm).
DEFAULT_BANDWIDTH_NM = 10.0
#: Relative repeatability of one spectrum (the floor under the scatter of few repeats).
REPEATABILITY = 0.005
#: Points whose direct spectrum is below this fraction of its peak are not used (no light).
MIN_DIRECT_FRACTION = 0.02
#: Parameter values scanned before the 1-D refinement.
SCAN_POINTS = 200
#: A reduced χ² above this says the model does not describe the measurement (warned).
MISFIT_REDUCED_CHI2 = 4.0


@dataclass(frozen=True, eq=False)
class BeamSpectra:
    """The spectra of one lamp in the grating's beams, on one wavelength axis.

    Attributes
    ----------
    wavelength_nm
        ``(n,)``.
    direct, order0
        ``(r, n)``: the repeats in the direct beam (no sheet) and in the 0th order.
    order1
        The 1st-order aims: the wavelength aimed at the field's centre, and its ``(r, n)`` repeats.
    bandwidth_nm
        The instrument's bandwidth (FWHM), if it said.
    lamp
        Which lamp.
    """

    wavelength_nm: FloatArray
    direct: FloatArray
    order0: FloatArray
    order1: Sequence[tuple[float, FloatArray]]
    bandwidth_nm: float | None = None
    lamp: str = ""


@dataclass(frozen=True, eq=False)
class MeasuredPoints:
    """Efficiency measured at wavelengths, with σ; each ``(k,)``."""

    wavelength_nm: FloatArray
    efficiency: FloatArray
    sigma: FloatArray


def _mean_and_sigma(repeats: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mean over repeats and its σ: the scatter's (pooled over wavelengths, as few repeats give
    a poor one each), never below :data:`REPEATABILITY`."""
    values = np.atleast_2d(np.asarray(repeats, dtype=np.float64))
    mean = values.mean(axis=0)
    relative = REPEATABILITY
    if values.shape[0] > 1:
        lit = mean > MIN_DIRECT_FRACTION * max(float(mean.max()), 1e-300)
        if np.any(lit):
            spread = values[:, lit].std(axis=0, ddof=1) / mean[lit]
            relative = max(relative, float(np.sqrt(np.mean(spread**2))))
    return mean, np.abs(mean) * relative / math.sqrt(values.shape[0])


def _ratio(
    numerator: FloatArray, denominator: FloatArray
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """``numerator/denominator`` with σ, and where the denominator has light."""
    top, top_sigma = _mean_and_sigma(numerator)
    bottom, bottom_sigma = _mean_and_sigma(denominator)
    lit = bottom > MIN_DIRECT_FRACTION * max(float(bottom.max()), 1e-300)
    safe = np.where(lit, bottom, 1.0)
    ratio = np.where(lit, top / safe, 0.0)
    sigma = np.where(
        lit,
        np.sqrt((top_sigma / safe) ** 2 + (ratio * bottom_sigma / safe) ** 2),
        np.inf,
    )
    return ratio, sigma, lit


def band_core(
    wavelength_nm: FloatArray, ratio: FloatArray, valid: BoolArray, bandwidth_nm: float
) -> BoolArray:
    """Where a 1st-order aim's band is wholly inside the field: a boolean ``(n,)`` mask.

    The band is the contiguous region above half the ratio's maximum around it; its core leaves
    ``bandwidth_nm + EDGE_MARGIN_NM`` on each side.
    """
    usable = np.where(valid.astype(bool), ratio, 0.0)
    if not np.any(usable > 0):
        return np.zeros(wavelength_nm.shape, dtype=bool)
    peak = int(np.argmax(usable))
    above = usable > usable[peak] / 2.0
    low = peak
    while low > 0 and above[low - 1]:
        low -= 1
    high = peak
    while high < above.size - 1 and above[high + 1]:
        high += 1
    margin = bandwidth_nm + EDGE_MARGIN_NM
    start, stop = wavelength_nm[low] + margin, wavelength_nm[high] - margin
    return np.asarray((wavelength_nm >= start) & (wavelength_nm <= stop), dtype=bool)


def first_order_points(beams: BeamSpectra) -> MeasuredPoints:
    """η₁ measured at the cores of the 1st-order bands (``order1 / direct``).

    Raises
    ------
    InputError
        No 1st-order band has a usable core.
    """
    bandwidth = DEFAULT_BANDWIDTH_NM if beams.bandwidth_nm is None else beams.bandwidth_nm
    wavelengths, values, sigmas = [], [], []
    for _centre_nm, repeats in beams.order1:
        ratio, sigma, lit = _ratio(repeats, beams.direct)
        core = band_core(beams.wavelength_nm, ratio, lit, bandwidth)
        wavelengths.append(beams.wavelength_nm[core])
        values.append(ratio[core])
        sigmas.append(sigma[core])
    if not wavelengths or sum(w.size for w in wavelengths) < 3:
        raise InputError(
            "the 1st-order spectra have no band wide enough to use (fewer than 3 wavelengths "
            "clear of the band edges): widen the spectrometer's field or check the aims",
            source=f"lamp {beams.lamp} grating beams",
        )
    wavelength = np.concatenate(wavelengths)
    order = np.argsort(wavelength, kind="stable")
    return MeasuredPoints(
        wavelength[order], np.concatenate(values)[order], np.concatenate(sigmas)[order]
    )


def zeroth_order_points(beams: BeamSpectra) -> MeasuredPoints:
    """η₀ measured wherever the lamp has light (``order0 / direct``)."""
    ratio, sigma, lit = _ratio(beams.order0, beams.direct)
    return MeasuredPoints(beams.wavelength_nm[lit], ratio[lit], sigma[lit])


@dataclass(frozen=True, eq=False)
class MeasuredFit:
    """A physical family fitted to measured η₁: ``scale · η₁(λ; parameter)``."""

    kind: PhysicalKind
    parameter: float
    scale: float
    covariance: FloatArray
    chi2: float
    n_points: int

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / max(self.n_points - 2, 1)

    def curve(self, wavelength_nm: FloatArray) -> FloatArray:
        return self.scale * physical_grating(self.kind, self.parameter).efficiency(1, wavelength_nm)

    def curve_sigma(self, wavelength_nm: FloatArray) -> FloatArray:
        """σ of :meth:`curve` (delta method), never below that of its shape.

        Two uses read it: the curve itself (absolute, scale included) and its shape — the curve
        over its maximum, as a grating file stores it and the estimators use it, where the scale
        cancels and σ is 0 at the maximum. Where the scale and the shape parameter are correlated
        the absolute σ understates the shape's error far from the maximum (issue 17: 2× at
        700 nm for a 1.2 rad sheet), so the larger of the two (the shape's times the maximum) is
        stated.
        """
        step = self.parameter * 1e-5
        shape = physical_grating(self.kind, self.parameter).efficiency(1, wavelength_nm)
        moved = physical_grating(self.kind, self.parameter + step).efficiency(1, wavelength_nm)
        jacobian = np.stack([self.scale * (moved - shape) / step, shape], axis=1)
        variance = np.einsum("ij,jk,ik->i", jacobian, self.covariance, jacobian)
        absolute = np.sqrt(np.clip(variance, 0.0, None))
        peak = int(np.argmax(shape))
        slope = (moved / moved[peak] - shape / shape[peak]) / step
        relative = np.abs(slope) * math.sqrt(max(float(self.covariance[0, 0]), 0.0))
        return np.asarray(np.maximum(absolute, relative * self.scale * shape[peak]), np.float64)

    def record(self) -> dict[str, Any]:
        sigma = np.sqrt(np.diag(self.covariance))
        return {
            "model": self.kind,
            "parameters": {
                PHYSICAL_PARAMETER_NAMES[self.kind]: self.parameter,
                "scale": self.scale,
            },
            "parameter_sigma": {
                PHYSICAL_PARAMETER_NAMES[self.kind]: float(sigma[0]),
                "scale": float(sigma[1]),
            },
            "reduced_chi2": self.reduced_chi2,
            "points": self.n_points,
            "fitted_to": "measured first-order efficiency",
        }


def fit_measured(points: MeasuredPoints, kind: PhysicalKind) -> MeasuredFit:
    """Fit ``scale · η₁(λ; p)`` of ``kind`` to ``points`` (scale in closed form at each ``p``)."""
    weight = 1.0 / points.sigma**2
    y = points.efficiency

    def at(parameter: float) -> tuple[float, float]:
        shape = physical_grating(kind, parameter).efficiency(1, points.wavelength_nm)
        norm = float(np.sum(weight * shape**2))
        scale = float(np.sum(weight * shape * y)) / norm if norm > 0 else 0.0
        return float(np.sum(weight * (y - scale * shape) ** 2)), scale

    low, high = PHYSICAL_PARAMETER_RANGES[kind]
    scanned = np.linspace(low, high, SCAN_POINTS)
    misfits = [at(float(p))[0] for p in scanned]
    best = int(np.argmin(misfits))
    left, right = scanned[max(best - 1, 0)], scanned[min(best + 1, scanned.size - 1)]
    refined = minimize_scalar(
        lambda p: at(float(p))[0], bounds=(left, right), method="bounded", options={"xatol": 1e-9}
    )
    parameter = float(refined.x)
    chi2, scale = at(parameter)
    step = parameter * 1e-5
    shape = physical_grating(kind, parameter).efficiency(1, points.wavelength_nm)
    moved = physical_grating(kind, parameter + step).efficiency(1, points.wavelength_nm)
    jacobian = np.stack([scale * (moved - shape) / step, shape], axis=1) / points.sigma[:, None]
    covariance = np.asarray(np.linalg.pinv(jacobian.T @ jacobian), dtype=np.float64)
    fit = MeasuredFit(kind, parameter, scale, covariance, chi2, int(points.wavelength_nm.size))
    inflation = max(fit.reduced_chi2, 1.0)
    covariance = covariance * inflation
    floor = (parameter * WAVELENGTH_SCALE_SIGMA) ** 2
    if covariance[0, 0] <= 0:
        covariance[0, 0] = floor
    elif covariance[0, 0] < floor:  # widen p's σ, keeping its correlation with the scale
        factor = math.sqrt(floor / covariance[0, 0])
        covariance[0, :] *= factor
        covariance[:, 0] *= factor
    return MeasuredFit(kind, parameter, scale, covariance, chi2, fit.n_points)


def _on_grid(points: MeasuredPoints, grid: WavelengthGrid) -> tuple[FloatArray, FloatArray]:
    """Measured values averaged onto the grid's nodes (±half a step), interpolated across
    nodes with none, held flat beyond the measured range; σ of each node's weighted mean."""
    nodes = grid.wavelength_nm
    half = grid.step_nm / 2.0
    values = np.full(nodes.shape, np.nan)
    sigmas = np.full(nodes.shape, np.nan)
    for index, node in enumerate(nodes):
        near = np.abs(points.wavelength_nm - node) <= half
        if np.any(near):
            weight = 1.0 / points.sigma[near] ** 2
            values[index] = float(np.sum(weight * points.efficiency[near]) / np.sum(weight))
            sigmas[index] = float(1.0 / math.sqrt(float(np.sum(weight))))
    known = np.isfinite(values)
    if not np.any(known):
        raise InputError("the 0th-order spectrum has no light on the grid", source="grating beams")
    values = np.interp(nodes, nodes[known], values[known])
    sigmas = np.interp(nodes, nodes[known], sigmas[known])
    return values, sigmas


def grating_from_beams(
    beams: BeamSpectra,
    grid: WavelengthGrid,
    *,
    provenance: Mapping[str, Any] | None = None,
) -> GratingEfficiency:
    """The grating's efficiency from its measured beams, as a grating file's contents.

    ``efficiency`` is the fitted physical η₁ on ``grid`` (absolute fraction) with σ;
    ``zeroth_order_efficiency`` the measured η₀; ``obtained`` ``"measured"``; ``model`` the fit
    (both families' χ² in ``model["candidates"]``; ``model["warning"]`` when the chosen one's
    reduced χ² exceeds :data:`MISFIT_REDUCED_CHI2`).

    Raises
    ------
    InputError
        No usable 1st-order band, or no light in the 0th order.

    Examples
    --------
    >>> import numpy as np
    >>> from calib.model.gratings import BlazedGrating
    >>> axis = np.arange(380.0, 781.0, 2.0)
    >>> lamp = np.ones((2, axis.size))
    >>> eta1 = 0.3 * BlazedGrating(480.0).efficiency(1, axis)
    >>> bands = [(c, lamp * eta1 * (np.abs(axis - c) < 30)) for c in (430.0, 530.0, 630.0)]
    >>> beams = BeamSpectra(axis, lamp, lamp * 0.1, bands, bandwidth_nm=4.0)
    >>> grating = grating_from_beams(beams, WavelengthGrid(400.0, 700.0, 10.0))
    >>> grating.obtained, grating.model["model"], round(grating.model["parameters"]["blaze_nm"])
    ('measured', 'blazed', 480)
    """
    first = first_order_points(beams)
    fits = [fit_measured(first, kind) for kind in PHYSICAL_KINDS]
    chosen = min(fits, key=lambda fit: fit.chi2)
    wavelength = grid.wavelength_nm
    zeroth, zeroth_sigma = _on_grid(zeroth_order_points(beams), grid)
    model: dict[str, Any] = {
        **chosen.record(),
        "candidates": {fit.kind: {"chi2": fit.chi2} for fit in fits},
        "measured_nm": [float(first.wavelength_nm.min()), float(first.wavelength_nm.max())],
    }
    if chosen.reduced_chi2 > MISFIT_REDUCED_CHI2:
        model["warning"] = (
            f"the {chosen.kind} model leaves a reduced χ² of {chosen.reduced_chi2:.3g} on the "
            "measured first-order efficiency: the sheet follows neither physical model, or the "
            "aims clipped their bands; σ is inflated by it"
        )
    return GratingEfficiency(
        wavelength_nm=wavelength,
        efficiency=chosen.curve(wavelength),
        efficiency_sigma=chosen.curve_sigma(wavelength),
        geometry={"order": 1, "description": "measured with the spectrometer in the beams"},
        provenance={"method": "measured in the grating's beams", **dict(provenance or {})},
        source=f"grating measured with {beams.lamp or 'a lamp'}",
        obtained="measured",
        model=model,
        zeroth_order_efficiency=zeroth,
        zeroth_order_efficiency_sigma=zeroth_sigma,
    )
