"""CPU time of the estimate after the mapping (the solve alone) in ``calib validate``'s scenes.

:mod:`bench.wavelength_speed` ``--solve-only`` times the solve on the paper's synthetic scene
(one camera, the Fourier model's path); this bench times it where the validation protocol runs
it: the first ``--cameras`` tasks of the VALIDATION split (seed 0: the rig's errors, profiles
from the direct spot, a spectrometer bandwidth), the variants "LED only", "LED+FL" (the prior
solve, its grating model chosen among Fourier and the physical families) and "5 lamps" (the
multi-lamp solve, with each physical fit's leave-one-lamp-out jackknife), each given the scene's
true mapping, with its σ budget (the perturbation re-solves) and without (``budget=None``).

Per variant: the CPU time (``time.process_time``, one BLAS thread) of one pass over the cameras,
the median of ``--repeats`` passes after a warm-up pass. The scenes are rendered before timing.
It imports only :func:`calib.methods.estimate` and the protocol's public functions, so the same
file times another checkout (``PYTHONPATH=that/checkout python bench/solve_speed.py ...``).

    python bench/solve_speed.py --data-dir ../shared/data/camera_sensitivities [--cameras 4] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    ProtocolSettings,
    render_task_scene,
    split_tasks,
    variant_arguments,
    variant_observations,
)
from calib.evaluation.validation.splits import load_splits
from calib.methods import estimate

VARIANTS = ("LED only", "LED+FL", "5 lamps")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    splits, _ = load_splits(args.data_dir)
    settings = ProtocolSettings(seed=0)
    tasks = split_tasks(splits.validation, settings)[: args.cameras]
    jobs: dict[str, list[tuple[list[Any], Any, dict[str, Any]]]] = {name: [] for name in VARIANTS}
    for task in tasks:
        scene = render_task_scene(task)
        truth = scene.plan.geometry.mapping
        for variant in DEFAULT_VARIANTS:
            if variant.label not in VARIANTS:
                continue
            keywords = {
                "method": variant.method,
                "grid": settings.grid,
                "basis": task.basis,
                **variant_arguments(variant),
            }
            jobs[variant.label].append((variant_observations(scene, variant), truth, keywords))
    for name, runs in jobs.items():
        for label, extra in (("solve alone", {}), ("no σ budget", {"budget": None})):

            def one_pass(
                runs: list[tuple[list[Any], Any, dict[str, Any]]] = runs,
                extra: dict[str, Any] = extra,
            ) -> None:
                for lamps, truth, keywords in runs:
                    estimate(lamps, mapping=truth, **keywords, **extra)

            one_pass()  # warm-up: imports, caches
            times = []
            for _ in range(args.repeats):
                started = time.process_time()
                one_pass()
                times.append(time.process_time() - started)
            per_estimate = statistics.median(times) / len(runs)
            print(
                f"{name:10s} {label:12s} {per_estimate * 1e3:8.1f} ms per estimate "
                f"({len(runs)} validation cameras, median of {args.repeats})",
                flush=True,
            )


if __name__ == "__main__":
    main()
