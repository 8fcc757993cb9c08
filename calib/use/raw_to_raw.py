"""A 3×3 matrix from one camera's raw RGB to another's, from their spectral sensitivities.

Both cameras see the same reflectances under the same illuminant (rawtoaces' 190 training
reflectances by default, the set ACES IDTs are fitted on); each camera's RGB is divided by its
perfect white's green, so the matrix carries the cameras' relative channel gains but not their
exposure. ``M`` minimises ``Σ_i ‖M a_i − b_i‖²`` (ordinary least squares); its residuals, relative
to the length of ``b_i``, say how far the two cameras are from being linear transforms of each
other (zero when their sensitivities span the same space).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.camera_curves import as_camera
from calib.core.colour_data import training_reflectances, use_illuminant
from calib.core.errors import InputError
from calib.use.colour_correction import INTEGRATION_GRID


@dataclass(frozen=True)
class RawToRaw:
    """A raw-to-raw transform and how well it holds.

    Attributes
    ----------
    source, target
        The cameras' names.
    illuminant
        The illuminant it was fitted under.
    matrix
        ``(3, 3)``: source raw RGB → target raw RGB (each normalised to its white's green = 1).
    relative_residual_median, relative_residual_max
        ``‖M a_i − b_i‖ / ‖b_i‖`` over the reflectances.
    n_reflectances
        How many reflectances it was fitted on.
    """

    source: str
    target: str
    illuminant: str
    matrix: FloatArray
    relative_residual_median: float
    relative_residual_max: float
    n_reflectances: int

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "target": self.target,
            "illuminant": self.illuminant,
            "matrix_source_rgb_to_target_rgb": self.matrix.tolist(),
            "relative_residual_median": self.relative_residual_median,
            "relative_residual_max": self.relative_residual_max,
            "n_reflectances": self.n_reflectances,
        }


def raw_to_raw(source: Any, target: Any, illuminant_name: str = "D65") -> RawToRaw:
    """The 3×3 matrix from ``source``'s raw RGB to ``target``'s (any camera-like objects).

    Raises
    ------
    InputError
        A camera with no signal in a channel under the illuminant.

    Examples
    --------
    >>> import colour
    >>> nikon = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    >>> round(raw_to_raw(nikon, nikon).relative_residual_max, 9)
    0.0
    """
    cameras = [as_camera(source), as_camera(target)]
    nodes = INTEGRATION_GRID
    power = use_illuminant(illuminant_name).resample(nodes).values * nodes.step_nm
    reflectances = training_reflectances().resample(nodes, out_of_range="zero").values
    responses = []
    for camera in cameras:
        sensitivity = camera.at(nodes.wavelength_nm)
        white = power @ sensitivity
        if np.any(white <= 0):
            raise InputError(f"no signal in a channel under {illuminant_name}", source=camera.name)
        responses.append((reflectances.T * power) @ sensitivity / white[1])
    a, b = responses
    solution, *_ = np.linalg.lstsq(a, b, rcond=None)
    matrix = np.asarray(solution.T, dtype=np.float64)
    relative = np.linalg.norm(a @ matrix.T - b, axis=1) / np.linalg.norm(b, axis=1)
    return RawToRaw(
        source=cameras[0].name,
        target=cameras[1].name,
        illuminant=illuminant_name,
        matrix=matrix,
        relative_residual_median=float(np.median(relative)),
        relative_residual_max=float(np.max(relative)),
        n_reflectances=int(a.shape[0]),
    )
