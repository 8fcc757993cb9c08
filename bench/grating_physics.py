"""Two targets of the grating-physics issue on the validation protocol's scenes (decision 0028).

1. A φ₀ = 1 rad sinusoidal sheet (η₀ = J₀² falls from 0.72 at 700 nm to 0.41 at 400 nm) against
   the same scene with a flat η₀: the multi-lamp estimate (3 lamps + RGB LEDs, ``auto`` grating
   model) should be as good (RE within 0.3 ×10⁻²) once η₀ is modelled.
2. One LED through a grating file from a physical-model calibration: η solved with 3 lamps + RGB
   LEDs on *another* camera of the split seen through the same grating (its file written and read
   back), then this camera from one LED-B3 shot (``known-grating``). ``--same-rig``: the other
   camera is calibrated in *this* camera's scene geometry (the same rig: sheet, line density, lens),
   both captures carry the optics a RAW file reports (``bench/wavelength_validate.py``'s
   ``with_exif_optics``) and the file stores the rig geometry (``geometry.rig``), as ``calib estimate``
   writes it (issue 16: a new camera through the file reuses what still holds). The one-LED
   estimate is made as ``calib estimate --grating FILE`` makes it (``calib.methods.estimate``, the
   σ budget's); its ±2σ coverage is printed beside that of the method's own σ. ``--diagnose``
   takes its error apart (:func:`diagnose`). ``--judge-factor`` (validation split only) also makes it
   at factor 1 and prints the coverage factor that brings its mean ±2σ coverage to 95 %
   (:func:`calib.evaluation.validation.budget.fit_scale`, as the budget judges every other method):
   the known-grating solve through a grating file runs in no protocol variant, so this is where its
   :data:`calib.methods.uncertainty.COVERAGE_SCALE` entry is judged.

Every scene is the protocol's own (``calib validate``'s plan for the camera, seed and scene: geometry,
rig errors, noise), with the grating replaced. The mapping is found from the lamps, as ``calib
validate`` does.

    python bench/grating_physics.py --data-dir DIR --split validation --cameras 8 [--seed 0] [--same-rig]
        [--diagnose] [--judge-factor]

Tuning looks at ``--split validation`` only; ``--split test`` is for reporting.
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.grating_file import GratingEfficiency, read_grating_file, write_grating_file
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import channel_relative_errors
from calib.core.observations import LampObservation
from calib.core.spectra import WavelengthGrid
from calib.core.spectrometer_scale import checked_observations, corrected_spectrum
from calib.evaluation.validation.budget import TARGET_COVERAGE, coverage_at, fit_scale
from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    ProtocolSettings,
    Task,
    draw_task_plan,
    mapping_scores,
    sensitivity_scores,
    spread_tasks,
)
from calib.evaluation.validation.scenes import RenderedScene, render_scene, with_exif_optics
from calib.methods import estimate
from calib.methods.known_grating import KNOWN_GRATING_METHOD, estimate_known_grating
from calib.methods.multilamp import (
    MultilampOptions,
    calibrate_lamps,
    estimate_multilamp,
    grating_file_from,
    prepare_lamps,
)
from calib.methods.uncertainty import BudgetSettings
from calib.model.bases import CameraPrior
from calib.model.gratings import GratingKind, SinusoidalPhaseGrating
from calib.model.resolution import camera_kernel
from calib.wavelength import RigGeometry, find_mapping
from calib.wavelength.rig_prior import rig_geometry

LAMPS = next(v for v in DEFAULT_VARIANTS if v.label == "3 lamps + RGB LEDs").lamps
PHASE_RAD = 1.0
#: σ of the true-response prior of :func:`true_response_mapping`, a fraction of each channel's peak:
#: tight enough that the prior cannot pull the mapping away from the true camera.
TRUE_RESPONSE_SIGMA = 0.01
#: The spectrometer's bandwidth (nm, FWHM) of the narrow-slit probe: the low end of the protocol's
#: 2–10 nm draw (:class:`calib.evaluation.validation.rig_errors.SpectrometerError`).
NARROW_SLIT_NM = 2.0


@dataclass(frozen=True)
class FlatZerothSheet:
    """A sinusoidal sheet whose 0th order is flat at its 550 nm value (the comparison scene)."""

    sheet: SinusoidalPhaseGrating
    kind: ClassVar[GratingKind] = "sinusoidal"

    @property
    def name(self) -> str:
        return f"{self.sheet.name}, flat 0th order"

    def efficiency(self, order: int, wavelength_nm: ArrayLike) -> FloatArray:
        if order == 0:
            wavelength = np.asarray(wavelength_nm, dtype=np.float64)
            return np.full(wavelength.shape, float(self.sheet.efficiency(0, 550.0)))
        return self.sheet.efficiency(order, wavelength_nm)

    def to_dict(self) -> dict[str, Any]:
        return {**self.sheet.to_dict(), "flat_zeroth_order": True}


def scene(
    task: Task, grating: Any, camera: Task | None = None, narrow_slit: bool = False
) -> RenderedScene:
    """``task``'s scene through ``grating``; with ``camera``, that camera seen in it instead;
    ``narrow_slit``: its spectrometer at :data:`NARROW_SLIT_NM` sampled every 1 nm (its wavelength
    offset kept: the probe of decision 0080)."""
    plan, noise = draw_task_plan(task)
    if narrow_slit and plan.spectrometer is not None:
        plan = replace(
            plan, spectrometer=replace(plan.spectrometer, bandwidth_nm=NARROW_SLIT_NM, step_nm=1.0)
        )
    if camera is not None:
        noise = np.random.default_rng([task.settings.seed, camera.camera.stable_id, 1])
    seen = (camera or task).camera.sensitivity
    return render_scene(replace(plan, grating=grating), seen, LAMPS, noise)


def coverage_of(result: Any, truth: FloatArray) -> float:
    """The ±2σ coverage (%, mean over channels) of ``result``'s stated σ, NaN without one."""
    coverage = sensitivity_scores(result, truth)[1]
    return np.nan if coverage is None else 100.0 * float(np.mean(coverage))


def factor_one_ratios(result: Any, truth: FloatArray) -> FloatArray:
    """``|error| / σ`` over the grid and channels of a result made at factor 1, as
    :class:`calib.evaluation.validation.budget.EstimateRecord` judges it (the delivered curves)."""
    curves = result.camera_curves()
    error = np.abs(np.asarray(curves.values - truth, dtype=np.float64)).ravel()
    sigma = np.asarray(curves.sigma, dtype=np.float64).ravel()
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(
            np.where(sigma > 0, error / sigma, np.where(error > 0, np.inf, 0.0)), dtype=np.float64
        )


def re_of(result: Any, truth: FloatArray) -> float:
    return 100.0 * float(np.mean(channel_relative_errors(result.physical_sensitivity(), truth)))


def true_response_mapping(
    led: LampObservation,
    grating: GratingEfficiency,
    grid: WavelengthGrid,
    truth: FloatArray,
    true_eta: FloatArray,
) -> QuadraticMapping:
    """The one-LED mapping searched as ``known-grating`` searches it (the file's stored geometry, the
    LED's own line spread), with the camera prior replaced by the *true* response ``η s`` (σ
    :data:`TRUE_RESPONSE_SIGMA` of each channel's peak): what is left of the mapping's error is not
    the population prior's pull (decision 0080)."""
    response = true_eta[:, None] * truth
    size = grid.size
    covariance = np.stack(
        [(TRUE_RESPONSE_SIGMA * float(response[:, c].max())) ** 2 * np.eye(size) for c in range(3)]
    )
    prior = CameraPrior(grid, response, covariance, np.zeros(3))
    rig = None if grating.rig is None else RigGeometry.from_dict(grating.rig)
    return find_mapping([led], camera=prior, grid=grid, kernel=camera_kernel([led]), rig=rig)


def diagnose(
    task: Task,
    rendered: RenderedScene,
    led: LampObservation,
    grating: GratingEfficiency,
    sheet: SinusoidalPhaseGrating,
    result: Any,
    calibration_lamps: list[LampObservation],
) -> tuple[float, ...]:
    """What the one-LED estimate's error comes from (``--diagnose``, decision 0073): its mapping's
    error (mean ``|Δλ|`` and mean ``Δλ``, nm) beside the scene spectrometer's drawn offset, the
    file's η error (RMS, % of its peak), then RE with the true mapping, the true η, and both,
    substituted; then RE with the LED's spectrum corrected by the calibration lamps' Hg-line check
    (:mod:`calib.core.spectrometer_scale`), alone and with both true (NaN where the check
    declines); then the mean ``Δλ`` (nm) of the mapping searched with the true response as the
    prior (:func:`true_response_mapping`, decision 0080); last the one-LED estimate's mean ``Δλ``
    and RE in the same scene measured through a narrow slit (``scene(..., narrow_slit=True)``)."""
    wavelength = np.asarray(result.wavelength_nm, dtype=np.float64)
    grid = WavelengthGrid(
        float(wavelength[0]), float(wavelength[-1]), float(wavelength[1] - wavelength[0])
    )
    pixel = rendered.plan.geometry.pixel
    mapping_nm = mapping_scores(result, pixel, rendered.true_wavelength_nm, grid)[0]
    inside = (rendered.true_wavelength_nm >= grid.start_nm) & (
        rendered.true_wavelength_nm <= grid.stop_nm
    )

    def signed(mapping: Any) -> float:
        return float(
            np.mean(mapping.wavelength_nm(pixel[inside]) - rendered.true_wavelength_nm[inside])
        )

    signed_nm = signed(result.mapping)
    reading = rendered.plan.spectrometer
    offset_nm = np.nan if reading is None else float(reading.offset_nm)
    true_eta = np.asarray(sheet.efficiency(1, grating.wavelength_nm), dtype=np.float64)
    true_eta = true_eta / true_eta.max()
    filed = grating.efficiency / grating.efficiency.max()
    eta_error = 100.0 * float(np.sqrt(np.mean((filed - true_eta) ** 2)))
    true_grating = replace(grating, efficiency=true_eta, efficiency_sigma=None)
    true_mapping = rendered.plan.geometry.mapping.quadratic((float(pixel[0]), float(pixel[-1])))
    runs = [
        estimate_known_grating([led], grating=grating, basis=task.basis, mapping=true_mapping),
        estimate_known_grating([led], grating=true_grating, basis=task.basis),
        estimate_known_grating([led], grating=true_grating, basis=task.basis, mapping=true_mapping),
    ]
    narrow_scene = scene(task, sheet, narrow_slit=True)
    narrow_rng = np.random.default_rng([task.settings.seed, task.camera.stable_id])
    narrow_led = with_exif_optics(narrow_scene.observations, narrow_scene.plan.geometry, narrow_rng)
    narrow = estimate_known_grating([narrow_led["LED-B3"]], grating=grating, basis=task.basis)
    checked = checked_observations(calibration_lamps)[1].check
    if checked is not None:
        corrected = replace(led, spectrum=corrected_spectrum(led.spectrum, checked))
        runs.append(estimate_known_grating([corrected], grating=grating, basis=task.basis))
        runs.append(
            estimate_known_grating(
                [corrected], grating=true_grating, basis=task.basis, mapping=true_mapping
            )
        )
    return (
        float(mapping_nm if mapping_nm is not None else np.nan),
        signed_nm,
        offset_nm,
        eta_error,
        *(re_of(run, rendered.truth) for run in runs),
        *((np.nan, np.nan) if checked is None else ()),
        signed(
            true_response_mapping(
                led,
                grating,
                grid,
                rendered.truth,
                np.asarray(sheet.efficiency(1, wavelength), dtype=np.float64),
            )
        ),
        signed(narrow.mapping),
        re_of(narrow, rendered.truth),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--split", choices=("validation", "test"), default="validation")
    parser.add_argument("--cameras", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--same-rig",
        action="store_true",
        help="calibrate the file in this camera's geometry, with EXIF optics, storing the rig",
    )
    parser.add_argument(
        "--diagnose",
        action="store_true",
        help="also the one-LED estimate with the true mapping, the true η, or both substituted",
    )
    parser.add_argument(
        "--judge-factor",
        action="store_true",
        help="validation only: the known-grating coverage factor that brings ±2σ to 95 %%",
    )
    arguments = parser.parse_args()
    if arguments.judge_factor and arguments.split != "validation":
        parser.error("--judge-factor judges on the validation split only")
    settings = ProtocolSettings(seed=arguments.seed)
    chosen = spread_tasks(arguments.data_dir, arguments.split, settings, arguments.cameras)
    sheet = SinusoidalPhaseGrating(PHASE_RAD)
    print(
        f"split {arguments.split}, seed {arguments.seed}, {len(chosen)} cameras, φ₀ = {PHASE_RAD}"
    )
    print(
        "camera | RE η₀ = J₀² | RE η₀ flat | model chosen | RE 1 LED via grating file | "
        "its ±2σ coverage % (budget) | the method's own σ's | its verdict: warning codes"
    )
    if arguments.diagnose:
        print(
            "diagnosis columns: one-LED mapping mean |Δλ| nm | its mean Δλ nm | the spectrometer's "
            "drawn offset nm | file η's RMS error % | "
            "RE true mapping | RE true η | RE both true | RE LED scale-corrected by the calibration's "
            "Hg check | the same, true mapping and η | mean Δλ nm of the mapping searched with the "
            "true response as the prior | through a 2 nm slit: mean Δλ nm | its RE"
        )
    physical, flat, through_file = [], [], []
    diagnosed: list[tuple[float, ...]] = []
    covered: list[float] = []
    covered_own: list[float] = []
    verdicts: list[str] = []
    ratios: list[FloatArray] = []
    for index, task in enumerate(chosen):
        with_eta0 = scene(task, sheet)
        flat_eta0 = scene(task, FlatZerothSheet(sheet))
        observations = [with_eta0.observations[lamp] for lamp in LAMPS]
        result = estimate_multilamp(observations, basis=task.basis)
        flat_result = estimate_multilamp(
            [flat_eta0.observations[lamp] for lamp in LAMPS], basis=task.basis
        )
        physical.append(re_of(result, with_eta0.truth))
        flat.append(re_of(flat_result, flat_eta0.truth))
        # The grating file: calibrated on the next camera of the list through the same sheet.
        other = chosen[(index + 1) % len(chosen)]
        measured = dict(with_eta0.observations)
        if arguments.same_rig:
            calibration = scene(task, sheet, camera=other)
            rng = np.random.default_rng([arguments.seed, task.camera.stable_id])
            measured = with_exif_optics(with_eta0.observations, with_eta0.plan.geometry, rng)
            calibration_lamps = [
                replace(calibration.observations[lamp], metadata=measured[lamp].metadata)
                for lamp in LAMPS
            ]
        else:
            calibration = scene(other, sheet)
            calibration_lamps = [calibration.observations[lamp] for lamp in LAMPS]
        prepared = prepare_lamps(calibration_lamps, basis=other.basis)
        calibrated = calibrate_lamps(
            prepared, other.basis.prior(), MultilampOptions().efficiency_settings()
        )
        rig = None
        if arguments.same_rig and isinstance(calibrated.mapping, QuadraticMapping):
            rig = rig_geometry(calibrated.mapping.details, calibration_lamps[0])
        with tempfile.TemporaryDirectory() as directory:
            path = write_grating_file(
                Path(directory) / "grating.json", grating_file_from(calibrated, rig=rig)
            )
            grating = read_grating_file(path)
        # As ``calib estimate --grating FILE`` makes it: the stated σ is the budget's.
        led = estimate(
            [measured["LED-B3"]], KNOWN_GRATING_METHOD, grating=grating, basis=task.basis
        )
        through_file.append(re_of(led, with_eta0.truth))
        covered.append(coverage_of(led, with_eta0.truth))
        if arguments.judge_factor:
            at_one = estimate(
                [measured["LED-B3"]],
                KNOWN_GRATING_METHOD,
                grating=grating,
                basis=task.basis,
                budget=BudgetSettings(coverage_scale={}),
            )
            ratios.append(factor_one_ratios(at_one, with_eta0.truth))
        own = replace(led, sensitivity_sigma=led.diagnostics.get("method_sigma"))
        covered_own.append(coverage_of(own, with_eta0.truth))
        extra = ""
        if arguments.diagnose:
            row = diagnose(
                task, with_eta0, measured["LED-B3"], grating, sheet, led, calibration_lamps
            )
            diagnosed.append(row)
            extra = " | " + " | ".join(f"{value:.2f}" for value in row)
        warned = list(dict.fromkeys(f.code for f in led.quality.flags if f.severity != "info"))
        verdicts.append(led.quality.verdict)
        print(
            f"{task.camera.name} | {physical[-1]:.2f} | {flat[-1]:.2f} | "
            f"{result.diagnostics['grating_model']['chosen']} | {through_file[-1]:.2f} | "
            f"{covered[-1]:.1f} | {covered_own[-1]:.1f} | {led.quality.verdict}: "
            f"{', '.join(warned) or '—'}{extra}",
            flush=True,
        )
    if diagnosed:
        means = np.nanmean(np.array(diagnosed), axis=0)
        print("diagnosis means: " + " | ".join(f"{value:.2f}" for value in means))
    print(
        f"mean RE ×10⁻²: η₀ = J₀² {np.mean(physical):.2f}, η₀ flat {np.mean(flat):.2f} "
        f"(difference {np.mean(physical) - np.mean(flat):+.2f}); one LED through a grating file "
        f"{np.mean(through_file):.2f} (median {np.median(through_file):.2f}), its ±2σ coverage "
        f"{np.nanmean(covered):.1f} % (the method's own σ {np.nanmean(covered_own):.1f} %); "
        f"verdicts: {', '.join(f'{v} {verdicts.count(v)}' for v in sorted(set(verdicts)))}"
    )

    if ratios:
        print(
            f"known-grating through a grating file, factor 1: ±2σ coverage "
            f"{100 * coverage_at(ratios, 1.0):.1f} %; the factor for {100 * TARGET_COVERAGE:.0f} % "
            f"{fit_scale(ratios):.2f} ({len(ratios)} estimates)"
        )


if __name__ == "__main__":
    main()
