"""Pure parsing and matching: exposure strings, nearest choices in stops, and the watchdog."""

from __future__ import annotations

import math
import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.camera.choices import (
    match_aperture,
    match_capture_target,
    match_choice,
    match_image_format,
    match_iso,
    parse_f_number,
)
from drivers.camera.exposure import (
    ExposureTable,
    format_exposure,
    is_bulb_choice,
    parse_exposure_s,
    stops_between,
)
from drivers.camera.watchdog import CallTimedOut, CallWatchdog
from mocks.fake_gphoto2.bodies import CANON_SHUTTER_CHOICES, NIKON_SHUTTER_CHOICES


@pytest.mark.parametrize(
    ("text", "seconds"),
    [
        ("1/125", 1 / 125),
        ("1/8000", 1 / 8000),
        ("0.3", 0.3),
        ("30", 30.0),
        ('1"', 1.0),
        ('2.5"', 2.5),
        ('0"5', 0.5),
        ('1"3', 1.3),
        ("1 1/3", 4 / 3),
        ("0.0100s", 0.01),
        ("30.0000s", 30.0),
        ("2.5 s", 2.5),
        ("1/60 sec", 1 / 60),
        (" 1/4 ", 0.25),
        ("1\u2033", 1.0),
    ],
)
def test_parse_exposure(text: str, seconds: float) -> None:
    assert parse_exposure_s(text) == pytest.approx(seconds)


@pytest.mark.parametrize("text", ["bulb", "Bulb", "Time", "x 200", "Auto", "0", "1/0", "", "-1"])
def test_parse_exposure_rejects_non_exposures(text: str) -> None:
    with pytest.raises(ValueError, match="not an exposure time"):
        parse_exposure_s(text)


def test_tables_of_real_bodies() -> None:
    canon = ExposureTable.from_choices(CANON_SHUTTER_CHOICES)
    assert canon.bulb_choice == "bulb"
    assert (canon.shortest_s, canon.longest_s) == (1 / 8000, 30.0)
    assert len(canon.timed) == len(CANON_SHUTTER_CHOICES) - 1
    nikon = ExposureTable.from_choices(NIKON_SHUTTER_CHOICES)
    assert nikon.bulb_choice == "Bulb"
    assert nikon.ignored == ("Time",)
    assert is_bulb_choice(" BULB ") and not is_bulb_choice("Time")


def test_nearest_and_bulb_threshold() -> None:
    table = ExposureTable.from_choices(CANON_SHUTTER_CHOICES)
    assert table.nearest(1 / 125) == ("1/125", 1 / 125)
    assert table.nearest(0.0105)[0] == "1/100"
    assert not table.needs_bulb(30.0 * 2 ** (1 / 7))
    assert table.needs_bulb(30.0 * 2 ** (1 / 5))
    with pytest.raises(ValueError, match="use bulb"):
        table.nearest(100.0)
    with pytest.raises(ValueError, match="positive"):
        table.nearest(math.nan)
    with pytest.raises(ValueError, match="no timed shutter speeds"):
        ExposureTable.from_choices(["bulb", "Time"]).nearest(1.0)


def test_ties_go_to_the_shorter_exposure() -> None:
    table = ExposureTable.from_choices(["1/100", "1/25"])
    assert table.nearest(1 / 50)[0] == "1/100"


def test_format_exposure() -> None:
    assert format_exposure(1 / 125) == "1/125 s"
    assert format_exposure(2.5) == "2.5 s"
    assert stops_between(1.0, 4.0) == 2.0


@settings(max_examples=200, deadline=None)
@given(st.floats(min_value=1 / 8000 * 0.8, max_value=30.0 * 1.25))
def test_nearest_is_nearest_in_stops(exposure_s: float) -> None:
    table = ExposureTable.from_choices(CANON_SHUTTER_CHOICES)
    _, chosen = table.nearest(exposure_s)
    best = min(abs(stops_between(exposure_s, s)) for _, s in table.timed)
    assert abs(stops_between(exposure_s, chosen)) == pytest.approx(best)


@settings(max_examples=100, deadline=None)
@given(st.integers(min_value=1, max_value=16000))
def test_fraction_strings_round_trip(denominator: int) -> None:
    assert parse_exposure_s(f"1/{denominator}") == pytest.approx(1 / denominator)


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=12))
def test_parse_exposure_raises_only_value_error(text: str) -> None:
    try:
        seconds = parse_exposure_s(text)
    except ValueError:
        return
    assert seconds > 0 and math.isfinite(seconds)


# ---------------------------------------------------------------------------------- choices


def test_aperture_matching() -> None:
    canon = ("2.8", "4", "5.6", "8")
    nikon = ("f/2.8", "f/4", "f/5.6", "f/8")
    assert match_aperture("f/5.6", canon) == "5.6"
    assert match_aperture("5.6", nikon) == "f/5.6"
    assert match_aperture("f/6.3", nikon) == "f/5.6"
    assert match_aperture("F8", canon) == "8"
    assert parse_f_number("f 11") == 11.0
    with pytest.raises(ValueError, match="outside"):
        match_aperture("f/32", canon)
    with pytest.raises(ValueError, match="not available"):
        match_aperture("wide", canon)


def test_iso_matching() -> None:
    choices = ("Auto", "100", "200", "400", "Hi 1")
    assert match_iso("auto", choices) == "Auto"
    assert match_iso("141", choices) == "100"
    assert match_iso("142", choices) == "200"
    with pytest.raises(ValueError, match="not available"):
        match_iso("auto", ("100", "200"))


def test_image_format_prefers_full_raw() -> None:
    canon = ("Large Fine JPEG", "RAW + Large Fine JPEG", "mRAW", "sRAW", "cRAW", "RAW")
    assert match_image_format("raw", canon) == "RAW"
    with pytest.raises(ValueError, match="not available"):
        match_image_format("raw", ("Large Fine JPEG", "sRAW", "RAW + Large Fine JPEG"))
    nikon = ("JPEG Fine", "NEF (Raw)", "NEF+Fine")
    assert match_image_format("RAW", nikon) == "NEF (Raw)"
    sony = ("Standard", "Fine", "RAW", "RAW+JPEG")
    assert match_image_format("raw", sony) == "RAW"


def test_capture_target_and_generic_matching() -> None:
    choices = ("Internal RAM", "Memory card")
    assert match_capture_target("sdram", choices) == "Internal RAM"
    assert match_capture_target("CARD", choices) == "Memory card"
    with pytest.raises(ValueError, match="capture target"):
        match_capture_target("cloud", choices)
    assert match_choice("generic", "cloudy", ("Daylight", "Cloudy")) == "Cloudy"
    assert match_choice("generic", " Daylight  ", ("Daylight",)) == "Daylight"


# ---------------------------------------------------------------------------------- watchdog


def test_watchdog_returns_results_and_raises_errors_in_order() -> None:
    watchdog = CallWatchdog("test")
    order: list[int] = []
    empty: dict[str, int] = {}

    def first() -> int:
        order.append(1)
        return 42

    try:
        assert watchdog.call(first, timeout_s=1.0, name="a") == 42
        with pytest.raises(KeyError):
            watchdog.call(lambda: empty["missing"], timeout_s=1.0, name="b")
        assert watchdog.call(lambda: threading.current_thread().name, timeout_s=1, name="c") == (
            "test-1"
        )
    finally:
        watchdog.close()
    assert order == [1]


def test_watchdog_abandons_a_call_that_never_returns() -> None:
    watchdog = CallWatchdog("test")
    release = threading.Event()
    returned = threading.Event()

    def stuck() -> None:
        release.wait(60)
        returned.set()

    try:
        with pytest.raises(CallTimedOut, match=r"stuck did not return within 0\.1 s"):
            watchdog.call(stuck, timeout_s=0.1, name="stuck")
        # The call is still inside (the test holds it): the deadline ended the wait, not the call.
        assert not returned.is_set()
        assert watchdog.abandoned == 1
        # A fresh worker serves the next call.
        assert watchdog.call(lambda: threading.current_thread().name, timeout_s=1, name="n") == (
            "test-2"
        )
    finally:
        release.set()
        watchdog.close()


def test_watchdog_refuses_bad_timeouts() -> None:
    watchdog = CallWatchdog("test")
    with pytest.raises(ValueError, match="positive"):
        watchdog.call(lambda: None, timeout_s=0, name="x")
    watchdog.close()


def test_a_denormal_exposure_is_a_distance_not_a_crash() -> None:
    """Found by the slow fuzz run: 5e-324 s against a 2 s choice underflowed log₂'s argument."""
    assert stops_between(2.0, 5e-324) == -1075.0
