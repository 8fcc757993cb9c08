"""Frame statistics that drive automatic bracketing, and the protocol of whatever computes them.

After each scene frame the runner asks a :class:`FrameAnalyzer` for the frame's :class:`FrameStats`
and sends them to the plan, which extends the bracket until its shortest frame leaves the direct
(0th-order) spot unsaturated and every pixel of the spot and the band usable to the HDR merge,
and its longest frame gives the first-order band enough signal. The real analyser decodes the RAW
file and finds the spot and the band (``calib.image.raw``, ``calib.image.profiles``); tests and the
dry run use modelled statistics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol


@dataclass(frozen=True)
class FrameStats:
    """What one frame shows of the direct spot and the first-order band.

    Parameters
    ----------
    direct_saturated_fraction
        Fraction (0–1) of the direct spot's pixels at or above the white level in any channel.
    band_snr
        Signal-to-noise ratio of the first-order band: its mean signal above black divided by the
        noise of that mean's pixels (dimensionless, ≥ 0).
    band_signal_dn
        Mean signal of the band above the black level, in digital numbers.
    band_saturated_fraction
        Fraction (0–1) of the band's pixels at or above the white level.
    direct_unmergeable_fraction, band_unmergeable_fraction
        Fraction (0–1) of the direct spot's and of the band's pixels that the HDR merge cannot take
        from this frame (:func:`calib.image.hdr.merge_bracket`: saturated, or the mean of its
        neighbours above the merge's ``prediction_fraction`` of the clipping level). The estimator's
        extraction refuses a spot or a band with such a pixel in every frame of the bracket, so the
        shortest frame must have none. 0 where not measured (modelled statistics, older logs).
    """

    direct_saturated_fraction: float
    band_snr: float
    band_signal_dn: float
    band_saturated_fraction: float = 0.0
    direct_unmergeable_fraction: float = 0.0
    band_unmergeable_fraction: float = 0.0

    def __post_init__(self) -> None:
        for name in (
            "direct_saturated_fraction",
            "band_saturated_fraction",
            "direct_unmergeable_fraction",
            "band_unmergeable_fraction",
        ):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must lie in 0..1, got {value!r}")
        for name in ("band_snr", "band_signal_dn"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value!r}")
        if self.band_snr < 0:
            raise ValueError(f"band_snr must be ≥ 0, got {self.band_snr!r}")


class FrameAnalyzer(Protocol):
    """Computes :class:`FrameStats` from a frame file as downloaded.

    Raise :class:`rig.errors.FrameAnalysisError` when the frame cannot be analysed.
    """

    def analyse(self, frame: Path) -> FrameStats: ...
