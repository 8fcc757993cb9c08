"""Judge the σ budget's coverage factor on the validation split (and nowhere else).

:mod:`calib.methods.uncertainty` names what limits an estimate; what it leaves out is covered by one
factor per method (:data:`calib.methods.uncertainty.COVERAGE_SCALE`). This module chooses it: every
validation camera's scene is estimated with the factor 1, each estimate's errors are divided by its
named σ, and the factor is the smallest that brings the mean ±2σ coverage to the target. The split
must be the validation split (:func:`~calib.evaluation.validation.splits.require_validation`); the
test split and the real data are only ever reported.

Run it with ``python -m calib.evaluation.validation.budget --data-dir DIR [--jobs 2]``; the factors
it prints are what ``COVERAGE_SCALE`` holds (with the command, in decision 0029).
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    EXTRA_VARIANTS,
    ProtocolSettings,
    Task,
    render_task_scene,
    split_tasks,
)
from calib.evaluation.validation.splits import ValidationSplit, load_splits, require_validation
from calib.methods.uncertainty import BudgetSettings

#: The mean ±2σ coverage the factor aims at on the validation split.
TARGET_COVERAGE = 0.95
#: Coverage width (σ).
WIDTH = 2.0


def task_ratios(task: Task) -> list[tuple[str, FloatArray]]:
    """Per variant of the task's scene: ``(registry method, |error| / named σ)`` flattened over the
    grid and channels (``inf`` where σ is 0 and the error is not); failed estimates are left out."""
    from calib.methods import estimate

    scene = render_task_scene(task)
    out: list[tuple[str, FloatArray]] = []
    unscaled = BudgetSettings(coverage_scale={})
    for variant in task.settings.variants:
        observations = [scene.observations[lamp] for lamp in variant.lamps]
        extra: dict[str, Any] = {} if variant.options is None else {"options": variant.options}
        try:
            result = estimate(
                observations,
                method=variant.method,
                grid=task.settings.grid,
                basis=task.basis,
                budget=unscaled,
                **extra,
            )
        except Exception:  # a failed estimate has no band to judge (the protocol counts it)
            continue
        # judged on the curve users get (negative lobes set to zero) and its σ
        curves = result.camera_curves()
        assert curves.sigma is not None
        error = np.abs(np.asarray(curves.values - scene.truth))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(
                curves.sigma > 0,
                error / curves.sigma,
                np.where(error > 0, np.inf, 0.0),
            )
        out.append((result.method, np.asarray(ratio, dtype=np.float64).ravel()))
    return out


def coverage_at(ratios: Sequence[FloatArray], scale: float, width: float = WIDTH) -> float:
    """Mean over estimates of the share with ``|error| ≤ width · scale · σ``."""
    return float(np.mean([np.mean(r <= width * scale) for r in ratios]))


def fit_scale(
    ratios: Sequence[FloatArray], target: float = TARGET_COVERAGE, width: float = WIDTH
) -> float:
    """The smallest factor ≥ 1 whose mean coverage reaches ``target`` (bisection on a log scale)."""
    if coverage_at(ratios, 1.0, width) >= target:
        return 1.0
    low, high = 0.0, 1.0
    while coverage_at(ratios, 10.0**high, width) < target and high < 6:
        high += 1.0
    for _ in range(40):
        middle = 0.5 * (low + high)
        if coverage_at(ratios, 10.0**middle, width) >= target:
            high = middle
        else:
            low = middle
    return float(10.0**high)


def validation_ratios(
    split: ValidationSplit, settings: ProtocolSettings, *, jobs: int = 1
) -> dict[str, list[FloatArray]]:
    """Registry method → every validation estimate's error/σ ratios (factor 1)."""
    tasks = split_tasks(require_validation(split), settings)
    gathered: dict[str, list[FloatArray]] = {}
    if jobs <= 1:
        results = [task_ratios(task) for task in tasks]
    else:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
            results = list(pool.map(task_ratios, tasks, chunksize=1))
    for rows in results:
        for method, ratio in rows:
            gathered.setdefault(method, []).append(ratio)
    return gathered


def fit_coverage_scales(
    ratios: Mapping[str, Sequence[FloatArray]], target: float = TARGET_COVERAGE
) -> dict[str, float]:
    """Per method, :func:`fit_scale` of its validation ratios."""
    return {method: round(fit_scale(values, target), 2) for method, values in ratios.items()}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--target", type=float, default=TARGET_COVERAGE)
    parser.add_argument("--limit", type=int, default=0, help="first N cameras only (smoke)")
    parser.add_argument("--save", default=None, help="write the ratios to this .npz")
    args = parser.parse_args(argv)
    splits, _ = load_splits(args.data_dir, seed=args.seed)
    split = splits.validation
    if args.limit:
        split = replace(split, cameras=split.cameras[: args.limit])
    settings = ProtocolSettings(seed=args.seed, variants=(*DEFAULT_VARIANTS, *EXTRA_VARIANTS))
    ratios = validation_ratios(split, settings, jobs=args.jobs)
    scales = fit_coverage_scales(ratios, args.target)
    if args.save:
        arrays: dict[str, Any] = {
            f"{m}__{i}": r for m, values in ratios.items() for i, r in enumerate(values)
        }
        np.savez_compressed(args.save, **arrays)
    for method, values in sorted(ratios.items()):
        print(
            f"{method}: {len(values)} estimates, coverage at factor 1 "
            f"{100 * coverage_at(values, 1.0):.1f} %, factor {scales[method]:.2f} "
            f"→ {100 * coverage_at(values, scales[method]):.1f} %"
        )
    print("COVERAGE_SCALE =", scales)
    return 0


if __name__ == "__main__":
    sys.exit(main())
