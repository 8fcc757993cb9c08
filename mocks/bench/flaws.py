"""The twin camera as a real rig's is: stray light along the band and a shutter that is not exact.

Two errors every grating rig has and the validation protocol renders
(:mod:`calib.evaluation.validation.rig_errors`), drawn here with the protocol's own ranges so the
twin and the protocol agree by construction:

- *Stray light along the band* (:class:`~calib.evaluation.validation.rig_errors.StrayLight`): the
  grooves scatter light of the direct beam in the plane of dispersion and the lens adds a flare
  streak along the same line. A fraction of the 0th order, 0.1–1 % (film replica gratings scatter
  more than ruled masters; a lens' veiling glare is ~1 % of a bright source), falls in a Lorentzian
  wing centred on the spot, across the band like the first order itself. It lies on the band, so
  the background strips beside the band do not remove it; it shows where the band is dim (the
  channels' tails, and towards the spot). The protocol draws the wing's half-width as 100–1000
  profile pixels on bands whose 400–700 nm spans 300–800 pixels; the scatter is an angle, so it
  scales with the dispersion: the twin keeps the wing's size relative to its own 400–700 nm length
  (the protocol's draw × the twin's length / the protocol's typical √(300·800) ≈ 490 pixels).
- *Shutter error* (:class:`~calib.evaluation.validation.rig_errors.ExposureTimeError`): a frame's
  true exposure differs from the time the DNG records (a focal-plane shutter's curtain timing, the
  third-stop labels rounding 2^(n/3) by up to ~3 %, a bulb exposure's USB latency): each frame's
  time × (1 + ε), ε Gaussian with a σ drawn per station within 1–3 %. The rig merges the bracket
  by the recorded times, so each frame carries a gain error; the spot comes from the short frames
  and the band from the long ones.

One draw per station from its seed alone (stream :data:`CAMERA_FLAWS_STREAM`); each frame's ε from
the seed, :data:`SHUTTER_STREAM` and the rig's step (the frame's noise key), so a step gives the
same frame in any process. ``devices.camera.stray_light: false`` and ``shutter_error: false`` switch
either off (both off: the twin before this module; the other keeps its draw). ``twin-truth.json``
records the draw (``camera_flaws``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.evaluation.validation.rig_errors import ExposureTimeError, StrayLight
from calib.evaluation.validation.scenes import GeometryRanges
from mocks.bench.spec import TwinSpec

#: Random stream of the camera's flaws (stray light, shutter σ), mixed with the seed.
CAMERA_FLAWS_STREAM = 4
#: Random stream of each frame's shutter error, mixed with the seed and the frame's key.
SHUTTER_STREAM = 5
#: The protocol's typical length of 400–700 nm in profile pixels (geometric mean of its range):
#: the wing's half-width is drawn against it.
PROTOCOL_BAND_PX = math.sqrt(
    GeometryRanges().band_length_px_range[0] * GeometryRanges().band_length_px_range[1]
)


@dataclass(frozen=True)
class CameraFlaws:
    """One station's stray light and shutter error.

    Attributes
    ----------
    stray_fraction
        Share of the direct spot's light in the wing along the band.
    stray_wing_band
        The wing's half-width in units of the band's 400–700 nm length.
    exposure_sigma
        Relative σ of each frame's true exposure about the recorded one.
    """

    stray_fraction: float
    stray_wing_band: float
    exposure_sigma: float

    def frame_exposure_error(self, seed: int, key: tuple[int, ...]) -> float:
        """ε of the frame keyed ``key`` (its true time is the recorded × (1 + ε))."""
        rng = np.random.default_rng(np.random.SeedSequence([seed, SHUTTER_STREAM, *key]))
        sigma = self.exposure_sigma
        return float(ExposureTimeError((sigma, sigma)).draw(rng, 1)[0])

    def to_dict(self, band_px: float | None = None) -> dict[str, Any]:
        record: dict[str, Any] = {
            "stray_fraction": self.stray_fraction,
            "stray_wing_band_lengths": self.stray_wing_band,
            "exposure_sigma": self.exposure_sigma,
        }
        if band_px is not None:
            record["stray_wing_px"] = self.stray_wing_band * band_px
        record["meaning"] = (
            "stray_fraction of the direct spot's light lies along the band in a Lorentzian wing of "
            "half-width stray_wing_px (sensor pixels) centred on the spot; each frame is exposed "
            "its recorded time × (1 + ε), ε Gaussian of σ exposure_sigma"
        )
        return record


def draw_camera_flaws(seed: int) -> CameraFlaws:
    """Station ``seed``'s stray light and shutter σ (module docstring).

    Examples
    --------
    >>> flaws = draw_camera_flaws(20251121)
    >>> bool(1e-3 <= flaws.stray_fraction <= 1e-2 and 0.01 <= flaws.exposure_sigma <= 0.03)
    True
    >>> draw_camera_flaws(20251121) == flaws
    True
    """
    rng = np.random.default_rng([seed, CAMERA_FLAWS_STREAM])
    stray = StrayLight().draw(rng)
    sigma = float(rng.uniform(*ExposureTimeError().sigma_range))
    return CameraFlaws(stray.fraction, stray.wing_px / PROTOCOL_BAND_PX, sigma)


def camera_flaws(spec: TwinSpec) -> CameraFlaws | None:
    """The twin camera's flaws (``None``: no twin camera, or both are off; one that is off is 0)."""
    camera = spec.camera
    if camera is None or not (camera.stray_light or camera.shutter_error):
        return None
    drawn = draw_camera_flaws(spec.seed)
    return CameraFlaws(
        drawn.stray_fraction if camera.stray_light else 0.0,
        drawn.stray_wing_band if camera.stray_light else 0.0,
        drawn.exposure_sigma if camera.shutter_error else 0.0,
    )
