"""A colour-correction matrix per illuminant, and how well the camera then reproduces a ColorChecker.

For an illuminant ``E`` the 24 ColorChecker patches (spectral reflectances ``ρ_i``) give

* camera RGB ``c_i = Σ_λ ρ_i E s Δλ`` from the sensitivities ``s`` (white-balanced: divided by the
  perfect white's RGB, so a neutral patch reads ``(1, 1, 1) × its reflectance``), and
* CIE XYZ ``x_i = Σ_λ ρ_i E x̄ Δλ / Σ_λ E ȳ Δλ`` (CIE 1931 2°, the white at Y = 1),

on 380–780 nm at 5 nm. The matrix ``M`` (white-balanced camera RGB → XYZ) maps the perfect white
exactly onto the illuminant's white, and otherwise minimises the patches' CIELAB differences
(least squares in XYZ to start, then in CIELAB); the report gives the ΔE2000 of each patch between
``M c_i`` and ``x_i``: how close a 3×3 matrix can bring this camera to colorimetry.

With a known truth, :func:`compare_with_truth` answers what a user cares about: develop the *real*
camera's RGB with the matrix fitted to the *estimate* and compare with (a) colorimetry and (b) the
same RGB developed with the matrix fitted to the truth — (b) is the colour error the estimate
itself costs.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.camera_curves import CameraCurves, as_camera
from calib.core.colour_data import (
    COLORCHECKER_OHTA,
    cie_1931_observer,
    colorchecker,
    delta_e_2000,
    use_illuminant,
    xyz_to_lab,
)
from calib.core.errors import InputError
from calib.core.spectra import WavelengthGrid

#: Every integral here is taken on this grid (rawtoaces' and the ColorChecker data's own).
INTEGRATION_GRID = WavelengthGrid(380.0, 780.0, 5.0)
#: The illuminants the report compares under.
REPORT_ILLUMINANTS: tuple[str, ...] = ("D65", "A")


@dataclass(frozen=True)
class DeltaE:
    """ΔE2000 per ColorChecker patch and its summary."""

    patches: tuple[str, ...]
    values: FloatArray

    @property
    def mean(self) -> float:
        return float(np.mean(self.values))

    @property
    def max(self) -> float:
        return float(np.max(self.values))

    @property
    def worst(self) -> str:
        return self.patches[int(np.argmax(self.values))]

    def to_dict(self) -> dict[str, Any]:
        return {
            "mean": self.mean,
            "max": self.max,
            "worst_patch": self.worst,
            "per_patch": {p: float(v) for p, v in zip(self.patches, self.values, strict=True)},
        }


@dataclass(frozen=True)
class ColourCorrection:
    """The colour-correction matrix of a camera under one illuminant.

    Attributes
    ----------
    illuminant
        ``"D65"``, ``"A"`` … (:data:`calib.core.colour_data.USE_ILLUMINANTS`).
    matrix
        ``(3, 3)``: white-balanced camera RGB → CIE XYZ (white at Y = 1).
    white_balance
        ``(3,)``: multipliers that make the illuminant neutral, green = 1.
    delta_e
        ΔE2000 of the 24 patches, ``M c_i`` against colorimetry.
    """

    illuminant: str
    matrix: FloatArray
    white_balance: FloatArray
    delta_e: DeltaE

    def to_dict(self) -> dict[str, Any]:
        return {
            "illuminant": self.illuminant,
            "matrix_camera_rgb_to_xyz": self.matrix.tolist(),
            "white_balance": self.white_balance.tolist(),
            "delta_e_2000": self.delta_e.to_dict(),
        }


@dataclass(frozen=True)
class _Scene:
    """The patches' XYZ and Lab under one illuminant, and what the camera integrals need."""

    patches: tuple[str, ...]
    weights: FloatArray  # (f, 24): ρ_i(λ) E(λ) Δλ
    white_weights: FloatArray  # (f,): E(λ) Δλ
    xyz: FloatArray  # (24, 3)
    white_xyz: FloatArray  # (3,)
    lab: FloatArray  # (24, 3)


@cache
def _scene(illuminant_name: str) -> _Scene:
    nodes = INTEGRATION_GRID
    step = nodes.step_nm
    power = use_illuminant(illuminant_name).resample(nodes).values
    reflectances = colorchecker(COLORCHECKER_OHTA).resample(nodes, out_of_range="zero")
    observer = cie_1931_observer().resample(nodes).values
    weights = reflectances.values * power[:, None] * step
    white = power * step
    norm = float(white @ observer[:, 1])
    xyz = weights.T @ observer / norm
    white_xyz = white @ observer / norm
    lab = xyz_to_lab(xyz, white_xyz)
    return _Scene(reflectances.channels, weights, white, xyz, white_xyz, lab)


def camera_rgb(camera: Any, illuminant_name: str) -> tuple[FloatArray, FloatArray]:
    """The ColorChecker's camera RGB ``(24, 3)`` under the illuminant, and the white's ``(3,)``.

    The camera is integrated on :data:`INTEGRATION_GRID` (zero where its curves stop).
    """
    curves = as_camera(camera)
    scene = _scene(illuminant_name)
    sensitivity = curves.at(INTEGRATION_GRID.wavelength_nm)
    return scene.weights.T @ sensitivity, scene.white_weights @ sensitivity


def _constrained_rows(rgb: FloatArray, xyz: FloatArray, white_xyz: FloatArray) -> FloatArray:
    """Least squares ``M`` with ``M (1, 1, 1) = white_xyz`` (each row: Lagrange's closed form)."""
    gram = rgb.T @ rgb
    inverse = np.linalg.inv(gram)
    ones = np.ones(3)
    rows = []
    for i in range(3):
        free = inverse @ (rgb.T @ xyz[:, i])
        correction = (white_xyz[i] - ones @ free) / (ones @ inverse @ ones)
        rows.append(free + correction * (inverse @ ones))
    return np.array(rows)


def _refine_in_lab(matrix: FloatArray, rgb: FloatArray, scene: _Scene) -> FloatArray:
    """Minimise the CIELAB residuals over the six free entries (the white stays exact)."""
    from scipy.optimize import least_squares

    def build(free: FloatArray) -> FloatArray:
        rows = free.reshape(3, 2)
        last = scene.white_xyz - rows.sum(axis=1)
        return np.column_stack([rows, last])

    def residuals(free: FloatArray) -> FloatArray:
        lab = xyz_to_lab(rgb @ build(free).T, scene.white_xyz)
        return np.asarray((lab - scene.lab).ravel(), dtype=np.float64)

    solution = least_squares(residuals, matrix[:, :2].ravel(), method="lm")
    return build(np.asarray(solution.x, dtype=np.float64))


def develop(rgb: FloatArray, white_rgb: FloatArray, matrix: FloatArray) -> FloatArray:
    """White-balance ``rgb`` ``(n, 3)`` by ``white_rgb`` and map it to XYZ with ``matrix``."""
    return np.asarray((rgb / white_rgb) @ matrix.T, dtype=np.float64)


def fit_colour_correction(camera: Any, illuminant_name: str = "D65") -> ColourCorrection:
    """The camera's colour-correction matrix under ``illuminant_name`` (see the module).

    Parameters
    ----------
    camera
        Anything :func:`~calib.core.camera_curves.as_camera` accepts (best on 380–780 nm).
    illuminant_name
        ``D50``, ``D55``, ``D65`` or ``A``.

    Raises
    ------
    InputError
        Unknown illuminant, or a camera that does not see the white (all-zero RGB).
    """
    scene = _scene(illuminant_name)
    rgb, white_rgb = camera_rgb(camera, illuminant_name)
    if np.any(white_rgb <= 0):
        raise InputError(
            f"the camera gives no signal in a channel under {illuminant_name}", source="camera"
        )
    balanced = rgb / white_rgb
    matrix = _refine_in_lab(
        _constrained_rows(balanced, scene.xyz, scene.white_xyz), balanced, scene
    )
    lab = xyz_to_lab(balanced @ matrix.T, scene.white_xyz)
    return ColourCorrection(
        illuminant=illuminant_name,
        matrix=matrix,
        white_balance=white_rgb[1] / white_rgb,
        delta_e=DeltaE(scene.patches, delta_e_2000(lab, scene.lab)),
    )


@dataclass(frozen=True)
class TruthComparison:
    """The real camera developed with the estimate's matrix, under one illuminant.

    Attributes
    ----------
    illuminant
        The illuminant.
    estimate_vs_truth
        ΔE2000 between the real camera's ColorChecker developed with the estimate's matrix and
        with the truth's own matrix: the colour error the estimate costs.
    estimate_vs_colorimetry
        ΔE2000 of the real camera developed with the estimate's matrix against colorimetry.
    truth_vs_colorimetry
        ΔE2000 of the real camera developed with its own matrix against colorimetry (the best a
        3×3 matrix does for this camera).
    """

    illuminant: str
    estimate_vs_truth: DeltaE
    estimate_vs_colorimetry: DeltaE
    truth_vs_colorimetry: DeltaE

    def to_dict(self) -> dict[str, Any]:
        return {
            "illuminant": self.illuminant,
            "estimate_vs_truth": self.estimate_vs_truth.to_dict(),
            "estimate_vs_colorimetry": self.estimate_vs_colorimetry.to_dict(),
            "truth_vs_colorimetry": self.truth_vs_colorimetry.to_dict(),
        }


def compare_with_truth(estimate: Any, truth: Any, illuminant_name: str = "D65") -> TruthComparison:
    """Develop the true camera's ColorChecker with the estimate's and the truth's own matrix.

    Examples
    --------
    >>> import colour
    >>> nikon = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    >>> compare_with_truth(nikon, nikon, "D65").estimate_vs_truth.max < 1e-6
    True
    """
    scene = _scene(illuminant_name)
    estimated = fit_colour_correction(estimate, illuminant_name)
    own = fit_colour_correction(truth, illuminant_name)
    rgb, white_rgb = camera_rgb(truth, illuminant_name)
    with_estimate = xyz_to_lab(develop(rgb, white_rgb, estimated.matrix), scene.white_xyz)
    with_truth = xyz_to_lab(develop(rgb, white_rgb, own.matrix), scene.white_xyz)
    return TruthComparison(
        illuminant=illuminant_name,
        estimate_vs_truth=DeltaE(scene.patches, delta_e_2000(with_estimate, with_truth)),
        estimate_vs_colorimetry=DeltaE(scene.patches, delta_e_2000(with_estimate, scene.lab)),
        truth_vs_colorimetry=own.delta_e,
    )


def curves_on_integration_grid(camera: Any) -> CameraCurves:
    """``camera`` sampled on :data:`INTEGRATION_GRID` (zero outside its range)."""
    curves = as_camera(camera)
    nodes = INTEGRATION_GRID.wavelength_nm
    return CameraCurves(nodes, curves.at(nodes), name=curves.name)
