"""Judge the σ budget's coverage factor on the validation split (and nowhere else).

:mod:`calib.methods.uncertainty` names what limits an estimate; what it leaves out is covered by one
factor per method and η family (:data:`calib.methods.uncertainty.COVERAGE_SCALE`). This module
chooses it: every validation camera's scene is estimated with the factor 1 and the tolerances as one
σ, each estimate's error and named σ components are kept (:class:`EstimateRecord`), and for each
tolerance σ asked for, the factor is the smallest that brings the mean ±2σ coverage to the target. The split
must be the validation split (:func:`~calib.evaluation.validation.splits.require_validation`); the
test split and the real data are only ever reported.

Run it with ``python -m calib.evaluation.validation.budget --data-dir DIR [--jobs 2]``; the factors
it prints are what ``COVERAGE_SCALE`` holds (with the command, in decisions 0029 and 0044).
``--grating`` (sinusoidal, blazed, catalogue with ``--catalogue FILE``, a list, or mix),
``--predictions N`` and ``--seed`` draw other validation sets (gratings and cameras a factor was
not judged on, decision 0099), as ``calib validate`` does.
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import sys
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.spectrometer_tolerance import IN_SPEC_TOLERANCE_SIGMA
from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    EXTRA_VARIANTS,
    ProtocolSettings,
    Task,
    protocol_gratings,
    render_task_scene,
    split_tasks,
    variant_inputs,
)
from calib.evaluation.validation.scenes import RenderedScene
from calib.evaluation.validation.splits import ValidationSplit, load_splits, require_validation
from calib.methods.uncertainty import BudgetSettings, efficiency_family, prior_sigma_at_scale
from calib.model.gratings import GRATING_KINDS

#: The mean ±2σ coverage the factor aims at on the validation split.
TARGET_COVERAGE = 0.95
#: Coverage width (σ).
WIDTH = 2.0


#: η families an estimate assumed rather than measured: their factors are judged under their own
#: ``method:family`` key only (:func:`ratios_by_method`).
ASSUMED_FAMILIES = ("assumed", "flat")

#: The components a spectrometer tolerance scales (``tolerance_sigma`` × the re-solve's change).
TOLERANCE_COMPONENTS = ("spectrometer scale", "spectrometer bandwidth")


@dataclass(frozen=True)
class EstimateRecord:
    """One validation estimate at factor 1 and ``tolerance_sigma`` = 1: its error and every named
    σ component, flattened over the grid and channels (so any tolerance σ and factor can be
    judged without re-estimating).

    Attributes
    ----------
    method
        The registry method.
    variant
        The protocol's variant label.
    error
        ``|estimate − truth|`` of the delivered curves.
    components
        Component name → σ (at ``tolerance_sigma`` = 1).
    assumed_bandwidth
        No bandwidth was given (its component is not a tolerance and does not scale).
    family
        The η model's family (:func:`calib.methods.uncertainty.efficiency_family`), or ``None``.
    outside_basis
        ``|ŝ − P ŝ|``: the delivered curves' part outside the basis span (not a component; kept so
        a camera-specific basis term can be judged offline from ``--save``).
    prior_sigma
        The camera prior's σ at the estimate's scale, ``α √diag Σ_c`` with ``α`` the estimate's
        least-squares scale against the basis mean (not a component; kept so a basis term that
        shrinks where the data pin the curve, against the method's σ, can be judged offline).
    """

    method: str
    variant: str
    error: FloatArray
    components: Mapping[str, FloatArray]
    assumed_bandwidth: bool = False
    family: str | None = None
    outside_basis: FloatArray | None = None
    prior_sigma: FloatArray | None = None
    #: The spectra's scale was checked against Hg lines (decision 0069): the ``spectrometer
    #: scale`` component is the check's σ, not a tolerance, and does not scale.
    scale_checked: bool = False
    #: The spectra's instrument's slit was measured by that check (decision 0099): the ``spectrometer
    #: bandwidth`` component is the measured slit's one σ, not a tolerance, and does not scale.
    slit_measured: bool = False

    @property
    def key(self) -> str:
        """The factor's key in :data:`calib.methods.uncertainty.COVERAGE_SCALE`."""
        return self.method if self.family is None else f"{self.method}:{self.family}"

    def scaled(self, name: str) -> bool:
        """Whether component ``name`` is a tolerance's (it scales with ``tolerance_sigma``)."""
        return name in TOLERANCE_COMPONENTS and not (
            (name == "spectrometer bandwidth" and (self.assumed_bandwidth or self.slit_measured))
            or (name == "spectrometer scale" and self.scale_checked)
        )

    def named(self, tolerance_sigma: float = 1.0) -> FloatArray:
        """The components' quadrature sum with the spectrometer tolerances as ``tolerance_sigma``."""
        total = np.zeros_like(self.error)
        for name, sigma in self.components.items():
            total = total + (sigma * (tolerance_sigma if self.scaled(name) else 1.0)) ** 2
        return np.asarray(np.sqrt(total), dtype=np.float64)

    def ratio(self, tolerance_sigma: float = 1.0) -> FloatArray:
        """``|error| / named σ`` (``inf`` where σ is 0 and the error is not)."""
        sigma = self.named(tolerance_sigma)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(
                np.where(sigma > 0, self.error / sigma, np.where(self.error > 0, np.inf, 0.0)),
                dtype=np.float64,
            )


def task_records(
    task: Task,
    scene: RenderedScene | None = None,
    extra_arguments: Mapping[str, Any] | None = None,
) -> list[EstimateRecord]:
    """Per variant of the task's scene, its :class:`EstimateRecord`; failed estimates are left
    out (the protocol counts them). ``scene`` (default: the task's, rendered) and
    ``extra_arguments`` (keywords every estimate takes besides the variant's, e.g. the true
    ``mapping``) let an ablation change what the estimates see (``bench/multilamp_limits.py``)."""
    from calib.methods import estimate

    scene = render_task_scene(task) if scene is None else scene
    out: list[EstimateRecord] = []
    unscaled = BudgetSettings(coverage_scale={}, tolerance_sigma=1.0, record_components=True)
    for variant in task.settings.variants:
        observations, keywords = variant_inputs(task, scene, variant)
        try:
            result = estimate(
                observations, budget=unscaled, **{**keywords, **dict(extra_arguments or {})}
            )
        except Exception:  # a failed estimate has no band to judge (the protocol counts it)
            continue
        # judged on the curve users get (negative lobes set to zero) and its σ
        curves = result.camera_curves()
        error = np.abs(np.asarray(curves.values - scene.truth, dtype=np.float64)).ravel()
        components = {
            name: np.asarray(sigma, dtype=np.float64).ravel()
            for name, sigma in result.diagnostics["budget_components"].items()
        }
        assumed = any(flag.code == "no_spectrometer_bandwidth" for flag in result.quality.flags)
        values = np.asarray(curves.values, dtype=np.float64)
        outside = prior = None
        if task.basis is not None and values.shape == (task.basis.grid.size, 3):
            outside = np.abs(values - task.basis.project(values)).ravel()
            prior = prior_sigma_at_scale(values, task.basis).ravel()
        out.append(
            EstimateRecord(
                result.method,
                variant.label,
                error,
                components,
                assumed,
                efficiency_family(result),
                outside,
                prior,
                scale_checked=scale_checked(result),
                slit_measured=slit_measured(result),
            )
        )
    return out


def scale_checked(result: Any) -> bool:
    """Whether ``result``'s lamp spectra were corrected by a spectrometer-scale check."""
    record = result.diagnostics.get("spectrometer_scale_check")
    return isinstance(record, dict) and record.get("check") is not None


def slit_measured(result: Any) -> bool:
    """Whether ``result``'s spectrometer-scale check measured the slit (decision 0099)."""
    record = result.diagnostics.get("spectrometer_scale_check")
    check = record.get("check") if isinstance(record, dict) else None
    return isinstance(check, dict) and check.get("slit_factor") is not None


def task_ratios(task: Task, tolerance_sigma: float = 1.0) -> list[tuple[str, FloatArray]]:
    """Per variant of the task's scene: ``(registry method, |error| / named σ)`` at factor 1."""
    return [(r.method, r.ratio(tolerance_sigma)) for r in task_records(task)]


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


def validation_records(
    split: ValidationSplit, settings: ProtocolSettings, *, jobs: int = 1
) -> list[EstimateRecord]:
    """Every validation estimate's :class:`EstimateRecord`, in the split's task order."""
    tasks = split_tasks(require_validation(split), settings)
    if jobs <= 1:
        results = [task_records(task) for task in tasks]
    else:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
            results = list(pool.map(task_records, tasks, chunksize=1))
    return [record for rows in results for record in rows]


def ratios_by_method(
    records: Sequence[EstimateRecord], tolerance_sigma: float
) -> dict[str, list[FloatArray]]:
    """Factor key → every record's error/σ ratios at factor 1 and ``tolerance_sigma``: each
    registry method pooled (for results that record no η model) and per ``method:η family``.

    An assumed η (family ``"assumed"`` or ``"flat"``, decisions 0074 and 0075) is judged under
    its own key only: pooled into the method's, it would stand for the same method through a
    grating file, which no variant runs."""
    gathered: dict[str, list[FloatArray]] = {}
    for record in records:
        ratio = record.ratio(tolerance_sigma)
        if record.family not in ASSUMED_FAMILIES:
            gathered.setdefault(record.method, []).append(ratio)
        if record.family is not None:
            gathered.setdefault(record.key, []).append(ratio)
    return gathered


def component_shares(records: Sequence[EstimateRecord], tolerance_sigma: float) -> dict[str, float]:
    """Each component's share of the named variance (mean over cells and records) and the ratio of
    the named σ's RMS to the error's RMS (``sigma/error``), at ``tolerance_sigma``."""
    shares: dict[str, float] = {}
    ratios = []
    for record in records:
        named = record.named(tolerance_sigma)
        total = float(np.mean(named**2))
        for name, sigma in record.components.items():
            factor = tolerance_sigma if record.scaled(name) else 1.0
            share = float(np.mean((factor * sigma) ** 2)) / total if total > 0 else 0.0
            shares[name] = shares.get(name, 0.0) + share / len(records)
        error_rms = float(np.sqrt(np.mean(record.error**2)))
        ratios.append(math.sqrt(total) / error_rms if error_rms > 0 else math.inf)
    shares["sigma/error (median)"] = float(np.median(ratios))
    return shares


#: The per-estimate coverage bands :func:`scene_spread` counts: below 70 %, within 85–98 %, above
#: 98 % (issue 15's range per estimate; a band calibrated in the mean can hide either tail).
SPREAD_BANDS = (0.70, 0.85, 0.98)


def scene_spread(coverages: Sequence[float]) -> dict[str, float]:
    """The share of estimates whose own ±2σ coverage is below 70 %, within 85–98 % and above 98 %.

    Examples
    --------
    >>> scene_spread([0.5, 0.9, 0.95, 0.99])
    {'< 70 %': 0.25, '85–98 %': 0.5, '> 98 %': 0.25}
    """
    values = np.asarray(coverages, dtype=np.float64)
    if values.size == 0:
        return {"< 70 %": math.nan, "85–98 %": math.nan, "> 98 %": math.nan}
    low, inside, high = SPREAD_BANDS
    return {
        "< 70 %": float(np.mean(values < low)),
        "85–98 %": float(np.mean((values >= inside) & (values <= high))),
        "> 98 %": float(np.mean(values > high)),
    }


def fit_coverage_scales(
    ratios: Mapping[str, Sequence[FloatArray]], target: float = TARGET_COVERAGE
) -> dict[str, float]:
    """Per method, :func:`fit_scale` of its validation ratios."""
    return {method: round(fit_scale(values, target), 2) for method, values in ratios.items()}


#: The record's own arrays in a saved file, beside its components.
_RECORD_ARRAYS = ("error", "outside_basis", "prior_sigma")


def save_records(records: Sequence[EstimateRecord], path: str) -> None:
    """Write ``records`` to a ``.npz`` (``--save``), one array per record and component, keyed
    ``index__key__variant__assumed_bandwidth__{scale_checked}{slit_measured}__name`` (a file
    written before decision 0099 has no slit digit: not measured); :func:`load_records` reads it,
    so other tolerance σ, factors or component rules can be judged offline."""
    arrays: dict[str, Any] = {}
    for i, record in enumerate(records):
        key = (
            f"{i}__{record.key}__{record.variant}__{int(record.assumed_bandwidth)}"
            f"__{int(record.scale_checked)}{int(record.slit_measured)}"
        )
        arrays[f"{key}__error"] = record.error
        for name, sigma in record.components.items():
            arrays[f"{key}__{name}"] = sigma
        if record.outside_basis is not None:
            arrays[f"{key}__outside_basis"] = record.outside_basis
        if record.prior_sigma is not None:
            arrays[f"{key}__prior_sigma"] = record.prior_sigma
    np.savez_compressed(path, **arrays)


def load_records(path: str) -> list[EstimateRecord]:
    """The records :func:`save_records` wrote, in their order."""
    fields: dict[int, dict[str, Any]] = {}
    with np.load(path) as saved:
        for name in saved.files:
            index, key, variant, assumed, checked, array = name.split("__")
            method, _, family = key.partition(":")
            entry = fields.setdefault(
                int(index),
                {
                    "method": method,
                    "variant": variant,
                    "family": family or None,
                    "assumed_bandwidth": assumed == "1",
                    "scale_checked": checked[:1] == "1",
                    "slit_measured": checked[1:] == "1",
                    "components": {},
                },
            )
            if array in _RECORD_ARRAYS:
                entry[array] = np.asarray(saved[name], dtype=np.float64)
            else:
                entry["components"][array] = np.asarray(saved[name], dtype=np.float64)
    return [EstimateRecord(**fields[index]) for index in sorted(fields)]


def without_components(
    records: Sequence[EstimateRecord], names: Sequence[str]
) -> list[EstimateRecord]:
    """``records`` with the σ components ``names`` left out (what the budget was without them)."""
    return [
        replace(r, components={k: v for k, v in r.components.items() if k not in names})
        for r in records
    ]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--target", type=float, default=TARGET_COVERAGE)
    parser.add_argument("--limit", type=int, default=0, help="first N cameras only (smoke)")
    parser.add_argument(
        "--tolerance-sigma",
        default=f"1,{IN_SPEC_TOLERANCE_SIGMA:.4g}",
        help="comma-separated σ per unit of the spectrometer tolerances to judge (one run)",
    )
    parser.add_argument("--save", default=None, help="write the records to this .npz")
    parser.add_argument(
        "--variant",
        action="append",
        default=None,
        help="judge only these variants (repeatable; default every default and extra one)",
    )
    parser.add_argument(
        "--grating",
        default="sinusoidal",
        help="grating kinds the scenes draw from: a comma-separated list of "
        f"{', '.join(GRATING_KINDS)}, or mix (catalogue needs --catalogue)",
    )
    parser.add_argument("--catalogue", default=None, help="the maker's curve, for catalogue")
    parser.add_argument(
        "--predictions", type=int, default=0, help="add N predicted cameras to the validation split"
    )
    parser.add_argument(
        "--group",
        action="append",
        default=None,
        help="only the split's cameras of this group (repeatable, e.g. 'predicted curve')",
    )
    parser.add_argument(
        "--load",
        action="append",
        default=None,
        help="judge the union of these --save files instead of estimating (repeatable); each "
        "file's coverage at the fitted factors is printed",
    )
    parser.add_argument(
        "--without",
        action="append",
        default=None,
        help="judge the --load records without this σ component (repeatable; e.g. what a "
        "component adds, decision 0109)",
    )
    args = parser.parse_args(argv)
    if args.without and not args.load:
        parser.error("--without judges saved records: give --load")
    if args.load:
        sets = {
            path: without_components(load_records(path), args.without or ()) for path in args.load
        }
        print(f"validation records: {', '.join(f'{p} ({len(r)})' for p, r in sets.items())}")
        return judge(
            [record for records in sets.values() for record in records],
            args.tolerance_sigma,
            args.target,
            sets,
        )
    try:
        kinds, curve = protocol_gratings(args.grating, args.catalogue)
    except InputError as exc:
        parser.error(str(exc))
    splits, _ = load_splits(args.data_dir, predictions=args.predictions, seed=args.seed)
    split = splits.validation
    if args.group:
        split = replace(split, cameras=tuple(c for c in split.cameras if c.group in args.group))
    if args.limit:
        split = replace(split, cameras=split.cameras[: args.limit])
    variants = (*DEFAULT_VARIANTS, *EXTRA_VARIANTS)
    if args.variant:
        unknown = sorted(set(args.variant) - {v.label for v in variants})
        if unknown:
            parser.error(f"unknown variant {'; '.join(unknown)}")
        variants = tuple(v for v in variants if v.label in args.variant)
    settings = ProtocolSettings(
        seed=args.seed, grating_kinds=kinds, catalogue=curve, variants=variants
    )
    records = validation_records(split, settings, jobs=args.jobs)
    if args.save:
        save_records(records, args.save)
    print(
        f"validation split: {len(split.cameras)} cameras, seed {args.seed}, gratings "
        f"{'/'.join(kinds)}, {len(records)} estimates"
    )
    return judge(records, args.tolerance_sigma, args.target)


def judge(
    records: Sequence[EstimateRecord],
    tolerance_sigmas: str,
    target: float = TARGET_COVERAGE,
    sets: Mapping[str, Sequence[EstimateRecord]] | None = None,
) -> int:
    """Print, per tolerance σ of ``tolerance_sigmas`` (comma-separated), each factor key's fitted
    factor and each variant's coverage; with ``sets`` (a name → its records, a part of
    ``records`` each) also each set's coverage at the fitted factors."""
    for tolerance_sigma in (float(item) for item in tolerance_sigmas.split(",")):
        ratios = ratios_by_method(records, tolerance_sigma)
        scales = fit_coverage_scales(ratios, target)
        print(f"tolerance_sigma = {tolerance_sigma:.4g}")
        for method, values in sorted(ratios.items()):
            print(
                f"  {method}: {len(values)} estimates, coverage at factor 1 "
                f"{100 * coverage_at(values, 1.0):.1f} %, factor {scales[method]:.2f} "
                f"→ {100 * coverage_at(values, scales[method]):.1f} %"
            )
        for variant in sorted({record.variant for record in records}):
            chosen = [r for r in records if r.variant == variant]
            at_one = coverage_at([r.ratio(tolerance_sigma) for r in chosen], 1.0)
            per_estimate = [
                float(np.mean(r.ratio(tolerance_sigma) <= WIDTH * scales[r.key])) for r in chosen
            ]
            fitted = float(np.mean(per_estimate))
            shares = component_shares(chosen, tolerance_sigma)
            print(
                f"    {variant}: coverage {100 * at_one:.1f} % at factor 1, "
                f"{100 * fitted:.1f} % fitted; "
                + ", ".join(f"{name} {value:.2f}" for name, value in shares.items())
            )
            print(
                "      estimates covering (fitted) "
                + ", ".join(
                    f"{band} {100 * share:.0f} %"
                    for band, share in scene_spread(per_estimate).items()
                )
            )
        for name, members in (sets or {}).items():
            per_estimate = [
                float(np.mean(r.ratio(tolerance_sigma) <= WIDTH * scales[r.key])) for r in members
            ]
            print(
                f"    {name}: {len(members)} estimates, {100 * float(np.mean(per_estimate)):.1f} % "
                "fitted; estimates covering "
                + ", ".join(
                    f"{band} {100 * share:.0f} %"
                    for band, share in scene_spread(per_estimate).items()
                )
            )
        print("  COVERAGE_SCALE =", scales)
    return 0


if __name__ == "__main__":
    sys.exit(main())
