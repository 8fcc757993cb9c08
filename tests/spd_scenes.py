"""Diffraction images of lamps rendered the way the digital twin renders them, for the SPD tests.

The first order is rendered at 1 nm by :func:`calib.model.forward.render_observation` through a physical
grating (:class:`calib.core.mapping.GratingGeometry`, sensor pixels from the spot), the 2-D frame by
:mod:`mocks.scene` (slit image, band, Bayer sensor with shot and read noise) and each exposure of a
bracket written as a real DNG by :mod:`mocks.dng`. The reading side is the real one: ``calib.image.hdr`` →
``calib.image.profiles`` → :class:`calib.spd.alvarez2014.DiffractedProfile`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.lamp_specs import colour_lamp
from calib.core.mapping import GratingGeometry
from calib.core.spectra import MultiSpectrum, Spectrum, write_csv
from calib.evaluation.synthetic import random_efficiency
from calib.image.hdr import merge_bracket
from calib.image.profiles import DiffractionGeometry, detect_geometry, extract
from calib.model.forward import render_observation
from calib.spd.alvarez2014 import DiffractedProfile, source_kernel_from_image
from mocks.scene import SceneLayout, SceneSignal, SensorModel, render_mosaic_radiance, write_bracket

#: 500 lines/mm in front of a 14 mm lens on 4 µm pixels: 400–700 nm span ~600 px (0.5 nm/px).
GRATING = GratingGeometry(grooves_per_mm=500.0, focal_length_mm=14.0, pixel_pitch_um=4.0)
SENSOR = SensorModel(height_px=320, width_px=1520, cfa_pattern="RGGB")
SPOT_CENTRE_PX = (60.0, 160.0)
BAND_HALF_WIDTH_PX = 100.0
#: Share of the direct flux that the first order carries (spread over the band).
FIRST_ORDER_RATIO = 0.3
#: Radiance of the band's brightest sample (DN/s per pixel).
BAND_PEAK_DN_PER_S = 4000.0
FULL_SCALE_DN = SENSOR.white_level_dn - SENSOR.black_level_dn


@lru_cache(maxsize=1)
def nikon_camera() -> MultiSpectrum:
    """The twin's default camera, colour-science's ``Nikon 5100 (NPL)``."""
    import colour

    return MultiSpectrum.from_colour(colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"])


def efficiency_spectrum(seed: int = 3) -> Spectrum:
    """A smooth grating efficiency (0.3…1) as :mod:`calib.evaluation.synthetic` draws them, as a Spectrum."""
    function: Callable[[FloatArray], FloatArray] = random_efficiency(np.random.default_rng(seed))
    wavelength = np.arange(360.0, 781.0, 1.0)
    return Spectrum(wavelength, function(wavelength), name="grating efficiency")


@dataclass(frozen=True)
class RenderedLamp:
    """A lamp's DNG bracket and the scene it shows."""

    frames: list[Path]
    slit_px: float


def render_lamp(
    directory: Path,
    lamp: Spectrum,
    *,
    camera: MultiSpectrum,
    efficiency: Spectrum,
    rng: np.random.Generator,
    slit_px: float = 12.0,
    psf_sigma_px: float = 1.0,
    prefix: str = "lamp",
) -> RenderedLamp:
    """Render ``lamp`` as the twin does and write an HDR bracket of DNGs into ``directory``."""
    lo, hi = GRATING.pixel_at(np.array([365.0, 745.0]))
    pixel = np.arange(np.floor(lo), np.ceil(hi) + 1.0)
    rendered = render_observation(
        lamp,
        camera,
        mapping=GRATING,
        pixel=pixel,
        grating_efficiency=efficiency,
        slit_width_px=slit_px,
        psf_sigma_px=psf_sigma_px,
    )
    profile = np.clip(rendered.clean_profile, 0.0, None)
    band_scale = FIRST_ORDER_RATIO / (2 * BAND_HALF_WIDTH_PX * float(profile.sum(axis=0).max()))
    direct = rendered.clean_direct / float(rendered.clean_direct.max())
    # One scale for the scene: the band's peak reaches BAND_PEAK_DN_PER_S.
    scale = BAND_PEAK_DN_PER_S / float((profile * band_scale).max())
    signal = SceneSignal(
        direct_rgb=direct * scale, pixel=pixel, profile=profile * band_scale * scale
    )
    layout = SceneLayout(
        spot_centre_px=SPOT_CENTRE_PX,
        dispersion_angle_deg=0.0,
        spot_half_size_px=(slit_px / 2.0, BAND_HALF_WIDTH_PX),
        band_half_width_px=BAND_HALF_WIDTH_PX,
        edge_px=2.0,
    )
    mosaic = render_mosaic_radiance(layout, signal, SENSOR)
    longest_s = 0.6 * FULL_SCALE_DN / BAND_PEAK_DN_PER_S
    exposures = [longest_s / 4.0**k for k in range(5)]
    directory.mkdir(parents=True, exist_ok=True)
    frames = write_bracket(directory, mosaic, SENSOR, exposures, rng, prefix=prefix)
    return RenderedLamp(frames, slit_px)


def read_profile(
    frames: list[Path], *, name: str, geometry: DiffractionGeometry | None = None
) -> tuple[DiffractedProfile, DiffractionGeometry]:
    """Merge, detect (unless given), extract and measure the spot's kernel, as ``calib spd`` does."""
    image = merge_bracket(frames)
    found = geometry if geometry is not None else detect_geometry(image)
    extraction = extract(image, found)
    kernel = source_kernel_from_image(image, found, background_rgb=extraction.direct_background_rgb)
    return DiffractedProfile.from_extraction(extraction, name=name, source_kernel=kernel), found


def triphosphor_lamp() -> Spectrum:
    """A tri-phosphor fluorescent tube at 0.1 nm with its lines at their true wavelengths.

    Mercury lines (NIST), the Eu³⁺ red lines, the Tb³⁺ green bands and the BAM blue band, as a
    spectrometer with a 2 nm bandwidth measures them. The CIE F-series tables are sampled at 5 nm,
    which moves their lines to multiples of 5 nm, so a test of the reference line list needs a
    spectrum like this one.
    """
    wavelength = np.arange(360.0, 780.05, 0.1)
    components = (  # (centre nm, FWHM nm, height)
        (404.66, 2.0, 0.2),
        (435.83, 2.0, 0.8),
        (546.07, 2.0, 1.5),
        (576.96, 2.0, 0.15),
        (579.07, 2.0, 0.15),
        (611.6, 3.0, 0.7),
        (590.0, 4.0, 0.1),
        (626.0, 4.0, 0.15),
        (650.0, 5.0, 0.06),
        (707.0, 4.0, 0.08),
        (487.7, 6.0, 0.25),
        (542.4, 4.0, 0.3),
        (585.0, 6.0, 0.08),
        (450.0, 50.0, 0.08),
    )
    values = np.zeros_like(wavelength)
    for centre, fwhm, height in components:
        values += height * np.exp(-4 * np.log(2) * ((wavelength - centre) / fwhm) ** 2)
    return Spectrum(wavelength, values + 0.005, name="tri-phosphor fluorescent")


def render_twin_lamp(
    directory: Path, lamp: Spectrum, *, seed: int, slit_px: float = 12.0, prefix: str = "lamp"
) -> list[Path]:
    """:func:`render_lamp` with the twin's camera and grating, seeded."""
    return render_lamp(
        directory,
        lamp,
        camera=nikon_camera(),
        efficiency=efficiency_spectrum(),
        rng=np.random.default_rng(seed),
        slit_px=slit_px,
        prefix=prefix,
    ).frames


@dataclass(frozen=True)
class CalibratedRig:
    """A calibrated set-up as files: camera, grating efficiency, and a fluorescent mapping lamp."""

    root: Path
    camera: Path
    efficiency: Path
    mapping_frames: tuple[Path, ...]
    mapping_spectrum: Path


def calibrated_rig(root: Path, *, seed: int = 11) -> CalibratedRig:
    """Write the Nikon's sensitivity, the grating's efficiency and an FL2 bracket into ``root``."""
    fluorescent = colour_lamp("FL2")
    frames = render_twin_lamp(root / "fl2", fluorescent, seed=seed, prefix="fl2")
    return CalibratedRig(
        root,
        write_csv(root / "camera.csv", nikon_camera()),
        write_csv(root / "efficiency.csv", efficiency_spectrum()),
        tuple(frames),
        write_csv(root / "fl2.csv", fluorescent),
    )
