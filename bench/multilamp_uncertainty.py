"""What the σ band costs: multi-lamp estimate with and without its uncertainty (target ≤ 0.2 s added).

Renders the 5-lamp scene (LED-B1, LED-B3, LED-B5, FL2, A; 1 % noise) for one camera — colour-science's
Nikon 5100 with the offline basis (excluding it), or with ``--data-dir`` the Canon 600D with the
44-camera basis — and times :func:`calib.methods.multilamp.estimate_multilamp` with the true mapping (the
mapping search does not depend on the uncertainty) with ``uncertainty="posterior"`` and ``"none"``:
medians of repeats after a warm-up, on one core. Also prints the share of the truth inside ±2σ.

    python bench/multilamp_uncertainty.py [--data-dir DIR] [--repeats 7]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from calib.core.datasets import colour_science_cameras, find_camera, makabe2025_split
from calib.core.spectra import DEFAULT_GRID
from calib.evaluation.synthetic import (
    LAMP_SETS,
    band_coverage,
    random_efficiency,
    random_mapping,
    render_lamps,
)
from calib.methods.multilamp import MultilampOptions, Uncertainty, estimate_multilamp
from calib.model.bases import camera_basis, fallback_camera_basis


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    if args.data_dir:
        train, test = makabe2025_split(args.data_dir)
        camera = find_camera(test, "Canon 600D")
        basis = camera_basis([r.sensitivity for r in train], source="Makabe 2025 train (44)")
    else:
        camera = find_camera(colour_science_cameras(), "Nikon 5100")
        basis = fallback_camera_basis(exclude=["Nikon 5100"])
    rng = np.random.default_rng(0)
    mapping = random_mapping(rng)
    observations = render_lamps(
        LAMP_SETS["5 lamps"], camera.sensitivity, mapping, random_efficiency(rng), rng, 0.01
    )

    def timed(uncertainty: Uncertainty) -> float:
        times = []
        for _ in range(args.repeats + 1):
            started = time.perf_counter()
            estimate_multilamp(
                observations,
                basis=basis,
                mapping=mapping,
                options=MultilampOptions(uncertainty=uncertainty),
            )
            times.append(time.perf_counter() - started)
        return statistics.median(times[1:])

    with_sigma = timed("posterior")
    without = timed("none")
    result = estimate_multilamp(observations, basis=basis, mapping=mapping)
    truth = camera.sensitivity.resample(DEFAULT_GRID, "interpolate", out_of_range="zero").values
    coverage = band_coverage(result, truth / truth.max())
    print(f"camera {camera.name}, 5 lamps, 1 % noise, true mapping")
    print(f"estimate without σ: {without:.3f} s; with σ: {with_sigma:.3f} s")
    print(f"σ adds {with_sigma - without:.3f} s (target ≤ 0.2 s); truth inside ±2σ: {coverage:.0%}")


if __name__ == "__main__":
    main()
