"""What makes the 2-D (RAW → profiles) estimate worse than the 1-D one, component by component
(decision 0119). Validation split only (a tuning tool).

Each validation task is rendered once as RAW brackets (:mod:`bench.validate_twin`) and run through
the offline pipeline; its observations are then estimated again with one part of them replaced by
the twin's truth in the same units (DN/s, the extraction's pixel axis):

- ``true direct``: each lamp's direct RGB = the rendered spot's total (noise-free);
- ``true profile``: each lamp's profile = the rendered first order at the profile's pixels
  (noise-free, the band's own per-pixel radiance);
- ``true line spread``: the first order's own kernel (the slit's box at the profile sampling),
  instead of the spot's measured cross-section;
- ``true mapping``: the plan's mapping given to the estimator;
- and their combinations. The 1-D protocol's row of the same task is printed beside them.

``--paths`` compares the σ budget of the two paths on the same tasks instead (decision 0126): each
variant's 1-D estimate (:func:`calib.evaluation.validation.budget.task_records`) and its 2-D one as
extracted, both at factor 1 and the spectrometer tolerances at the product's σ; per path, the
error's RMS, each component's RMS over the error's (median over estimates), the lamp spread's share
of the named variance, and the ±2σ coverage at factor 1 and at the product's factor, with and
without the lamp spread, and the factor that brings each to 95 %.

    python bench/twin_limits.py --data-dir DIR [--cameras-per-group 12] [--only NAME ...]
    python bench/twin_limits.py --data-dir DIR --paths [--variant '5 lamps']
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from calib.core.observations import LampObservation
from calib.core.result import EstimateResult
from calib.evaluation.validation.budget import (
    EstimateRecord,
    coverage_at,
    fit_scale,
    scale_checked,
    slit_measured,
    task_records,
)
from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    ProtocolSettings,
    Task,
    ValidationRow,
    draw_task_plan,
    evaluate_task,
    row_identity,
    scored_row,
    split_tasks,
)
from calib.evaluation.validation.splits import load_splits, require_validation
from calib.methods import estimate
from calib.methods.uncertainty import (
    DEFAULT_BUDGET,
    TOLERANCE_SIGMA,
    BudgetSettings,
    efficiency_family,
)
from calib.model.forward import blur_kernel
from calib.pipeline.estimate import OfflineSettings, estimate_offline

# The 2-D twin's rendering lives in bench/validate_twin.py, beside this script.
sys.path.insert(0, str(Path(__file__).resolve().parent))
from validate_twin import TwinLamp, _subset, render_lamps

Swap = Callable[[LampObservation, TwinLamp], LampObservation]


def _true_direct(obs: LampObservation, lamp: TwinLamp) -> LampObservation:
    return replace(obs, direct_rgb=lamp.true_direct())


def _true_profile(obs: LampObservation, lamp: TwinLamp) -> LampObservation:
    return replace(obs, profile=lamp.true_profile(obs.pixel))


def _true_spread(obs: LampObservation, lamp: TwinLamp) -> LampObservation:
    step = float(np.median(np.diff(obs.pixel)))
    return replace(obs, line_spread=blur_kernel(lamp.slit_width_px / step, 0.0))


def _none(obs: LampObservation, lamp: TwinLamp) -> LampObservation:
    return obs


ABLATIONS: dict[str, tuple[tuple[Swap, ...], bool]] = {
    "2-D as extracted": ((_none,), False),
    "true direct": ((_true_direct,), False),
    "true profile": ((_true_profile,), False),
    "true line spread": ((_true_spread,), False),
    "true mapping": ((_none,), True),
    "true direct + profile": ((_true_direct, _true_profile), False),
    "true direct + profile + spread": ((_true_direct, _true_profile, _true_spread), False),
    "true direct + profile + spread + mapping": (
        (_true_direct, _true_profile, _true_spread),
        True,
    ),
}


def _score(task: Task, variant_label: str, result: object, pixel: np.ndarray) -> ValidationRow:
    plan, _ = draw_task_plan(task)
    variant = next(v for v in task.settings.variants if v.label == variant_label)
    truth = task.camera.sensitivity.resample(plan.grid, "interpolate", out_of_range="zero").values
    true_nm = np.asarray(plan.geometry.mapping.wavelength_nm(pixel), dtype=np.float64)
    identity = row_identity(task, variant, split="validation (2-D ablation)")
    return scored_row(identity, result, truth / truth.max(), pixel, true_nm, time.perf_counter())  # type: ignore[arg-type]


def _component_scores(
    result: EstimateResult, task: Task, grid: object
) -> dict[str, tuple[float, float]]:
    """Per budget component: its share of the named variance and the ±2σ coverage of the delivered
    curves with it left out (the factor kept)."""
    plan, _ = draw_task_plan(task)
    truth = task.camera.sensitivity.resample(plan.grid, "interpolate", out_of_range="zero").values
    truth = truth / truth.max()
    curves = result.camera_curves()
    found = result.diagnostics.get("budget_components") or {}
    named2 = sum(np.asarray(v, dtype=np.float64) ** 2 for v in found.values())
    if curves.sigma is None or not found:
        return {}
    scale = float(np.sqrt(np.mean(np.asarray(curves.sigma) ** 2)) / np.sqrt(np.mean(named2)))
    difference = np.abs(np.asarray(curves.values) - truth)
    out = {"(all)": (1.0, float(np.mean(difference <= 2 * scale * np.sqrt(named2))))}
    for component, sigma in found.items():
        rest = np.clip(named2 - np.asarray(sigma, dtype=np.float64) ** 2, 0.0, None)
        out[component] = (
            float(np.mean(np.asarray(sigma) ** 2) / np.mean(named2)),
            float(np.mean(difference <= 2 * scale * np.sqrt(rest))),
        )
    return out


#: The budget both paths are judged with in ``--paths``: factor 1, tolerances at σ 1, every component
#: kept (as :func:`calib.evaluation.validation.budget.task_records` estimates the 1-D path).
UNSCALED = BudgetSettings(coverage_scale={}, tolerance_sigma=1.0, record_components=True)
#: Component name ``--paths`` leaves out for its "without" columns.
LAMP_SPREAD = "lamp spread"


def _record(result: EstimateResult, label: str, task: Task) -> EstimateRecord:
    """The 2-D estimate as :func:`calib.evaluation.validation.budget.task_records` records a 1-D
    one (its error on the delivered curves and its components at factor 1)."""
    plan, _ = draw_task_plan(task)
    truth = task.camera.sensitivity.resample(plan.grid, "interpolate", out_of_range="zero").values
    curves = result.camera_curves()
    error = np.abs(np.asarray(curves.values, dtype=np.float64) - truth / truth.max()).ravel()
    return EstimateRecord(
        result.method,
        label,
        error,
        {
            name: np.asarray(sigma, dtype=np.float64).ravel()
            for name, sigma in result.diagnostics["budget_components"].items()
        },
        any(flag.code == "no_spectrometer_bandwidth" for flag in result.quality.flags),
        efficiency_family(result),
        scale_checked=scale_checked(result),
        slit_measured=slit_measured(result),
    )


def _without(record: EstimateRecord, name: str) -> EstimateRecord:
    return replace(record, components={k: v for k, v in record.components.items() if k != name})


def _path_summary(records: list[EstimateRecord]) -> list[str]:
    """``--paths``' lines for one path and variant (module docstring)."""
    if not records:
        return ["    no estimates"]
    factor = BudgetSettings().scale_for(records[0].method, records[0].family)
    error_rms = [float(np.sqrt(np.mean(r.error**2))) for r in records]
    names = list(dict.fromkeys(name for r in records for name in r.components))
    parts = []
    for name in names:
        ratio = [
            float(np.sqrt(np.mean(r.components[name] ** 2))) / e
            for r, e in zip(records, error_rms, strict=True)
            if name in r.components
        ]
        parts.append(f"{name} {np.median(ratio):.2f}")
    shares = [
        float(np.mean(r.components.get(LAMP_SPREAD, 0.0 * r.error) ** 2))
        / float(np.mean(r.named(TOLERANCE_SIGMA) ** 2))
        for r in records
    ]
    lines = [
        f"    {len(records)} estimates, error RMS mean {np.mean(error_rms):.4f} (median "
        f"{np.median(error_rms):.4f}); component RMS / error RMS (median): " + ", ".join(parts),
        f"    lamp spread's share of the named variance {np.mean(shares):.2f}",
    ]
    for label, chosen in (
        ("all components", records),
        ("without the lamp spread", [_without(r, LAMP_SPREAD) for r in records]),
    ):
        ratios = [r.ratio(TOLERANCE_SIGMA) for r in chosen]
        lines.append(
            f"    {label:24s} ±2σ at factor 1 {100 * coverage_at(ratios, 1.0):.1f} %, at the "
            f"product's {factor:g} {100 * coverage_at(ratios, factor):.1f} %; factor to 95 % "
            f"{fit_scale(ratios):.2f}"
        )
    return lines


def reduced(
    task: Task,
    directory: Path,
    variants: tuple[Any, ...],
    budget: BudgetSettings | None = DEFAULT_BUDGET,
) -> tuple[Any, dict[str, TwinLamp], dict[str, Any]]:
    """The task rendered as the twin's RAW brackets (in ``directory``) and each variant's lamps
    reduced by ``calib estimate``'s offline path: ``(plan, lamps by spec, offline by label)``."""
    plan, noise = draw_task_plan(task)
    lamps = render_lamps(directory, plan, task, noise)
    offline = {
        variant.label: estimate_offline(
            [lamps[spec].images for spec in variant.lamps],
            OfflineSettings(
                method=variant.method,
                method_options=variant.options,
                grid=plan.grid,
                basis=task.basis,
                budget=budget,
            ),
        )
        for variant in variants
    }
    return plan, lamps, offline


def compare_paths(split: object, variants: tuple[object, ...]) -> None:
    """``--paths``: the 1-D and the 2-D estimates' budgets on the same tasks (module docstring)."""
    settings = ProtocolSettings(variants=variants)  # type: ignore[arg-type]
    found: dict[tuple[str, str], list[EstimateRecord]] = {}
    started = time.process_time()
    with tempfile.TemporaryDirectory() as temporary:
        for index, task in enumerate(split_tasks(split, settings)):  # type: ignore[arg-type]
            for record in task_records(task):
                found.setdefault(("1-D", record.variant), []).append(record)
            _, _, offline = reduced(
                task, Path(temporary) / f"task_{index:03d}", settings.variants, UNSCALED
            )
            for label, one in offline.items():
                found.setdefault(("2-D", label), []).append(_record(one.result, label, task))
            print(f"task {index} {task.camera.name} done", file=sys.stderr, flush=True)
    print(
        "validation split, seed 0; both paths at factor 1 (tolerances at the product's σ "
        f"{TOLERANCE_SIGMA:.3g})"
    )
    for (path, label), records in found.items():
        print(f"  {path} {label}:")
        print("\n".join(_path_summary(records)))
    print(f"CPU time: {time.process_time() - started:.0f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data-dir", type=Path, required=True)
    parser.add_argument("--cameras-per-group", type=int, default=12)
    parser.add_argument("--only", action="append", default=None)
    parser.add_argument("--variant", action="append", default=None)
    parser.add_argument("--paths", action="store_true", help="the 1-D and 2-D budgets compared")
    args = parser.parse_args()
    labels = args.variant or ["LED+FL", "5 lamps"]
    variants = tuple(v for v in DEFAULT_VARIANTS if v.label in labels)
    settings = ProtocolSettings(variants=variants)
    splits, _ = load_splits(args.data_dir)
    split = _subset(require_validation(splits.validation), args.cameras_per_group)
    if args.paths:
        compare_paths(split, variants)
        return
    names = args.only or list(ABLATIONS)
    table: dict[tuple[str, str], list[ValidationRow]] = {}
    components: dict[str, list[dict[str, tuple[float, float]]]] = {}
    started = time.process_time()
    with tempfile.TemporaryDirectory() as temporary:
        for index, task in enumerate(split_tasks(split, settings)):
            plan, lamps, reductions = reduced(task, Path(temporary) / f"task_{index:03d}", variants)
            for one in evaluate_task(task):
                table.setdefault(("1-D protocol", one.variant), []).append(one)
            for variant in variants:
                offline = reductions[variant.label]
                for name in names:
                    swaps, true_mapping = ABLATIONS[name]
                    observations = []
                    for obs in offline.observations:
                        for swap in swaps:
                            obs = swap(obs, lamps[obs.name])
                        observations.append(obs)
                    extra: dict[str, object] = {}
                    if variant.options is not None:
                        extra["options"] = variant.options
                    if true_mapping:
                        extra["mapping"] = plan.geometry.mapping
                    try:
                        result = estimate(
                            observations,
                            variant.method,
                            grid=plan.grid,
                            basis=task.basis,
                            budget=BudgetSettings(record_components=True),
                            **extra,  # type: ignore[arg-type]
                        )
                    except Exception as exc:  # a failure is a result
                        print(f"  {task.camera.name} {variant.label} {name}: {exc}", flush=True)
                        continue
                    row = _score(task, variant.label, result, observations[0].pixel)
                    table.setdefault((name, variant.label), []).append(row)
                    if name == names[0]:
                        components.setdefault(variant.label, []).append(
                            _component_scores(result, task, plan.grid)
                        )
            print(f"task {index} {task.camera.name} done", file=sys.stderr, flush=True)
    print("validation split, seed 0, 2-D twin; RE ×10⁻² mean / median, ±2σ coverage %")
    print("| ablation | variant | n | mean RE | median RE | ±2σ | \\|Δλ\\| nm |")
    print("|---|---|---|---|---|---|---|")
    for (name, label), rows in table.items():
        re = np.array([r.relative_error for r in rows], dtype=np.float64) * 100
        cov = np.array([np.mean(r.coverage) for r in rows if r.coverage is not None]) * 100
        nm = np.array([r.mapping_mean_abs_nm or np.nan for r in rows], dtype=np.float64)
        print(
            f"| {name} | {label} | {len(rows)} | {np.nanmean(re):.2f} | {np.nanmedian(re):.2f} | "
            f"{np.mean(cov):.1f} | {np.nanmedian(nm):.2f} |"
        )
    print()
    print(
        f"σ components of '{names[0]}': share of the named variance (mean), ±2σ coverage without it"
    )
    for label, scores in components.items():
        print(f"{label}:")
        for component in scores[0]:
            shares = [one[component][0] for one in scores if component in one]
            covered = [one[component][1] for one in scores if component in one]
            print(
                f"  {component:24s} share {np.mean(shares):.3f}, coverage without "
                f"{100 * np.mean(covered):.1f} % ({len(shares)} estimates)"
            )
    print(f"CPU time: {time.process_time() - started:.0f} s")


if __name__ == "__main__":
    main()
