"""``bench/twin_coverage.py``'s validation twins meet the spot phases a rig meets (decision 0136).

The twin centres the first order of the true curve's longest tabulated wavelength on the frame, so
the direct spot's sub-pixel phase on the Bayer mosaic follows from the curve's table: every
rawtoaces-data body (380–780 nm) had its spot at one phase, where decision 0114's fit judges the
demo's spot blurred, and the test bodies tabulated over 400–720 nm at another, where it is judged
sharp and the Bayer interleaving reads it. The validation twins now draw the phase."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from rig.config import load_config
from tests.benches import load_bench

#: Importing the bench imports the rig (capture, estimate): seconds, so not in the default suite.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]


def _bench() -> ModuleType:
    return load_bench("twin_coverage.py")


def _validation_twins(bench: ModuleType) -> list[tuple[str, int]]:
    """The 98 validation twins of decisions 0123 and 0134: 49 bodies at two station seeds."""
    bodies = [name for name, _ in (*bench.VALIDATION, *bench.extra_validation_cameras(43))]
    return [(name, seed) for seed in (0, 1) for name in bodies]


def test_the_twin_places_the_spot_by_the_curves_tabulated_range() -> None:
    bench = _bench()
    base = load_config(ROOT / "config.yaml")

    def spot(camera: str, collection: str) -> tuple[float, float]:
        x, y = bench.twin_spot_px(bench.twin_config(base, camera, collection, None))
        return float(x), float(y)

    # two rawtoaces-data bodies (380–780 nm): one spot, to the bit
    assert spot("Canon EOS 5D Mark II", "rawtoaces-data") == spot("Nikon D850", "rawtoaces-data")
    # a curve tabulated over 400–680 nm: another sub-pixel phase along the dispersion
    x_wide, _ = spot("Canon EOS 5D Mark II", "rawtoaces-data")
    x_narrow, _ = spot("Sigma SDMerill (NPL)", "colour-science")
    phase = (x_narrow - x_wide) % bench.CFA_PERIOD_PX
    assert 0.1 < phase < bench.CFA_PERIOD_PX - 0.1


def test_a_shift_moves_the_twins_spot_by_itself() -> None:
    bench = _bench()
    base = load_config(ROOT / "config.yaml")
    camera = ("Nikon D850", "rawtoaces-data")
    shift = bench.spot_shift(camera[0], 1)
    placed = bench.twin_spot_px(bench.twin_config(base, *camera, None))
    moved = bench.twin_spot_px(bench.twin_config(base, *camera, None, spot_shift_px=shift))
    assert np.allclose(np.subtract(moved, placed), shift, atol=1e-9)


def test_the_validation_twins_spot_phases_span_the_bayer_period() -> None:
    bench = _bench()
    twins = _validation_twins(bench)
    shifts = np.array([bench.spot_shift(name, seed) for name, seed in twins])
    assert shifts.shape == (98, 2)
    assert np.all((shifts >= 0) & (shifts < bench.CFA_PERIOD_PX))
    # every quarter of the period along the dispersion (x) and across it (y) is met, where the
    # protocol before had one phase for all 98
    for axis in (0, 1):
        quarters = np.floor(shifts[:, axis] / (bench.CFA_PERIOD_PX / 4)).astype(int)
        assert set(quarters.tolist()) == {0, 1, 2, 3}
    # a twin's own draw: fixed across runs, and another body or seed draws another phase
    assert bench.spot_shift(*twins[0]) == bench.spot_shift(*twins[0])
    assert len({tuple(row) for row in shifts}) == len(twins)
