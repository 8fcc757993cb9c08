"""Colour-matrix baseline ("Exif+CC"): sensitivities from a camera's DNG ColorMatrix1/2 and a chart.

A DNG's ``ColorMatrix1/2`` map CIE XYZ to the camera's native RGB for surfaces under the calibration
illuminants (EXIF LightSource codes in ``CalibrationIlluminant1/2``). Solomatov & Akkaynak (2023) learn
sensitivities from these matrices with a neural network; here the same information is used by
constrained least squares in the measured-camera basis, no network:

1. For each matrix ``M_k`` and a set of training reflectances ``ρ_j`` (ColorChecker + CIE test colour
   samples) under its illuminant ``L_k``, the camera should see ``y_jk = M_k · XYZ(L_k ρ_j)``, i.e. for
   channel ``c``: ``Σ_i A^(k)_ji s_ci = g_ck · y_jck`` with the stimulus rows ``A^(k)`` of
   :func:`calib.model.charts.radiance_rows`. Every row of a DNG matrix carries its own unknown scale (the
   white balance), hence one gain ``g_ck`` per channel and matrix (``g_c1 = 1``).
2. ``s_c = B_c x_c`` in the leading ``k`` vectors of the dataset basis, with a ridge term pulling
   towards the dataset mean ``ŝ_c`` (the matrices fix only ~3 numbers per channel each) and the
   constraints ``s_c(λ_i) ≥ 0``, ``g ≥ 0`` (:mod:`calib.model.inequality_lstsq`).
3. The per-channel scales the matrices leave open are taken from a colour checker of known
   reflectances under a known light, as Makabe et al. (2025) §4 resolve the Exif method's
   white-balance ambiguity: a gain per channel (``white_balance="diagonal"``), or a full 3×3
   (``"full"``) when the matrices' rows are not trusted either.

The matrices are read from a DNG with tifffile (:func:`read_color_matrices`); other RAW formats fall
back to LibRaw's built-in table (``rawpy``'s ``rgb_xyz_matrix``, Adobe's D65 matrices for cameras it
knows). :func:`simulate_color_matrix` makes the matrix a camera maker would publish from known
sensitivities (least squares over a patch set), for the synthetic protocol and tests.

References
----------
Solomatov, G., Akkaynak, D. (2023). Spectral Sensitivity Estimation Without a Camera. ICCP.
Makabe, L. et al. (2025). Spectral Sensitivity Estimation with an Uncalibrated Diffraction Grating,
§4 ("Exif+CC"). Adobe, Digital Negative (DNG) Specification 1.6, ColorMatrix1/2,
CalibrationIlluminant1/2.
"""

from __future__ import annotations

import os
import struct
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread
from calib.core.colour_data import cie_test_colour_samples, colorchecker, colour_matching_functions
from calib.core.errors import InputError
from calib.core.lamp_specs import colour_lamp
from calib.core.observations import ChartObservation, ColorMatrixObservation, Observation
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum, WavelengthGrid
from calib.methods.baselines.inputs import (
    check_basis,
    check_weight,
    normalised_curves,
    split_observations,
)
from calib.model.bases import CameraBasis
from calib.model.charts import combined, radiance_rows, stimulus_rows
from calib.model.inequality_lstsq import lstsq_inequality

WhiteBalance = Literal["diagonal", "full", "none"]

#: Basis vectors per channel and ridge weight (chosen by leave-one-out over 22 of the 44 training
#: cameras of Makabe et al.'s split with simulated matrices; docs/decisions/0009).
SOLOMATOV2023_N_VECTORS = 5
SOLOMATOV2023_RIDGE = 0.1

#: EXIF/DNG LightSource codes with a colour-science illuminant (DNG spec, CalibrationIlluminant).
LIGHT_SOURCES: dict[int, str] = {
    3: "A",  # tungsten (incandescent) — CIE A by definition
    12: "FL1",  # daylight fluorescent
    14: "FL2",  # cool white fluorescent
    15: "FL3",  # white fluorescent
    16: "FL4",  # warm white fluorescent
    17: "A",
    18: "B",
    19: "C",
    20: "D55",
    21: "D65",
    22: "D75",
    23: "D50",
}

_COLOR_MATRIX_TAGS = (50721, 50722)
_CALIBRATION_ILLUMINANT_TAGS = (50778, 50779)
_UNIQUE_CAMERA_MODEL_TAG = 50708
_CMFS = "CIE 1931 2 Degree Standard Observer"


# ----------------------------------------------------------------------------- reading


def _rationals(value: Any) -> FloatArray:
    """TIFF (S)RATIONAL values as floats (tifffile gives ``(num, den, num, den, …)``)."""
    numbers = np.asarray(value, dtype=np.float64).ravel()
    if numbers.size % 2:
        raise ValueError("odd number of rational parts")
    numerators, denominators = numbers[0::2], numbers[1::2]
    if np.any(denominators == 0):
        raise ValueError("zero denominator")
    return numerators / denominators


def _illuminant_name(code: int, path: Path, tag: str) -> str:
    if code not in LIGHT_SOURCES:
        raise InputError(
            f"{tag} is EXIF LightSource {code}, which has no standard spectrum here (known: "
            f"{sorted(LIGHT_SOURCES)}); pass illuminants=[...] with the names or measured spectra",
            source=str(path),
        )
    return LIGHT_SOURCES[code]


def _dng_matrices(
    path: Path,
) -> tuple[list[FloatArray], list[int | None], str | None] | None:
    """ColorMatrix1/2, CalibrationIlluminant1/2 and the camera name of a TIFF-based file."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tiff:
            tags = tiff.pages.first.tags
            matrices: list[FloatArray] = []
            codes: list[int | None] = []
            for matrix_tag, illuminant_tag in zip(
                _COLOR_MATRIX_TAGS, _CALIBRATION_ILLUMINANT_TAGS, strict=True
            ):
                entry = tags.get(matrix_tag)
                if entry is None:
                    continue
                try:
                    values = _rationals(entry.value)
                except ValueError as exc:
                    raise InputError(f"damaged {entry.name} tag ({exc})", source=str(path)) from exc
                if values.size != 9:
                    raise InputError(
                        f"{entry.name} has {values.size} values; only 3-colour cameras (9) are "
                        "supported",
                        source=str(path),
                    )
                matrices.append(values.reshape(3, 3))
                code = tags.get(illuminant_tag)
                codes.append(None if code is None else int(np.ravel(code.value)[0]))
            model = tags.get(_UNIQUE_CAMERA_MODEL_TAG)
            if model is None:
                parts = [tags.get(271), tags.get(272)]
                text = " ".join(str(p.value).strip() for p in parts if p is not None)
                name = text or None
            else:
                name = str(model.value).strip()
    except (tifffile.TiffFileError, struct.error):
        return None  # not TIFF-based: the caller asks LibRaw
    return matrices, codes, name


def _libraw_matrix(path: Path) -> FloatArray | None:
    """LibRaw's XYZ→camera matrix for the file's camera (its built-in Adobe D65 table), if any."""
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            matrix = np.array(raw.rgb_xyz_matrix[:3], dtype=np.float64)
    except (rawpy.LibRawError, OSError):
        return None
    return matrix if np.any(matrix != 0) else None


def read_color_matrices(
    path: str | os.PathLike[str], *, illuminants: Sequence[str | Spectrum] | None = None
) -> ColorMatrixObservation:
    """Read a camera's XYZ→camera matrices from a RAW file.

    DNG: ``ColorMatrix1`` and (if present) ``ColorMatrix2`` with ``CalibrationIlluminant1/2``
    (tifffile). Other RAW formats: LibRaw's built-in matrix for the camera (Adobe's, for D65).

    Parameters
    ----------
    path
        A DNG, or a RAW file of a camera LibRaw knows.
    illuminants
        Override the calibration illuminants (names or spectra), one per matrix: needed when a
        file names a LightSource without a standard spectrum, or to use measured ones.

    Returns
    -------
    ColorMatrixObservation

    Raises
    ------
    InputError
        Missing file, no matrix anywhere, unknown calibration illuminant.
    """
    file = Path(path)
    if not file.is_file():
        raise InputError("file not found", source=str(file))
    found = _dng_matrices(file)
    name = file.stem
    source: str
    if found is not None and found[0]:
        matrices, codes, camera = found
        name = camera or name
        if illuminants is None:
            names: list[str | Spectrum] = []
            for index, code in enumerate(codes):
                tag = f"CalibrationIlluminant{index + 1}"
                if code is None:
                    raise InputError(
                        f"ColorMatrix{index + 1} has no {tag}; pass illuminants=[...]",
                        source=str(file),
                    )
                names.append(_illuminant_name(code, file, tag))
            chosen: Sequence[str | Spectrum] = names
        else:
            chosen = illuminants
        source = f"{file} (DNG ColorMatrix1{'/2' if len(matrices) > 1 else ''})"
    else:
        matrix = _libraw_matrix(file)
        if matrix is None:
            raise InputError(
                "no colour matrix: not a DNG with ColorMatrix1, and LibRaw has no matrix for "
                "this camera; convert the file with Adobe DNG Converter",
                source=str(file),
            )
        matrices = [matrix]
        chosen = illuminants if illuminants is not None else ["D65"]
        source = f"{file} (LibRaw built-in matrix, D65)"
    return ColorMatrixObservation(
        name=name, matrices=np.stack(matrices), illuminants=tuple(chosen), source=source
    )


# ------------------------------------------------------------------------------ model


def calibration_illuminant(value: str | Spectrum) -> Spectrum:
    """A calibration illuminant as a spectrum (colour-science name, or a given spectrum)."""
    if isinstance(value, Spectrum):
        return value
    return colour_lamp(value)


def _cmfs_on_grid(grid: WavelengthGrid) -> FloatArray:
    wavelength, values = colour_matching_functions(_CMFS)
    curves = MultiSpectrum(wavelength, values, channels=("x", "y", "z"), name=_CMFS)
    return curves.resample(grid, "interpolate").values


def default_training_reflectances(grid: WavelengthGrid = DEFAULT_GRID) -> MultiSpectrum:
    """BabelColor's ColorChecker (24) and the CIE 1995 test colour samples (14), on a 1 nm axis."""
    return combined([colorchecker(), cie_test_colour_samples("CIE 1995")], grid)


def simulate_color_matrix(
    sensitivity: ArrayLike,
    illuminant: str | Spectrum,
    grid: WavelengthGrid = DEFAULT_GRID,
    *,
    reflectances: MultiSpectrum | None = None,
) -> FloatArray:
    """The XYZ→camera matrix a maker would fit for known sensitivities (as in a DNG ColorMatrix).

    Least squares ``camera ≈ M · XYZ`` over patches under the illuminant, scaled so that the
    illuminant's white (Y = 1) maps to a camera vector with maximum 1 (the row scales are the
    white-balance freedom the estimator does not rely on).

    Parameters
    ----------
    sensitivity
        Shape ``(f, 3)`` on ``grid``.
    illuminant
        Calibration illuminant (name or spectrum).
    reflectances
        Patches to fit over; default the ColorChecker N Ohta data plus the CIE 2024 test colour
        samples (deliberately not the estimator's own training set).

    Returns
    -------
    numpy.ndarray
        Shape ``(3, 3)``, rows R, G, B, columns X, Y, Z.
    """
    curves = np.asarray(sensitivity, dtype=np.float64)
    if curves.shape != (grid.size, 3):
        raise InputError(
            f"sensitivity must have shape ({grid.size}, 3), got {curves.shape}",
            source="sensitivity",
        )
    patches = reflectances or combined(
        [colorchecker("ColorChecker N Ohta"), cie_test_colour_samples("CIE 2024")], grid
    )
    light = calibration_illuminant(illuminant)
    rows = radiance_rows(patches, light, grid)
    cmfs = _cmfs_on_grid(grid)
    xyz = rows @ cmfs
    camera = rows @ curves
    matrix_t, *_ = np.linalg.lstsq(xyz, camera, rcond=None)
    matrix = matrix_t.T
    white = radiance_rows(
        MultiSpectrum(grid.wavelength_nm, np.ones((grid.size, 1)), channels=("white",)),
        light,
        grid,
    )
    white_xyz = (white @ cmfs)[0]
    scale = float(np.max(matrix @ (white_xyz / white_xyz[1])))
    return np.asarray(matrix / scale, dtype=np.float64)


def _channel_fit(
    vectors: FloatArray,
    prior: FloatArray,
    blocks: Sequence[tuple[FloatArray, FloatArray]],
    ridge: float,
) -> tuple[FloatArray, FloatArray, float]:
    """Coefficients, per-matrix gains and the relative misfit for one channel.

    ``blocks``: per matrix, stimulus rows ``(n, f)`` and targets ``y`` ``(n,)``.
    """
    k = vectors.shape[1]
    n_matrices = len(blocks)
    design_rows: list[FloatArray] = []
    targets: list[FloatArray] = []
    for index, (rows, target) in enumerate(blocks):
        weight = 1.0 / max(float(np.sqrt(np.mean(target**2))), 1e-300)
        block = np.zeros((rows.shape[0], k + n_matrices - 1))
        block[:, :k] = weight * (rows @ vectors)
        if index == 0:
            targets.append(weight * target)
        else:
            block[:, k + index - 1] = -weight * target
            targets.append(np.zeros(rows.shape[0]))
        design_rows.append(block)
    first_rows, first_target = blocks[0]
    predicted_prior = first_rows @ prior
    prior_scale = float(predicted_prior @ first_target) / max(
        float(predicted_prior @ predicted_prior), 1e-300
    )
    scaled_prior = prior_scale * prior
    n_data = sum(rows.shape[0] for rows, _ in blocks)
    if ridge > 0:
        rms = max(float(np.sqrt(np.mean(scaled_prior**2))), 1e-300)
        weight = np.sqrt(ridge * n_data / vectors.shape[0]) / rms
        block = np.zeros((vectors.shape[0], k + n_matrices - 1))
        block[:, :k] = weight * vectors
        design_rows.append(block)
        targets.append(weight * scaled_prior)
    design = np.vstack(design_rows)
    target_all = np.concatenate(targets)
    constraints = np.zeros((vectors.shape[0] + n_matrices - 1, k + n_matrices - 1))
    constraints[: vectors.shape[0], :k] = vectors
    constraints[vectors.shape[0] :, k:] = np.eye(n_matrices - 1)
    solution = lstsq_inequality(design, target_all, constraints, np.zeros(constraints.shape[0]))
    data_rows = np.vstack(design_rows[:n_matrices])
    data_target = np.concatenate(targets[:n_matrices])
    misfit = float(np.linalg.norm(data_rows @ solution - data_target) / np.sqrt(data_target.size))
    return solution[:k], np.concatenate([[1.0], solution[k:]]), misfit


def _white_balance(
    sensitivity: FloatArray,
    charts: Sequence[ChartObservation],
    grid: WavelengthGrid,
    mode: WhiteBalance,
) -> tuple[FloatArray, FloatArray]:
    """Apply the chart's channel gains (``"diagonal"``) or 3×3 (``"full"``); returns the new curves
    and the transform ``(3, 3)`` (curves_new = curves @ transform)."""
    rows = np.vstack([stimulus_rows(chart, grid) for chart in charts])
    observed = np.vstack([chart.patch_rgb for chart in charts])
    sigmas = [chart.patch_sigma for chart in charts]
    weights = (
        np.ones_like(observed) if any(s is None for s in sigmas) else 1.0 / np.vstack(sigmas)  # type: ignore[arg-type]
    )
    predicted = rows @ sensitivity
    if mode == "diagonal":
        gains = np.sum(weights**2 * predicted * observed, axis=0) / np.maximum(
            np.sum((weights * predicted) ** 2, axis=0), 1e-300
        )
        transform = np.diag(gains)
    else:
        transform = np.empty((3, 3))
        for channel in range(3):
            w = weights[:, channel]
            transform[:, channel] = np.linalg.lstsq(
                predicted * w[:, None], observed[:, channel] * w, rcond=None
            )[0]
    return sensitivity @ transform, transform


@one_blas_thread
def estimate_solomatov2023(
    observations: Sequence[Observation],
    *,
    basis: CameraBasis,
    grid: WavelengthGrid = DEFAULT_GRID,
    n_vectors: int = SOLOMATOV2023_N_VECTORS,
    ridge: float = SOLOMATOV2023_RIDGE,
    white_balance: WhiteBalance = "diagonal",
    training_reflectances: MultiSpectrum | None = None,
) -> EstimateResult:
    """Estimate sensitivities from colour matrices and a colour checker (see the module docstring).

    Parameters
    ----------
    observations
        Exactly one :class:`~calib.core.observations.ColorMatrixObservation` (the camera's
        ColorMatrix1, and 2, with their calibration illuminants; read one with
        :func:`read_color_matrices`) and the colour-chart observations resolving the channel scales
        (not needed with ``white_balance="none"``).
    basis
        Per-channel camera basis on ``grid`` (leading ``n_vectors`` used; its mean is the prior).
    grid
        Working grid.
    n_vectors
        Basis vectors per channel.
    ridge
        Weight of the pull towards the (rescaled) dataset mean, relative to the matrix data.
    white_balance
        ``"diagonal"`` (a gain per channel from the chart), ``"full"`` (a 3×3 from the chart) or
        ``"none"`` (channel scales from the matrices alone — the Exif-only ambiguity remains).
    training_reflectances
        Surfaces over which the matrices are matched (default
        :func:`default_training_reflectances`).

    Returns
    -------
    EstimateResult
    """
    started = time.perf_counter()
    groups = split_observations(
        observations,
        "solomatov2023",
        {"matrices": ColorMatrixObservation, "charts": ChartObservation},
    )
    if len(groups["matrices"]) != 1:
        raise InputError(
            f"solomatov2023 needs exactly one ColorMatrixObservation (read one with "
            f"calib.methods.baselines.solomatov2023.read_color_matrices), got "
            f"{len(groups['matrices'])}",
            source="observations",
        )
    matrices: ColorMatrixObservation = groups["matrices"][0]
    charts: list[ChartObservation] = groups["charts"]
    check_basis(basis, grid, n_vectors)
    check_weight(ridge, "ridge")
    if white_balance not in ("diagonal", "full", "none"):
        raise InputError(
            f"white_balance must be 'diagonal', 'full' or 'none', got {white_balance!r}",
            source="white_balance",
        )
    if white_balance != "none" and not charts:
        raise InputError(
            "colour matrices fix each channel only up to its own scale (white balance); give a "
            "colour-checker observation to resolve it, or white_balance='none' to accept it",
            source="solomatov2023",
        )
    reflectances = training_reflectances or default_training_reflectances(grid)
    cmfs = _cmfs_on_grid(grid)
    stimulus = [
        radiance_rows(reflectances, calibration_illuminant(light), grid, label=matrices.name)
        for light in matrices.illuminants
    ]
    targets = [
        (rows @ cmfs) @ matrix.T for rows, matrix in zip(stimulus, matrices.matrices, strict=True)
    ]
    sensitivity = np.empty((grid.size, 3))
    gains = np.empty((3, len(stimulus)))
    misfits: list[float] = []
    for channel in range(3):
        vectors = basis.channel(channel)[:, :n_vectors]
        blocks = [
            (rows, target[:, channel]) for rows, target in zip(stimulus, targets, strict=True)
        ]
        coefficients, gains[channel], misfit = _channel_fit(
            vectors, basis.mean[:, channel], blocks, ridge
        )
        sensitivity[:, channel] = vectors @ coefficients
        misfits.append(misfit)
    transform = np.eye(3)
    if white_balance != "none":
        sensitivity, transform = _white_balance(sensitivity, charts, grid, white_balance)
    curves, _, peak = normalised_curves(sensitivity, None, "solomatov2023")
    residuals: dict[str, Any] = {}
    for chart in charts:
        residuals[chart.name] = {
            "patch_rgb": chart.patch_rgb - stimulus_rows(chart, grid) @ sensitivity
        }
    diagnostics = {
        "basis": basis.to_dict(),
        "n_vectors": n_vectors,
        "ridge": ridge,
        "matrices": {
            "camera": matrices.name,
            "source": matrices.source,
            "illuminants": [
                light if isinstance(light, str) else light.name for light in matrices.illuminants
            ],
        },
        "matrix_gains": gains.tolist(),
        "matrix_misfit": misfits,
        "white_balance": white_balance,
        "white_balance_transform": transform.tolist(),
        "training_reflectances": reflectances.name,
        "sensitivity_scale": peak,
        "timings": {"total_s": time.perf_counter() - started},
    }
    return EstimateResult(
        method="solomatov2023",
        wavelength_nm=grid.wavelength_nm,
        sensitivity=curves,
        residuals=residuals,
        diagnostics=diagnostics,
    )
