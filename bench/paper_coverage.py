"""The paper-reproduction protocol's ±2σ coverage taken apart, per variant and noise level.

``calib synthetic`` judges the σ users get (the σ budget of :func:`calib.methods.estimate`, decision
0129). This bench runs the same scenes (:func:`calib.evaluation.synthetic.run_protocol`, same seeds)
with every budget component recorded and prints, per variant × noise level, the share of the truth
inside ±2σ of

``stated``        the budget's σ as users get it (components × the validation-judged factor);
``own``           the method's own σ;
``named``         the components at factor 1;
``−spectrometer`` the stated σ without the two spectrometer components (what is left when the
                  spectra are known exactly, as this protocol's are: it draws no instrument error);
``−X``            the stated σ without component X;
``mapping actual`` the stated σ with the ``mapping`` component from the mapping's *actual* RMS error
                  (nm, over the grid) instead of its stated one: an oracle, to tell whether the
                  mapping's σ is what a band lacks (never a product σ);

and each component's share of the stated variance, the median ratio of the stated σ's RMS to the
actual error's RMS, and how many estimates lie within 85–98 %.

``--eta-experiment``: for the ``true mapping`` variant, the mean RE of the same prior solve with 5, 7
(the default), 9 and 11 Fourier terms of η, and of the known-grating solve given the scene's true η:
how much of the error is η's form and how much its confounding with the sensitivity.

``--mappings``: each searched mapping's largest error over the working grid (nm) and whether it
carries an ambiguity warning; the count of mappings more than 3 nm off, and every one of them
without a warning (a silent wrong mapping), listed, with how many of those the mapping's stated σ
does not cover either (beyond ``paper_mapping_sigma.COVERED_SIGMAS`` σ at the worst pixel); and
the count of mappings within 3 nm that carry a warning (false alarms). ``--mappings-csv FILE``
also writes one row per searched mapping (camera, variant, noise, largest error, warned, whether
the coarse-view check adopted its rival, the largest error over the stated σ there, the signed
error at the first, middle and last pixel on the grid — one sign and size throughout is a whole-
mapping shift —, the largest stated σ on the grid, and whether the warning is decision 0158's
imprecise end alone, the search's evaluations and those of its stalled-basin probe), to compare
two runs scene by scene.

Tuning choices may look at ``--split validation`` only (the training curves, each camera's own body
left out of its basis); ``--split test`` (the paper's 5) is for the report.

    python bench/paper_coverage.py --data-dir ../shared/data/camera_sensitivities --split validation \\
        --noise 0,0.01 --variant "true mapping" --variant LED+Flu --variant "LED only"
"""

from __future__ import annotations

import argparse
import os
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from paper_mapping_sigma import COVERED_SIGMAS, mapping_errors

from calib.core.arrays import FloatArray
from calib.core.grating_file import GratingEfficiency
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import relative_error
from calib.core.result import MAPPING_FAILURE_NM, EstimateResult, mapping_warned
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum
from calib.evaluation.synthetic import (
    NOISE_LEVELS,
    PAPER_VARIANTS,
    SyntheticRow,
    SyntheticScene,
    run_protocol,
)
from calib.evaluation.synthetic_splits import paper_split_cameras, validation_cameras
from calib.evaluation.validation.splits import PREDICTION
from calib.methods import PriorOptions, estimate
from calib.methods.uncertainty import BudgetSettings
from calib.model.bases import CameraBasis

WIDTH = 2.0
SPECTROMETER = ("spectrometer scale", "spectrometer bandwidth")


@dataclass(frozen=True)
class Record:
    """One estimate: its error and σ pieces on the delivered scale (maximum 1)."""

    variant: str
    noise: float
    error: FloatArray
    components: dict[str, FloatArray]
    factor: float
    own: FloatArray | None
    mapping_actual: FloatArray


def record(result: EstimateResult, scene: SyntheticScene, variant: str, noise: float) -> Record:
    truth = scene.truth
    curves = result.camera_curves()
    actual = np.zeros_like(truth)
    if result.mapping is not None and result.mapping is not scene.mapping:
        pixels = scene.broadband.observation.pixel
        true_nm = scene.mapping.wavelength_nm(pixels)
        inside = (true_nm >= DEFAULT_GRID.start_nm) & (true_nm <= DEFAULT_GRID.stop_nm)
        error_nm = result.mapping.wavelength_nm(pixels[inside]) - true_nm[inside]
        slope = np.gradient(curves.values, result.wavelength_nm, axis=0)
        actual = np.abs(slope) * float(np.sqrt(np.mean(error_nm**2)))
    peak = float(np.clip(result.sensitivity, 0.0, None).max())
    own = result.diagnostics.get("method_sigma")
    uncertainty = result.quality.uncertainty or {}
    return Record(
        variant,
        noise,
        np.asarray(curves.values - truth),
        {k: np.asarray(v) for k, v in result.diagnostics.get("budget_components", {}).items()},
        float(uncertainty.get("coverage_scale", 1.0)),
        None if own is None else np.asarray(own) / peak,
        actual,
    )


def coverage(error: FloatArray, sigma: FloatArray) -> float:
    return float(np.mean(np.abs(error) <= WIDTH * sigma))


def total(components: dict[str, FloatArray], without: tuple[str, ...] = ()) -> FloatArray:
    kept = [v for k, v in components.items() if k not in without]
    return np.asarray(np.sqrt(np.sum(np.stack(kept) ** 2, axis=0)), dtype=np.float64)


def summarise(records: list[Record]) -> None:
    groups: dict[tuple[str, float], list[Record]] = defaultdict(list)
    for item in records:
        groups[(item.variant, item.noise)].append(item)
    names = sorted({k for item in records for k in item.components})
    print(
        "variant | noise | n | stated % | in 85–98 % | own % | named (×1) % | −spectrometer % | "
        "−spectrometer ×1 % | mapping actual % | σ/err RMS | "
        + " | ".join(f"−{n} %" for n in names)
        + " | "
        + " | ".join(f"{n} share" for n in names)
    )
    for (variant, noise), items in groups.items():
        stated = [coverage(r.error, total(r.components) * r.factor) for r in items]
        own = [coverage(r.error, r.own) for r in items if r.own is not None]
        named = [coverage(r.error, total(r.components)) for r in items]
        bare = [coverage(r.error, total(r.components, SPECTROMETER) * r.factor) for r in items]
        bare1 = [coverage(r.error, total(r.components, SPECTROMETER)) for r in items]
        oracle = [
            coverage(r.error, total({**r.components, "mapping": r.mapping_actual}) * r.factor)
            for r in items
        ]
        ratio = [
            float(
                np.sqrt(np.mean((total(r.components) * r.factor) ** 2))
                / max(np.sqrt(np.mean(r.error**2)), 1e-300)
            )
            for r in items
        ]
        without = [
            np.mean([coverage(r.error, total(r.components, (n,)) * r.factor) for r in items])
            for n in names
        ]
        shares = []
        for n in names:
            part = [
                float(np.mean(r.components.get(n, 0.0) ** 2) / np.mean(total(r.components) ** 2))
                for r in items
            ]
            shares.append(np.mean(part))
        within = sum(0.85 <= c <= 0.98 for c in stated)
        print(
            f"{variant} | {100 * noise:g} % | {len(items)} | {100 * np.mean(stated):.1f} | "
            f"{within}/{len(items)} | {100 * np.mean(own) if own else float('nan'):.1f} | "
            f"{100 * np.mean(named):.1f} | {100 * np.mean(bare):.1f} | {100 * np.mean(bare1):.1f} | "
            f"{100 * np.mean(oracle):.1f} | "
            f"{np.median(ratio):.2f} | "
            + " | ".join(f"{100 * w:.1f}" for w in without)
            + " | "
            + " | ".join(f"{100 * s:.0f} %" for s in shares)
        )


def eta_experiment(scene: SyntheticScene, basis: CameraBasis) -> list[tuple[str, float]]:
    """RE of the true-mapping solve with other η term counts, and given the true η."""
    led = scene.broadband.observation
    out = []
    for terms in (5, 7, 9, 11):
        options = PriorOptions(efficiency_terms=terms, solve_lamps=(led.name,))
        solved = estimate(
            [led], "prior", basis=basis, mapping=scene.mapping, options=options, budget=None
        )
        out.append((f"{terms} η terms", relative_error(solved.physical_sensitivity(), scene.truth)))
    if scene.efficiency is not None:
        wavelength = DEFAULT_GRID.wavelength_nm
        grating = GratingEfficiency(
            wavelength, scene.efficiency(wavelength), np.full(wavelength.shape, 1e-6)
        )
        solved = estimate(
            [led], "known-grating", basis=basis, mapping=scene.mapping, grating=grating, budget=None
        )
        out.append(("true η given", relative_error(solved.physical_sensitivity(), scene.truth)))
    return out


def predicted_cameras(
    data_dir: str | None, count: int, seed: int
) -> tuple[list[tuple[str, MultiSpectrum]], Callable[[str], CameraBasis]]:
    """``count`` of the validation split's predicted curves (drawn with ``seed``), each with a
    basis of the other bodies' training curves, as the measured ones have theirs."""
    cameras, basis_for, _source = validation_cameras(
        data_dir, predictions=count, seed=seed, group=PREDICTION
    )
    return cameras, basis_for


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--split", choices=("validation", "test"), default="validation")
    parser.add_argument("--lamp", default="D65")
    parser.add_argument(
        "--noise",
        default=",".join(f"{v:g}" for v in NOISE_LEVELS),
        help="noise levels to run (fractions of the peak); a level keeps the scenes it has in the "
        "full list's run, so a subset reproduces those rows",
    )
    parser.add_argument("--variant", action="append", default=None)
    parser.add_argument("--cameras", type=int, default=None, help="the first N cameras only")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--predictions",
        type=int,
        default=0,
        help="validation only: Solomatov & Akkaynak's predicted curves (N drawn with --seed) as "
        "the cameras instead of the training curves, each with the basis of the other bodies",
    )
    parser.add_argument("--eta-experiment", action="store_true")
    parser.add_argument("--mappings", action="store_true")
    parser.add_argument(
        "--mappings-csv", default=None, help="one row per mapping (with --mappings)"
    )
    args = parser.parse_args()
    basis: CameraBasis | Callable[[str], CameraBasis]
    if args.predictions:
        if args.split != "validation":
            parser.error("--predictions is a validation-split option")
        cameras, basis = predicted_cameras(args.data_dir, args.predictions, args.seed)
    else:
        cameras, basis = paper_split_cameras(args.split, args.data_dir)
    cameras = cameras[: args.cameras] if args.cameras else cameras
    # A scene's seed follows its level's place in the list: the protocol's levels keep theirs, so
    # `--noise 0.003` draws the scenes of the full run's 0.3 % rows; other levels come after them.
    wanted = [float(v) for v in args.noise.split(",")]
    levels = [*NOISE_LEVELS, *(v for v in wanted if v not in NOISE_LEVELS)]
    records: list[Record] = []
    experiment: dict[tuple[float, str], list[float]] = defaultdict(list)
    mappings: list[tuple[str, str, float, float, bool]] = []
    adopted: list[bool] = []
    over_sigma: list[float] = []
    ends_error: list[tuple[float, float, float]] = []
    largest_sigma: list[float] = []
    imprecise: list[bool] = []
    evaluations: list[tuple[int, int]] = []

    def keep(scene: SyntheticScene, row: SyntheticRow, result: EstimateResult) -> None:
        records.append(record(result, scene, row.variant, row.noise))
        mapping = result.mapping
        if args.mappings and row.mapping_relative_error is not None and mapping is not None:
            if not isinstance(mapping, QuadraticMapping):
                raise TypeError(f"{row.camera}, {row.variant}: a searched mapping of {mapping!r}")
            pixel, truth_nm, error, sigma = mapping_errors(scene, mapping)
            worst = int(np.argmax(error))
            signed = mapping.wavelength_nm(pixel) - truth_nm
            ends_error.append(
                (float(signed[0]), float(signed[len(signed) // 2]), float(signed[-1]))
            )
            largest_sigma.append(float(np.max(sigma)))
            over_sigma.append(float(error[worst] / sigma[worst]))
            mapping_details = getattr(result.mapping, "details", None) or {}
            imprecise.append(mapping_details.get("imprecise_end") is not None)
            evaluations.append(
                (
                    int(mapping_details.get("evaluations", 0)),
                    int(mapping_details.get("stalled_probe_evaluations", 0)),
                )
            )
            codes = mapping_details.get("warning_codes", ())
            view = mapping_details.get("quadratic_coarse_view") or {}
            adopted.append(bool(view.get("adopted", False)))
            mappings.append(
                (
                    row.camera,
                    row.variant,
                    row.noise,
                    float(np.max(error)),
                    mapping_warned(codes),
                )
            )
        if args.eta_experiment and row.variant == "true mapping":
            for label, value in eta_experiment(
                scene, basis(row.camera) if callable(basis) else basis
            ):
                experiment[(row.noise, label)].append(value)

    rows = run_protocol(
        cameras,
        basis,
        variants=args.variant or list(PAPER_VARIANTS),
        noise_levels=levels,
        broadband_lamp=args.lamp,
        seed=args.seed,
        budget=BudgetSettings(record_components=True),
        on_result=keep,
        only=lambda _name, noise: noise in wanted,
    )
    failures = [row for row in rows if row.failure]
    print(
        f"{args.split} split, {len(cameras)} cameras, lamp {args.lamp}, seed {args.seed}; "
        f"{len(failures)} failed"
    )
    summarise(records)
    if args.mappings:
        off = [k for k, m in enumerate(mappings) if m[3] > MAPPING_FAILURE_NM]
        silent = [k for k in off if not mappings[k][4]]
        uncovered = [k for k in silent if over_sigma[k] > COVERED_SIGMAS]
        warned_right = [m for m in mappings if m[3] <= MAPPING_FAILURE_NM and m[4]]
        print(
            f"mappings: {len(mappings)} searched, > {MAPPING_FAILURE_NM:g} nm {len(off)}, "
            f"of them without an ambiguity warning {len(silent)} ({len(uncovered)} of those "
            f"beyond {COVERED_SIGMAS:g}σ at the worst pixel); "
            f"≤ {MAPPING_FAILURE_NM:g} nm with a warning {len(warned_right)}"
        )
        for k in silent:
            camera, variant, noise, worst, _ = mappings[k]
            print(
                f"  silent: {camera}, {variant}, noise {100 * noise:g} %: {worst:.2f} nm at worst, "
                f"{over_sigma[k]:.1f}σ"
            )
        if args.mappings_csv:
            with Path(args.mappings_csv).open("w", encoding="utf-8") as handle:
                handle.write(
                    "camera,variant,noise,worst_nm,warned,adopted,err_over_sigma,"
                    "first_error_nm,middle_error_nm,last_error_nm,max_sigma_nm,imprecise,"
                    "evaluations,stalled_probe_evaluations\n"
                )
                for (camera, variant, noise, worst, warned), *more in zip(
                    mappings,
                    adopted,
                    over_sigma,
                    ends_error,
                    largest_sigma,
                    imprecise,
                    evaluations,
                    strict=True,
                ):
                    taken, ratio, ends, most, loose, (count, stalled) = more
                    handle.write(
                        f'"{camera}",{variant},{noise:g},{worst:.4f},{int(warned)},{int(taken)},'
                        f"{ratio:.2f},{ends[0]:.3f},{ends[1]:.3f},{ends[2]:.3f},{most:.3f},"
                        f"{int(loose)},{count},{stalled}\n"
                    )
    for (noise, label), values in experiment.items():
        print(
            f"true mapping, noise {100 * noise:g} %: {label}: mean RE {100 * np.mean(values):.2f} ×10⁻²"
        )


if __name__ == "__main__":
    main()
