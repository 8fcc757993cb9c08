"""Choose the camera prior's covariance shrinkage by leave-one-camera-out on the TRAINING cameras.

For each of the 44 training cameras of Makabe et al. (2025) §4.1: the prior is built from the other
43, the camera is rendered through a random grating and mapping (the synthetic protocol, 1 % noise,
true mapping: this isolates the solve), and the sensitivity is estimated with the prior solve
(``estimate_prior``) for every candidate shrinkage. Prints the mean RE per shrinkage; the five test cameras are never used.

    python bench/tune_prior.py --data-dir ../shared/data/camera_sensitivities
"""

from __future__ import annotations

import argparse

import numpy as np

from calib.core.datasets import makabe2025_split
from calib.core.lamp_specs import colour_lamp
from calib.core.metrics import relative_error
from calib.core.spectra import DEFAULT_GRID
from calib.evaluation.synthetic import render_scene
from calib.methods.prior_solve import PriorOptions, estimate_prior
from calib.model.bases import camera_basis


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--noise", type=float, default=0.01)
    parser.add_argument("--lamps", default="D65,LED-B3")
    parser.add_argument("--shrinkages", default="lw,0.05,0.1,0.2,0.3,0.5,0.7,0.9")
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    train, _test = makabe2025_split(args.data_dir)
    shrinkages: list[float | None] = [
        None if s == "lw" else float(s) for s in args.shrinkages.split(",")
    ]
    fluorescent = colour_lamp("FL2")
    errors: dict[float | None, list[float]] = {s: [] for s in shrinkages}
    for lamp_name in args.lamps.split(","):
        lamp = colour_lamp(lamp_name)
        for index, held_out in enumerate(train):
            others = [r.sensitivity for i, r in enumerate(train) if i != index]
            basis = camera_basis(others, grid=DEFAULT_GRID, cache=False)
            rng = np.random.default_rng([args.seed, index])
            scene = render_scene(
                held_out.name,
                held_out.sensitivity,
                rng,
                broadband_lamp=lamp,
                fluorescent_lamp=fluorescent,
                noise_fraction=args.noise,
            )
            for shrinkage in shrinkages:
                result = estimate_prior(
                    [scene.broadband.observation],
                    basis=basis,
                    mapping=scene.mapping,
                    options=PriorOptions(prior_shrinkage=shrinkage),
                )
                errors[shrinkage].append(relative_error(result.physical_sensitivity(), scene.truth))
    print(
        f"leave-one-out over {len(train)} training cameras × lamps {args.lamps}, noise {args.noise}"
    )
    print("  shrinkage  mean RE (×10⁻²)  median")
    for shrinkage in shrinkages:
        values = 100 * np.array(errors[shrinkage])
        label = "Ledoit-Wolf" if shrinkage is None else f"{shrinkage:.2f}"
        print(f"{label:>11}  {values.mean():15.3f}  {np.median(values):6.3f}")
    best = min(shrinkages, key=lambda s: float(np.mean(errors[s])))
    print(f"best: {'Ledoit-Wolf' if best is None else best}")


if __name__ == "__main__":
    main()
