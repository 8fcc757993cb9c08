"""Camera sensitivity from one image of a fluorescent chart under unknown light (Han et al. 2012).

A fluorescent paint re-emits absorbed light with a fixed emission spectrum ``e_p``, whatever the
illuminant (Eq. 1–2), so the *chromaticity* of its fluorescent component depends on the camera only
(Eq. 5). One image of a fluorescent chart next to a non-fluorescent reference chart (a ColorChecker)
therefore gives the camera's sensitivity without knowing the light:

1. **Separation** (Eq. 7–11): reflectances are written in an ``N``-vector basis (``N = 8``); the
   reference patches (known reflectances ``s_q = Σ α_qn b_n``) give the unknown integrals
   ``M_nc = ∫ b_n c_c l dλ`` by least squares (``R_q = α_q M``), which predict the reflective part
   of each fluorescent patch from its reflectance (the Donaldson matrix's diagonal); the rest is
   fluorescence.
2. **Chromaticity invariance** (Eq. 12–16): with ``c_c = Σ_m β_cm b_m`` in a Fourier basis
   (``M = 9``) and ``t_pm = ∫ e_p b_m dλ``, each patch's fluorescent chromaticity ``(r, g, b)``
   gives three homogeneous equations ``[(r−1) t_p, r t_p, r t_p] β = 0`` …; stacked with a
   second-derivative smoothness term ``w_c Φ β_c`` they form ``A X = 0``, solved by the
   eigenvector of ``AᵀA`` of the smallest eigenvalue; the result is normalised to a maximum of 1.
3. **Daylight** (Eq. 17–19): with the sensitivity known, the ColorChecker's RGBs give the three
   coefficients of the CIE daylight basis ``S0, S1, S2`` by least squares.

Bases used here: the reflectance basis is the SVD of the 190 training reflectances of rawtoaces
(shipped with colour-science; the paper used Parkkinen's Munsell basis, which does not ship);
the Fourier basis is :func:`calib.model.bases.fourier_basis` (``1, cos, sin, …``, the paper's footnote 2);
``Φ`` is the exact second derivative of that basis on a normalised wavelength ``t ∈ [0, 1]``,
divided by ``(2π)²`` and ``√f``, and the rows of ``A`` use unit-area emission spectra, so the
smoothness weights are relative to these units (the paper's ``(8, 8, 3)`` are in units it does not
state).

:func:`synthetic_fluorescent_paints` and :func:`render_fluorescent_chart` generate charts for tests
and benchmarks: paints with absorption, emission and reflectance spectra like fluorescent poster
paints (seeded), seen by a camera under any illuminant, with noise; the reference chart is
:func:`calib.core.colour_data.colorchecker` (BabelColor's average, as the paper's ColorChecker).

References
----------
Han, S., Matsushita, Y., Sato, I., Okabe, T., Sato, Y. (2012). Camera Spectral Sensitivity
Estimation from a Single Image under Unknown Illumination by using Fluorescence. CVPR.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import FloatArray, checked_array
from calib.core.blas import one_blas_thread
from calib.core.colour_data import cie_daylight_basis, training_reflectances
from calib.core.errors import EstimationError, InputError
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum, WavelengthGrid
from calib.model.bases import CameraBasis, fourier_basis
from calib.model.charts import chart_rgb, check_noise_request
from calib.model.forward import hat_matrix

Normalisation = Literal["brightness", "unit"]
RowWeighting = Literal["fraction", "paper"]

#: Reflectance basis vectors (the paper's N, after Parkkinen et al. 1989).
DEFAULT_REFLECTANCE_VECTORS = 8
#: Fourier basis functions per channel (the paper's M, after Finlayson et al. 1998).
DEFAULT_FOURIER_TERMS = 9
#: Smoothness weights (R, G, B) in this module's units (see the module docstring).
DEFAULT_SMOOTHNESS = (0.01, 0.01, 0.004)
#: Patches fluorescing for less of their signal than this are left out.
MIN_FLUORESCENT_FRACTION = 0.02


# ------------------------------------------------------------------------------------------ input


@dataclass(frozen=True, eq=False)
class FluorescentChart:
    """One image of a fluorescent chart and a reference chart, lit by the same (unknown) light.

    Parameters
    ----------
    fluorescent_rgb
        Shape ``(P, 3)``: linear camera RGB of each fluorescent patch.
    reference_rgb
        Shape ``(Q, 3)``: linear camera RGB of each reference (non-fluorescent) patch.
    emission
        ``P`` curves: each fluorescent paint's emission spectrum (measured under UV; any scale).
    fluorescent_reflectance
        ``P`` curves: each paint's reflectance (the diagonal of its Donaldson matrix).
    reference_reflectance
        ``Q`` curves: the reference patches' reflectances.
    fluorescent_sigma, reference_sigma
        Standard deviations of the RGBs (same shapes), or ``None``.
    name
        What the image is (for messages and results).
    """

    fluorescent_rgb: FloatArray
    reference_rgb: FloatArray
    emission: MultiSpectrum
    fluorescent_reflectance: MultiSpectrum
    reference_reflectance: MultiSpectrum
    fluorescent_sigma: FloatArray | None = None
    reference_sigma: FloatArray | None = None
    name: str = "chart"

    def __post_init__(self) -> None:
        source = f"chart {self.name!r}"
        n_paints = self.emission.values.shape[1]
        n_reference = self.reference_reflectance.values.shape[1]
        if self.fluorescent_reflectance.values.shape[1] != n_paints:
            raise InputError(
                f"{self.fluorescent_reflectance.values.shape[1]} paint reflectances for "
                f"{n_paints} emission spectra",
                source=source,
            )
        if n_paints < 2:
            raise InputError(f"need at least 2 fluorescent patches, got {n_paints}", source=source)
        object.__setattr__(
            self,
            "fluorescent_rgb",
            checked_array(self.fluorescent_rgb, (n_paints, 3), "fluorescent RGB", source),
        )
        object.__setattr__(
            self,
            "reference_rgb",
            checked_array(self.reference_rgb, (n_reference, 3), "reference RGB", source),
        )
        for name, shape in (
            ("fluorescent_sigma", (n_paints, 3)),
            ("reference_sigma", (n_reference, 3)),
        ):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, checked_array(value, shape, name, source))

    @property
    def n_paints(self) -> int:
        return int(self.emission.values.shape[1])

    @property
    def n_reference(self) -> int:
        return int(self.reference_reflectance.values.shape[1])


# ------------------------------------------------------------------------------------------ bases


@lru_cache(maxsize=8)
def reflectance_basis(
    grid: WavelengthGrid = DEFAULT_GRID, n_vectors: int = DEFAULT_REFLECTANCE_VECTORS
) -> FloatArray:
    """Orthonormal reflectance basis on ``grid``, shape ``(f, n_vectors)``.

    The leading right-singular vectors (no mean-centring, as Parkkinen et al.) of the 190 training
    reflectances of rawtoaces, which ship with colour-science.
    """
    curves = training_reflectances().resample(grid)
    if not 1 <= n_vectors <= min(curves.values.shape):
        raise InputError(
            f"n_vectors must be within 1..{min(curves.values.shape)}, got {n_vectors}",
            source="reflectance basis",
        )
    _, _, right = np.linalg.svd(curves.values.T, full_matrices=False)
    vectors = right[:n_vectors].T
    vectors = vectors * np.sign(vectors.sum(axis=0, keepdims=True) + 1e-300)
    vectors.flags.writeable = False
    return np.asarray(vectors, dtype=np.float64)


def fourier_curvature(grid: WavelengthGrid, n_terms: int) -> FloatArray:
    """``Φ``: second derivatives of :func:`calib.model.bases.fourier_basis` (``t ∈ [0, 1]``), ``(f, n_terms)``.

    Scaled by ``1/((2π)² √f)``: the first frequency has unit curvature amplitude, and the sum over
    the grid is an RMS.
    """
    position = (grid.wavelength_nm - grid.start_nm) / (grid.stop_nm - grid.start_nm)
    columns = [np.zeros_like(position)]
    for k in range(1, n_terms):
        frequency = (k + 1) // 2
        trig = np.cos if k % 2 == 1 else np.sin
        columns.append(-(frequency**2) * trig(2 * np.pi * frequency * position))
    return np.stack(columns, axis=1) / math.sqrt(grid.size)


def daylight_basis(grid: WavelengthGrid = DEFAULT_GRID) -> FloatArray:
    """The CIE daylight basis ``S0, S1, S2`` on ``grid``, shape ``(f, 3)`` (colour-science data)."""
    wavelength, values = cie_daylight_basis()
    # S1 and S2 change sign, so they are not spectra: interpolated as plain curves.
    return np.stack(
        [np.interp(grid.wavelength_nm, wavelength, values[:, k]) for k in range(3)], axis=1
    )


# ------------------------------------------------------------------------------------- estimation


@dataclass(frozen=True, eq=False)
class Separation:
    """Reflective and fluorescent components of the fluorescent patches (Eq. 7–11).

    Attributes
    ----------
    fluorescent_rgb, reflective_rgb
        Shape ``(P, 3)`` each; they sum to the observed RGB.
    integrals
        Shape ``(N, 3)``: ``M_nc = ∫ b_n c_c l dλ`` from the reference chart.
    reference_residual
        Shape ``(Q, 3)``: observed − predicted reference RGB.
    """

    fluorescent_rgb: FloatArray
    reflective_rgb: FloatArray
    integrals: FloatArray
    reference_residual: FloatArray

    @property
    def chromaticity(self) -> FloatArray:
        """Shape ``(P, 3)``: ``(r, g, b)`` of each patch's fluorescent component (NaN if none)."""
        total = self.fluorescent_rgb.sum(axis=1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(
                np.where(total > 0, self.fluorescent_rgb / total, np.nan), dtype=np.float64
            )

    @property
    def fluorescent_fraction(self) -> FloatArray:
        """Shape ``(P,)``: the fluorescent share of each patch's signal (all channels)."""
        total = (self.fluorescent_rgb + self.reflective_rgb).sum(axis=1)
        return np.asarray(self.fluorescent_rgb.sum(axis=1) / total, dtype=np.float64)

    @property
    def usable(self) -> NDArray[np.bool_]:
        """Shape ``(P,)``: patches that fluoresce in every channel and for at least
        :data:`MIN_FLUORESCENT_FRACTION` of their signal (below, the separation's error is the
        chromaticity)."""
        positive = np.all(self.fluorescent_rgb > 0, axis=1)
        return np.asarray(positive & (self.fluorescent_fraction >= MIN_FLUORESCENT_FRACTION))


def separate_fluorescence(
    chart: FluorescentChart,
    grid: WavelengthGrid = DEFAULT_GRID,
    n_reflectance_vectors: int = DEFAULT_REFLECTANCE_VECTORS,
) -> Separation:
    """Split each fluorescent patch into its reflective and fluorescent parts (Eq. 7–11).

    Raises
    ------
    InputError
        Fewer reference patches than basis vectors.
    EstimationError
        A patch shows no fluorescence (its fluorescent part is not positive in sum).
    """
    if chart.n_reference < n_reflectance_vectors:
        raise InputError(
            f"{chart.n_reference} reference patches cannot fix {n_reflectance_vectors} basis "
            "integrals per channel; use a chart with more patches (a ColorChecker has 24)",
            source=f"chart {chart.name!r}",
        )
    basis = reflectance_basis(grid, n_reflectance_vectors)
    reference_alpha = chart.reference_reflectance.resample(grid).values.T @ basis
    paint_alpha = chart.fluorescent_reflectance.resample(grid).values.T @ basis
    solved, *_ = np.linalg.lstsq(reference_alpha, chart.reference_rgb, rcond=None)
    integrals = np.asarray(solved, dtype=np.float64)
    reflective = paint_alpha @ integrals
    fluorescent = chart.fluorescent_rgb - reflective
    return Separation(
        fluorescent_rgb=fluorescent,
        reflective_rgb=reflective,
        integrals=integrals,
        reference_residual=chart.reference_rgb - reference_alpha @ integrals,
    )


@dataclass(frozen=True, eq=False)
class SensitivityBasis:
    """The functions each channel's sensitivity is written in (Eq. 12), with their curvature.

    Attributes
    ----------
    grid
        The working grid (``f`` nodes).
    vectors
        Shape ``(3, f, M)``: per-channel basis functions on the grid (the Fourier basis is the
        same for all three).
    curvature
        Shape ``(3, r, M)``: ``Φ`` per channel (Eq. 16), in this module's units.
    description
        What the basis is, for results.
    """

    grid: WavelengthGrid
    vectors: FloatArray
    curvature: FloatArray
    description: str

    @property
    def n_terms(self) -> int:
        return int(self.vectors.shape[2])

    @classmethod
    def fourier(
        cls, grid: WavelengthGrid, n_terms: int = DEFAULT_FOURIER_TERMS
    ) -> SensitivityBasis:
        """The paper's choice: ``n_terms`` Fourier functions over the grid, for every channel."""
        vectors = np.broadcast_to(fourier_basis(grid, n_terms), (3, grid.size, n_terms))
        curvature = np.broadcast_to(fourier_curvature(grid, n_terms), (3, grid.size, n_terms))
        return cls(grid, np.array(vectors), np.array(curvature), f"Fourier, {n_terms} terms")

    @classmethod
    def from_camera_basis(cls, basis: CameraBasis) -> SensitivityBasis:
        """Footnote 2 of the paper: eigenvectors of measured cameras' sensitivities.

        ``Φ`` is the second difference of the vectors on the grid, scaled like the Fourier one
        (normalised wavelength, ``1/((2π)² √f)``).
        """
        grid = basis.grid
        vectors = np.asarray(basis.vectors, dtype=np.float64)
        steps = grid.size - 1
        curvature = (
            np.diff(vectors, n=2, axis=1) * steps**2 / ((2 * np.pi) ** 2 * math.sqrt(grid.size))
        )
        return cls(
            grid, vectors, curvature, f"camera basis: {basis.source}, {basis.n_vectors} per channel"
        )

    def emission_integrals(self, emission: MultiSpectrum) -> FloatArray:
        """``t_cpm = ∫ e_p b_cm dλ`` with each ``e_p`` of unit area, shape ``(3, P, M)``.

        On a 1 nm axis (emission bands are narrower than the grid step), the basis functions
        linear between grid nodes.
        """
        grid = self.grid
        axis = np.arange(grid.start_nm, grid.stop_nm + 0.5, 1.0)
        values = np.stack(
            [
                np.interp(axis, emission.wavelength_nm, emission.values[:, p], 0.0, 0.0)
                for p in range(emission.values.shape[1])
            ],
            axis=1,
        )
        areas = np.trapezoid(values, axis, axis=0)
        if np.any(areas <= 0):
            empty = np.flatnonzero(areas <= 0).tolist()
            raise InputError(
                f"emission spectra {empty} are zero over {grid.start_nm:g}–{grid.stop_nm:g} nm",
                source=emission.name,
            )
        fine = hat_matrix(grid, axis) @ self.vectors  # (3, n_fine, M)
        integrals = np.trapezoid(values[None, :, :, None] * fine[:, :, None, :], axis, axis=1)
        return np.asarray(integrals / areas[None, :, None], dtype=np.float64)


def chromaticity_system(chromaticity: FloatArray, integrals: FloatArray) -> FloatArray:
    """``A`` of Eq. 15, shape ``(3P, 3M)``.

    Parameters
    ----------
    chromaticity
        Shape ``(P, 3)``: ``(r, g, b)`` of each patch's fluorescent component.
    integrals
        Shape ``(3, P, M)``: ``t_cpm`` (equal for the three channels with the Fourier basis).
    """
    _, n_paints, n_terms = integrals.shape
    system = np.zeros((3 * n_paints, 3 * n_terms))
    for p in range(n_paints):
        for row in range(3):
            for channel in range(3):
                factor = chromaticity[p, row] - (1.0 if channel == row else 0.0)
                system[3 * p + row, channel * n_terms : (channel + 1) * n_terms] = (
                    factor * integrals[channel, p]
                )
    return system


def solve_sensitivity(
    system: FloatArray,
    curvature: FloatArray,
    smoothness: Sequence[float],
    integrals: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Eq. 16: the ``X`` minimising ``‖A X‖² + Σ_c w_c² ‖Φ_c β_c‖²`` under a normalisation.

    Parameters
    ----------
    system
        ``A``, shape ``(rows, 3M)``.
    curvature
        ``Φ`` per channel, shape ``(3, r, M)``.
    smoothness
        ``(w_R, w_G, w_B)``.
    integrals
        ``t_cpm`` of shape ``(3, P, M)``: when given, ``X`` is normalised by the patches' predicted
        brightness, ``Σ_p (Σ_c t_cp · β_c)² = 1`` (a generalised eigenproblem), so the objective is
        a relative chromaticity error; ``None``: ``‖X‖ = 1`` as in the paper, which lets
        combinations that are nearly dark on every paint (broad emission bands leave some)
        satisfy ``A X ≈ 0`` without matching any chromaticity.

    Returns
    -------
    (coefficients, eigenvalues)
        ``X`` of shape ``(3M,)`` (sign: positive sum) and the ascending (generalised) eigenvalues
        (their gap says how well the solution is determined).
    """
    n_terms = curvature.shape[2]
    blocks = [system]
    for channel, weight in enumerate(smoothness):
        block = np.zeros((curvature.shape[1], 3 * n_terms))
        block[:, channel * n_terms : (channel + 1) * n_terms] = weight * curvature[channel]
        blocks.append(block)
    stacked = np.vstack(blocks)
    normal = stacked.T @ stacked
    if integrals is None:
        eigenvalues, eigenvectors = np.linalg.eigh(normal)
    else:
        from scipy import linalg  # deferred: scipy.linalg is slow to import

        brightness = np.concatenate(list(integrals), axis=1)  # (P, 3M): Σ_c t_cp · β_c
        metric = brightness.T @ brightness
        # The brightness form has rank P at most: a tiny ridge keeps it definite.
        metric += 1e-9 * np.trace(metric) / metric.shape[0] * np.eye(metric.shape[0])
        eigenvalues, eigenvectors = linalg.eigh(normal, metric)
    solution = eigenvectors[:, 0] / np.linalg.norm(eigenvectors[:, 0])
    return solution * (1.0 if solution.sum() >= 0 else -1.0), np.asarray(eigenvalues, float)


def recover_daylight(
    reference_rgb: FloatArray,
    reference_reflectance: MultiSpectrum,
    sensitivity: FloatArray,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> Spectrum:
    """The illuminant as ``Σ γ_j S_j`` from the reference chart's RGBs (Eq. 17–19), maximum 1.

    Parameters
    ----------
    reference_rgb
        Shape ``(Q, 3)``.
    reference_reflectance
        The ``Q`` reflectances.
    sensitivity
        Shape ``(f, 3)`` on ``grid`` (any scale).
    """
    reflectance = reference_reflectance.resample(grid).values
    basis = daylight_basis(grid)
    step = grid.step_nm
    # design[q, c, j] = ∫ s_q c_c S_j dλ
    design = np.einsum("fq,fc,fj->qcj", reflectance, sensitivity, basis) * step
    coefficients, *_ = np.linalg.lstsq(design.reshape(-1, 3), reference_rgb.reshape(-1), rcond=None)
    values = basis @ coefficients
    peak = float(values.max())
    if peak <= 0:
        raise EstimationError("the recovered daylight is not positive anywhere")
    return Spectrum(
        grid.wavelength_nm, np.clip(values / peak, 0.0, None), name="recovered daylight"
    )


@dataclass(frozen=True, eq=False)
class Han2012Result:
    """What :func:`recover_han2012` found.

    Attributes
    ----------
    wavelength_nm
        Shape ``(f,)``: the grid.
    sensitivity
        Shape ``(f, 3)``: R, G, B, maximum over all channels 1.
    coefficients
        Shape ``(3, M)``: Fourier coefficients ``β`` (same scale).
    illuminant
        The recovered daylight (maximum 1), or ``None`` when not asked for.
    separation
        The reflective/fluorescent split of the fluorescent patches.
    eigenvalues
        Ascending eigenvalues of the normal matrix of Eq. 16.
    settings
        Fourier terms, reflectance vectors, smoothness weights.
    """

    wavelength_nm: FloatArray
    sensitivity: FloatArray
    coefficients: FloatArray
    illuminant: Spectrum | None
    separation: Separation
    eigenvalues: FloatArray
    settings: dict[str, Any] = field(default_factory=dict)

    def to_estimate_result(self) -> EstimateResult:
        """As the registry's :class:`calib.core.result.EstimateResult` (illuminant in diagnostics)."""
        illuminant = None
        if self.illuminant is not None:
            illuminant = {
                "wavelength_nm": self.illuminant.wavelength_nm,
                "values": self.illuminant.values,
            }
        chromaticity = self.separation.chromaticity
        return EstimateResult(
            method="han2012",
            wavelength_nm=self.wavelength_nm,
            sensitivity=self.sensitivity,
            residuals={"reference_rgb": self.separation.reference_residual},
            diagnostics={
                **self.settings,
                "illuminant": illuminant,
                "fluorescent_chromaticity": chromaticity,
                "fluorescent_fraction": self.separation.fluorescent_fraction,
                "eigenvalue_ratio": float(self.eigenvalues[1] / max(self.eigenvalues[0], 1e-300)),
            },
        )


@dataclass(frozen=True)
class Han2012Options:
    """Options of :func:`estimate_han2012` (checked on construction).

    Attributes
    ----------
    n_terms
        Fourier functions per channel (the paper's 9; with the Fourier basis).
    n_reflectance_vectors
        Reflectance basis size for the separation (the paper's 8).
    smoothness
        ``(w_R, w_G, w_B)`` in this module's units (see the module docstring).
    normalisation
        ``"brightness"`` (default): the solution is scaled by the paints' predicted brightness
        (see :func:`solve_sensitivity`); ``"unit"``: the paper's unit-norm eigenvector.
    weighting
        ``"fraction"`` (default): each patch's equations weighted by its fluorescent share of the
        signal; ``"paper"``: all equal. Patches left with no fluorescence in some channel are left
        out either way (listed in the diagnostics).
    recover_illuminant
        Also recover the light as a CIE daylight (Eq. 17–19).
    """

    n_terms: int = DEFAULT_FOURIER_TERMS
    n_reflectance_vectors: int = DEFAULT_REFLECTANCE_VECTORS
    smoothness: tuple[float, float, float] = DEFAULT_SMOOTHNESS
    normalisation: Normalisation = "brightness"
    weighting: RowWeighting = "fraction"
    recover_illuminant: bool = True

    def __post_init__(self) -> None:
        smoothness = tuple(float(w) for w in self.smoothness)
        if len(smoothness) != 3 or any(w < 0 or not math.isfinite(w) for w in smoothness):
            raise InputError(
                f"smoothness needs 3 finite weights >= 0, got {self.smoothness}",
                source="smoothness",
            )
        object.__setattr__(self, "smoothness", smoothness)
        if self.n_terms < 1:
            raise InputError(
                f"need at least one Fourier term, got {self.n_terms}", source="n_terms"
            )
        if self.weighting not in ("fraction", "paper"):
            raise InputError(
                f"weighting must be 'fraction' or 'paper', got {self.weighting!r}",
                source="weighting",
            )
        if self.normalisation not in ("brightness", "unit"):
            raise InputError(
                f"normalisation must be 'brightness' or 'unit', got {self.normalisation!r}",
                source="normalisation",
            )


#: The paper's basis: Fourier functions (``basis="fourier"``), not measured cameras.
FOURIER: Literal["fourier"] = "fourier"


@one_blas_thread
def recover_han2012(
    chart: FluorescentChart,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    basis: CameraBasis | Literal["fourier"] = FOURIER,
    options: Han2012Options = Han2012Options(),
) -> Han2012Result:
    """Camera sensitivity (and the daylight) from one chart image (Han et al. 2012), in full.

    Parameters
    ----------
    chart
        The fluorescent and reference patches' RGBs and spectra.
    grid
        Working grid; the Fourier basis spans it (the paper's ``[λ_l, λ_u]``).
    basis
        ``"fourier"``: the paper's Fourier basis of ``options.n_terms`` functions; a
        :class:`calib.model.bases.CameraBasis` (on ``grid``): eigenvectors of measured cameras, which
        the paper's footnote 2 suggests when such data are available.
    options
        :class:`Han2012Options`.

    Returns
    -------
    Han2012Result
        The curves, the recovered light, the separation and the eigenvalues
        (:func:`estimate_han2012` gives the registry's :class:`~calib.core.result.EstimateResult`).
    """
    n_terms, n_reflectance_vectors = options.n_terms, options.n_reflectance_vectors
    smoothness, normalisation = options.smoothness, options.normalisation
    weighting, recover_illuminant = options.weighting, options.recover_illuminant
    if isinstance(basis, CameraBasis) and basis.grid != grid:
        raise InputError(
            f"the camera basis is on {basis.grid}, the working grid is {grid}", source="basis"
        )
    functions = (
        SensitivityBasis.from_camera_basis(basis)
        if isinstance(basis, CameraBasis)
        else SensitivityBasis.fourier(grid, n_terms)
    )
    unknowns = 3 * functions.n_terms - 1
    if 2 * chart.n_paints < unknowns and not any(smoothness):
        raise InputError(
            f"{chart.n_paints} fluorescent patches give {2 * chart.n_paints} independent equations "
            f"for {unknowns} unknowns; use more patches, fewer terms or smoothness",
            source=f"chart {chart.name!r}",
        )
    separation = separate_fluorescence(chart, grid, n_reflectance_vectors)
    usable = separation.usable
    if usable.sum() < 2:
        raise EstimationError(
            f"only {int(usable.sum())} of {chart.n_paints} fluorescent patches still fluoresce "
            f"(in every channel, for ≥ {MIN_FLUORESCENT_FRACTION:.0%} of their signal) once their "
            "reflection is removed; the light lacks the short "
            "wavelengths the paints absorb (daylight, especially skylight, works best)"
        )
    integrals = functions.emission_integrals(chart.emission)[:, usable]
    system = chromaticity_system(separation.chromaticity[usable], integrals)
    if weighting == "fraction":
        # A patch's chromaticity is as good as its separation: the error of the predicted
        # reflection, relative to the fluorescence, grows as reflection / fluorescence.
        fraction = separation.fluorescent_fraction[usable]
        system = system * np.repeat(fraction / fraction.max(), 3)[:, None]
    solution, eigenvalues = solve_sensitivity(
        system,
        functions.curvature,
        smoothness,
        integrals if normalisation == "brightness" else None,
    )
    coefficients = solution.reshape(3, functions.n_terms)
    sensitivity = np.einsum("cfm,cm->fc", functions.vectors, coefficients)
    peak = float(np.max(np.abs(sensitivity)))
    if peak <= 0:
        raise EstimationError("the chromaticity system gave a zero sensitivity")
    sensitivity = sensitivity / peak
    illuminant = (
        recover_daylight(chart.reference_rgb, chart.reference_reflectance, sensitivity, grid)
        if recover_illuminant
        else None
    )
    return Han2012Result(
        wavelength_nm=grid.wavelength_nm,
        sensitivity=sensitivity,
        coefficients=coefficients / peak,
        illuminant=illuminant,
        separation=separation,
        eigenvalues=eigenvalues,
        settings={
            "grid": str(grid),
            "basis": functions.description,
            "reflectance_vectors": n_reflectance_vectors,
            "reflectance_basis": "rawtoaces 190 training reflectances (SVD)",
            "smoothness": list(smoothness),
            "normalisation": normalisation,
            "weighting": weighting,
            "patches_left_out": np.flatnonzero(~usable).tolist(),
            "chart": chart.name,
        },
    )


def estimate_han2012(
    observations: Sequence[object],
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    basis: CameraBasis | Literal["fourier"] = FOURIER,
    options: Han2012Options = Han2012Options(),
) -> EstimateResult:
    """The registry's ``"han2012"``: :func:`recover_han2012` on the one chart in ``observations``.

    Raises
    ------
    InputError
        ``observations`` is not exactly one :class:`FluorescentChart`.

    Examples
    --------
    >>> import numpy as np
    >>> from calib.core.colour_data import cie_daylight, colorchecker
    >>> from calib.core.datasets import colour_science_cameras
    >>> rng = np.random.default_rng(6)
    >>> chart = render_fluorescent_chart(
    ...     synthetic_fluorescent_paints(rng),
    ...     colorchecker(),
    ...     colour_science_cameras()[0].sensitivity,
    ...     cie_daylight(6500),
    ... )
    >>> estimate_han2012([chart]).method
    'han2012'
    """
    charts = [item for item in observations if isinstance(item, FluorescentChart)]
    if len(charts) != 1 or len(observations) != 1:
        raise InputError(
            "han2012 works from one image of a fluorescent and a reference chart: call "
            "estimate([FluorescentChart(...)], method='han2012'); it uses no lamp observations",
            source="observations",
        )
    return recover_han2012(charts[0], grid=grid, basis=basis, options=options).to_estimate_result()


# -------------------------------------------------------------------------------- synthetic data


@dataclass(frozen=True, eq=False)
class FluorescentPaints:
    """Spectra of fluorescent paints on one wavelength axis (``P`` curves each).

    Attributes
    ----------
    absorption
        ``a_p(λ')``: how strongly each paint absorbs (0…1), from the UV on.
    emission
        ``e_p(λ)``: its emission spectrum, unit area.
    reflectance
        Its reflectance (the Donaldson matrix's diagonal).
    quantum_yield
        Shape ``(P,)``: emitted / absorbed energy.
    """

    absorption: MultiSpectrum
    emission: MultiSpectrum
    reflectance: MultiSpectrum
    quantum_yield: FloatArray


def synthetic_fluorescent_paints(
    rng: np.random.Generator,
    n_paints: int = 16,
    *,
    emission_range_nm: tuple[float, float] = (440.0, 640.0),
) -> FluorescentPaints:
    """A seeded set of fluorescent poster paints on 300–780 nm (1 nm), like the paper's chart.

    Emission peaks spread over ``emission_range_nm`` (jittered), each a skewed band 30–60 nm wide
    with a longer red tail; absorption is a band 40–80 nm below the emission peak (Stokes shift)
    over a UV shoulder; reflectance is low where the paint absorbs and 0.6–0.9 from just below its
    emission peak up (warm paints) or over a band around it (green and blue paints).
    """
    if n_paints < 2:
        raise InputError(f"need at least 2 paints, got {n_paints}", source="n_paints")
    wavelength = np.arange(300.0, 781.0, 1.0)
    peaks = np.linspace(*emission_range_nm, n_paints) + rng.uniform(-6.0, 6.0, n_paints)
    absorption, emission, reflectance = [], [], []
    for peak in peaks:
        width = rng.uniform(30.0, 60.0)
        sigma_blue, sigma_red = width / 2.8, width / 2.0
        sigma = np.where(wavelength < peak, sigma_blue, sigma_red)
        band = np.exp(-0.5 * ((wavelength - peak) / sigma) ** 2)
        emission.append(band / np.trapezoid(band, wavelength))
        absorption_peak = peak - rng.uniform(40.0, 80.0)
        absorption_width = rng.uniform(25.0, 45.0)
        shoulder = 0.4 / (1.0 + np.exp((wavelength - 380.0) / 12.0))
        absorbed = 0.9 * np.exp(-0.5 * ((wavelength - absorption_peak) / absorption_width) ** 2)
        absorption.append(np.clip(shoulder + absorbed, 0.0, 0.95))
        # The paint's colour: it reflects from just below its emission peak up to a cut-off (far
        # beyond 700 nm for yellow, orange and red paints, a band for green and blue ones).
        rise = peak - rng.uniform(5.0, 25.0)
        fall = peak + rng.uniform(60.0, 140.0) if peak < 540.0 else 900.0
        high = rng.uniform(0.6, 0.9)
        low = rng.uniform(0.03, 0.1)
        window = 1.0 / (1.0 + np.exp(-(wavelength - rise) / 8.0))
        window = window / (1.0 + np.exp((wavelength - fall) / 15.0))
        reflectance.append(low + (high - low) * window)
    channels = [f"paint {k + 1}" for k in range(n_paints)]
    return FluorescentPaints(
        absorption=MultiSpectrum(wavelength, np.stack(absorption, 1), channels, "absorption"),
        emission=MultiSpectrum(wavelength, np.stack(emission, 1), channels, "emission"),
        reflectance=MultiSpectrum(wavelength, np.stack(reflectance, 1), channels, "reflectance"),
        quantum_yield=rng.uniform(0.5, 0.9, n_paints),
    )


def render_fluorescent_chart(
    paints: FluorescentPaints,
    reference: MultiSpectrum,
    camera: MultiSpectrum,
    illuminant: Spectrum,
    *,
    rng: np.random.Generator | None = None,
    noise_fraction: float = 0.0,
    name: str = "synthetic chart",
) -> FluorescentChart:
    """What the camera records of the paints and the reference chart under ``illuminant``.

    Reflected light ``∫ s c l dλ`` and emitted light ``∫ e_p c dλ`` as
    :func:`calib.model.charts.chart_rgb` renders any chart; fluorescence
    ``y_p (∫ a_p l dλ') ∫ e_p c dλ`` with the absorbed energy taken over 300–780 nm (daylight's UV
    included). Gaussian noise of ``noise_fraction`` × the brightest patch value, from ``rng``.
    """
    check_noise_request(noise_fraction, rng)
    axis = np.arange(300.0, 781.0, 1.0)
    absorption = np.stack(
        [
            np.interp(axis, paints.absorption.wavelength_nm, column, 0.0, 0.0)
            for column in paints.absorption.values.T
        ],
        axis=1,
    )
    absorbed = np.trapezoid(absorption * illuminant.at(axis)[:, None], axis, axis=0)
    emitted = chart_rgb(paints.emission, None, camera)
    fluorescent = (
        chart_rgb(paints.reflectance, illuminant, camera)
        + (paints.quantum_yield * absorbed)[:, None] * emitted
    )
    reference_rgb = chart_rgb(reference, illuminant, camera)
    fluorescent_sigma = reference_sigma = None
    if noise_fraction > 0 and rng is not None:
        level = noise_fraction * float(max(fluorescent.max(), reference_rgb.max()))
        fluorescent_sigma = np.full(fluorescent.shape, level)
        reference_sigma = np.full(reference_rgb.shape, level)
        fluorescent = fluorescent + rng.standard_normal(fluorescent.shape) * level
        reference_rgb = reference_rgb + rng.standard_normal(reference_rgb.shape) * level
    return FluorescentChart(
        fluorescent_rgb=fluorescent,
        reference_rgb=reference_rgb,
        emission=paints.emission,
        fluorescent_reflectance=paints.reflectance,
        reference_reflectance=reference,
        fluorescent_sigma=fluorescent_sigma,
        reference_sigma=reference_sigma,
        name=name,
    )
