"""Exposure-time strings as cameras write them, and the nearest available exposure.

Camera bodies list their shutter speeds as strings in several notations: Canon EOS ``"30"``,
``"0.3"``, ``"1/125"``, ``"bulb"``; Nikon ``shutterspeed2`` ``"1/125"``, ``"30"``, ``"Bulb"``,
``"Time"``, ``"x 200"``; generic PTP ExposureTime ``"0.0100s"``; older displays ``1"`` and ``0"5`` (the
inch mark standing for seconds and the decimal point). :func:`parse_exposure_s` turns any of them into
seconds; :class:`ExposureTable` holds a widget's timed choices and picks the nearest one in stops
(log₂ of the ratio), which is how photographers and the HDR bracket think about exposure.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from fractions import Fraction

__all__ = [
    "BULB_THRESHOLD_STOPS",
    "OUT_OF_RANGE_TOLERANCE_STOPS",
    "ExposureTable",
    "format_exposure",
    "is_bulb_choice",
    "parse_exposure_s",
    "stops_between",
]

OUT_OF_RANGE_TOLERANCE_STOPS = 1.0 / 3.0
"""How far (stops) a request may lie outside the camera's range and still snap to its end."""
BULB_THRESHOLD_STOPS = 1.0 / 6.0
"""A request longer than the longest timed choice by more than this (stops) uses bulb, when the
camera has bulb: half a third-stop step, so anything nearer to the longest choice uses that."""
BULB_WORDS = frozenset({"bulb"})
"""Choice strings (case-insensitive) that select host-timed bulb exposures. Nikon's ``Time`` (press
once to open, again to close) is deliberately not bulb."""

_NUMBER = r"\d+(?:\.\d+)?"
_PATTERNS: tuple[tuple[re.Pattern[str], str], ...] = (
    (re.compile(rf"^(?P<n>\d+)\s*/\s*(?P<d>{_NUMBER})$"), "fraction"),  # 1/125
    (re.compile(r"^(?P<w>\d+)\s+(?P<n>\d+)\s*/\s*(?P<d>\d+)$"), "mixed"),  # 1 1/3
    (re.compile(r"^(?P<w>\d+)\"(?P<f>\d+)$"), "inch_decimal"),  # 0"5 = 0.5 s, 1"3 = 1.3 s
    (re.compile(rf"^(?P<x>{_NUMBER})\"?$"), "seconds"),  # 30, 0.3, 1"
)
_UNIT_SUFFIX = re.compile(r"\s*(?:s|sec|secs|second|seconds)$", re.IGNORECASE)


def parse_exposure_s(text: str) -> float:
    """Seconds of a timed exposure string.

    Parameters
    ----------
    text
        ``"1/125"``, ``"0.3"``, ``"30"``, ``'1"'``, ``'0"5'``, ``"1 1/3"``, ``"0.0100s"``,
        ``"2.5 s"`` …

    Returns
    -------
    float
        Exposure time, seconds (> 0).

    Raises
    ------
    ValueError
        For anything that is not a timed exposure: ``"bulb"``, ``"Time"``, ``"x 200"``, ``"Auto"``,
        zero or garbage.

    Examples
    --------
    >>> parse_exposure_s("1/125"), parse_exposure_s('0"5'), parse_exposure_s("0.0100s")
    (0.008, 0.5, 0.01)
    """
    cleaned = _UNIT_SUFFIX.sub("", text.strip().replace("\u2033", '"'))
    for pattern, kind in _PATTERNS:
        match = pattern.match(cleaned)
        if match is None:
            continue
        try:
            seconds = _seconds(kind, match)
        except ZeroDivisionError:
            break
        if seconds > 0 and math.isfinite(seconds):
            return seconds
        break
    raise ValueError(f'{text!r} is not an exposure time (expected e.g. 1/125, 0.3, 30, 1")')


def _seconds(kind: str, match: re.Match[str]) -> float:
    if kind == "fraction":
        return float(match["n"]) / float(match["d"])
    if kind == "mixed":
        return float(match["w"]) + float(Fraction(int(match["n"]), int(match["d"])))
    if kind == "inch_decimal":
        return float(f"{match['w']}.{match['f']}")
    return float(match["x"])


def is_bulb_choice(text: str) -> bool:
    """Whether a shutter choice selects bulb (host-timed) exposures."""
    return text.strip().casefold() in BULB_WORDS


def stops_between(a_s: float, b_s: float) -> float:
    """Signed distance in stops from exposure ``a_s`` to ``b_s`` (log₂ of their ratio).

    A difference of logarithms: the ratio of a denormal and an ordinary exposure underflows to 0.
    """
    return math.log2(b_s) - math.log2(a_s)


def format_exposure(seconds: float) -> str:
    """Human form for messages: ``1/125 s`` below 0.3 s, else ``2.5 s``."""
    if seconds <= 0 or not math.isfinite(seconds):
        return f"{seconds} s"
    if seconds < 0.3:
        denominator = 1.0 / seconds
        return f"1/{denominator:.0f} s" if denominator >= 10 else f"1/{denominator:.3g} s"
    return f"{seconds:.4g} s"


@dataclass(frozen=True)
class ExposureTable:
    """The timed shutter choices of a camera, sorted from shortest, and its bulb choice.

    Attributes
    ----------
    timed
        ``(choice string, seconds)`` pairs, ascending in seconds.
    bulb_choice
        The choice string that selects bulb, or ``None``.
    ignored
        Choices that are neither timed nor bulb (``Time``, ``x 200``, ``Auto``).
    """

    timed: tuple[tuple[str, float], ...]
    bulb_choice: str | None = None
    ignored: tuple[str, ...] = ()

    @classmethod
    def from_choices(cls, choices: Iterable[str]) -> ExposureTable:
        timed: list[tuple[str, float]] = []
        ignored: list[str] = []
        bulb: str | None = None
        for choice in choices:
            if is_bulb_choice(choice):
                bulb = bulb or choice
                continue
            try:
                timed.append((choice, parse_exposure_s(choice)))
            except ValueError:
                ignored.append(choice)
        timed.sort(key=lambda pair: pair[1])
        return cls(tuple(timed), bulb, tuple(ignored))

    @property
    def shortest_s(self) -> float:
        self._require_timed()
        return self.timed[0][1]

    @property
    def longest_s(self) -> float:
        self._require_timed()
        return self.timed[-1][1]

    def needs_bulb(self, exposure_s: float) -> bool:
        """Whether ``exposure_s`` is longer than every timed choice (by the bulb threshold)."""
        return bool(self.timed) and stops_between(self.longest_s, exposure_s) > BULB_THRESHOLD_STOPS

    def nearest(self, exposure_s: float) -> tuple[str, float]:
        """The timed choice nearest to ``exposure_s`` in stops (ties go to the shorter one).

        Raises
        ------
        ValueError
            When ``exposure_s`` is not positive, or lies outside the timed range by more than
            :data:`OUT_OF_RANGE_TOLERANCE_STOPS` (the message gives the range, and says when bulb
            would be needed).
        """
        if not exposure_s > 0 or not math.isfinite(exposure_s):
            raise ValueError(f"exposure must be a positive number of seconds, got {exposure_s}")
        self._require_timed()
        span = f"{format_exposure(self.shortest_s)} … {format_exposure(self.longest_s)}"
        if stops_between(exposure_s, self.shortest_s) > OUT_OF_RANGE_TOLERANCE_STOPS:
            raise ValueError(
                f"exposure {format_exposure(exposure_s)} is shorter than the camera's shortest "
                f"shutter speed (timed range {span})"
            )
        if stops_between(self.longest_s, exposure_s) > OUT_OF_RANGE_TOLERANCE_STOPS:
            hint = (
                "use bulb"
                if self.bulb_choice
                else "the camera offers no bulb choice (set the mode dial to M or B)"
            )
            raise ValueError(
                f"exposure {format_exposure(exposure_s)} is longer than the camera's longest "
                f"shutter speed (timed range {span}); {hint}"
            )
        return min(self.timed, key=lambda pair: (abs(stops_between(exposure_s, pair[1])), pair[1]))

    def _require_timed(self) -> None:
        if not self.timed:
            raise ValueError(
                f"the camera lists no timed shutter speeds (choices ignored: {list(self.ignored)})"
            )
