"""Error measures for estimated sensitivities and pixel→wavelength mappings.

References
----------
Makabe et al. (2025), Eq. 16 (sensitivity RE) and Supplementary Eq. 1 (mapping RE);
Solomatov & Akkaynak (2023) (angular RGB error).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import InputError


def _curves(values: ArrayLike, name: str) -> FloatArray:
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise InputError(f"expected shape (f, 3), got {array.shape}", source=name)
    if not np.all(np.isfinite(array)):
        raise InputError("contains NaN or infinite values", source=name)
    return array


def _normalised(curves: FloatArray, name: str) -> FloatArray:
    peak = float(np.max(np.abs(curves)))
    if peak <= 0:
        raise InputError("all-zero curves cannot be normalised", source=name)
    return curves / peak


def relative_error(estimated: ArrayLike, truth: ArrayLike, *, normalise: bool = True) -> float:
    """Average relative full-scale error RE over the three channels (Makabe et al. 2025, Eq. 16).

    ``RE = 1/3 Σ_c RMSE_c / max(s_c)`` with ``RMSE_c = ‖ŝ_c − s_c‖₂ / √f``.

    Parameters
    ----------
    estimated, truth
        Shape ``(f, 3)`` on the same wavelength grid.
    normalise
        Divide each set of curves by its maximum over all channels first (the paper's plots and
        :class:`calib.core.result.EstimateResult` use this convention), so an overall scale does not count.

    Returns
    -------
    float
        RE (dimensionless; the paper prints it ×10⁻²).

    Examples
    --------
    >>> truth = np.array([[1.0, 0.5, 0.2], [0.5, 1.0, 0.4]])
    >>> relative_error(2 * truth, truth)
    0.0
    """
    return float(np.mean(channel_relative_errors(estimated, truth, normalise=normalise)))


def channel_relative_errors(
    estimated: ArrayLike, truth: ArrayLike, *, normalise: bool = True
) -> FloatArray:
    """Each channel's term ``RMSE_c / max(s_c)`` of :func:`relative_error`, shape ``(3,)``.

    Examples
    --------
    >>> truth = np.array([[1.0, 0.5, 0.2], [0.5, 1.0, 0.4]])
    >>> channel_relative_errors(truth + [[0.0, 0.0, 0.04], [0.0, 0.0, 0.04]], truth).round(6).tolist()
    [0.0, 0.0, 0.1]
    """
    est = _curves(estimated, "estimated sensitivity")
    ref = _curves(truth, "true sensitivity")
    if est.shape != ref.shape:
        raise InputError(f"shapes differ: estimated {est.shape}, truth {ref.shape}")
    if normalise:
        est = _normalised(est, "estimated sensitivity")
        ref = _normalised(ref, "true sensitivity")
    rmse = np.sqrt(np.mean((est - ref) ** 2, axis=0))
    peaks = np.max(ref, axis=0)
    if np.any(peaks <= 0):
        raise InputError("a true channel is all zero; RE is undefined", source="true sensitivity")
    return np.asarray(rmse / peaks, dtype=np.float64)


def format_re(value: float | None, digits: int = 2) -> str:
    """An RE (sensitivity or mapping) as every command and report prints it: ×10⁻², as the paper.

    Examples
    --------
    >>> format_re(0.0431)
    '4.31 ×10⁻²'
    >>> format_re(None)
    '—'
    """
    if value is None or not np.isfinite(value):
        return "—"
    return f"{value * 100:.{digits}f} ×10⁻²"


def mapping_relative_error(
    estimated_nm: ArrayLike, truth_nm: ArrayLike, *, range_nm: tuple[float, float] = (400.0, 700.0)
) -> float:
    """Relative RMS error of a pixel→wavelength mapping (Makabe et al. 2025, Supp. Eq. 1).

    ``RE = RMS(λ̂(p) − λ(p)) / (λ_M − λ_m)`` over the profile's pixels.

    Parameters
    ----------
    estimated_nm, truth_nm
        Shape ``(n_pixels,)``: the wavelength each pixel maps to, estimated and true.
    range_nm
        ``(λ_m, λ_M)``, the working range (the grid's ends).

    Returns
    -------
    float
        Mapping RE (a fraction; ×100 for per cent).
    """
    est = np.asarray(estimated_nm, dtype=np.float64)
    ref = np.asarray(truth_nm, dtype=np.float64)
    if est.shape != ref.shape or est.ndim != 1 or est.size == 0:
        raise InputError(f"need two equal 1-D wavelength arrays, got {est.shape} and {ref.shape}")
    span = range_nm[1] - range_nm[0]
    if span <= 0:
        raise InputError(f"range {range_nm} must increase", source="range_nm")
    return float(np.sqrt(np.mean((est - ref) ** 2)) / span)


def angular_error_deg(estimated_rgb: ArrayLike, truth_rgb: ArrayLike) -> FloatArray:
    """Angle between RGB vectors in degrees (Solomatov & Akkaynak 2023).

    Parameters
    ----------
    estimated_rgb, truth_rgb
        Shape ``(..., 3)``.

    Returns
    -------
    numpy.ndarray
        Shape ``(...)``: the angle in degrees; ``nan`` where either vector is zero.
    """
    est = np.asarray(estimated_rgb, dtype=np.float64)
    ref = np.asarray(truth_rgb, dtype=np.float64)
    if est.shape != ref.shape or est.shape[-1] != 3:
        raise InputError(f"need two (..., 3) arrays of equal shape, got {est.shape}, {ref.shape}")
    norms = np.linalg.norm(est, axis=-1) * np.linalg.norm(ref, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.sum(est * ref, axis=-1) / norms
    return np.asarray(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))), dtype=np.float64)
