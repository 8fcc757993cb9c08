"""The offline estimate decoded tile by tile over the region of interest equals the estimate decoded
whole by LibRaw, on a rendered capture stored as cameras store it (lossless-JPEG tiles)."""

from __future__ import annotations

import functools

import numpy as np
import pytest

import calib.pipeline.estimate as estimate_module
from calib.pipeline import LampImages, OfflineEstimate, OfflineSettings, estimate_offline
from calib.pipeline.brackets import bracket_profiles
from tests.rendered_capture import Capture, render_capture


def _inputs(capture: Capture) -> list[LampImages]:
    return [
        LampImages(lamp.name, lamp.kind, lamp.spectrum_csv, lamp.frames, lamp.darks)
        for lamp in capture.lamps
    ]


def _decodings(estimate: OfflineEstimate) -> list[str]:
    assert estimate.profiles is not None
    return [
        record.decoding
        for item in estimate.profiles.extractions
        for record in item.merged.image.frames
    ]


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Capture:
    root = tmp_path_factory.mktemp("roi")
    return render_capture(
        root / "capture",
        root / "basis",
        exposures_s=(0.002, 0.008, 0.032, 0.128),
        dark_frames=True,
        dark_current_dn_per_s=300.0,
        padding_px=120,
        compression="lossless-jpeg",
        tile_px=(64, 64),  # type: ignore[arg-type]
    )


def test_bracket_profiles_decode_the_region_only_and_agree_with_libraw(capture: Capture) -> None:
    lamps = _inputs(capture)
    tiles = bracket_profiles(lamps, use_region=True)
    libraw = bracket_profiles(lamps, use_region=True, decoder="libraw")
    decodings = [
        record.decoding for item in tiles.extractions for record in item.merged.image.frames
    ]
    assert all(text.startswith("tiles: ") for text in decodings), decodings
    read = [int(text.split()[1]) for text in decodings]
    total = int(decodings[0].split()[-1])
    # the first lamp's first frame is decoded whole (it chooses the region), every later frame
    # of every lamp only where the region is
    assert read.count(total) == 1 and max(read) == total
    assert max(r for r in read if r < total) < 0.75 * total
    assert {r.decoding for item in libraw.extractions for r in item.merged.image.frames} == {
        "LibRaw"
    }
    assert tiles.region_origin_px == libraw.region_origin_px is not None
    for ours, reference in zip(tiles.extractions, libraw.extractions, strict=True):
        a, b = ours.merged.image, reference.merged.image
        np.testing.assert_array_equal(a.radiance, b.radiance)
        np.testing.assert_array_equal(a.variance, b.variance)
        np.testing.assert_array_equal(a.saturated, b.saturated)
        np.testing.assert_array_equal(ours.extraction.profile, reference.extraction.profile)


@pytest.mark.slow  # the bracket profiles' libraw agreement stays in the default suite
def test_the_estimate_is_the_same_decoded_by_tiles_or_by_libraw(
    capture: Capture, monkeypatch: pytest.MonkeyPatch
) -> None:
    settings = OfflineSettings(basis=capture.basis, use_region=True)
    tiles = estimate_offline(_inputs(capture), settings)
    monkeypatch.setattr(
        estimate_module, "bracket_profiles", functools.partial(bracket_profiles, decoder="libraw")
    )
    libraw = estimate_offline(_inputs(capture), settings)
    assert all(text.startswith("tiles: ") for text in _decodings(tiles))
    assert set(_decodings(libraw)) == {"LibRaw"}
    for ours, reference in zip(tiles.observations, libraw.observations, strict=True):
        np.testing.assert_array_equal(ours.pixel, reference.pixel)
        np.testing.assert_allclose(ours.profile, reference.profile, rtol=1e-12, atol=0)
        assert ours.profile_sigma is not None and reference.profile_sigma is not None
        np.testing.assert_allclose(ours.profile_sigma, reference.profile_sigma, rtol=1e-12)
    np.testing.assert_allclose(
        tiles.result.sensitivity, libraw.result.sensitivity, rtol=1e-9, atol=1e-12
    )
    assert tiles.result.mapping is not None and libraw.result.mapping is not None
    pixel = tiles.observations[0].pixel
    np.testing.assert_allclose(
        tiles.result.mapping.wavelength_nm(pixel),
        libraw.result.mapping.wavelength_nm(pixel),
        rtol=1e-12,
    )
    relative, _ = capture.errors(tiles.result, pixel)
    assert relative < 0.035  # and both are right (tests/test_offline.py's target)
