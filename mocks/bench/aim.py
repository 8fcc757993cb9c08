"""Where the twin's spectrometer looks: its usual target, or a beam of the grating sheet.

On a real bench a person turns the spectroradiometer (``rig``'s ``AimSpectrometer`` step); on the
twin :meth:`SpectrometerAim.aim` does. The radiance the spectrometer's emulator then measures
(:meth:`SpectrometerAim.radiance`, handed to the emulators in place of the lamps' own) is:

* ``lamp``: the lamps' radiance, as for every warm-up and reference spectrum;
* ``direct``: the slit without the sheet — the lamps' radiance times the fraction of the
  measuring field the slit's image fills (``slit angle / field``; a spot instrument averages over
  its field);
* ``order0`` / ``order1`` (turned ``angle_deg`` from the 0th order): through the sheet, the sum over
  orders m = 0, 1, 2 of ``η_m(λ)`` times the fraction of the slit's image of order m at ``λ`` that
  lies inside the field. The image of order m leaves at ``θ_m = asin(mλ/d)`` (normal incidence)
  and is widened to ``slit angle / cos θ_m``; the field spans ``angle ± field/2``. So the 1st order
  shows a band of ``d cos θ · field`` nm around the aimed wavelength with soft edges, and the 2nd
  order its own band at half those wavelengths — which a spectroradiometer separates spectrally.

The efficiencies are the twin's true ones (:func:`mocks.bench.optics.grating_orders`), the line
spacing the twin grating's: an aim computed from a wrong line density lands elsewhere, as on a
bench. The emulators then apply their own slit function, integration time and noise.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.core.arrays import FloatArray
from mocks.bench.optics import grating_orders
from mocks.bench.spec import CameraSpec, TwinSpecError

#: The measuring field of each emulated spectrometer (degrees): PR-655/670 and CS-2000 with their
#: standard 1° apertures; an Ocean fibre's acceptance and an i1Pro's aperture are much wider.
FIELD_DEG = {"pr655": 1.0, "pr670": 1.0, "cs2000": 1.0, "seabreeze": 25.0, "argyll": 10.0}
BEAMS = ("lamp", "direct", "order0", "order1")


class SpectrometerAim:
    """The aim of the twin's spectrometer and the radiance it sees there (thread-safe).

    Parameters
    ----------
    lamps
        The lamps' radiance at given wavelengths (``LampBank.radiance``).
    camera
        The twin camera's spec (the sheet and the slit), or ``None`` when the camera is real:
        then only the usual target can be measured.
    field_deg
        The spectrometer's measuring field.
    """

    def __init__(
        self,
        lamps: Callable[[ArrayLike], NDArray[np.float64]],
        camera: CameraSpec | None,
        field_deg: float,
    ) -> None:
        self.lamps = lamps
        self.camera = camera
        self.field_rad = math.radians(field_deg)
        self.beam = "lamp"
        self.angle_rad = 0.0
        self._lock = threading.Lock()
        self._orders = None if camera is None else grating_orders(camera.grating)[:3]
        if camera is None:
            self.slit_rad = 0.0
        else:
            optics = camera.optics
            self.slit_rad = (
                optics.slit_width_px * camera.pixel_pitch_um * 1e-3 / (optics.focal_length_mm)
            )

    def aim(self, beam: str, angle_deg: float = 0.0) -> None:
        """Turn to ``beam`` (``angle_deg`` from the 0th order for ``order1``)."""
        if beam not in BEAMS:
            raise TwinSpecError(f"the twin's spectrometer cannot look at {beam!r} ({BEAMS})")
        if beam != "lamp" and self.camera is None:
            raise TwinSpecError(
                "the twin's spectrometer cannot look through the grating: the camera (and its "
                "sheet) is real; measure the grating by hand or set measure_grating to null"
            )
        with self._lock:
            self.beam = beam
            self.angle_rad = math.radians(angle_deg) if beam == "order1" else 0.0

    def radiance(self, wavelength_nm: ArrayLike) -> NDArray[np.float64]:
        """The radiance the spectrometer sees at ``wavelength_nm`` where it is aimed, ``(n,)``."""
        axis = np.asarray(wavelength_nm, dtype=np.float64)
        lamps = np.asarray(self.lamps(axis), dtype=np.float64)
        with self._lock:
            beam, angle_rad = self.beam, self.angle_rad
        if beam == "lamp":
            return lamps
        fill = self.slit_rad / self.field_rad
        if beam == "direct":
            return lamps * fill
        return lamps * fill * self.transmission(axis, angle_rad)

    def transmission(self, wavelength_nm: NDArray[np.float64], angle_rad: float) -> FloatArray:
        """``Σ_m η_m(λ) · (share of order m's slit image inside the field)`` at ``angle_rad``."""
        assert self.camera is not None and self._orders is not None
        spacing_nm = 1e6 / self.camera.grating.grooves_per_mm
        half_field = self.field_rad / 2.0
        total = np.zeros_like(wavelength_nm)
        for order, efficiency in enumerate(self._orders):
            sine = order * wavelength_nm / spacing_nm
            exists = sine < 1.0
            theta = np.arcsin(np.where(exists, sine, 0.0))
            width = self.slit_rad / np.cos(theta)
            low = np.maximum(theta - width / 2.0, angle_rad - half_field)
            high = np.minimum(theta + width / 2.0, angle_rad + half_field)
            inside = np.clip((high - low) / width, 0.0, 1.0)
            total += np.where(exists, efficiency.at(wavelength_nm) * inside, 0.0)
        return total
