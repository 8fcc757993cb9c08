"""Choose the mapping search's local flexibility by leave-one-camera-out on the TRAINING cameras.

For each of the 44 training cameras of Makabe et al. (2025) §4.1: the prior is built from the other
43, the camera is rendered through a random grating and mapping (the synthetic protocol), and the
mapping is found from the broadband lamp alone ("LED only") for every candidate
``local_flexibility`` of the search as it was before issue 16 (``bench/mapping_before.py``; the
product's :data:`calib.wavelength.profile_search.LOCAL_FLEXIBILITY` took its value from this run);
the sensitivity is then solved with that mapping.
Prints, per lamp, noise level and flexibility, the mean and worst mapping RE, the number of cameras
whose mapping RE exceeds 1 % and the mean RE. The five test cameras are never used.

    python bench/tune_mapping.py --data-dir ../shared/data/camera_sensitivities
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from mapping_before import search_mapping

from calib.core.datasets import makabe2025_split
from calib.core.lamp_specs import colour_lamp
from calib.core.metrics import mapping_relative_error, relative_error
from calib.core.spectra import DEFAULT_GRID
from calib.evaluation.synthetic import render_scene
from calib.methods.prior_solve import estimate_prior
from calib.model.bases import camera_basis
from calib.model.resolution import camera_kernel


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--noise", default="0.01")
    parser.add_argument("--lamps", default="D65,LED-B3")
    parser.add_argument("--flexibilities", default="0.05,0.5,2")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    train, _test = makabe2025_split(args.data_dir)
    flexibilities = [float(f) for f in args.flexibilities.split(",")]
    noise_levels = [float(n) for n in args.noise.split(",")]
    fluorescent = colour_lamp("FL2")
    grid = DEFAULT_GRID
    for lamp_name in args.lamps.split(","):
        lamp = colour_lamp(lamp_name)
        for noise_index, noise in enumerate(noise_levels):
            mapping_errors: dict[float, list[float]] = {f: [] for f in flexibilities}
            errors: dict[float, list[float]] = {f: [] for f in flexibilities}
            for index, held_out in enumerate(train):
                others = [r.sensitivity for i, r in enumerate(train) if i != index]
                basis = camera_basis(others, grid=grid, cache=False)
                prior = basis.prior()
                for repeat in range(args.repeats):
                    rng = np.random.default_rng([args.seed, index, noise_index, repeat])
                    scene = render_scene(
                        held_out.name,
                        held_out.sensitivity,
                        rng,
                        broadband_lamp=lamp,
                        fluorescent_lamp=fluorescent,
                        noise_fraction=noise,
                    )
                    observation = scene.broadband.observation
                    true_nm = scene.mapping.wavelength_nm(observation.pixel)
                    inside = (true_nm >= grid.start_nm) & (true_nm <= grid.stop_nm)
                    for flexibility in flexibilities:
                        found = search_mapping(
                            [observation],
                            prior,
                            grid,
                            kernel=camera_kernel([observation]),
                            local_flexibility=flexibility,
                        )
                        mapping_errors[flexibility].append(
                            mapping_relative_error(
                                found.wavelength_nm(observation.pixel[inside]),
                                true_nm[inside],
                                range_nm=(grid.start_nm, grid.stop_nm),
                            )
                        )
                        if mapping_errors[flexibility][-1] > 0.01:
                            print(
                                f"  {held_out.name}: mapping RE "
                                f"{100 * mapping_errors[flexibility][-1]:.2f} % at local "
                                f"flexibility {flexibility:g}, repeat {repeat}",
                                flush=True,
                            )
                        result = estimate_prior([observation], basis=basis, mapping=found)
                        errors[flexibility].append(
                            relative_error(result.physical_sensitivity(), scene.truth)
                        )
            for flexibility in flexibilities:
                values = 100 * np.array(mapping_errors[flexibility])
                print(
                    f"{lamp_name:7s} noise {noise:<6g} local flexibility {flexibility:<5g} "
                    f"mapping RE mean {values.mean():.3f} %, max {values.max():.3f} %, "
                    f"> 1 %: {int(np.sum(values > 1.0))}/{values.size}; "
                    f"RE mean {100 * np.mean(errors[flexibility]):.2f}×10⁻²",
                    flush=True,
                )


if __name__ == "__main__":
    main()
