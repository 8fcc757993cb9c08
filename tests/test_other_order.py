"""Decision 0197: the other first order measures the lens and the grating's tilt, and that joins
the grating prior as a correlated Gaussian."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from calib.core.errors import InputError
from calib.core.lamp_specs import colour_lamp
from calib.core.mapping import TiltedGrating
from calib.core.observations import LampObservation, OrderProfile
from calib.model.forward import render_observation
from calib.wavelength.other_order import corresponding_pixel, other_order_geometry
from tests.synthetic_cameras import as_spectrum, gaussian_camera

#: A 600 lines/mm sheet tilted by −4° in front of a 3000 px lens.
GRATING = TiltedGrating(1e6 / 600.0 / 3000.0, 3000.0, -4.0)
PIXEL = np.arange(420.0, 1400.0, 2.0)


def test_the_corresponding_pixel_is_the_gratings_own_other_order() -> None:
    other = np.array([500.0, 800.0, 1100.0])
    wavelength = GRATING.other_order().wavelength_nm(other)
    expected = GRATING.pixel_at(wavelength)
    found = corresponding_pixel(
        other, np.array([[GRATING.focal_length_px]]), np.array([[GRATING.incidence_deg]])
    )
    np.testing.assert_allclose(found[0], expected, rtol=1e-10)
    # At normal incidence the two orders mirror each other at any focal length.
    for focal in (800.0, 3000.0, 20000.0):
        mirrored = corresponding_pixel(other, np.array([[focal]]), np.array([[0.0]]))
        np.testing.assert_allclose(mirrored[0], other, rtol=1e-12)


def _lamp(
    grating: TiltedGrating, seed: int, *, ratio: float = 0.5, swap_channels: bool = False
) -> tuple[LampObservation, float]:
    """An LED's +1 and −1 profiles through ``grating`` (the −1 order weaker by ``ratio`` and
    tilted in λ, as a blazed sheet's is), 0.3 % noise on each; and the noise level."""
    camera = as_spectrum(gaussian_camera((600.0, 540.0, 460.0), (40.0, 45.0, 30.0)))
    led = colour_lamp("LED-B3")
    common: dict[str, Any] = {"pixel": PIXEL, "slit_width_px": 3.0, "psf_sigma_px": 1.0}
    plus = render_observation(led, camera, mapping=grating, **common).clean_profile
    minus = render_observation(
        led,
        camera,
        mapping=grating.other_order(),
        grating_efficiency=lambda nm: ratio * (1.2 - 0.4 * (np.asarray(nm) - 400.0) / 300.0),
        **common,
    ).clean_profile
    if swap_channels:
        minus = minus[:, ::-1]
    rng = np.random.default_rng(seed)
    level = 0.003 * float(plus.max())
    sigma = np.full(plus.shape, level)
    lamp = LampObservation(
        "LED",
        led,
        PIXEL,
        plus + level * rng.standard_normal(plus.shape),
        profile_sigma=sigma,
        kind="led",
        pixel_origin="direct_spot",
        other_order=OrderProfile(PIXEL, minus + level * rng.standard_normal(minus.shape), sigma),
    )
    return lamp, level


def test_both_orders_measure_the_incidence_and_the_focal_length() -> None:
    lamp, _ = _lamp(GRATING, 1)
    measured = other_order_geometry(lamp)
    assert measured is not None and measured.refused is None
    assert 0.5 < measured.reduced_chi2 < 1.5
    # Within the σ the measurement states (widened: decision 0197), and tight enough to tell
    # the LED-only basins apart (a median 16° on the validation split).
    assert abs(measured.incidence_deg - GRATING.incidence_deg) < 3 * measured.incidence_sigma_deg
    assert measured.incidence_sigma_deg < 1.0
    assert abs(measured.log_focal - math.log(GRATING.focal_length_px)) < 3 * (
        measured.log_focal_sigma
    )


def test_an_other_order_the_ratio_model_does_not_describe_is_refused() -> None:
    # Its colours the wrong way round: no geometry makes it the +1 profile's shape.
    lamp, _ = _lamp(GRATING, 0, swap_channels=True)
    measured = other_order_geometry(lamp)
    assert measured is not None
    assert measured.refused is not None and "not the +1 profile's shape" in measured.refused


def test_without_the_other_order_nothing_is_measured() -> None:
    lamp, _ = _lamp(GRATING, 0)
    from dataclasses import replace

    assert other_order_geometry(replace(lamp, other_order=None)) is None
    with pytest.raises(InputError, match="direct spot"):
        replace(lamp, pixel_origin="arbitrary")


def test_a_flat_valleys_sigma_reaches_the_result_as_none_not_infinity() -> None:
    import json

    from calib.wavelength.other_order import OtherOrderGeometry

    flat = OtherOrderGeometry(
        0.01, math.inf, 8.0, math.inf, 0.9, 300, ((math.inf, 0.0), (0.0, math.inf)), None
    )
    record = json.loads(json.dumps(flat.to_dict(), allow_nan=False))
    assert record["incidence_sigma_deg"] is None and record["correlation"] is None


def test_the_report_says_what_both_orders_hold_and_why_not() -> None:
    from types import SimpleNamespace

    from calib.pipeline.report import _both_orders

    def row(record: object) -> str | None:
        return _both_orders(SimpleNamespace(details={"other_order": record}))

    held = {
        "focal_length_px": 3216.0,
        "log_focal_sigma": 0.033,
        "incidence_deg": -4.9,
        "incidence_sigma_deg": 0.17,
        "refused": None,
    }
    assert row(held) == (
        "focal length 3216 ± 106 px, grating tilt (incidence) -4.90 ± 0.17°; reported, not used "
        "by the mapping"
    )
    mirrored = {**held, "log_focal_sigma": None, "incidence_sigma_deg": 140.0}
    assert row(mirrored) is not None and row(mirrored).startswith(  # type: ignore[union-attr]
        "focal length not held, grating tilt not held"
    )
    assert row({"refused": "too few lit samples"}) == "not measured: too few lit samples"
    assert _both_orders(SimpleNamespace(details={})) is None
