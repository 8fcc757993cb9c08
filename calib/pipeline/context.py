"""What the caller knows about an estimate beyond its input files, for the outputs and the report.

``rig estimate`` hands over what the session recorded (the lamps' warm-up) and, for a digital-twin
session, the twin's truth; a validation run hands over the camera's measured curves. calib reads
none of it from the session itself: the caller builds an :class:`EstimateContext`.
"""

from __future__ import annotations

from dataclasses import dataclass

from calib.core.truth import GroundTruth


@dataclass(frozen=True)
class WarmupTrace:
    """A lamp's warm-up as the session recorded it.

    Attributes
    ----------
    lamp
        The lamp.
    elapsed_s
        When each warm-up spectrum was measured, seconds after the lamp was switched on.
    relative_change
        ``‖current − previous‖ / ‖current‖`` of each spectrum against the one before (``NaN`` for
        the first).
    tolerance
        The change below which the lamp counted as stable, if known.
    """

    lamp: str
    elapsed_s: tuple[float, ...]
    relative_change: tuple[float, ...]
    tolerance: float | None = None


@dataclass(frozen=True)
class EstimateContext:
    """The known truth (if any) and the session's warm-up records (if any)."""

    truth: GroundTruth | None = None
    warmup: tuple[WarmupTrace, ...] = ()
