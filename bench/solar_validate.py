"""The absorption-line (Fraunhofer) mapping on a validation analog: synthetic sunlight through the
validation protocol's scenes, validation cameras only.

The sunlight is :func:`calib.evaluation.validation.solar.synthetic_sunlight` (features built from
their physics: the G band's CH lines, the O₂ B band's head and red tail, the Balmer wings). Each
validation camera gets one scene drawn as the protocol draws them (``calib.evaluation.validation.
scenes``: a physical grating, the grating equation through a lens, slit and lens blur, stray light,
photon budget, EXIF optics) from its own seed, with two changes a Fraunhofer capture needs:

- the band spans 300–1600 px for 400–700 nm (0.19–1 nm per pixel: the protocol's sheet-in-front-of-
  a-lens range and a spectrograph's like the Canon 10D's LHires III at 0.24 nm per pixel), with the
  protocol's slit (1.5–6 px) and lens blur — resolutions of ~0.3–6 nm;
- the spectrometer's bandwidth is 0.3–1.0 nm (sampled every 1 nm, its wavelength scale off by up to
  ±0.5 nm as the protocol draws it): a measured solar spectrum resolves its dips only that finely
  (``calib.wavelength.locate.DIP_SAMPLING_NM``).

The scene is rendered on a 0.02 nm spectral axis (the protocol's 1 nm would wash out the lines).
Printed per camera: the mapping's error (fitted − true wavelength, nm) at the true pixel of each
feature the 10D bench checks (G, Hβ, Mg b, D, Hα, O₂ B; references as ``bench/wavelength_real.py``
takes them), their RMS, the stated σ there and the 10D-style residual (the mapping at the depth
minimum found in the profile minus the reference: what the real-data bench can measure), and the
same with each feature matched by its shape (``wavelength_real.matched_columns``). Summary:
per-feature mean and RMS of the errors over the cameras and of each measure less the error (its
own bias and scatter), the RMS over the six, and the coverage of the errors by ±2 stated σ.
Decision 0110 adds the two measures against the scene's own sunlight at full resolution (what a
high-resolution atlas is to the real Sun): "minima" (each depth minimum against that spectrum's
minimum at the camera's resolution) and "matched sun" (each shape against that spectrum's), and a
summary over the 10D-like scenes (≤ 0.4 nm per pixel, resolution 1.2–2.5 nm).

``--atlas FILE`` renders the scenes with a high-resolution solar atlas (``wavelength_real.
read_atlas``, read at run time and never stored; e.g. SAO2010) through the analog's atmosphere
instead of the synthetic Sun: the real Sun's blends and bands, the G band's among them.
``--bandwidth`` fixes the spectrometer's bandwidth (the 10D's reference table: 1 nm bins).

``--sensitivity`` also estimates each camera as ``bench/real_grating.py`` estimates the Canon 10D
(the sunlight's profile alone through a grating file, channel gains unknown, no optics; here the
file is the scene's own η₁, so what is left is everything but the grating file's departure from the
real sheet) and scores it the 10D's way (decision 0088).

``--geometry spectrograph`` (decision 0086) renders the same scenes through a slit spectrograph
instead (:func:`calib.evaluation.validation.solar.draw_spectrograph`: a reflection grating of
150–600 l/mm at 0–30° between the arms, the 0th order off the frame, a camera lens' radial
distortion of −3 … +2 % at the sensor's corner, the sensor tilted up to ±2°), its columns a crop of
arbitrary origin with no EXIF optics — the Canon 10D's case, outside the mapping family's
grating-through-a-lens-from-the-0th-order.

``--airmass drawn`` (decision 0095) draws each scene's airmass within 1–3 (:data:`AIRMASS_RANGE`;
the Rayleigh continuum and the O₂ bands alike) instead of the fixed 1.5.

    python bench/solar_validate.py --data-dir ../shared/data/camera_sensitivities \
        [--sensitivity] [--geometry spectrograph] [--airmass drawn|AIRMASS] [--atlas FILE] \
        [--bandwidth NM]
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from real_grating import rms_and_coverage
from scipy import ndimage
from wavelength_real import (
    matched_columns,
    read_atlas,
    reference_minima,
    spectrum_offset_nm,
)

import calib.evaluation.validation.scenes as scenes
from calib.core.errors import EstimationError, InputError
from calib.core.grating_file import GratingEfficiency
from calib.core.line_lists import line_list
from calib.core.mapping import QuadraticMapping, TiltedGrating
from calib.core.metrics import channel_relative_errors
from calib.core.observations import CHANNEL_GAINS_KEY, LampObservation
from calib.core.result import mapping_warned
from calib.core.spectra import Spectrum
from calib.evaluation.validation.protocol import (
    ProtocolSettings,
    Task,
    mapping_sigma_nm,
    scene_seed,
    split_tasks,
)
from calib.evaluation.validation.rig_errors import RigErrors, SpectrometerError
from calib.evaluation.validation.solar import (
    SpectrographMapping,
    draw_spectrograph,
    sunlight_from_atlas,
    synthetic_sunlight,
)
from calib.evaluation.validation.splits import load_splits
from calib.methods import estimate
from calib.model import forward
from calib.wavelength.locate import fwhm_px, locate_mapping

SUN = "sunlight"
#: The features of the 10D bench: the solar list's components of each.
FEATURES: dict[str, tuple[str, ...]] = {
    "G": ("Fraunhofer G",),
    "Hβ": ("Fraunhofer F (H-beta)",),
    "Mg b": ("Fraunhofer b1", "Fraunhofer b2", "Fraunhofer b4"),
    "D": ("Fraunhofer D1", "Fraunhofer D2"),
    "Hα": ("Fraunhofer C (H-alpha)",),
    "O₂ B": ("Fraunhofer B (O2)",),
}
GEOMETRY = scenes.GeometryRanges(band_length_px_range=(300.0, 1600.0))
ERRORS = replace(RigErrors(), spectrometer=SpectrometerError(bandwidth_range_nm=(0.3, 1.0)))
#: The scene's spectral axis (nm): finer than any line width the cameras resolve.
FINE_STEP_NM = 0.02
#: ``--airmass drawn``: the Sun from the zenith to 19.5° above the horizon (sec z ≤ 3); lower, its
#: light changes by the minute and a capture is rarely made. The Canon 10D's was 2.13 (the
#: upstream atmosphere file's). Drawn uniformly per scene.
AIRMASS_RANGE = (1.0, 3.0)


def references() -> dict[str, float]:
    """Each feature's reference wavelength: its components' strength-weighted mean (the 10D bench's)."""
    solar = {line.label: line for line in line_list("solar")}
    out = {}
    for name, labels in FEATURES.items():
        lines = [solar[label] for label in labels]
        weights = np.array([line.strength for line in lines])
        out[name] = float(np.sum(weights * [line.wavelength_nm for line in lines]) / weights.sum())
    return out


def dip_minimum(profile: np.ndarray, guess: float, window: int) -> float:
    """The 10D bench's column of a feature: the depth's maximum within ±``window`` of ``guess``
    (0-based), refined by a parabola."""
    total = np.sum(profile, axis=1)
    envelope = total.copy()
    for _ in range(6):
        envelope = ndimage.gaussian_filter1d(np.maximum(envelope, total), 30.0)
    depth = 1.0 - total / envelope
    lo, hi = max(int(guess) - window, 1), min(int(guess) + window, total.size - 2)
    at = lo + int(np.argmax(depth[lo : hi + 1]))
    y0, y1, y2 = depth[at - 1 : at + 2]
    curvature = y0 - 2 * y1 + y2
    return at + (0.5 * (y0 - y2) / curvature if curvature < 0 else 0.0)


def silent(errors: np.ndarray, sigmas: np.ndarray, codes: list[str]) -> bool:
    """A silent wrong mapping (decision 0091): RMS over the six features above 2 nm or above three
    times its stated σ there, and no mapping warning (``MAPPING_WARNING_CODES``)."""
    rms = float(np.sqrt(np.mean(errors**2)))
    stated = float(np.sqrt(np.nanmean(sigmas**2)))
    return (rms > 2.0 or rms > 3.0 * stated) and not mapping_warned(codes)


def sensitivity(
    task: Task,
    plan: scenes.ScenePlan,
    sun_obs: LampObservation,
    truth: np.ndarray,
    refs: dict[str, float],
) -> dict[str, Any]:
    """The Canon 10D's set-up on the analog (``--sensitivity``): the sunlight's first order alone,
    through a grating file that is the scene's own η₁ (the 10D's is the maker's curve), channel
    gains unknown and no optics recorded (its FITS planes carry neither), estimated by ``auto``
    with the σ budget and scored as ``bench/real_grating.py`` scores the 10D (RMS and ±2σ coverage,
    each channel normalised on its own and all together) and by RE (×10⁻²)."""
    axis = np.arange(370.0, 801.0, 1.0)
    grating = GratingEfficiency(
        axis, plan.grating.efficiency(1, axis), source=f"the scene's own {plan.grating.kind} η₁"
    )
    observation = replace(sun_obs, metadata={CHANNEL_GAINS_KEY: "unknown"})
    result = estimate([observation], basis=task.basis, grid=task.settings.grid, grating=grating)
    per_channel = rms_and_coverage(result, truth, per_channel=True)
    together = rms_and_coverage(result, truth)
    # Its mapping (no optics: the 0th order at the spot alone), at the six features.
    wavelengths = np.array(list(refs.values()))
    at = plan.geometry.mapping.pixel_at(wavelengths)
    assert isinstance(result.mapping, QuadraticMapping)
    errors = result.mapping.wavelength_nm(at) - wavelengths
    stated = mapping_sigma_nm(result.mapping, at)
    sigmas = np.full(at.shape, np.nan) if stated is None else stated
    codes = list(result.mapping.details.get("warning_codes", ()))
    return {
        "mapping_rms_nm": float(np.sqrt(np.mean(errors**2))),
        "mapping_sigma_nm": float(np.sqrt(np.nanmean(sigmas**2))),
        "mapping_silent": silent(errors, sigmas, codes),
        "rms_per_channel": per_channel[0],
        "coverage_per_channel": per_channel[1],
        "rms": together[0],
        "coverage": together[1],
        "re": 100 * float(np.mean(channel_relative_errors(result.camera_curves().values, truth))),
    }


def run(
    task: Task,
    sun: Spectrum | None,
    refs: dict[str, float],
    geometry: str = "protocol",
    with_sensitivity: bool = False,
    airmass: float = 1.5,
    atlas: Spectrum | None = None,
) -> dict[str, Any]:
    """One scene; ``sun``: the sunlight (at ``airmass``), or ``None`` to draw its airmass
    (:data:`AIRMASS_RANGE`) — the synthetic sunlight's, or ``atlas`` through the analog's
    atmosphere (:func:`sunlight_from_atlas`)."""
    seed = scene_seed(task.settings.seed, task.camera, task.scene)
    # The first three children as the protocol's scenes draw them; the fourth, the spectrograph;
    # the fifth, the airmass (spawning five leaves the first four as they were).
    plan_seed, noise_seed, optics_seed, spectrograph_seed, airmass_seed = seed.spawn(5)
    if sun is None:
        airmass = float(np.random.default_rng(airmass_seed).uniform(*AIRMASS_RANGE))
        sun = synthetic_sunlight(airmass) if atlas is None else sunlight_from_atlas(atlas, airmass)
    plan = scenes.draw_scene_plan(
        np.random.default_rng(plan_seed), [SUN], errors=ERRORS, geometry=GEOMETRY
    )
    spectrograph: SpectrographMapping | None = None
    if geometry == "spectrograph":
        spectrograph, n_pixels = draw_spectrograph(np.random.default_rng(spectrograph_seed))
        # Only the mapping and the columns change: the slit, blur, sensor, stray light and
        # spectrometer stay the plan's. (The renderer needs only ``wavelength_nm``.)
        plan = replace(
            plan,
            geometry=replace(
                plan.geometry,
                mapping=cast(TiltedGrating, spectrograph),
                first_pixel=0,
                n_pixels=n_pixels,
            ),
        )
    scene = scenes.render_scene(
        plan,
        task.camera.sensitivity,
        [SUN],
        np.random.default_rng(noise_seed),
        lamp_spectra={SUN: sun},
    )
    if spectrograph is None:
        observations = scenes.with_exif_optics(
            scene.observations, plan.geometry, np.random.default_rng(optics_seed)
        )
        sun_obs = replace(observations[SUN], kind="other")
        truth: TiltedGrating | SpectrographMapping = plan.geometry.mapping
    else:
        # A crop of columns exported from a spectrograph: no 0th order, no lens in EXIF.
        sun_obs = replace(scene.observations[SUN], kind="other", pixel_origin="arbitrary")
        truth = spectrograph
    started = time.process_time()
    solution = locate_mapping([sun_obs], task.basis.prior(), task.settings.grid)
    cpu = time.process_time() - started
    pixel = sun_obs.pixel
    dispersion = abs(float(truth.wavelength_nm(pixel[-1:])[0] - truth.wavelength_nm(pixel[:1])[0]))
    dispersion /= pixel[-1] - pixel[0]
    resolution = (
        float(plan.geometry.slit_width_px**2 + (2.3548 * plan.geometry.psf_sigma_px) ** 2) ** 0.5
        * dispersion
    )
    errors, sigmas, bench_style, matched_style = {}, {}, {}, {}
    window = max(3, round(2.0 / dispersion))
    # The camera's resolution as the line spread and the fitted mapping's dispersion say it is.
    signed_dispersion = float(np.mean(np.diff(solution.exact.wavelength_nm(pixel))))
    fitted_dispersion = abs(signed_dispersion)
    offset = spectrum_offset_nm(
        sun_obs.spectrum, refs, sun_obs.spectrum_bandwidth_nm or 0.0, 30.0 * fitted_dispersion
    )
    # The guesses: where the mapping puts each feature (on the 10D, the author's columns).
    guessed = solution.exact.pixel_at(np.array(list(refs.values()))) - pixel[0]
    matched = matched_columns(
        sun_obs,
        sun_obs.spectrum,
        {
            name: (float(column), nm + offset)
            for (name, nm), column in zip(refs.items(), guessed, strict=True)
        },
        nm_per_column=signed_dispersion,
        resolution_nm=fwhm_px(sun_obs, "absorption") * fitted_dispersion,
        bandwidth_nm=sun_obs.spectrum_bandwidth_nm or 0.0,
    )
    # The two measures against the scene's own sunlight at full resolution (what an atlas is to
    # the real Sun; decision 0110): each minimum against where the spectrum's own minimum lies at
    # the camera's resolution, and each shape against that spectrum's (its scale needs no offset).
    resolution_measured = fwhm_px(sun_obs, "absorption") * fitted_dispersion
    minima = reference_minima(
        sun,
        refs,
        resolution_nm=resolution_measured,
        bandwidth_nm=0.0,
        envelope_nm=30.0 * fitted_dispersion,
    )
    matched_sun = matched_columns(
        sun_obs,
        sun,
        {
            name: (float(column), nm)
            for (name, nm), column in zip(refs.items(), guessed, strict=True)
        },
        nm_per_column=signed_dispersion,
        resolution_nm=resolution_measured,
        bandwidth_nm=0.0,
    )
    minima_style, matched_sun_style = {}, {}
    for name, ref in refs.items():
        at = float(truth.pixel_at(np.array([ref]))[0])
        errors[name] = float(solution.exact.wavelength_nm(np.array([at]))[0]) - ref
        sigma = mapping_sigma_nm(solution.mapping, np.array([at]))
        sigmas[name] = float("nan") if sigma is None else float(sigma[0])
        column = dip_minimum(sun_obs.profile, at - pixel[0], window) + pixel[0]
        mapped = float(solution.exact.wavelength_nm(np.array([column]))[0])
        bench_style[name] = mapped - ref
        minima_style[name] = mapped - minima[name]
        matched_sun_style[name] = (
            float(solution.exact.wavelength_nm(np.array([matched_sun[name] + pixel[0]]))[0]) - ref
        )
        matched_style[name] = (
            float(solution.exact.wavelength_nm(np.array([matched[name] + pixel[0]]))[0]) - ref
        )
    return {
        "camera": task.camera.name,
        "airmass": airmass,
        "source": str(solution.details.get("line_source")),
        "nm_per_px": dispersion,
        "resolution_nm": resolution,
        "bandwidth_nm": plan.spectrometer.bandwidth_nm if plan.spectrometer else None,
        "errors": errors,
        "sigmas": sigmas,
        "bench_style": bench_style,
        "matched_style": matched_style,
        "minima_style": minima_style,
        "matched_sun_style": matched_sun_style,
        "resolution_measured_nm": resolution_measured,
        "cpu_s": cpu,
        "profile_fit_distance_nm": solution.details.get("profile_fit_distance_nm"),
        "profile_sigma_nm": (solution.details.get("profile_fit") or {}).get("wavelength_rms_nm"),
        "warnings": list(solution.warnings),
        "warning_codes": list(solution.details.get("warning_codes", ())),
        "family": solution.details.get("family"),
        "spectrograph": None if spectrograph is None else spectrograph.to_dict(),
        **(
            {"sensitivity": sensitivity(task, plan, sun_obs, scene.truth, refs)}
            if with_sensitivity
            else {}
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cameras", default=None, help="comma-separated indices (default all)")
    parser.add_argument("--json", default=None, help="write the rows here")
    parser.add_argument(
        "--sensitivity",
        action="store_true",
        help="also estimate the camera as the Canon 10D is (module docstring)",
    )
    parser.add_argument(
        "--geometry",
        choices=("protocol", "spectrograph"),
        default="protocol",
        help="the protocol's grating through a lens (0th order at the origin) or a slit "
        "spectrograph (solar.draw_spectrograph: 0th order off the frame, distortion, tilt)",
    )
    parser.add_argument(
        "--airmass",
        default="1.5",
        help="the sunlight's airmass, or 'drawn': per scene within AIRMASS_RANGE (1–3)",
    )
    parser.add_argument(
        "--atlas",
        type=Path,
        default=None,
        help="a high-resolution solar atlas (wavelength_real.read_atlas; read, never stored) as the "
        "scenes' Sun instead of the synthetic one, through the same atmosphere",
    )
    parser.add_argument(
        "--bandwidth",
        type=float,
        default=None,
        help="the spectrometer's bandwidth (nm) for every scene instead of 0.3–1.0 (the 10D's "
        "reference spectrum: 1 nm bins)",
    )
    args = parser.parse_args()
    if args.bandwidth is not None:
        global ERRORS
        ERRORS = replace(
            ERRORS,
            spectrometer=SpectrometerError(bandwidth_range_nm=(args.bandwidth, args.bandwidth)),
        )
    atlas = None if args.atlas is None else read_atlas(args.atlas)
    # The protocol renders on a 1 nm axis; the lines need a finer one (module docstring).
    setattr(  # noqa: B010 (a module's name rebound for this run)
        scenes,
        "render_observation",
        functools.partial(forward.render_observation, fine_step_nm=FINE_STEP_NM),
    )
    splits, _ = load_splits(args.data_dir, seed=args.seed)
    tasks = split_tasks(splits.validation, ProtocolSettings(seed=args.seed))
    if args.cameras is not None:
        tasks = [tasks[int(i)] for i in args.cameras.split(",")]
    if args.airmass == "drawn":
        sun = None
    elif atlas is None:
        sun = synthetic_sunlight(float(args.airmass))
    else:
        sun = sunlight_from_atlas(atlas, float(args.airmass))
    refs = references()
    rows = []
    for task in tasks:
        try:
            row = run(
                task,
                sun,
                refs,
                args.geometry,
                args.sensitivity,
                1.5 if args.airmass == "drawn" else float(args.airmass),
                atlas,
            )
        except (EstimationError, InputError) as exc:
            print(f"{task.camera.name[:36]:36s} FAILED: {exc}", flush=True)
            continue
        rows.append(row)
        errs = np.array(list(row["errors"].values()))
        print(
            f"{row['camera'][:36]:36s} {row['nm_per_px']:.2f} nm/px res {row['resolution_nm']:4.1f} "
            f"airmass {row['airmass']:.2f} "
            f"bw {row['bandwidth_nm']:.2f} | "
            + " ".join(f"{k} {v:+.2f}" for k, v in row["errors"].items())
            + f" | RMS {float(np.sqrt(np.mean(errs**2))):.2f} σ̄ "
            f"{float(np.nanmean(list(row['sigmas'].values()))):.2f} "
            f"{'abs' if 'absorption' in row['source'] else 'PROFILE'} cpu {row['cpu_s']:.1f}"
            f" | profile fit {row['profile_fit_distance_nm'] or float('nan'):.2f} nm away (σ "
            f"{row['profile_sigma_nm'] or float('nan'):.2f}) warnings {len(row['warnings'])}"
            + (
                " | 10D-style RMS per channel {rms_per_channel:.4f} (±2σ {coverage_per_channel:.2f})"
                ", together {rms:.4f} (±2σ {coverage:.2f}), RE {re:.2f}; its mapping (no optics) "
                "{mapping_rms_nm:.2f} nm (σ {mapping_sigma_nm:.2f}){flag}".format(
                    flag=" SILENT" if row["sensitivity"]["mapping_silent"] else "",
                    **row["sensitivity"],
                )
                if "sensitivity" in row
                else ""
            ),
            flush=True,
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1), encoding="utf-8")
    names = list(FEATURES)
    errors = np.array([[row["errors"][n] for n in names] for row in rows])
    sigmas = np.array([[row["sigmas"][n] for n in names] for row in rows])
    bench = np.array([[row["bench_style"][n] for n in names] for row in rows])
    matched = np.array([[row["matched_style"][n] for n in names] for row in rows])
    minima = np.array([[row["minima_style"][n] for n in names] for row in rows])
    matched_sun = np.array([[row["matched_sun_style"][n] for n in names] for row in rows])
    absorption = np.array(["absorption" in row["source"] for row in rows])
    print(
        f"\n{args.geometry} scenes, validation split, {len(rows)} cameras ({int(absorption.sum())} through the dips)"
    )
    for label, values in (
        ("mapping error", errors),
        ("10D-style, listed", bench),
        ("listed − error", bench - errors),
        ("10D-style, matched", matched),
        ("matched − error", matched - errors),
        ("minima − error", minima - errors),
        ("matched sun − error", matched_sun - errors),
    ):
        print(
            f"{label:20s} mean  "
            + " ".join(f"{n} {float(np.mean(values[:, k])):+.3f}" for k, n in enumerate(names))
        )
        print(
            f"{label:20s} RMS   "
            + " ".join(
                f"{n} {float(np.sqrt(np.mean(values[:, k] ** 2))):.3f}" for k, n in enumerate(names)
            )
        )
    # The Canon 10D's case: a spectrograph's dispersion and a resolution near its 1.7 nm.
    like = np.array(
        [row["nm_per_px"] <= 0.4 and 1.2 <= row["resolution_nm"] <= 2.5 for row in rows]
    )
    if like.any():
        print(f"10D-like (≤ 0.4 nm/px, resolution 1.2–2.5 nm): {int(like.sum())} cameras")
        for label, values in (
            ("mapping error", errors),
            ("listed − error", bench - errors),
            ("matched − error", matched - errors),
            ("minima − error", minima - errors),
            ("matched sun − error", matched_sun - errors),
        ):
            part = values[like]
            print(
                f"  {label:20s} mean/RMS "
                + " ".join(
                    f"{n} {float(np.mean(part[:, k])):+.3f}/{float(np.sqrt(np.mean(part[:, k] ** 2))):.3f}"
                    for k, n in enumerate(names)
                )
            )
    if args.sensitivity:
        scored = [row["sensitivity"] for row in rows]
        print(
            "the 10D's set-up (one sunlight profile through its own η₁, gains unknown): "
            + ", ".join(
                f"{key} mean {np.mean([s[key] for s in scored]):.4f} median "
                f"{np.median([s[key] for s in scored]):.4f}"
                for key in scored[0]
                if key != "mapping_silent"
            )
            + f"; silent wrong mappings {sum(s['mapping_silent'] for s in scored)}"
        )
    per_camera = np.sqrt(np.mean(errors**2, axis=1))
    print(
        f"RMS over the six per camera: median {float(np.median(per_camera)):.3f} nm, mean "
        f"{float(np.mean(per_camera)):.3f}, max {float(np.max(per_camera)):.3f}; overall "
        f"{float(np.sqrt(np.mean(errors**2))):.3f} nm"
    )
    fine = np.array([row["nm_per_px"] <= 0.4 for row in rows])
    if fine.any():
        print(
            f"  spectrograph-like (≤ 0.4 nm/px, {int(fine.sum())} cameras): overall RMS "
            f"{float(np.sqrt(np.mean(errors[fine] ** 2))):.3f} nm"
        )
    silent_rows = [
        row["camera"]
        for row, e, sg in zip(rows, errors, sigmas, strict=True)
        if silent(e, sg, row["warning_codes"])
    ]
    print(
        f"silent wrong mappings (RMS over the six > 2 nm or > 3 stated σ, not flagged "
        f"ambiguous): {len(silent_rows)}" + (f" ({', '.join(silent_rows)})" if silent_rows else "")
    )
    covered = np.abs(errors) <= 2.0 * sigmas
    print(
        f"±2 stated σ covers {100.0 * float(np.mean(covered)):.1f} % of the feature errors; "
        f"RMS error / RMS σ {float(np.sqrt(np.mean(errors**2)) / np.sqrt(np.nanmean(sigmas**2))):.2f}"
    )


if __name__ == "__main__":
    main()
