"""The ACES input device transform (IDT) of a camera from its spectral sensitivities.

``colour.matrix_idt`` (the Academy's P-2013-001 procedure as rawtoaces implements it): the camera
and the CIE 1931 observer see rawtoaces' 190 training reflectances under the scene illuminant; the
3×3 matrix from white-balanced camera RGB to ACES2065-1 minimises their CIELAB differences (after a
CAT02 adaptation to the ACES white). rawtoaces computes the same matrix from the camera JSON when
it converts a RAW file; here it is computed once per illuminant for the report, ``result.json`` and
``calib idt``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.colour_data import aces_idt_matrix, use_illuminant
from calib.use.colour_correction import curves_on_integration_grid

#: The illuminants the report gives an IDT for (ACES' D55 and D65 daylight, CIE A tungsten).
IDT_ILLUMINANTS: tuple[str, ...] = ("D55", "D65", "A")


@dataclass(frozen=True)
class AcesIdt:
    """An IDT matrix and the white balance it assumes.

    Attributes
    ----------
    illuminant
        The scene illuminant.
    matrix
        ``(3, 3)``: white-balanced camera RGB → ACES2065-1.
    white_balance
        ``(3,)``: the multipliers applied to camera RGB first (the smallest is 1, as rawtoaces).
    """

    illuminant: str
    matrix: FloatArray
    white_balance: FloatArray

    def to_dict(self) -> dict[str, Any]:
        return {
            "illuminant": self.illuminant,
            "matrix_camera_rgb_to_aces2065_1": self.matrix.tolist(),
            "white_balance": self.white_balance.tolist(),
        }


def aces_idt(camera: Any, illuminant_name: str = "D65") -> AcesIdt:
    """The ACES IDT of ``camera`` (any camera-like; sampled on 380–780 nm at 5 nm) under
    ``illuminant_name`` (``D50``, ``D55``, ``D65``, ``A``).

    Examples
    --------
    >>> import colour
    >>> idt = aces_idt(colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"], "D65")
    >>> idt.matrix.shape, round(float(idt.matrix.sum(axis=1).mean()), 2)
    ((3, 3), 1.0)
    """
    curves = curves_on_integration_grid(camera)
    matrix, white_balance = aces_idt_matrix(
        curves.wavelength_nm, curves.values, use_illuminant(illuminant_name)
    )
    return AcesIdt(illuminant_name, np.asarray(matrix), np.asarray(white_balance))
