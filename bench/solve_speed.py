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

With ``--stages``, also where one pass's time goes (decision 0116): the CPU time inside each of
the solve's named stages (:data:`STAGES`: the Fourier η model's prior-weight search, the physical
families' fits, the prior solve, a lamp prepared and its response fitted, and the σ budget), per
estimate, each stage's time inclusive of what it calls (the budget's re-solves run the other
stages again: they are counted in their rows too), read by wrapping the functions where the solve
looks them up (the same names on older checkouts).

    python bench/solve_speed.py --data-dir ../shared/data/camera_sensitivities [--cameras 4] [--repeats 3] [--stages]
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
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

#: The solve's stages :func:`staged` times: label → the modules that look the function up and
#: its name there.
STAGES: dict[str, tuple[tuple[str, ...], str]] = {
    "Fourier η model (prior-weight search)": (
        ("calib.methods.multilamp",),
        "solve_fourier_efficiency",
    ),
    "physical families' fits": (
        ("calib.methods.multilamp", "calib.methods.grating_models"),
        "fit_physical",
    ),
    "prior solve": (("calib.methods.prior_solve",), "solve_with_prior"),
    "lamp prepared + response fitted": (
        ("calib.methods.prior_solve", "calib.methods.multilamp"),
        "prepared_response",
    ),
    "σ budget (its re-solves included)": (("calib.methods",), "uncertainty_budget"),
}


@contextmanager
def staged(spent: dict[str, float]) -> Iterator[None]:
    """Within the block, add each :data:`STAGES` function's CPU time to ``spent[label]`` (a call
    inside a call of the same stage counted once)."""
    patched: list[tuple[Any, str, Any]] = []

    def timed(label: str, function: Callable[..., Any]) -> Callable[..., Any]:
        depth = [0]

        @functools.wraps(function)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            depth[0] += 1
            started = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                depth[0] -= 1
                if depth[0] == 0:
                    spent[label] = spent.get(label, 0.0) + time.process_time() - started

        return wrapper

    for label, (modules, name) in STAGES.items():
        wrappers: dict[int, Any] = {}
        for module_name in modules:
            module = importlib.import_module(module_name)
            original = getattr(module, name, None)
            if original is None:
                continue
            wrapper = wrappers.setdefault(id(original), timed(label, original))
            patched.append((module, name, original))
            setattr(module, name, wrapper)
    try:
        yield
    finally:
        for module, name, original in reversed(patched):
            setattr(module, name, original)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--stages", action="store_true", help="also the CPU time of the solve's named stages"
    )
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
            if args.stages:
                spent: dict[str, float] = {}
                with staged(spent):
                    for _ in range(args.repeats):
                        one_pass()
                count = args.repeats * len(runs)
                for stage in STAGES:
                    if stage in spent:
                        print(f"    {stage:38s} {spent[stage] / count * 1e3:7.1f} ms", flush=True)


if __name__ == "__main__":
    main()
