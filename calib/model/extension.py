"""Extend an estimate beyond the wavelengths it was measured on, with a σ that says so.

Downstream formats want 380–780 nm at 5 nm (rawtoaces requires it); an estimate usually covers less
(400–700 nm by default). Writing zeros there would pretend to a measurement; instead each missing
end is predicted from measured cameras that look like this one at that end:

1. inside the measured range the curves are interpolated linearly onto the grid (σ too: the
   interpolated σ bounds the σ of the interpolated value whatever the correlation of the two
   neighbours);
2. for each channel and each missing end, every reference camera is scaled to the estimate over the
   last :data:`EDGE_WINDOW_NM` of the measured range (least squares, scale ≥ 0); the
   :data:`N_NEIGHBOURS` that fit best, weighted by 1 / (RMS misfit + 10⁻³), give the extension
   (their weighted mean) and its σ: their weighted spread, plus the estimate's own σ at the edge
   carried along (relative to the fitted scale, and absolute fading over :data:`EDGE_WINDOW_NM`).

The reference cameras are the 52 measured cameras of rawtoaces-data (bundled, Apache-2.0). Each left
out in turn and extended from the others from its 400–700 nm at 10 nm, the truth falls within ±1σ
of the extension at 74 % of the extended samples and within ±2σ at 92 % (tails heavier than a
Gaussian's: a camera unlike every other at its edge); with noise of σ = 0.005 added to those
400–700 nm samples (and that σ given), 84 % and 97 % (``tests/test_extension.py``).

When the camera's truth is known (the digital twin, validation), the reference cameras measured on
the same camera (RE < :data:`SAME_CAMERA_RE` against it) are left out, as the camera basis leaves
the truth out, so that the extension does not flatter a comparison with the truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

import numpy as np

from calib.core.arrays import BoolArray, FloatArray
from calib.core.camera_curves import CameraCurves
from calib.core.errors import InputError
from calib.core.formats.ampas import RAWTOACES_GRID, reference_cameras
from calib.core.metrics import relative_error
from calib.core.spectra import WavelengthGrid

#: How much of the measured range next to a missing end decides which cameras are alike (nm).
EDGE_WINDOW_NM = 20.0
#: How many alike reference cameras predict a missing end.
N_NEIGHBOURS = 8
#: A reference camera closer than this RE to a known truth is the same camera (left out).
SAME_CAMERA_RE = 0.02
_MISFIT_FLOOR = 1e-3
#: No extended sample is certain: σ is at least the references' own resolution (their files print
#: about 10⁻⁵ of the peak; several store what they could not resolve as exact zeros).
SIGMA_FLOOR = 1e-5


@dataclass(frozen=True)
class Extension:
    """Curves on the output grid and how their unmeasured part was made.

    Attributes
    ----------
    curves
        On the grid; ``curves.measured`` marks the interpolated samples, ``curves.sigma`` is set
        everywhere it is known (``NaN`` inside where the estimate has no σ).
    measured_range_nm
        The estimate's own range, ``(start, stop)``.
    extended_nm
        The grid's wavelengths that were predicted, not measured.
    references
        How many reference cameras were available (after leaving out the truth's).
    left_out
        Names of the reference cameras left out as being the known truth.
    """

    curves: CameraCurves
    measured_range_nm: tuple[float, float]
    extended_nm: tuple[float, ...]
    references: int
    left_out: tuple[str, ...]

    @property
    def is_extended(self) -> bool:
        return bool(self.extended_nm)

    def describe(self) -> str:
        """One sentence for a file's comments."""
        low, high = self.measured_range_nm
        if not self.is_extended:
            return f"measured over the whole range ({low:g}–{high:g} nm)"
        outside = ", ".join(_ranges(self.extended_nm))
        text = (
            f"estimated from measurements over {low:g}–{high:g} nm; {outside} extended from the "
            f"{N_NEIGHBOURS} of {self.references} rawtoaces-data cameras most alike over the last "
            f"{EDGE_WINDOW_NM:g} nm (sigma says how uncertain)"
        )
        if self.left_out:
            text += f"; left out as the known truth: {', '.join(self.left_out)}"
        return text


def _ranges(values: Sequence[float]) -> list[str]:
    """``[380, 385, 390, 705, 710]`` → ``["380–390 nm", "705–710 nm"]``."""
    groups: list[list[float]] = []
    for value in values:
        if groups and value - groups[-1][-1] <= 5.0 + 1e-9:
            groups[-1].append(value)
        else:
            groups.append([value])
    return [f"{g[0]:g}–{g[-1]:g} nm" if len(g) > 1 else f"{g[0]:g} nm" for g in groups]


@cache
def _reference_stack(grid: WavelengthGrid) -> tuple[tuple[str, ...], FloatArray]:
    """Names and curves ``(n, f, 3)`` of the bundled cameras on ``grid``, each with maximum 1."""
    cameras = reference_cameras()
    names = tuple(c.curves.name for c in cameras)
    stack = np.stack([c.curves.at(grid.wavelength_nm) for c in cameras])
    stack /= stack.reshape(len(cameras), -1).max(axis=1)[:, None, None]
    stack.flags.writeable = False
    return names, stack


def _interpolate(values: FloatArray, axis: FloatArray, nodes: FloatArray) -> FloatArray:
    return np.stack([np.interp(nodes, axis, values[:, k]) for k in range(3)], axis=1)


def _predict_end(
    target: FloatArray,
    target_sigma: FloatArray | None,
    window: BoolArray,
    region: BoolArray,
    references: FloatArray,
    distance_nm: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Extension ``(len(region), 3)`` and its σ from the references' alike cameras."""
    values = np.zeros((int(region.sum()), 3))
    sigma = np.zeros_like(values)
    k = min(N_NEIGHBOURS, references.shape[0])
    ones = np.ones(int(window.sum()))
    fade = np.exp(-distance_nm / EDGE_WINDOW_NM)
    for c in range(3):
        edge = references[:, window, c]
        wanted = target[window, c]
        norms = np.einsum("ij,ij->i", edge, edge)
        scale = np.clip(edge @ wanted / np.where(norms > 0, norms, 1.0), 0.0, None)
        misfit = np.sqrt(np.mean((scale[:, None] * edge - wanted) ** 2, axis=1))
        nearest = np.argsort(misfit, kind="stable")[:k]
        weights = 1.0 / (misfit[nearest] + _MISFIT_FLOOR)
        weights /= weights.sum()
        predictions = scale[nearest, None] * references[nearest][:, region, c]
        mean = weights @ predictions
        spread = weights @ (predictions - mean) ** 2 * (k / (k - 1) if k > 1 else 1.0)
        # A noisy edge: the fitted scale is uncertain by σ / ‖fitted edge‖ (relative), and the
        # extension no more certain than the edge itself (absolute).
        relative, absolute = 0.0, 0.0
        if target_sigma is not None and np.all(np.isfinite(target_sigma[window, c])):
            absolute = float(np.sqrt(np.mean(target_sigma[window, c] ** 2)))
            fitted = float(np.sqrt(weights @ (scale[nearest, None] * edge[nearest]) ** 2 @ ones))
            if fitted > 0:
                relative = absolute / fitted
        values[:, c] = mean
        sigma[:, c] = np.sqrt(
            spread + (mean * relative) ** 2 + (absolute * fade) ** 2 + SIGMA_FLOOR**2
        )
    return values, sigma


def extend(
    curves: CameraCurves,
    grid: WavelengthGrid = RAWTOACES_GRID,
    *,
    truth: CameraCurves | None = None,
) -> Extension:
    """``curves`` on ``grid``: interpolated where measured, predicted with σ beyond (see module).

    Parameters
    ----------
    curves
        The estimate (its ``measured`` samples are what was measured), any wavelength axis.
    grid
        The output grid (default 380–780 nm at 5 nm).
    truth
        The camera's known truth, if any: reference cameras measured on it are left out.

    Raises
    ------
    InputError
        When fewer than 2 measured wavelengths fall on the grid's range.

    Examples
    --------
    >>> import numpy as np
    >>> wavelength = np.arange(400.0, 701.0, 10.0)
    >>> bell = np.exp(-0.5 * ((wavelength[:, None] - [600.0, 530.0, 460.0]) / 30.0) ** 2)
    >>> extended = extend(CameraCurves(wavelength, bell))
    >>> extended.curves.wavelength_nm.size, extended.extended_nm[:2]
    (81, (380.0, 385.0))
    """
    measured_axis = curves.wavelength_nm[curves.measured]
    if measured_axis.size < 2:
        raise InputError("fewer than 2 measured wavelengths", source=curves.name)
    low, high = float(measured_axis[0]), float(measured_axis[-1])
    nodes = grid.wavelength_nm
    inside = (nodes >= low - 1e-9) & (nodes <= high + 1e-9)
    if inside.sum() < 2:
        raise InputError(
            f"the estimate covers {low:g}–{high:g} nm: fewer than 2 of the output grid's "
            f"wavelengths ({grid}) fall inside it",
            source=curves.name,
        )
    keep = curves.measured
    values = np.zeros((nodes.size, 3))
    sigma = np.full((nodes.size, 3), np.nan)
    values[inside] = _interpolate(curves.values[keep], measured_axis, nodes[inside])
    if curves.sigma is not None:
        sigma[inside] = _interpolate(curves.sigma[keep], measured_axis, nodes[inside])
    names, stack = _reference_stack(grid)
    left_out: list[str] = []
    if truth is not None:
        overlap = inside & (nodes >= truth.range_nm[0]) & (nodes <= truth.range_nm[1])
        true_curves = truth.at(nodes[overlap])
        same = [
            relative_error(stack[j][overlap], true_curves) < SAME_CAMERA_RE
            for j in range(len(names))
        ]
        left_out = [name for name, drop in zip(names, same, strict=True) if drop]
        stack = stack[~np.array(same)]
    target_sigma = sigma if curves.sigma is not None else None
    for region, window in (
        (nodes < low - 1e-9, inside & (nodes <= low + EDGE_WINDOW_NM + 1e-9)),
        (nodes > high + 1e-9, inside & (nodes >= high - EDGE_WINDOW_NM - 1e-9)),
    ):
        if region.any():
            edge_nm = low if region[0] else high
            values[region], sigma[region] = _predict_end(
                values, target_sigma, window, region, stack, np.abs(nodes[region] - edge_nm)
            )
    extended = CameraCurves(nodes, values, sigma, measured=inside, name=curves.name)
    return Extension(
        curves=extended,
        measured_range_nm=(low, high),
        extended_nm=tuple(float(w) for w in nodes[~inside]),
        references=int(stack.shape[0]),
        left_out=tuple(left_out),
    )
