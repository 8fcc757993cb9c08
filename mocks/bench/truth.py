"""What the twin knows and an estimate is judged against: the true camera, grating and mapping.

:class:`TwinTruth` is written as ``twin-truth.json`` next to a session's files (not acknowledged by
its log, so it is never one of the session's trusted files) so that the demo can report the
estimate's error against the camera the twin really has.

The JSON holds the camera sensitivity (maximum 1) and the grating's first-order efficiency on 1 nm
axes, the pixel→wavelength mapping as a ``calib.core.mapping.GratingGeometry`` record (sensor pixels from
the direct spot's centre along the dispersion — the axis of ``calib.image.profiles``' profiles), and the
slit image and layout.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.mapping import GratingGeometry
from calib.core.spectra import MultiSpectrum, Spectrum, WavelengthGrid
from mocks.bench.flaws import CameraFlaws
from mocks.bench.optics import TwinOptics, visible_band_px

TRUTH_FORMAT = "spectral-rig/twin-truth"
TRUTH_VERSION = 1
TRUTH_FILE_NAME = "twin-truth.json"


class TruthFormatError(ValueError):
    """A twin-truth file that cannot be read (the message names the file and the field)."""


@dataclass(frozen=True, eq=False)
class TwinTruth:
    """The twin's ground truth.

    Attributes
    ----------
    camera
        Name of the true camera.
    sensitivity
        Its RGB sensitivity, maximum 1 over all channels.
    grating_efficiency
        First-order efficiency η(λ) (absolute).
    zeroth_order_efficiency
        η₀(λ) (absolute; a file written before physical gratings holds one number: a flat η₀).
    grating
        The grating's model and parameters (``mocks.bench.optics.grating_orders``).
    mapping
        Pixel→wavelength of the first order (sensor pixels from the spot centre).
    dispersion_angle_deg, spot_centre_px
        Where the first order runs on the sensor and where the spot is, ``(x, y)``.
    slit_width_px, slit_length_px, edge_px
        The slit's image.
    seed
        The twin's seed.
    spectrometer
        The emulated spectrometer and its in-spec errors (:mod:`mocks.bench.deviation`), or
        ``None`` (a real spectrometer, or a file written before the twin had them).
    camera_flaws
        The camera's stray light along the band and shutter error (:mod:`mocks.bench.flaws`), or
        ``None`` (a clean camera, or a file written before the twin had them).
    """

    camera: str
    sensitivity: MultiSpectrum
    grating_efficiency: Spectrum
    zeroth_order_efficiency: Spectrum
    mapping: GratingGeometry
    dispersion_angle_deg: float
    spot_centre_px: tuple[float, float]
    slit_width_px: float
    slit_length_px: float
    edge_px: float
    seed: int
    grating: dict[str, Any] = field(default_factory=dict)
    spectrometer: dict[str, Any] | None = None
    camera_flaws: dict[str, Any] | None = None

    @classmethod
    def of(
        cls,
        optics: TwinOptics,
        seed: int,
        spectrometer: dict[str, Any] | None = None,
        camera_flaws: CameraFlaws | None = None,
    ) -> TwinTruth:
        """The truth of a twin built with ``optics`` (and ``spectrometer``'s record, and the
        camera's ``camera_flaws``)."""
        low, high = optics.sensitivity.range_nm
        grid = WavelengthGrid(float(math.ceil(low)), float(math.floor(high)), 1.0)
        axis = grid.wavelength_nm
        efficiency = Spectrum(axis, optics.efficiency.at(axis), name="grating efficiency")
        return cls(
            camera=optics.camera_name,
            sensitivity=optics.sensitivity.resample(grid),
            grating_efficiency=efficiency,
            zeroth_order_efficiency=Spectrum(
                axis, optics.zeroth_order_efficiency.at(axis), name="0th-order efficiency"
            ),
            grating=dict(optics.grating),
            mapping=optics.mapping,
            dispersion_angle_deg=optics.layout.dispersion_angle_deg,
            spot_centre_px=optics.layout.spot_centre_px,
            slit_width_px=optics.slit_width_px,
            slit_length_px=optics.slit_length_px,
            edge_px=optics.edge_px,
            seed=seed,
            spectrometer=spectrometer,
            camera_flaws=(
                None
                if camera_flaws is None
                else camera_flaws.to_dict(visible_band_px(optics.mapping))
            ),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": TRUTH_FORMAT,
            "version": TRUTH_VERSION,
            "camera": self.camera,
            "sensitivity": {
                "wavelength_nm": self.sensitivity.wavelength_nm.tolist(),
                "r": self.sensitivity.values[:, 0].tolist(),
                "g": self.sensitivity.values[:, 1].tolist(),
                "b": self.sensitivity.values[:, 2].tolist(),
            },
            "grating_efficiency": {
                "wavelength_nm": self.grating_efficiency.wavelength_nm.tolist(),
                "values": self.grating_efficiency.values.tolist(),
            },
            "zeroth_order_efficiency": {
                "wavelength_nm": self.zeroth_order_efficiency.wavelength_nm.tolist(),
                "values": self.zeroth_order_efficiency.values.tolist(),
            },
            "grating": self.grating,
            "mapping": self.mapping.to_dict(),
            "mapping_axis": "sensor pixels from the direct spot centre along the first order",
            "dispersion_angle_deg": self.dispersion_angle_deg,
            "spot_centre_px": list(self.spot_centre_px),
            "slit_image": {
                "width_px": self.slit_width_px,
                "length_px": self.slit_length_px,
                "edge_px": self.edge_px,
            },
            "seed": self.seed,
            "spectrometer": self.spectrometer,
            "camera_flaws": self.camera_flaws,
        }

    def write(self, directory: str | Path) -> Path:
        """Write ``twin-truth.json`` into ``directory``; return its path."""
        path = Path(directory) / TRUTH_FILE_NAME
        temporary = path.with_name(f".{path.name}.part")
        temporary.write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")
        temporary.replace(path)
        return path

    @classmethod
    def read(cls, path: str | Path) -> TwinTruth:
        """Read a ``twin-truth.json`` (data only; nothing in it is executed).

        Raises
        ------
        TruthFormatError
            Not JSON, another format or version, or a missing/malformed field.
        """
        file = Path(path)
        try:
            data = json.loads(file.read_text(encoding="utf-8"))
            if data.get("format") != TRUTH_FORMAT or data.get("version") != TRUTH_VERSION:
                raise TruthFormatError(
                    f"{file}: not a {TRUTH_FORMAT} version {TRUTH_VERSION} file "
                    f"(format {data.get('format')!r}, version {data.get('version')!r})"
                )
            curves = data["sensitivity"]
            efficiency = data["grating_efficiency"]
            slit = data["slit_image"]
            x, y = data["spot_centre_px"]
            return cls(
                camera=str(data["camera"]),
                sensitivity=MultiSpectrum(
                    curves["wavelength_nm"],
                    np.stack([curves["r"], curves["g"], curves["b"]], axis=1),
                    name=str(data["camera"]),
                ),
                grating_efficiency=Spectrum(
                    efficiency["wavelength_nm"], efficiency["values"], name="grating efficiency"
                ),
                zeroth_order_efficiency=_zeroth_order(data["zeroth_order_efficiency"], efficiency),
                grating=dict(data.get("grating") or {}),
                mapping=GratingGeometry.from_dict(data["mapping"]),
                dispersion_angle_deg=float(data["dispersion_angle_deg"]),
                spot_centre_px=(float(x), float(y)),
                slit_width_px=float(slit["width_px"]),
                slit_length_px=float(slit["length_px"]),
                edge_px=float(slit["edge_px"]),
                seed=int(data["seed"]),
                spectrometer=_optional_record(data.get("spectrometer"), "spectrometer"),
                camera_flaws=_optional_record(data.get("camera_flaws"), "camera_flaws"),
            )
        except TruthFormatError:
            raise
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise TruthFormatError(f"{file}: cannot read the twin's truth ({exc!r})") from None


def _zeroth_order(value: Any, first_order: Mapping[str, Any]) -> Spectrum:
    """η₀ from a truth file: a curve, or one number (a flat η₀, files before physical gratings)."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        axis = np.asarray(first_order["wavelength_nm"], dtype=np.float64)
        return Spectrum(axis, np.full(axis.size, float(value)), name="0th-order efficiency")
    return Spectrum(value["wavelength_nm"], value["values"], name="0th-order efficiency")


def _optional_record(value: Any, name: str) -> dict[str, Any] | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise TypeError(f"{name} is not an object")
    return dict(value)
