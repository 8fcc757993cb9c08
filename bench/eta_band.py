"""Does the estimate's ±2σ band of the grating efficiency η hold the true η? (issue 17, decision 0040)

The validation protocol's scenes (``calib validate``'s plan for each camera: a sinusoidal sheet
drawn per scene, the rig's errors, the mapping found from the lamps), estimated as the registry does
(the σ budget included) for the protocol's method variants; per estimate: RE (×10⁻²), the grating
model chosen, the share of grid nodes whose true first-order η (normalised to its maximum, as the
estimate is) lies inside ±2σ, the ratio of the stated σ's RMS to the actual error's RMS, and,
where the estimate fitted the scene's own family, its parameter's error over its stated σ and the
direct equations' χ²/dof (:func:`bench.twin_coverage.physical_parameter_scores`; per variant, the
RMS of that ratio and the median χ²/dof).

    python bench/eta_band.py --data-dir DIR --split validation --cameras 8 [--seed 0]
        [--variants "LED+FL,LED only"] [--off spectrometer-offset,stray,...] [--true-mapping]

``--off`` switches drawn error sources off for a diagnostic (decision 0164): ``exposure``,
``drift``, ``spectrometer`` (all of it), ``spectrometer-offset``, ``spectrometer-bandwidth``
(a 0.01 nm slit), ``spectrometer-noise``, ``stray``. ``--true-mapping`` gives every estimate the
scene's true pixel→wavelength mapping instead of the one its lamps find (the search's error taken
out; decision 0164's addendum).

Any choice is judged on ``--split validation`` only; ``--split test`` is for reporting.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.metrics import relative_error
from calib.evaluation.synthetic import efficiency_coverage
from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    ProtocolSettings,
    render_task_scene,
    spread_tasks,
)
from calib.evaluation.validation.rig_errors import RigErrors
from calib.methods import estimate

# The parameter's scores are the 2-D twins' (bench/twin_coverage.py, beside this script).
sys.path.insert(0, str(Path(__file__).resolve().parent))
from twin_coverage import physical_parameter_scores


def errors_without(sources: list[str]) -> RigErrors:
    """The protocol's default rig errors with ``sources`` switched off (module docstring)."""
    errors = RigErrors()
    spectrometer = errors.spectrometer
    assert spectrometer is not None
    for source in sources:
        if source == "exposure":
            errors = dataclasses.replace(errors, exposure=None)
        elif source == "drift":
            errors = dataclasses.replace(errors, drift=None)
        elif source == "spectrometer":
            errors = dataclasses.replace(errors, spectrometer=None)
        elif source == "stray":
            errors = dataclasses.replace(errors, stray=None)
        elif source == "spectrometer-offset":
            spectrometer = dataclasses.replace(spectrometer, offset_range_nm=(0.0, 0.0))
        elif source == "spectrometer-bandwidth":
            spectrometer = dataclasses.replace(spectrometer, bandwidth_range_nm=(0.01, 0.01))
        elif source == "spectrometer-noise":
            spectrometer = dataclasses.replace(spectrometer, noise_fraction=0.0, floor_fraction=0.0)
        else:
            raise SystemExit(f"--off: unknown source {source!r}")
    if errors.spectrometer is not None:
        errors = dataclasses.replace(errors, spectrometer=spectrometer)
    return errors


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--split", choices=("validation", "test"), default="validation")
    parser.add_argument("--cameras", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--variants", default="LED+FL,LED only")
    parser.add_argument("--off", default="", help="drawn error sources switched off")
    parser.add_argument(
        "--true-mapping",
        action="store_true",
        help="give each estimate the scene's true mapping (the search's error taken out)",
    )
    arguments = parser.parse_args()
    labels = [item.strip() for item in arguments.variants.split(",")]
    variants = tuple(v for v in DEFAULT_VARIANTS if v.label in labels)
    errors = errors_without([item.strip() for item in arguments.off.split(",") if item.strip()])
    settings = ProtocolSettings(seed=arguments.seed, variants=variants, errors=errors)
    chosen = spread_tasks(arguments.data_dir, arguments.split, settings, arguments.cameras)
    off = arguments.off or "nothing"
    given = ", the true mapping given" if arguments.true_mapping else ""
    print(
        f"split {arguments.split}, seed {arguments.seed}, {len(chosen)} cameras, off: {off}{given}"
    )
    print("camera | variant | model | RE ×10⁻² | η ±2σ coverage | η σ/err | δp/σ_p | direct χ²/dof")
    rows: dict[str, list[tuple[float, float, float, float, float]]] = {
        v.label: [] for v in variants
    }
    for task in chosen:
        scene = render_task_scene(task)
        wavelength = task.settings.grid.wavelength_nm
        true_eta = scene.plan.grating.efficiency(1, wavelength)
        for variant in variants:
            extra: dict[str, Any] = {} if variant.options is None else {"options": variant.options}
            if arguments.true_mapping:
                extra["mapping"] = scene.plan.geometry.mapping
            try:
                result = estimate(
                    [scene.observations[lamp] for lamp in variant.lamps],
                    method=variant.method,
                    grid=task.settings.grid,
                    basis=task.basis,
                    **extra,
                )
            except Exception as exc:  # a failed estimate has no band; say so and go on
                print(f"{task.camera.name} | {variant.label} | failed: {exc}".splitlines()[0])
                continue
            if result.grating_efficiency_sigma is None:
                print(f"{task.camera.name} | {variant.label} | no σ of η")
                continue
            coverage, ratio = efficiency_coverage(result, true_eta)
            error = 100.0 * relative_error(result.physical_sensitivity(), scene.truth)
            record = result.diagnostics.get("grating_model", {})
            shift, sigma, chi2_per_dof = physical_parameter_scores(
                record, scene.plan.grating.to_dict()
            )
            rows[variant.label].append((error, coverage, ratio, shift / sigma, chi2_per_dof))
            print(
                f"{task.camera.name} | {variant.label} | {record.get('chosen', '?')} | "
                f"{error:.2f} | {100 * coverage:.1f} % | {ratio:.2f} | {shift / sigma:+.2f} | "
                f"{chi2_per_dof:.3g}",
                flush=True,
            )
    print(
        "\n| split | variant | estimates | mean RE ×10⁻² | mean η ±2σ coverage | median η σ/err "
        "| RMS(δp/σ_p) | mean δp/σ_p | median direct χ²/dof |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for label, scored in rows.items():
        if scored:
            values = np.asarray(scored)
            print(
                f"| {arguments.split} | {label} | {len(scored)} | {values[:, 0].mean():.2f} | "
                f"{100 * values[:, 1].mean():.1f} % | {np.median(values[:, 2]):.2f} | "
                f"{np.sqrt(np.nanmean(values[:, 3] ** 2)):.2f} | {np.nanmean(values[:, 3]):+.2f} | "
                f"{np.nanmedian(values[:, 4]):.3g} |"
            )


if __name__ == "__main__":
    main()
