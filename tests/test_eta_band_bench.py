"""``bench/eta_band.py``'s diagnostic switch (decision 0164): each named drawn error source is off,
the others stay at the protocol's defaults."""

from __future__ import annotations

import pytest

from calib.evaluation.validation.rig_errors import RigErrors
from tests.benches import load_bench

#: Importing the bench imports the rig (capture, estimate): seconds, so not in the default suite.
pytestmark = pytest.mark.slow


def test_each_named_source_is_switched_off_and_the_rest_kept() -> None:
    bench = load_bench("eta_band.py")
    default = RigErrors()
    assert bench.errors_without([]) == default
    errors = bench.errors_without(["stray", "spectrometer-offset", "spectrometer-noise"])
    assert errors.stray is None
    assert errors.exposure == default.exposure and errors.drift == default.drift
    assert errors.spectrometer is not None
    assert errors.spectrometer.offset_range_nm == (0.0, 0.0)
    assert errors.spectrometer.noise_fraction == 0.0 == errors.spectrometer.floor_fraction
    assert errors.spectrometer.bandwidth_range_nm == default.spectrometer.bandwidth_range_nm  # type: ignore[union-attr]
    assert bench.errors_without(["spectrometer"]).spectrometer is None
    with pytest.raises(SystemExit):
        bench.errors_without(["lens"])
