"""Validation scenes through the twin's 2-D optics: RAW frames → the offline pipeline → estimates.

The 1-D protocol (``calib validate``, decision 0023) hands the estimators rendered profiles. This
bench renders a subset of the *same* tasks — the same splits, cameras, bases, scene plans and
noise seeds (:func:`calib.evaluation.validation.protocol.draw_task_plan`) — as DNG brackets with
the twin's sensor (:mod:`mocks.scene`), then runs the offline pipeline on them (HDR merge, spot and
band detection, profile extraction, :func:`calib.pipeline.estimate.estimate_offline`) and scores
the result exactly as the 1-D protocol does. It prints both, side by side, per camera and method.

What the twin renders of a plan: the first order through ``η₁`` and the direct spot through the
0th order's own ``η₀(λ)`` along the plan's physical mapping; the slit's width and a soft edge of
≈ 2σ of the plan's lens blur; the lamp as the 1-D scene's shines
(:func:`calib.evaluation.validation.scenes.true_lamp`: a fluorescent lamp with its narrow mercury
lines, not the CIE table's 5 nm bins; decision 0126) drifted for the capture, the spectrometer's
reading of it (offset, bandwidth, noise) as the lamp's spectrum, with its bandwidth; the plan's full well and
read noise (DN gain from a 14-bit range); dark frames; the rig's bracket
(:meth:`calib.evaluation.validation.rig_errors.PhotonBudget.bracket`, the rule ``calib validate``'s
1-D scenes take since decision 0098: a shortest frame at the plan's spot fill, 2-stop steps while
one cell's band SNR over the band's bright part is below the HDR policy's minimum, at most
``max_frames``) and each frame's exposure error (frames exposed ``t (1 + ε)``, the pipeline told
``t``).

What the twin cannot render yet (so the 2-D rows lack it; the 1-D rows have it):

- the 2nd order as physics: :class:`mocks.scene.SceneLayout` draws a scaled copy of the *first*
  order's spectrum stretched ×2 (``second_order_strength``), not ``e(λ) η₂(λ) s(λ)`` at ``2λ``;
  it is left off here;
- stray light along the band: the layout has only a uniform background, which the extraction's
  background strips remove;
- the band's cross-section: a flat top with soft edges, not the lens blur's Gaussian.

    python bench/validate_twin.py [--data-dir DIR] [--cameras-per-group 1] [--split both]
        [--variant 'LED+FL' ...] [--keep DIR]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.spectra import write_csv
from calib.evaluation.synthetic import lamp_kind
from calib.evaluation.validation.capture import BLACK_DN, SHORTEST_S, WHITE_DN
from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    ProtocolSettings,
    Task,
    ValidationRow,
    draw_task_plan,
    evaluate_task,
    failed_row,
    row_identity,
    scored_row,
    split_tasks,
)
from calib.evaluation.validation.report import markdown_report
from calib.evaluation.validation.rig_errors import drifted
from calib.evaluation.validation.scenes import ScenePlan, true_lamp
from calib.evaluation.validation.splits import Split, load_splits
from calib.model.forward import render_observation
from calib.pipeline.estimate import OfflineSettings, estimate_offline
from calib.pipeline.inputs import LampImages
from mocks.forward_scene import first_order_signal
from mocks.scene import (
    PixelFootprint,
    SceneLayout,
    SceneSignal,
    SensorModel,
    render_mosaic_radiance,
    write_bracket,
)

#: Room around the spot and the band on the sensor (px): detection's background strips.
MARGIN_PX = 80


def _sensor_and_layout(plan: ScenePlan) -> tuple[SensorModel, SceneLayout]:
    shape = plan.geometry
    gain = (WHITE_DN - BLACK_DN) / plan.sensor.full_well_e
    half_across = plan.sensor.band_rows / 2
    last = shape.first_pixel + shape.n_pixels
    width = 2 * math.ceil((last + 2 * MARGIN_PX + shape.slit_width_px) / 2)
    height = 2 * math.ceil((2 * half_across * 1.25 + 2 * MARGIN_PX) / 2)
    sensor = SensorModel(
        height_px=height,
        width_px=width,
        black_level_dn=BLACK_DN,
        white_level_dn=WHITE_DN,
        gain_dn_per_electron=gain,
        read_noise_dn=plan.sensor.read_noise_e * gain,
    )
    edge = min(2.0 * shape.psf_sigma_px, shape.slit_width_px)
    layout = SceneLayout(
        spot_centre_px=(MARGIN_PX + shape.slit_width_px, height / 2),
        spot_half_size_px=(shape.slit_width_px / 2, half_across),
        band_half_width_px=half_across,
        edge_px=edge,
    )
    return sensor, layout


@dataclass(frozen=True, eq=False)
class TwinLamp:
    """One lamp as rendered: its bracket (the pipeline's input) and what the twin rendered, in the
    pipeline's units (DN/s at the exposure the pipeline is told), for ablations
    (``bench/twin_limits.py``)."""

    images: LampImages
    signal: SceneSignal
    dn_per_s: float
    dispersion_angle_deg: float
    slit_width_px: float

    def true_direct(self) -> FloatArray:
        """Shape ``(3,)``: the spot's rendered total, DN/s summed over sensor pixels."""
        return np.asarray(self.signal.direct_rgb * self.dn_per_s, dtype=np.float64)

    def true_profile(self, pixel: FloatArray) -> FloatArray:
        """Shape ``(n, 3)``: the rendered first order's radiance at ``pixel`` from the spot, DN/s."""
        footprint = PixelFootprint.at_angle(self.dispersion_angle_deg)
        return np.stack(
            [self.dn_per_s * self.signal.first_order(c, pixel, footprint) for c in range(3)],
            axis=1,
        )


def render_lamps(
    directory: Path, plan: ScenePlan, task: Task, rng: np.random.Generator
) -> dict[str, TwinLamp]:
    """Every lamp of the task's variants rendered as a bracket with dark frames."""
    return {
        spec: _lamp_images(directory, plan, task, spec, rng)
        for spec in dict.fromkeys(s for v in task.settings.variants for s in v.lamps)
    }


def _lamp_images(
    directory: Path, plan: ScenePlan, task: Task, spec: str, rng: np.random.Generator
) -> TwinLamp:
    """Render one lamp of ``plan`` as a bracket with dark frames (module docstring)."""
    draw = plan.lamps[spec]
    errors = plan.errors
    reference = true_lamp(spec)
    seen = drifted(reference, draw.drift_gain, draw.drift_tilt_per_100nm)
    sensor, layout = _sensor_and_layout(plan)
    shape = plan.geometry
    rendered = render_observation(
        seen,
        task.camera.sensitivity,
        mapping=shape.mapping,
        pixel=2,
        grating_efficiency=lambda nm: plan.grating.efficiency(1, nm),
        zeroth_order_efficiency=lambda nm: plan.grating.efficiency(0, nm),
    )
    signal = first_order_signal(
        rendered,
        shape.mapping,
        pixel_range_px=(
            float(shape.first_pixel) - 10.0,
            float(shape.first_pixel + shape.n_pixels) + 10.0,
        ),
        slit_length_px=2.0 * layout.spot_half_size_px[1],
        slit_width_px=shape.slit_width_px,
    )
    mosaic = render_mosaic_radiance(layout, signal, sensor)
    # The rig's bracket rule (decision 0098, as calib validate's 1-D scenes take it): the shortest
    # frame puts the brightest pixel at the plan's spot fill, frames are added while one cell's band
    # SNR over the band's bright part is below the HDR policy's minimum. The band's per-pixel
    # radiance on its centre line is the signal's profile (the bracket takes the profile summed
    # over the slit's rows); the spot's pixels are its total over its brightest rendered pixel.
    spot_end = int(layout.spot_centre_px[0] + shape.slit_width_px + 4)
    spot_px = float(signal.direct_rgb.max()) / float(mosaic[:, :spot_end].max())
    gain, factors = errors.photons.bracket(
        signal.profile * plan.sensor.band_rows,
        signal.direct_rgb,
        plan.sensor,
        spot_px,
        draw.spot_fill,
    )
    # The scene's brightness is free: scale it so the bracket starts at SHORTEST_S, its shortest
    # frame exposed ``gain`` electrons per unit of the signal.
    dn_per_s = gain * sensor.gain_dn_per_electron / SHORTEST_S
    mosaic = mosaic * np.float32(dn_per_s)
    exposures = [SHORTEST_S * factor for factor in factors]
    actual = [t * (1.0 + e) for t, e in zip(exposures, draw.exposure_errors, strict=False)]
    folder = directory / spec.replace(":", "_")
    folder.mkdir(parents=True, exist_ok=True)
    frames = write_bracket(folder, mosaic, sensor, actual, rng, prefix="scene")
    darks = write_bracket(folder, np.zeros_like(mosaic), sensor, actual, rng, prefix="dark")
    bandwidth = None
    spectrum = reference
    if plan.spectrometer is not None and errors.spectrometer is not None:
        spectrum = errors.spectrometer.measure(reference, plan.spectrometer, rng)
        bandwidth = plan.spectrometer.bandwidth_nm
    write_csv(folder / "spectrum.csv", spectrum)
    images = LampImages(
        name=spec,
        kind=lamp_kind(spec),
        spectrum=spectrum,
        images=tuple(frames),
        darks=tuple(darks),
        exposure_s=tuple(exposures),
        dark_exposure_s=tuple(exposures),
        spectrum_bandwidth_nm=bandwidth,
    )
    return TwinLamp(images, signal, dn_per_s, layout.dispersion_angle_deg, shape.slit_width_px)


def evaluate_2d(task: Task, directory: Path) -> list[ValidationRow]:
    """The task's scene rendered as RAW brackets, each variant estimated from them and scored."""
    plan, noise = draw_task_plan(task)
    lamps = {spec: lamp.images for spec, lamp in render_lamps(directory, plan, task, noise).items()}
    truth = task.camera.sensitivity.resample(plan.grid, "interpolate", out_of_range="zero").values
    truth = truth / truth.max()
    rows = []
    for variant in task.settings.variants:
        started = time.perf_counter()
        identity = row_identity(task, variant, split=f"{task.split} (2-D twin)")
        try:
            estimate = estimate_offline(
                [lamps[spec] for spec in variant.lamps],
                OfflineSettings(
                    method=variant.method,
                    method_options=variant.options,
                    grid=plan.grid,
                    basis=task.basis,
                ),
            )
            pixel = estimate.observations[0].pixel
            true_nm = np.asarray(plan.geometry.mapping.wavelength_nm(pixel), dtype=np.float64)
            rows.append(scored_row(identity, estimate.result, truth, pixel, true_nm, started))
        except Exception as exc:  # a failure is a result
            rows.append(failed_row(identity, exc, started))
    return rows


def _subset(split: Split, per_group: int) -> Split:
    counts: dict[str, int] = {}
    chosen = []
    for camera in split.cameras:
        if counts.get(camera.group, 0) < per_group:
            counts[camera.group] = counts.get(camera.group, 0) + 1
            chosen.append(camera)
    return replace(split, cameras=tuple(chosen))


def _cell(value: float | None, scale: float = 1.0) -> str:
    return "—" if value is None or not math.isfinite(value) else f"{value * scale:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--split", choices=("validation", "test", "both"), default="both")
    parser.add_argument("--cameras-per-group", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--variant", action="append", default=None)
    parser.add_argument("--keep", type=Path, default=None, help="Keep the DNG frames here.")
    args = parser.parse_args()
    labels = args.variant or ["LED+FL", "5 lamps"]
    variants = tuple(v for v in DEFAULT_VARIANTS if v.label in labels)
    settings = ProtocolSettings(seed=args.seed, variants=variants)
    splits, _ = load_splits(args.data_dir)
    chosen = [s for s in (splits.validation, splits.test) if args.split in ("both", s.role)]
    rows_1d: list[ValidationRow] = []
    rows_2d: list[ValidationRow] = []
    started = time.process_time()
    with tempfile.TemporaryDirectory() as temporary:
        root = args.keep or Path(temporary)
        for split in chosen:
            for index, task in enumerate(
                split_tasks(_subset(split, args.cameras_per_group), settings)
            ):
                rows_1d += evaluate_task(task)
                rows_2d += evaluate_2d(task, root / split.role / f"task_{index:03d}")
    print(
        "| split | camera | method | RE 1-D | RE 2-D | \\|Δλ\\| 1-D nm | \\|Δλ\\| 2-D nm | cov 1-D % | cov 2-D % |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for one, two in zip(rows_1d, rows_2d, strict=True):
        cov = [None if r.coverage is None else float(np.mean(r.coverage)) for r in (one, two)]
        print(
            f"| {one.split} | {one.camera} | {one.variant} | {_cell(one.relative_error, 100)} | "
            f"{_cell(two.relative_error, 100)} | {_cell(one.mapping_mean_abs_nm)} | "
            f"{_cell(two.mapping_mean_abs_nm)} | {_cell(cov[0], 100)} | {_cell(cov[1], 100)} |"
        )
        if two.failure:
            print(f"|  |  | 2-D failure: {two.failure} | | | | | | |")
    print()
    print(markdown_report([], rows_2d, settings))
    print(f"CPU time (this process): {time.process_time() - started:.0f} s")


if __name__ == "__main__":
    main()
