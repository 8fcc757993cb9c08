"""Wall time of mapping + estimate for one camera on one core (target ≤ 0.5 s), and its accuracy.

Renders the paper's synthetic scene (§4.1) for one camera — colour-science's Nikon 5100 with the offline
basis (excluding it), or with ``--data-dir`` the Canon 600D with the 44-camera basis — and times
``calib.methods.estimate`` (method ``auto``: the prior solve here) for the LED-only and
LED+fluorescent variants (median of repeats, after a warm-up).

    python bench/estimate.py [--data-dir DIR] [--repeats 5]
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
from calib.core.lamp_specs import colour_lamp
from calib.core.metrics import relative_error
from calib.core.spectra import DEFAULT_GRID
from calib.evaluation.synthetic import render_scene
from calib.methods import estimate
from calib.model.bases import camera_basis, fallback_camera_basis


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--noise", type=float, default=0.01)
    args = parser.parse_args()
    if args.data_dir:
        train, test = makabe2025_split(args.data_dir)
        camera = find_camera(test, "Canon 600D")
        basis = camera_basis([r.sensitivity for r in train], source="Makabe 2025 train (44)")
    else:
        camera = find_camera(colour_science_cameras(), "Nikon 5100 (NPL)")
        basis = fallback_camera_basis(exclude=["Nikon 5100"])
    sensitivity = camera.sensitivity.resample(DEFAULT_GRID, "interpolate")
    scene = render_scene(
        camera.name,
        sensitivity,
        np.random.default_rng(0),
        broadband_lamp=colour_lamp("D65"),
        fluorescent_lamp=colour_lamp("FL2"),
        noise_fraction=args.noise,
    )
    led, fluorescent = scene.broadband.observation, scene.fluorescent.observation
    print(
        f"camera {camera.name}, basis: {basis.source}, noise {args.noise:g} of peak, n_pixels {led.n_pixels}"
    )
    for label, observations in (("LED only", [led]), ("LED+Flu", [led, fluorescent])):
        estimate(observations, basis=basis)  # warm-up (imports, caches)
        times = []
        for _ in range(args.repeats):
            started = time.perf_counter()
            result = estimate(observations, basis=basis)
            times.append(time.perf_counter() - started)
        print(
            f"{label:9s} mapping + estimate: median {statistics.median(times):.3f} s "
            f"(min {min(times):.3f} s, {args.repeats} runs); RE {100 * relative_error(result.physical_sensitivity(), scene.truth):.2f}×10⁻²"
        )


if __name__ == "__main__":
    main()
