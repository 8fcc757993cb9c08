"""A validation scene's capture of one lamp: the slit's direct image and its band on the sensor,
bracketed with the shutter's errors and merged by the rig's own HDR merge.

The 1-D protocol once summed the spot as one level over ``slit × band_rows`` pixels. All of a
lamp's channels then came from the same frames, so a frame's exposure error
(:class:`~.rig_errors.ExposureTimeError`) scaled the channels alike. A real spot has soft edges (the
lens blur): its core is measured in the short frames and its dim edges in the long ones, and the
mix differs per channel with the channel's level. So on a real rig (and on the twin, decision 0087)
each channel of a lamp's direct RGB carries its own frame errors. Here the capture is rendered as
the sensor sees it:

- **The slit's image** (:class:`SlitImage`): along the dispersion the scene's line spread (the slit
  ⊗ the lens blur, :func:`calib.model.forward.blur_kernel`, what the first order is blurred with
  and what the rig measures as the spot's cross-section); across it the slit's length
  (``band_rows`` sensor rows) with the same blur at its ends. The direct spot is the direct RGB
  spread over that image; the band is the profile with the same cross-section (the first order is
  the slit's image too). Both lie in one image, spot and band a few dark columns apart, as they
  lie in one frame of a capture: the merge estimates each frame's gain from both.
- **The bracket** (:meth:`~.rig_errors.PhotonBudget.bracket`, the HDR policy): frame ``k`` is
  exposed ``gain · factor_k · (1 + ε_k)`` electrons per unit and records ``gain · factor_k``; a
  14-bit raw range over the full well (as ``bench/validate_twin.py``'s twin sensor), Gaussian shot
  and read noise per site, the green plane the mean of its two sites, samples clipped and flagged
  at :data:`calib.image.raw.DEFAULT_SATURATION_FRACTION` of the range as
  :func:`calib.image.raw.read_raw` flags them. The dark frames' subtraction is carried as read
  noise of ``σ √(1 + 1/dark_frames)``: without dark current a master dark adds exactly that
  variance to a sample (:func:`calib.image.hdr.merge_bracket`'s ``Var(dark)``), so the merge
  gets the same variances without rendering the dark frames. The bracket puts its brightest
  pixel below the merge's ceiling before the shutter's error; where that error (or the noise)
  lifts a sample of the shortest frame over it, no frame measures the sample, and the capture
  adds a shorter frame as the rig's auto-bracketing does (:func:`capture_lamp`).
- **The merge**: :func:`calib.image.hdr.merge_planes`, the rig's merge (decision 0006) with its
  neighbour-predicted weights and exclusions and each frame's estimated gain (decision 0089;
  :attr:`~.rig_errors.PhotonBudget.merge_gains` off trusts the recorded times), told the sensor's
  true noise model. The spot is the merged image summed over its columns, the profile the band
  summed over its rows; their σ the summed variances, as :mod:`calib.image.profiles` states them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.evaluation.validation.rig_errors import PhotonBudget, SensorDraw
from calib.image.hdr import merge_planes
from calib.image.raw import DEFAULT_SATURATION_FRACTION, RawPlanes
from calib.image.raw_metadata import RawMetadata
from calib.image.sensor_noise import SITES_PER_SAMPLE, NoiseModel
from calib.model.forward import blur_kernel

#: A 14-bit raw range above a black level, as the twin sensor's (``bench/validate_twin.py``).
BLACK_DN, WHITE_DN = 512, 16383
#: The bracket's shortest exposure (s): only the rates' unit depends on it.
SHORTEST_S = 1e-3
#: Dark columns between the spot and the band: the merge predicts a sample's level from its 3×3
#: neighbours, so two are enough to keep the spot's edge and the band apart.
GAP_COLUMNS = 3
#: The channel origins in the 2×2 cell (RGGB); the merge does not use them.
_ORIGINS = ((0.0, 0.0), (0.5, 0.5), (1.0, 1.0))


@dataclass(frozen=True)
class SlitImage:
    """The slit's image on the sensor: its cross-sections along and across the dispersion.

    Attributes
    ----------
    along
        The line spread along the dispersion in profile pixels (sum 1).
    across
        The slit's length across it in sensor rows, blurred at its ends (sum 1).
    """

    along: FloatArray
    across: FloatArray

    @classmethod
    def of(cls, line_spread: FloatArray, band_rows: int, psf_sigma_px: float) -> SlitImage:
        """The image of a slit whose line spread is ``line_spread``, ``band_rows`` rows long, through
        a lens blur of σ ``psf_sigma_px``."""
        across = blur_kernel(float(band_rows), psf_sigma_px)
        return cls(
            np.asarray(line_spread, dtype=np.float64),
            np.full(band_rows, 1.0 / band_rows) if across is None else across,
        )

    @property
    def spot_px(self) -> float:
        """The spot's total over its brightest pixel: the pixels it would fill at that level."""
        return 1.0 / float(self.along.max() * self.across.max())

    def image(self, profile: FloatArray, direct: FloatArray) -> FloatArray:
        """Shape ``(3, rows, spot columns + gap + n)``: the spot and the band per pixel, in the units
        of ``profile`` ``(n, 3)`` and ``direct`` ``(3,)`` (the spot sums to ``direct``, each band
        column to the profile)."""
        spot = direct[:, None, None] * np.multiply.outer(self.across, self.along)[None]
        band = self.across[None, :, None] * np.asarray(profile, dtype=np.float64).T[:, None, :]
        gap = np.zeros((3, self.across.size, GAP_COLUMNS))
        return np.concatenate([spot, gap, np.clip(band, 0.0, None)], axis=2)


@dataclass(frozen=True)
class CapturedLamp:
    """A lamp's merged direct RGB and profile, their stated σ, and the merge's frame gains.

    Attributes
    ----------
    direct, direct_sigma
        Shape ``(3,)``.
    profile, profile_sigma
        Shape ``(n, 3)``.
    factors
        The frames' exposures relative to the bracket's first (shortest) frame, shortest first:
        the bracket's, with the shorter frames :func:`capture_lamp` added to it.
    frame_gains, frame_gain_sigmas
        Each frame's exposure as the merge estimated it (1 where it kept the recorded time) and
        the estimate's σ (0 for the first merged frame, ``None`` where the recorded time was kept
        for want of overlap), shortest frame first.
    """

    direct: FloatArray
    direct_sigma: FloatArray
    profile: FloatArray
    profile_sigma: FloatArray
    factors: tuple[float, ...]
    frame_gains: tuple[float, ...]
    frame_gain_sigmas: tuple[float | None, ...]


def capture_lamp(
    profile: FloatArray,
    direct: FloatArray,
    slit: SlitImage,
    budget: PhotonBudget,
    sensor: SensorDraw,
    electrons_per_unit: float,
    factors: Sequence[float],
    exposure_errors: Sequence[float] | FloatArray,
    rng: np.random.Generator,
) -> CapturedLamp:
    """The bracket of ``profile`` ``(n, 3)`` and ``direct`` ``(3,)`` through ``budget``'s sensor
    and merge (module docstring), merged.

    ``electrons_per_unit`` is the recorded electrons per unit of the signals at factor 1 (the
    bracket's shortest frame) and ``factors`` the frames' exposures relative to it
    (:meth:`~.rig_errors.PhotonBudget.bracket`), ``exposure_errors`` the ``ε`` of the frames in the
    order they are captured (at least one per frame).

    Where the merge finds a sample that no frame measured (the shortest frame's is at or above
    the merge's ``clip_fraction`` of the clipping level: a spot fill near 1 exposed a few percent
    long by the shutter), the bracket is extended as the rig extends it
    (``rig.plan.auto_bracket``): a frame ``step_stops`` shorter is captured after the others,
    with the next exposure error, and the bracket merged again, up to ``budget.max_frames``
    frames. The frames already captured keep their noise (the generator is rewound to redraw
    it), so a bracket that needed no extension is rendered exactly as before.
    """
    if len(exposure_errors) < len(factors):
        raise ValueError(f"{len(factors)} frames but {len(exposure_errors)} exposure errors")
    image = slit.image(profile, direct).astype(np.float32)
    sensor_dn = _SensorDn.of(budget, sensor)
    captured = list(factors)
    start = rng.bit_generator.state
    while True:
        frames = [
            sensor_dn.frame(
                image, electrons_per_unit, factor, float(exposure_errors[index]), index, rng
            )
            for index, factor in enumerate(captured)
        ]
        merged = merge_planes(
            frames,
            noise_model=NoiseModel(
                sensor_dn.dn_per_electron, (sensor_dn.read_dn,) * 3, source="the scene's sensor"
            ),
            prediction_fraction=budget.clip_fraction,
            estimate_gains=budget.merge_gains,
        )
        if not merged.saturated.any():
            break
        if len(captured) >= min(budget.max_frames, len(exposure_errors)):
            raise InputError(
                "a sample is saturated in every frame of the bracket, and the bracket has "
                f"{len(captured)} frames (max_frames {budget.max_frames})",
                source="photon budget",
            )
        rng.bit_generator.state = start
        captured.append(min(captured) / 2.0**budget.step_stops)
    shortest_first = sorted(captured)
    scale = SHORTEST_S / (sensor_dn.dn_per_electron * electrons_per_unit)
    radiance = merged.radiance.astype(np.float64) * scale
    variance = merged.variance.astype(np.float64) * scale**2
    spot = slice(0, slit.along.size)
    band = slice(slit.along.size + GAP_COLUMNS, None)
    records = {record.exposure_s: record for record in merged.frames}
    frame_records = [records[SHORTEST_S * factor] for factor in shortest_first]
    return CapturedLamp(
        direct=radiance[:, :, spot].sum(axis=(1, 2)),
        direct_sigma=np.sqrt(variance[:, :, spot].sum(axis=(1, 2))),
        profile=radiance[:, :, band].sum(axis=1).T,
        profile_sigma=np.sqrt(variance[:, :, band].sum(axis=1).T),
        factors=tuple(shortest_first),
        frame_gains=tuple(record.gain for record in frame_records),
        frame_gain_sigmas=tuple(record.gain_sigma for record in frame_records),
    )


@dataclass(frozen=True)
class _SensorDn:
    """The scene's sensor in DN above black: its gain, read noise and levels (module docstring)."""

    dn_per_electron: float
    read_dn: float
    clip_dn: float

    @classmethod
    def of(cls, budget: PhotonBudget, sensor: SensorDraw) -> _SensorDn:
        dn_per_electron = (WHITE_DN - BLACK_DN) / sensor.full_well_e
        return cls(
            dn_per_electron,
            dn_per_electron * math.sqrt(budget.read_variance_e2(sensor)),
            float(WHITE_DN - BLACK_DN),
        )

    def frame(
        self,
        image: NDArray[np.float32],
        electrons_per_unit: float,
        factor: float,
        exposure_error: float,
        index: int,
        rng: np.random.Generator,
    ) -> RawPlanes:
        """Capture ``index`` of ``image`` ``(3, rows, columns)``, recorded at ``factor`` times the
        shortest exposure and exposed ``1 + exposure_error`` times that."""
        level = image * np.float32(
            self.dn_per_electron * electrons_per_unit * factor * (1.0 + exposure_error)
        )
        # in place (a frame's temporaries are most of the scene's rendering cost):
        # signal = level + √((g·level + σ²) / sites) · N(0, 1), clipped
        sigma = np.multiply(level, np.float32(self.dn_per_electron))
        sigma += np.float32(self.read_dn**2)
        np.divide(sigma, np.asarray(SITES_PER_SAMPLE, dtype=np.float32)[:, None, None], out=sigma)
        np.sqrt(sigma, out=sigma)
        signal = rng.standard_normal(image.shape, dtype=np.float32)
        signal *= sigma
        signal += level
        np.minimum(signal, np.float32(self.clip_dn), out=signal)
        meta = RawMetadata(
            Path(f"frame_{index}"), SHORTEST_S * factor, "override", None, None, None, None, None
        )
        return RawPlanes(
            meta,
            signal,
            signal >= np.float32(DEFAULT_SATURATION_FRACTION * self.clip_dn),
            "RGGB",
            (float(BLACK_DN),) * 3,
            (self.clip_dn,) * 3,
            _ORIGINS,
        )
