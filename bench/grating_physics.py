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
   writes it (issue 16: a new camera through the file reuses what still holds).

Every scene is the protocol's own (``calib validate``'s plan for the camera, seed and scene: geometry,
rig errors, noise), with the grating replaced. The mapping is found from the lamps, as ``calib
validate`` does.

    python bench/grating_physics.py --data-dir DIR --split validation --cameras 8 [--seed 0] [--same-rig]

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
from calib.core.grating_file import read_grating_file, write_grating_file
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import channel_relative_errors
from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    ProtocolSettings,
    Task,
    draw_task_plan,
    spread_tasks,
)
from calib.evaluation.validation.scenes import RenderedScene, render_scene, with_exif_optics
from calib.methods.known_grating import estimate_known_grating
from calib.methods.multilamp import (
    MultilampOptions,
    calibrate_lamps,
    estimate_multilamp,
    grating_file_from,
    prepare_lamps,
)
from calib.model.gratings import GratingKind, SinusoidalPhaseGrating
from calib.wavelength.rig_prior import rig_geometry

LAMPS = next(v for v in DEFAULT_VARIANTS if v.label == "3 lamps + RGB LEDs").lamps
PHASE_RAD = 1.0


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


def scene(task: Task, grating: Any, camera: Task | None = None) -> RenderedScene:
    """``task``'s scene through ``grating``; with ``camera``, that camera seen in it instead."""
    plan, noise = draw_task_plan(task)
    if camera is not None:
        noise = np.random.default_rng([task.settings.seed, camera.camera.stable_id, 1])
    seen = (camera or task).camera.sensitivity
    return render_scene(replace(plan, grating=grating), seen, LAMPS, noise)


def re_of(result: Any, truth: FloatArray) -> float:
    return 100.0 * float(np.mean(channel_relative_errors(result.physical_sensitivity(), truth)))


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
    arguments = parser.parse_args()
    settings = ProtocolSettings(seed=arguments.seed)
    chosen = spread_tasks(arguments.data_dir, arguments.split, settings, arguments.cameras)
    sheet = SinusoidalPhaseGrating(PHASE_RAD)
    print(
        f"split {arguments.split}, seed {arguments.seed}, {len(chosen)} cameras, φ₀ = {PHASE_RAD}"
    )
    print("camera | RE η₀ = J₀² | RE η₀ flat | model chosen | RE 1 LED via grating file")
    physical, flat, through_file = [], [], []
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
        led = estimate_known_grating([measured["LED-B3"]], grating=grating, basis=task.basis)
        through_file.append(re_of(led, with_eta0.truth))
        print(
            f"{task.camera.name} | {physical[-1]:.2f} | {flat[-1]:.2f} | "
            f"{result.diagnostics['grating_model']['chosen']} | {through_file[-1]:.2f}",
            flush=True,
        )
    print(
        f"mean RE ×10⁻²: η₀ = J₀² {np.mean(physical):.2f}, η₀ flat {np.mean(flat):.2f} "
        f"(difference {np.mean(physical) - np.mean(flat):+.2f}); one LED through a grating file "
        f"{np.mean(through_file):.2f} (median {np.median(through_file):.2f})"
    )


if __name__ == "__main__":
    main()
