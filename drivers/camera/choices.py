"""Matching a requested setting value to one of a camera widget's choices.

Choice lists differ between bodies: ``"f/5.6"`` (generic PTP, Nikon) versus ``"5.6"`` (Canon);
``"RAW"`` (Canon) versus ``"NEF (Raw)"`` (Nikon ``imagequality``); ``"Internal RAM"`` /
``"Memory card"``. The functions here are pure: they take the request and the choices and return the
choice to set, or raise ``ValueError`` naming what is allowed. Exposure times are in
:mod:`drivers.camera.exposure`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from typing import Literal

from drivers.camera.exposure import OUT_OF_RANGE_TOLERANCE_STOPS

__all__ = [
    "ChoiceKind",
    "match_aperture",
    "match_capture_target",
    "match_choice",
    "match_image_format",
    "match_iso",
    "normalise",
    "parse_f_number",
]

ChoiceKind = Literal["aperture", "iso", "imageformat", "capturetarget", "generic"]

RAW_MARKERS = ("raw", "nef", "cr2", "cr3", "arw", "dng", "orf", "raf", "rw2", "pef")
"""Words that mark a RAW file format in ``imageformat`` / ``imagequality`` choices."""
JPEG_MARKERS = ("jpeg", "jpg", "fine", "normal", "basic", "+")
REDUCED_RAW_PREFIXES = ("sraw", "mraw", "s-raw", "m-raw", "craw", "c-raw")
"""Reduced-resolution or lossy RAW variants (Canon sRAW/mRAW/C-RAW): not the full sensor data."""
CAPTURE_TARGET_WORDS = {
    "sdram": ("ram", "sdram"),
    "card": ("card",),
}
"""Request words and the substring that identifies each capture target choice."""

_SPACES = re.compile(r"\s+")
_F_NUMBER = re.compile(r"^f\s*/?\s*(?P<n>\d+(?:\.\d+)?)$|^(?P<m>\d+(?:\.\d+)?)$", re.IGNORECASE)


def normalise(text: str) -> str:
    """Case-folded text with runs of whitespace collapsed, for tolerant comparison."""
    return _SPACES.sub(" ", text.strip()).casefold()


def _exact(requested: str, choices: Sequence[str]) -> str | None:
    if requested in choices:
        return requested
    folded = [c for c in choices if normalise(c) == normalise(requested)]
    return folded[0] if len(folded) == 1 else None


def _refuse(what: str, requested: str, choices: Sequence[str]) -> ValueError:
    shown = ", ".join(repr(c) for c in choices[:40])
    more = f" and {len(choices) - 40} more" if len(choices) > 40 else ""
    return ValueError(f"{what} {requested!r} is not available; the camera offers {shown}{more}")


def _nearest_in_stops(
    what: str,
    requested: str,
    value: float,
    choices: Sequence[str],
    parse: Callable[[str], float],
    stops_per_doubling: float,
) -> str:
    """The choice whose parsed value is nearest to ``value`` on a log scale, within range."""
    parsed: list[tuple[str, float]] = []
    for choice in choices:
        try:
            number = parse(choice)
        except ValueError:
            continue
        if number > 0 and math.isfinite(number):  # a log scale has no room for 0 or ∞
            parsed.append((choice, number))
    if not parsed or not (value > 0 and math.isfinite(value)):
        raise _refuse(what, requested, choices)

    def stops(a: float, b: float) -> float:
        return stops_per_doubling * (math.log2(b) - math.log2(a))  # no underflowing ratio

    low = min(v for _, v in parsed)
    high = max(v for _, v in parsed)
    if stops(value, low) > OUT_OF_RANGE_TOLERANCE_STOPS or (
        stops(high, value) > OUT_OF_RANGE_TOLERANCE_STOPS
    ):
        raise ValueError(
            f"{what} {requested!r} is outside the camera's range {low:g} … {high:g}"
            f" (choices {', '.join(repr(c) for c, _ in parsed)})"
        )
    return min(parsed, key=lambda pair: (abs(stops(value, pair[1])), pair[1]))[0]


def parse_f_number(text: str) -> float:
    """The f-number of ``"f/5.6"``, ``"f5.6"`` or ``"5.6"``; ValueError otherwise."""
    match = _F_NUMBER.match(text.strip())
    if match is None:
        raise ValueError(f"{text!r} is not an f-number")
    number = float(match["n"] or match["m"])
    if number <= 0:
        raise ValueError(f"{text!r} is not an f-number")
    return number


def match_aperture(requested: str, choices: Sequence[str]) -> str:
    """Nearest aperture: f-numbers compare in stops (2·log₂ N)."""
    exact = _exact(requested, choices)
    if exact is not None:
        return exact
    try:
        value = parse_f_number(requested)
    except ValueError:
        raise _refuse("aperture", requested, choices) from None
    return _nearest_in_stops("aperture", requested, value, choices, parse_f_number, 2.0)


def _parse_iso(text: str) -> float:
    cleaned = normalise(text).removeprefix("iso").strip()
    if not cleaned.isdigit() or int(cleaned) <= 0:
        raise ValueError(f"{text!r} is not an ISO speed")
    return float(cleaned)


def match_iso(requested: str, choices: Sequence[str]) -> str:
    """Nearest ISO speed in stops; ``"auto"`` picks the camera's Auto choice."""
    exact = _exact(requested, choices)
    if exact is not None:
        return exact
    if normalise(requested).startswith("auto"):
        autos = [c for c in choices if normalise(c).startswith("auto")]
        if autos:
            return autos[0]
        raise _refuse("ISO", requested, choices)
    try:
        value = _parse_iso(requested)
    except ValueError:
        raise _refuse("ISO", requested, choices) from None
    return _nearest_in_stops("ISO", requested, value, choices, _parse_iso, 1.0)


def _is_full_raw(choice: str) -> bool:
    folded = normalise(choice)
    return (
        any(marker in folded for marker in RAW_MARKERS)
        and not any(marker in folded for marker in JPEG_MARKERS)
        and not folded.startswith(REDUCED_RAW_PREFIXES)
    )


def match_image_format(requested: str, choices: Sequence[str]) -> str:
    """``"RAW"`` picks the full-resolution RAW-only choice (``RAW``, ``NEF (Raw)`` …)."""
    exact = _exact(requested, choices)
    if exact is not None:
        return exact
    if normalise(requested) == "raw":
        raws = [c for c in choices if _is_full_raw(c)]
        if raws:
            return raws[0]
    raise _refuse("image format", requested, choices)


def match_capture_target(requested: str, choices: Sequence[str]) -> str:
    """``"sdram"`` → the camera's RAM choice, ``"card"`` → its memory-card choice."""
    exact = _exact(requested, choices)
    if exact is not None:
        return exact
    words = CAPTURE_TARGET_WORDS.get(normalise(requested))
    if words is not None:
        hits = [c for c in choices if any(word in normalise(c) for word in words)]
        if len(hits) == 1:
            return hits[0]
    raise _refuse("capture target", requested, choices)


def match_choice(kind: ChoiceKind, requested: str, choices: Sequence[str]) -> str:
    """The choice to set for ``requested`` on a widget of the given kind.

    ``generic`` accepts the exact choice or a unique case/space-insensitive match.
    """
    if kind == "aperture":
        return match_aperture(requested, choices)
    if kind == "iso":
        return match_iso(requested, choices)
    if kind == "imageformat":
        return match_image_format(requested, choices)
    if kind == "capturetarget":
        return match_capture_target(requested, choices)
    exact = _exact(requested, choices)
    if exact is None:
        raise _refuse("value", requested, choices)
    return exact
