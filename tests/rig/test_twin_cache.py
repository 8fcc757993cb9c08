"""The twin's colour-science tables on disk: the same numbers as colour's, stored once per colour
version, recomputed when a stored file is damaged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.core.lamp_specs import colour_lamp
from mocks.bench import colour_cache
from mocks.bench.lamps import settled_spectrum
from mocks.bench.optics import load_sensitivity
from tests.rig.twin_setup import twin_spec


def test_stored_tables_are_colours_own(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    spec = twin_spec()
    lamp = spec.lamps[0]
    first = settled_spectrum(lamp)
    stored = sorted(colour_cache.cache_directory().glob("*.npz"))
    assert len(stored) == 1 and colour_cache.cache_directory().is_relative_to(tmp_path)
    assert "colour-0." in colour_cache.cache_directory().name
    again = settled_spectrum(lamp)
    np.testing.assert_array_equal(again.values, first.values)
    reference = colour_lamp(lamp.spd)
    np.testing.assert_allclose(
        again.values / again.values.max(), reference.values / reference.values.max(), rtol=1e-12
    )
    camera = spec.twin_camera
    sensitivity = load_sensitivity(camera)
    assert len(sorted(colour_cache.cache_directory().glob("*.npz"))) == 2
    np.testing.assert_array_equal(load_sensitivity(camera).values, sensitivity.values)
    for path in colour_cache.cache_directory().glob("*.npz"):
        path.write_bytes(b"damaged")
    np.testing.assert_array_equal(settled_spectrum(lamp).values, first.values)
    np.testing.assert_array_equal(load_sensitivity(camera).values, sensitivity.values)


def test_colours_version_is_read_once(monkeypatch: pytest.MonkeyPatch) -> None:
    # Reading a distribution's metadata parses its METADATA file (3 ms each); a twin opens with
    # three tables, and the bench opens one per capture.
    looked_up: list[str] = []

    def counting(name: str) -> str:
        looked_up.append(name)
        return "0.4.7"

    monkeypatch.setattr(colour_cache, "version", counting)
    colour_cache.colour_version.cache_clear()
    try:
        names = {colour_cache.cache_directory().name for _ in range(3)}
    finally:
        colour_cache.colour_version.cache_clear()
    assert looked_up == ["colour-science"]
    assert names == {f"{colour_cache.CACHE_FORMAT}-colour-0.4.7"}
