"""A small rig capture rendered through calib.model.forward into real DNG brackets (shared by tests).

A physical grating (300 grooves/mm, 17.8 mm lens, 4 µm pixels: about 0.75 nm per sensor pixel, 400 nm
at 537 px and 700 nm at 955 px from the direct spot) and a camera inside an exact 7-vector basis, so
every error the estimate shows comes from the images, the pipeline and the estimator, not from the
basis. The lamps are colour-science's LED-B3 and FL2, as on the digital twin.
"""

from __future__ import annotations

import atexit
import functools
import math
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from calib.core.lamp_specs import colour_lamp
from calib.core.mapping import GratingGeometry
from calib.core.metrics import mapping_relative_error, relative_error
from calib.core.observations import LampKind
from calib.core.result import EstimateResult
from calib.core.spectra import Spectrum
from calib.model.bases import CameraBasis
from calib.model.forward import render_observation
from mocks.forward_scene import RenderedLamp, write_capture
from mocks.scene import SceneLayout, SensorModel
from tests.synthetic_cameras import as_spectrum, exact_basis

GRATING = GratingGeometry(grooves_per_mm=300.0, focal_length_mm=17.776, pixel_pitch_um=4.0)
#: First order rendered over these distances from the spot (sensor px): about 330–780 nm.
ORDER_RANGE_PX = (440.0, 1080.0)
BRACKET_S = (0.0005, 0.002, 0.008, 0.032, 0.128)


@functools.cache
def colour_lamps() -> dict[str, tuple[LampKind, Spectrum]]:
    """colour-science's LED-B3 and FL2 (the twin's lamps), by short name."""
    return {
        "LED": ("led", colour_lamp("LED-B3")),
        "FL": ("fluorescent", colour_lamp("FL2")),
    }


def efficiency(wavelength_nm: np.ndarray) -> np.ndarray:
    """A smooth grating efficiency (between 0.4 and 1)."""
    return 0.7 + 0.3 * np.cos(2 * np.pi * (np.asarray(wavelength_nm) - 400.0) / 300.0)


@dataclass(frozen=True)
class Capture:
    """A rendered capture and its truth."""

    lamps: list[RenderedLamp]
    truth: np.ndarray  # (31, 3) on the default grid
    basis: CameraBasis
    layout: SceneLayout
    sensor: SensorModel

    def lamp(self, name: str) -> RenderedLamp:
        return next(lamp for lamp in self.lamps if lamp.name == name)

    def clean_profile(self, lamp: str, pixel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The renderer's noise-free profile ``(n, 3)`` at ``pixel`` (integrals over the pixels'
        wavelength intervals, in forward units) and its direct RGB ``(3,)``."""
        # The first order is blurred by the slit's image (the direct spot, a box along the
        # dispersion); ``render_observation`` takes its width in profile samples.
        spacing = float(np.median(np.diff(pixel)))
        rendered = render_observation(
            colour_lamps()[lamp][1],
            as_spectrum(self.truth),
            mapping=GRATING,
            pixel=pixel,
            grating_efficiency=efficiency,
            slit_width_px=2.0 * self.layout.spot_half_size_px[0] / spacing,
        )
        return rendered.clean_profile, rendered.clean_direct

    def errors(self, result: EstimateResult, pixel: np.ndarray) -> tuple[float, float]:
        """``(RE, mapping RE)`` against the truth; the mapping RE over the pixels whose true
        wavelength lies on the working grid (Makabe et al. 2025, Supp. Eq. 1)."""
        assert result.mapping is not None
        true_nm = GRATING.wavelength_nm(pixel)
        inside = (true_nm >= result.wavelength_nm[0]) & (true_nm <= result.wavelength_nm[-1])
        mapping_error = mapping_relative_error(
            result.mapping.wavelength_nm(pixel[inside]), true_nm[inside]
        )
        return relative_error(result.sensitivity, self.truth), mapping_error


#: The rendered camera: a mixture of the exact basis' cameras, ``(index, weight)`` pairs.
CAMERA_MIX: tuple[tuple[int, float], ...] = ((1, 0.6), (4, 0.4))


def truth_camera(
    cache_dir: Path, mix: tuple[tuple[int, float], ...] = CAMERA_MIX
) -> tuple[CameraBasis, np.ndarray]:
    basis, cameras = exact_basis(cache_dir)
    return basis, sum((weight * cameras[index] for index, weight in mix), np.zeros_like(cameras[0]))


def render_capture(
    directory: Path,
    cache_dir: Path,
    *,
    lamps: tuple[str, ...] = ("LED", "FL"),
    angle_deg: float = 3.0,
    cfa_pattern: str = "RGGB",
    exposures_s: tuple[float, ...] = BRACKET_S,
    dark_frames: bool = False,
    dark_current_dn_per_s: float = 0.0,
    minus_first_strength: float = 0.0,
    spot_shift_px: float = 0.0,
    direct_throughput: float = 0.5,
    padding_px: int = 0,
    seed: int = 2025,
    camera_mix: tuple[tuple[int, float], ...] = CAMERA_MIX,
    **dng_fields: str | int | float | None,
) -> Capture:
    """Render ``lamps`` at ``angle_deg`` on a sensor just large enough, and write the DNGs.

    The spot sits so that the first order (and the −1 order when ``minus_first_strength`` > 0)
    falls inside the frame with a margin; the sensor is the bounding box of all that, plus
    ``padding_px`` on every side; ``spot_shift_px`` then moves the spot (and the orders with it)
    that far towards the +1 order, which runs off the frame once the shift passes the 40 px
    margin. With ``direct_throughput`` 5 (instead of 0.5) the direct spot clips in the bracket's
    longest frame.
    """
    reach = ORDER_RANGE_PX[1] + 40.0
    angle = math.radians(angle_deg)
    half_across = 60.0
    extent_x = abs(math.cos(angle)) * reach + abs(math.sin(angle)) * half_across
    extent_y = abs(math.sin(angle)) * reach + abs(math.cos(angle)) * half_across
    both = minus_first_strength > 0
    width = 2 * math.ceil(((2 if both else 1) * extent_x + 2 * half_across + 40) / 2 + padding_px)
    height = 2 * math.ceil(((2 if both else 1) * extent_y + 2 * half_across + 40) / 2 + padding_px)
    centre_x = width / 2 if both else (width / 2 - math.cos(angle) * reach / 2)
    centre_y = height / 2 if both else (height / 2 - math.sin(angle) * reach / 2)
    centre_x += math.cos(angle) * spot_shift_px
    centre_y += math.sin(angle) * spot_shift_px
    sensor = SensorModel(
        height_px=height,
        width_px=width,
        cfa_pattern=cfa_pattern,
        dark_current_dn_per_s=dark_current_dn_per_s,
    )
    layout = SceneLayout(
        spot_centre_px=(centre_x, centre_y),
        dispersion_angle_deg=angle_deg,
        spot_half_size_px=(5.0, 40.0),
        band_half_width_px=40.0,
        minus_first_strength=minus_first_strength,
    )
    basis, truth = truth_camera(cache_dir, camera_mix)
    rendered = write_capture(
        directory,
        [(name, *colour_lamps()[name]) for name in lamps],
        as_spectrum(truth),
        mapping=GRATING,
        sensor=sensor,
        layout=layout,
        exposures_s=exposures_s,
        rng=np.random.default_rng(seed),
        grating_efficiency=efficiency,
        pixel_range_px=ORDER_RANGE_PX,
        direct_throughput=direct_throughput,
        dark_frames=dark_frames,
        **cast(dict[str, Any], dng_fields),
    )
    return Capture(rendered, truth / truth.max(), basis, layout, sensor)


_SHARED_DIRECTORY: list[Path] = []


def _shared_directory() -> Path:
    """A temporary directory for this test process, removed when it exits."""
    if not _SHARED_DIRECTORY:
        path = Path(tempfile.mkdtemp(prefix="spectral-rig-capture-"))
        atexit.register(shutil.rmtree, path, ignore_errors=True)
        _SHARED_DIRECTORY.append(path)
    return _SHARED_DIRECTORY[0]


@functools.cache
def shared_capture() -> Capture:
    """The standard capture (LED + FL, 5-frame brackets, dark frames, dark current 300 DN/s),
    rendered once per test process and shared by the test modules that only read it."""
    root = _shared_directory()
    return render_capture(
        root / "capture", root / "basis", dark_frames=True, dark_current_dn_per_s=300.0
    )
