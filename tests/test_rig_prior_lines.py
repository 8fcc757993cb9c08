"""A RAW file's focal length is a prior, not a licence to bend a line lamp's mapping (decision 0066).

A capture whose metadata states the lens' focal length and the pixel pitch but not where the spot
lies on the sensor gives the mapping nothing about the lens axis: the 0th order stays on it, as
without a focal length, and the lines decide as they do without EXIF.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calib.core.datasets import colour_science_cameras, find_camera
from calib.core.lamp_specs import lamp_from_spec
from calib.core.mapping import TiltedGrating
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum
from calib.model.bases import CameraPrior, fallback_camera_basis
from calib.model.forward import PeakFractionNoise, render_observation
from calib.wavelength.locate import locate_mapping
from calib.wavelength.rig_prior import RigOptics, rig_prior

CAMERA_NAME = "Canon EOS 5D Mark II"
#: The validation protocol's largest focus extension (scenes.FOCUS_EXTENSION_RANGE's top): EXIF
#: states the focal length 8 % short of the lens' image distance.
TOP_FOCUS_EXTENSION = 0.08
PITCH_UM = 9.2


@pytest.fixture(scope="module")
def camera() -> MultiSpectrum:
    return find_camera(colour_science_cameras(), CAMERA_NAME).sensitivity


@pytest.fixture(scope="module")
def prior() -> CameraPrior:
    return fallback_camera_basis(exclude=[CAMERA_NAME]).prior()


def _mercury_profile(camera: MultiSpectrum, truth: TiltedGrating, seed: int) -> LampObservation:
    """A mercury lamp's first order, measured from the direct spot (its lines end at 579 nm: the
    red end is the grating equation's extrapolation)."""
    first, last = truth.pixel_at(np.array([375.0, 815.0]))
    observation = render_observation(
        lamp_from_spec("builtin:hg"),
        camera,
        mapping=truth,
        pixel=np.arange(np.ceil(first), np.floor(last) + 1.0),
        slit_width_px=3.0,
        psf_sigma_px=1.0,
        noise=PeakFractionNoise(0.002),
        rng=np.random.default_rng(seed),
        kind="fluorescent",
        fine_step_nm=0.05,
    ).observation
    return replace(observation, pixel_origin="direct_spot")


@pytest.mark.parametrize(
    "grooves_per_mm, focal_length_px, incidence_deg, seed",
    [(632.0, 2105.0, 9.5, 0), (800.0, 1200.0, 8.0, 3)],
)
def test_exif_optics_leave_a_line_lamps_mapping_where_the_lines_put_it(
    camera, prior, grooves_per_mm, focal_length_px, incidence_deg, seed
):
    """With the EXIF focal length at the top of its focus extension, the mapping stays within
    0.3 nm of the one without EXIF over the working grid (the axis offset fitted from a prior
    centred on a guess moved it 0.6–1.4 nm from it, 0.9–1.3 nm from the truth)."""
    truth = TiltedGrating(1e6 / grooves_per_mm / focal_length_px, focal_length_px, incidence_deg)
    plain = _mercury_profile(camera, truth, seed)
    nominal_mm = focal_length_px * PITCH_UM * 1e-3 / (1.0 + TOP_FOCUS_EXTENSION)
    optics = {"focal_length_mm": round(nominal_mm, 1), "pixel_pitch_um": PITCH_UM}
    with_exif = replace(plain, metadata={**plain.metadata, "optics": optics})
    wavelength_nm = np.linspace(DEFAULT_GRID.start_nm, DEFAULT_GRID.stop_nm, 61)
    pixel = truth.pixel_at(wavelength_nm)
    found = {
        name: locate_mapping(observation, prior, DEFAULT_GRID).exact.wavelength_nm(pixel)
        for name, observation in (("exif", with_exif), ("plain", plain))
    }
    np.testing.assert_allclose(found["exif"], found["plain"], atol=0.3)
    np.testing.assert_allclose(found["exif"], wavelength_nm, atol=0.6)


def test_the_axis_offset_is_fitted_only_where_the_spot_is_placed():
    """A focal length alone holds the 0th order on the lens axis; a recorded spot position (the
    geometry of :mod:`calib.image.profiles`) lets the fit move it around that position."""
    bare = RigOptics(focal_length_mm=20.0, pixel_pitch_um=5.0)
    held, _ = rig_prior(bare)
    assert held is not None and "axis_offset_px" not in held.values
    assert held.axis_offset_px == 0.0
    placed = replace(bare, axis_offset_px=-800.0, order_angle_deg=0.0, band_distance_px=1500.0)
    fitted, _ = rig_prior(placed)
    assert fitted is not None and fitted.values["axis_offset_px"][0] == -800.0
    assert fitted.values["axis_offset_px"][1] > 0
