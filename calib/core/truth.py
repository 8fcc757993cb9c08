"""What an estimate is judged against when it is known: :class:`GroundTruth`.

The digital twin knows the camera it simulates (``twin-truth.json``, handed over by ``rig``), and
validation cameras come with their measured curves; the report overlays the truth on every curve
and the camera's uses compare the colours the estimate and the truth give.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from calib.core.camera_curves import CameraCurves, as_camera
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.spectra import Spectrum


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """The known truth of an estimate.

    Parameters
    ----------
    sensitivity
        The true camera: anything :func:`~calib.core.camera_curves.as_camera` accepts (a colour
        ``RGB_CameraSensitivities`` too); stored as :class:`CameraCurves` with maximum 1.
    grating_efficiency
        The true first-order efficiency η(λ), when known (any scale).
    mapping
        The true pixel→wavelength mapping, when known (same pixel axis as the estimate's).
    zeroth_order_efficiency
        The true 0th-order efficiency η₀(λ), when known (absolute, as ``grating_efficiency``).
    source
        Where it comes from, for the report (``"twin-truth.json (digital twin)"``).
    """

    sensitivity: Any
    grating_efficiency: Spectrum | None = None
    mapping: QuadraticMapping | GratingGeometry | None = None
    source: str = "known truth"
    zeroth_order_efficiency: Spectrum | None = None

    def __post_init__(self) -> None:
        camera = as_camera(self.sensitivity, name=None).normalised()
        object.__setattr__(self, "sensitivity", camera)

    @property
    def camera(self) -> CameraCurves:
        curves: CameraCurves = self.sensitivity
        return curves
