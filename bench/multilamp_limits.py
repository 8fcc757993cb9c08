"""What limits a multi-lamp estimate on the validation split: the protocol's error sources switched
off one at a time (decision 0109).

For each ablation the validation split's first ``--cameras`` cameras are rendered with that change
and estimated by the multi-lamp variants (5 lamps; 3 lamps + RGB LEDs) at factor 1
(:func:`calib.evaluation.validation.budget.task_records`); printed per ablation: the mean relative
error ×10⁻², the error's RMS, the named σ's RMS over the error's (median), the ±2σ coverage at
factor 1 and the factor that brings it to 95 %. The ablation whose removal collapses the error and
the factor names what limits the estimate. Validation split only (a tuning tool).

    python bench/multilamp_limits.py --data-dir DIR [--cameras 12] [--jobs 1] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from calib.core.spectra import MultiSpectrum
from calib.evaluation.validation.budget import (
    EstimateRecord,
    coverage_at,
    fit_scale,
    save_records,
    task_records,
)
from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    ProtocolSettings,
    Task,
    render_task_scene,
    split_tasks,
)
from calib.evaluation.validation.rig_errors import PhotonBudget, RigErrors, SpectrometerError
from calib.evaluation.validation.splits import load_splits, require_validation

MULTILAMP_VARIANTS = ("5 lamps", "3 lamps + RGB LEDs")
DEFAULT = RigErrors()
QUIET = PhotonBudget(full_well_range_e=(1e8, 1e8), read_noise_range_e=(0.0, 0.0))


@dataclass(frozen=True)
class Ablation:
    """One change to the protocol: its rig errors, and whether the estimate is given the true
    mapping / the camera is replaced by its projection on the basis span."""

    errors: RigErrors = DEFAULT
    true_mapping: bool = False
    in_span: bool = False


ABLATIONS: dict[str, Ablation] = {
    "all errors": Ablation(),
    "no exposure error": Ablation(replace(DEFAULT, exposure=None)),
    "no lamp drift": Ablation(replace(DEFAULT, drift=None)),
    "no stray light": Ablation(replace(DEFAULT, stray=None)),
    "no spectrometer offset": Ablation(
        replace(DEFAULT, spectrometer=SpectrometerError(offset_range_nm=(0.0, 0.0)))
    ),
    "no spectrometer noise": Ablation(
        replace(DEFAULT, spectrometer=SpectrometerError(noise_fraction=0.0, floor_fraction=0.0))
    ),
    "narrow spectrometer (0.5 nm)": Ablation(
        replace(DEFAULT, spectrometer=SpectrometerError(bandwidth_range_nm=(0.5, 0.5)))
    ),
    "no spectrometer": Ablation(replace(DEFAULT, spectrometer=None)),
    "quiet sensor": Ablation(replace(DEFAULT, photons=QUIET)),
    "noise only": Ablation(RigErrors.noise_only()),
    "noise only, quiet sensor": Ablation(RigErrors.noise_only(QUIET)),
    "true mapping": Ablation(true_mapping=True),
    "camera in basis span": Ablation(in_span=True),
    "noise only, true mapping": Ablation(RigErrors.noise_only(), true_mapping=True),
    "noise only, in span": Ablation(RigErrors.noise_only(), in_span=True),
    "noise only, true mapping, in span": Ablation(
        RigErrors.noise_only(), true_mapping=True, in_span=True
    ),
}


def in_span(task: Task) -> Task:
    """The task with its camera replaced by the camera's projection on the basis span (clipped at
    0): what the basis can represent exactly."""
    grid = task.basis.grid
    truth = task.camera.sensitivity.resample(grid, "interpolate", out_of_range="zero").values
    projected = np.clip(task.basis.project(truth), 0.0, None)
    curves = MultiSpectrum(grid.wavelength_nm, projected / projected.max(), name="in span")
    return replace(task, camera=replace(task.camera, sensitivity=curves))


def ablation_records(item: tuple[Task, Ablation]) -> tuple[list[EstimateRecord], float]:
    task, ablation = item
    started = time.process_time()
    if ablation.in_span:
        task = in_span(task)
    scene = render_task_scene(task)
    extra: dict[str, Any] = {}
    if ablation.true_mapping:
        extra["mapping"] = scene.plan.geometry.mapping
    return task_records(task, scene, extra), time.process_time() - started


def summary(records: list[EstimateRecord]) -> str:
    if not records:
        return "no estimates"
    ratios = [r.ratio() for r in records]
    error_rms = [float(np.sqrt(np.mean(r.error**2))) for r in records]
    named = [
        float(np.sqrt(np.mean(r.named() ** 2))) / e for r, e in zip(records, error_rms, strict=True)
    ]
    return (
        f"{len(records):3d} est, error RMS {np.mean(error_rms):.4f} (median "
        f"{np.median(error_rms):.4f}), named/error "
        f"{np.median(named):.2f}, coverage@1 {100 * coverage_at(ratios, 1.0):.1f} %, factor "
        f"{fit_scale(ratios):.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data-dir", required=True)
    parser.add_argument("--cameras", type=int, default=12)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--only", action="append", default=None)
    parser.add_argument("--save", default=None, help="directory for each ablation's records")
    args = parser.parse_args()
    splits, _ = load_splits(args.data_dir)
    split = require_validation(splits.validation)
    split = replace(split, cameras=split.cameras[: args.cameras])
    variants = tuple(v for v in DEFAULT_VARIANTS if v.label in MULTILAMP_VARIANTS)
    names = args.only or list(ABLATIONS)
    mapper: Callable[..., Any] = map
    pool = ProcessPoolExecutor(args.jobs) if args.jobs > 1 else None
    if pool is not None:
        mapper = pool.map
    print(f"validation split, first {len(split.cameras)} cameras, seed 0, sinusoidal gratings")
    for name in names:
        ablation = ABLATIONS[name]
        settings = ProtocolSettings(errors=ablation.errors, variants=variants)
        tasks = split_tasks(split, settings)
        results = list(mapper(ablation_records, [(task, ablation) for task in tasks]))
        records = [record for rows, _ in results for record in rows]
        cpu = sum(seconds for _, seconds in results)
        if args.save:
            save_records(records, str(Path(args.save) / (name.replace(" ", "_") + ".npz")))
        print(f"{name} ({cpu:.0f} s CPU)", flush=True)
        for label in MULTILAMP_VARIANTS:
            print(f"  {label:20s} {summary([r for r in records if r.variant == label])}")
        print(f"  {'both':20s} {summary(records)}", flush=True)
    if pool is not None:
        pool.shutdown()


if __name__ == "__main__":
    main()
