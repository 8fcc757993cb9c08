"""The mapping on the validation protocol's cameras: LED alone, and one LED through a grating file.

The scenes are ``calib validate``'s (:mod:`calib.evaluation.validation`, default settings: the same
seed, plans and rig errors, profiles measured from the direct spot), one per camera of the chosen
split; each camera's basis is its split's (leave-one-camera-out over the training cameras for the
validation split, all of them for the test split). Each profile's metadata carries what a capture's
RAW files record (``optics``, :func:`calib.evaluation.validation.scenes.exif_optics`): the lens'
focal length as EXIF states it (the image distance the scene drew, less a focus extension of
0–8 %, as EXIF rounds it) and the pitch.

Scenarios (``--scenario``):

``led``           the mapping from the broadband LED alone (:func:`calib.wavelength.locate.
                  locate_mapping`, what ``calib validate``'s "LED only" variant runs): per camera the
                  mean and maximum ``|Δλ|`` over the profile's pixels inside the grid, the stated σ,
                  RMS ``Δλ`` over RMS σ_λ (1 when σ is honest) and whether the result warned of
                  ambiguity (the summary counts warnings on mappings within 1 nm: decision 0118's
                  false alarms; the rows carry the coarser profile's verdict on the answer);
                  (``--grooves``: with the sheet's nominal line density, as a rig's configuration
                  gives it, the true one within ±2 %);
``grating-file``  a grating file from the same rig: the grating is calibrated once in the scene's
                  geometry on a *calibration camera* (a training camera, never the one measured:
                  ``--calibration-camera``) with five lamps (multilamp), its efficiency and rig
                  geometry stored as ``calib estimate`` stores them; the camera of the split is then
                  measured through that file with one LED (``known-grating``): RE ×10⁻² (Makabe et
                  al. 2025 Eq. 16) and its mapping error.

Which split: ``--split validation`` for any tuning, ``--split test`` for reporting only.
``--predictions N`` adds N of Solomatov & Akkaynak's predicted curves to the validation split as
extra synthetic cameras (issue 15's protocol, as ``calib validate --predictions``; basis: all
training curves); ``--only-predicted`` runs those alone. ``--no-optics`` measures the scenes as
``calib validate``'s "LED only, no EXIF" variant does (no focal length or pitch from EXIF).
``--scale-transfer NM`` (``led``) renders each scene with the reference spectrometer's wavelength
offset forced to ±NM and states how much of it the mapping takes up (decision 0108). The ``led``
summary says what σ scale would give the median ratio a calibrated σ of the rows' own shape gives
(~0.67–0.9, not 1) and what scale would cover 95 %.
For scenes whose two best basins are both gratings, the ``led`` rows also say how far apart the two
put the other first order's counterpart of a +1 pixel (``other_order_apart_px``: the largest
``|Δu|`` over the pixels both put inside the grid; that correspondence depends on the focal
length, the incidence and the axis offset, not on the groove spacing), and the summary counts
them: what a −1 order in the frame could settle (decision 0196). ``--other-order`` (``led``) puts
the LED's −1 order in the frame: rendered in the same bracket through the true grating's other order
with the grating's own −1 and −2 efficiencies (:func:`calib.evaluation.validation.scenes.
render_other_order`), so the mapping reports the incidence and the focal length both orders measure
(:mod:`calib.wavelength.other_order`, decision 0197); the rows say how far that measurement lies
from the truth in its own (stated) σ and whether it was refused, and the summary counts them.

    python bench/wavelength_validate.py --data-dir ../shared/data/camera_sensitivities --split test --scenario led
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from calib.core.errors import EstimationError, InputError
from calib.core.grating_file import GratingEfficiency
from calib.core.mapping import QuadraticMapping, TiltedGrating
from calib.core.metrics import channel_relative_errors
from calib.core.observations import LampObservation, OrderProfile
from calib.evaluation.validation.protocol import (
    FIVE_LAMPS,
    MethodVariant,
    ProtocolSettings,
    Task,
    draw_task_plan,
    mapping_sigma_nm,
    render_task_scene,
    scene_lamps,
    split_tasks,
    variant_observations,
)
from calib.evaluation.validation.scenes import RenderedScene, render_other_order, render_scene
from calib.evaluation.validation.splits import PREDICTION, TRANSFORMED, load_splits
from calib.methods import estimate
from calib.wavelength.locate import locate_mapping
from calib.wavelength.rig_prior import rig_geometry

LED = "LED-B3"


#: A calibrated Gaussian σ does not give an actual/stated RMS ratio of 1 per camera: the ratio of
#: an error drawn from the stated covariance itself has a median of ~0.67 when one parameter (a
#: common offset) dominates and nearer 0.9 when several do. Each row draws this many errors from
#: its own stated covariance, so the summary can say what median ratio its σ would give if honest.
CALIBRATED_DRAWS = 64
#: The ±2σ coverage the σ-scale column aims at (the band's nominal share is 95.4 %).
TARGET_COVERAGE = 0.95


def calibrated_ratios(mapping: Any, pixel: np.ndarray, rng: np.random.Generator) -> list[float]:
    """Actual/stated RMS ratios of errors drawn from the mapping's own stated covariance."""
    covariance = getattr(mapping, "covariance", None)
    sigma = mapping_sigma_nm(mapping, pixel)
    if covariance is None or sigma is None:
        return []
    stated = float(np.sqrt(np.mean(sigma**2)))
    if not stated > 0:
        return []
    design = np.stack([pixel**2, pixel, np.ones_like(pixel)], axis=1)
    draws = rng.multivariate_normal(
        np.zeros(3), np.asarray(covariance, dtype=np.float64), CALIBRATED_DRAWS, method="eigh"
    )
    errors = draws @ design.T
    return [round(float(v), 4) for v in np.sqrt(np.mean(errors**2, axis=1)) / stated]


def sigma_scales(done: list[dict[str, Any]]) -> str:
    """The summary's honest reading of σ: the median ratio a calibrated σ of the rows' own shape
    gives, the σ scale that would bring the measured median ratio there, and the σ scale whose
    ±2σ band covers :data:`TARGET_COVERAGE` of the pixels (from each row's 32 stored pixels)."""
    simulated = [v for row in done for v in json.loads(row.get("calibrated_ratios", "[]"))]
    ratio = np.array([row["ratio"] for row in done])
    pairs = [
        (np.array(json.loads(row["errors_nm"])), np.array(json.loads(row["sigmas_nm"])))
        for row in done
        if json.loads(row.get("sigmas_nm", "[]"))
    ]
    if not simulated or not pairs:
        return ""
    calibrated = float(np.median(simulated))

    def coverage(scale: float) -> float:
        return float(np.mean([np.mean(np.abs(e) <= 2.0 * scale * s) for e, s in pairs]))

    low, high = 1e-3, 1e3
    for _ in range(60):
        middle = float(np.sqrt(low * high))
        low, high = (low, middle) if coverage(middle) >= TARGET_COVERAGE else (middle, high)
    return (
        f"; a calibrated σ of this shape gives a median ratio of {calibrated:.2f}: σ × "
        f"{float(np.median(ratio)) / calibrated:.2f} would give it, σ × {high:.2f} covers "
        f"{100 * TARGET_COVERAGE:.0f} % (±2σ, 32 pixels per camera)"
    )


def group_summaries(done: list[dict[str, Any]]) -> list[str]:
    """One line per camera group of ``led`` rows (as run, or read back from ``--csv``): ±2σ
    coverage, median ratio and :func:`sigma_scales` — the sets a mapping σ is judged on."""
    lines = []
    for group in sorted({str(row["group"]) for row in done}):
        rows = [
            {**row, "ratio": float(row["ratio"]), "coverage": float(row["coverage"])}
            for row in done
            if row["group"] == group and row.get("coverage") not in (None, "")
        ]
        if not rows:
            continue
        coverage = 100.0 * float(np.nanmean([row["coverage"] for row in rows]))
        ratio = float(np.median([row["ratio"] for row in rows]))
        lines.append(
            f"  {group} ({len(rows)}): ±2σ {coverage:.2f} %, ratio median {ratio:.2f}"
            f"{sigma_scales(rows)}"
        )
    return lines


def mapping_errors(
    mapping: Any,
    pixel: np.ndarray,
    true_nm: np.ndarray,
    grid_nm: tuple[float, float],
    rng: np.random.Generator | None = None,
) -> dict[str, Any]:
    inside = (true_nm >= grid_nm[0]) & (true_nm <= grid_nm[1])
    error = np.asarray(mapping.wavelength_nm(pixel[inside])) - true_nm[inside]
    sigma = mapping_sigma_nm(mapping, pixel[inside])
    stated = float("nan") if sigma is None else float(np.sqrt(np.mean(sigma**2)))
    rms = float(np.sqrt(np.mean(error**2)))
    # The protocol's own share (calib.evaluation.validation.protocol.mapping_scores): pixels
    # whose |Δλ| is within ±2σ.
    covered = float("nan") if sigma is None else float(np.mean(np.abs(error) <= 2.0 * sigma))
    probe = np.linspace(0, error.size - 1, 32).astype(int)
    return {
        # Per-pixel error and σ at 32 pixels (for re-sizing σ offline on the validation split).
        "errors_nm": json.dumps([round(float(v), 4) for v in error[probe]]),
        "sigmas_nm": json.dumps(
            [] if sigma is None else [round(float(v), 4) for v in np.asarray(sigma)[probe]]
        ),
        "coverage": covered,
        "mean_abs_nm": float(np.mean(np.abs(error))),
        "max_abs_nm": float(np.max(np.abs(error))),
        "rms_nm": rms,
        "stated_nm": stated,
        "ratio": rms / stated if stated > 0 else float("inf"),
        "calibrated_ratios": json.dumps(
            calibrated_ratios(mapping, pixel[inside], rng or np.random.default_rng(0))
        ),
        # The signed mean error (the common offset's share of it).
        "mean_signed_nm": float(np.mean(error)),
    }


def candidate_mapping(record: dict[str, Any]) -> QuadraticMapping | TiltedGrating:
    if record.get("type") == "tilted_grating":
        return TiltedGrating.from_dict(record)
    return QuadraticMapping.from_dict(record)


def other_order_apart_px(candidates: list[dict[str, Any]], pixel: np.ndarray) -> float | None:
    """How far apart the two best basins put the other first order's counterpart of a +1 pixel:
    the largest ``|Δu|`` over the pixels both put inside 400–700 nm (``None`` unless both are
    gratings). The ±1 orders share the focal length, the incidence (with its sign turned) and the
    axis offset; the groove spacing cancels, so basins that differ only in it are not told apart."""
    if len(candidates) < 2:
        return None
    best, runner_up = (candidate_mapping(c["mapping"]) for c in candidates[:2])
    if not (isinstance(best, TiltedGrating) and isinstance(runner_up, TiltedGrating)):
        return None
    probe = np.linspace(float(pixel[0]), float(pixel[-1]), 200)
    first, second = best.wavelength_nm(probe), runner_up.wavelength_nm(probe)
    inside = (first > 400.0) & (first < 700.0) & (second > 400.0) & (second < 700.0)
    if not inside.any():
        return None
    try:
        apart = best.other_order().pixel_at(first[inside]) - runner_up.other_order().pixel_at(
            second[inside]
        )
    except InputError:
        return None
    return float(np.max(np.abs(apart)))


def with_other_order(task: Task, scene: RenderedScene, led: LampObservation) -> LampObservation:
    """The LED's observation with its −1 order, rendered in the same bracket
    (:func:`render_other_order`, noise from its own child of the scene's seed)."""
    rng = np.random.default_rng([task.settings.seed, task.camera.stable_id, task.scene, 7])
    profile, sigma = render_other_order(scene, task.camera.sensitivity, LED, rng)
    return replace(led, other_order=OrderProfile(led.pixel, profile, sigma))


def other_order_columns(scene: RenderedScene, details: dict[str, Any]) -> dict[str, Any]:
    """What the mapping's search recorded of both orders' geometry
    (:func:`calib.wavelength.other_order.other_order_geometry`), against the truth."""
    measured = details.get("other_order")
    if not measured or "focal_length_px" not in measured:
        return {"other_measured": False}
    truth = scene.plan.geometry.mapping

    def in_sigmas(error: float, sigma: float | None) -> float:
        return error / sigma if sigma else math.nan

    runner_up = measured.get("runner_up")
    return {
        "other_measured": True,
        "other_refused": measured.get("refused") or "",
        "other_incidence_error_sigmas": in_sigmas(
            measured["incidence_deg"] - truth.incidence_deg, measured["incidence_sigma_deg"]
        ),
        "other_focal_error_sigmas": in_sigmas(
            math.log(measured["focal_length_px"] / truth.focal_length_px),
            measured["log_focal_sigma"],
        ),
        "other_incidence_sigma_deg": measured["incidence_sigma_deg"],
        "other_log_focal_sigma": measured["log_focal_sigma"],
        "other_reduced_chi2": measured["reduced_chi2"],
        "other_runner_up_delta_chi2": None if runner_up is None else runner_up["delta_chi2"],
    }


def nominal_grooves(scene: RenderedScene, rng: np.random.Generator) -> float:
    """The sheet's line density as a rig's configuration states it: the true one within ±2 %."""
    return scene.plan.geometry.grooves_per_mm * float(1.0 + rng.uniform(-0.02, 0.02))


def led_row(
    task: Task,
    scene: RenderedScene,
    lamps: dict[str, LampObservation],
    grooves_per_mm: float | None = None,
    other_order: bool = False,
) -> dict[str, Any]:
    grid = task.settings.grid
    led = lamps[LED]
    if other_order:
        led = with_other_order(task, scene, led)
    if grooves_per_mm is not None:
        # Where the rig's configuration puts it: the capture's optics record.
        given = led.metadata.get("optics")
        optics = {**(given if isinstance(given, dict) else {}), "grooves_per_mm": grooves_per_mm}
        led = replace(led, metadata={**dict(led.metadata), "optics": optics})
    started = time.process_time()
    solution = locate_mapping([led], task.basis.prior(), grid)
    cpu_s = time.process_time() - started
    scores = mapping_errors(
        solution.mapping, led.pixel, scene.true_wavelength_nm, (grid.start_nm, grid.stop_nm)
    )
    # The basins it weighed: the runner-up's tempered Δχ² and distance, and the basin nearest the
    # truth (for choosing the ambiguity threshold on the validation split).
    candidates = solution.details.get("candidates", [])
    runner_up = candidates[1] if len(candidates) > 1 else {}
    inside = (scene.true_wavelength_nm >= grid.start_nm) & (
        scene.true_wavelength_nm <= grid.stop_nm
    )
    nearest = (
        min(
            (
                float(
                    np.mean(
                        np.abs(
                            candidate_mapping(c["mapping"]).wavelength_nm(led.pixel[inside])
                            - scene.true_wavelength_nm[inside]
                        )
                    )
                ),
                index,
            )
            for index, c in enumerate(candidates)
        )
        if candidates
        else (float("nan"), -1)
    )
    return {
        **scores,
        **(other_order_columns(scene, solution.details) if other_order else {}),
        "ambiguous": solution.ambiguous,
        "n_basins": len(candidates),
        "runner_up_delta_chi2": runner_up.get("delta_chi2", float("inf")),
        "nearest_basin_delta_chi2": (
            candidates[nearest[1]].get("delta_chi2") if nearest[1] >= 0 else None
        ),
        "temper": solution.details.get("temper", float("nan")),
        "first_nm": float(solution.mapping.wavelength_nm(led.pixel[:1])[0]),
        "last_nm": float(solution.mapping.wavelength_nm(led.pixel[-1:])[0]),
        "true_first_nm": float(scene.true_wavelength_nm[0]),
        "true_last_nm": float(scene.true_wavelength_nm[-1]),
        "runner_up_distance_nm": runner_up.get("rms_distance_nm", 0.0),
        "other_order_apart_px": other_order_apart_px(candidates, led.pixel),
        "nearest_basin": nearest[1],
        "nearest_basin_mean_abs_nm": nearest[0],
        "reduced_chi2": solution.details.get("reduced_chi2", float("nan")),
        # How the coarser profile the basins were found on rates the answer (decision 0118).
        "coarse_delta_chi2": (solution.details.get("coarse_view") or {}).get(
            "delta_chi2", float("nan")
        ),
        "coarse_distance_nm": (solution.details.get("coarse_view") or {}).get(
            "distance_nm", float("nan")
        ),
        **{
            key: solution.details.get(key, float("nan"))
            for key in (
                "local_rms_nm",
                "basin_spread_nm",
                "prior_misfit_sigma_nm",
                "spectrometer_scale_sigma_nm",
            )
        },
        **edge_columns(solution.details.get("red_edge_nm"), led, scene.true_wavelength_nm),
        "basins": json.dumps(
            [
                {
                    "delta_chi2": c.get("delta_chi2"),
                    "distance_nm": c.get("rms_distance_nm"),
                    "mean_abs_nm": float(
                        np.mean(
                            np.abs(
                                candidate_mapping(c["mapping"]).wavelength_nm(led.pixel[inside])
                                - scene.true_wavelength_nm[inside]
                            )
                        )
                    ),
                }
                for c in candidates
            ]
        ),
        # Everything else the search recorded (the grating's parameters and prior, the coarse
        # view, …): per-scene quantities known at estimate time, for judging a σ offline.
        "search_details": json.dumps(
            {k: v for k, v in solution.details.items() if k != "candidates"}, default=str
        ),
        "cpu_s": cpu_s,
    }


def edge_columns(
    edge: dict[str, float] | None, led: LampObservation, true_nm: np.ndarray
) -> dict[str, float]:
    """The red edge the search compared (decision 0049) and where the truth puts the profile's."""
    signal = np.sum(np.clip(np.asarray(led.profile, dtype=np.float64), 0.0, None), axis=1)
    above = np.flatnonzero(signal >= 0.03 * float(np.max(signal)))
    true_edge = float(np.max(true_nm[above])) if above.size else float("nan")
    if edge is None:
        return {"edge_true_nm": true_edge}
    return {
        "edge_profile_nm": float(edge["profile"]),
        "edge_prior_nm": float(edge["prior_mean"]),
        "edge_true_nm": true_edge,
    }


def calibration_file(
    task: Task, calibration: Task, lamps: dict[str, LampObservation]
) -> GratingEfficiency:
    """The grating calibrated on the calibration camera in the task's geometry, as a file holds it."""
    # The calibration camera sees the same plan (grating, geometry, lamps) as the measured one.
    plan, _noise = draw_task_plan(task)
    scene = render_scene(
        plan,
        calibration.camera.sensitivity,
        scene_lamps(task.settings.variants),
        np.random.default_rng([task.settings.seed, calibration.camera.stable_id, 1]),
    )
    # Same lens and pitch as the measured camera's capture (one rig).
    calib_lamps = {
        name: replace(
            obs, metadata={**dict(obs.metadata), "optics": lamps[name].metadata["optics"]}
        )
        for name, obs in scene.observations.items()
    }
    observations = [calib_lamps[name] for name in FIVE_LAMPS]
    result = estimate(
        observations, method="multilamp", grid=task.settings.grid, basis=calibration.basis
    )
    assert result.grating_efficiency is not None
    assert isinstance(result.mapping, QuadraticMapping)
    geometry: dict[str, Any] = {"order": 1}
    rig = rig_geometry(result.mapping.details, observations[0])
    if rig is not None:
        geometry["rig"] = rig.to_dict()
    return GratingEfficiency(
        wavelength_nm=result.wavelength_nm,
        efficiency=result.grating_efficiency,
        efficiency_sigma=result.grating_efficiency_sigma,
        geometry=geometry,
        provenance={"source": "bench/wavelength_validate.py", "camera": calibration.camera.name},
        source=f"calibrated on {calibration.camera.name}",
    )


def grating_file_row(
    task: Task, calibration: Task, scene: RenderedScene, lamps: dict[str, LampObservation]
) -> dict[str, Any]:
    grid = task.settings.grid
    grating = calibration_file(task, calibration, lamps)
    led = lamps[LED]
    started = time.process_time()
    result = estimate([led], method="known-grating", grid=grid, basis=task.basis, grating=grating)
    cpu_s = time.process_time() - started
    assert isinstance(result.mapping, QuadraticMapping)
    scores = mapping_errors(
        result.mapping, led.pixel, scene.true_wavelength_nm, (grid.start_nm, grid.stop_nm)
    )
    re = channel_relative_errors(result.physical_sensitivity(), scene.truth)
    # What the file's η costs: the same estimate through the true η (the file's geometry kept),
    # and the file's η against the truth (both at a maximum of 1, RMS over the grid).
    true_eta = np.asarray(scene.plan.grating.efficiency(1, grid.wavelength_nm), dtype=np.float64)
    exact_file = replace(grating, efficiency=true_eta, efficiency_sigma=None)
    exact = estimate([led], method="known-grating", grid=grid, basis=task.basis, grating=exact_file)
    re_exact = channel_relative_errors(exact.physical_sensitivity(), scene.truth)
    eta = np.asarray(grating.at(grid.wavelength_nm))
    eta_error = float(np.sqrt(np.mean((eta / eta.max() - true_eta / true_eta.max()) ** 2)))
    return {
        **scores,
        "re_x100": 100.0 * float(np.mean(re)),
        "re_true_eta_x100": 100.0 * float(np.mean(re_exact)),
        "eta_rms_error": eta_error,
        "rig_prior": str(result.mapping.details.get("rig_prior", "")),
        "cpu_s": cpu_s,
    }


def task_scene(task: Task, offset_nm: float | None = None) -> RenderedScene:
    """The task's scene (:func:`render_task_scene`); with ``offset_nm`` the reference
    spectrometer's wavelength offset is forced to it and everything else is the same draw (the
    offset is drawn with the plan and takes no random number when the scene is rendered)."""
    if offset_nm is None:
        return render_task_scene(task)
    import calib.evaluation.validation.protocol as protocol

    drawn = protocol.draw_task_plan

    def forced(forced_task: Task) -> tuple[Any, np.random.Generator]:
        plan, noise = drawn(forced_task)
        assert plan.spectrometer is not None, "the protocol's scenes have a spectrometer"
        return replace(plan, spectrometer=replace(plan.spectrometer, offset_nm=offset_nm)), noise

    protocol.draw_task_plan = forced  # type: ignore[assignment]
    try:
        return render_task_scene(task)
    finally:
        protocol.draw_task_plan = drawn


def led_lamps(scene: RenderedScene, optics: bool) -> dict[str, LampObservation]:
    """The scene's observations as the "LED only" variant has them (--no-optics: no EXIF)."""
    variant = MethodVariant(LED, "prior", tuple(scene.observations), exif_optics=optics)
    return dict(zip(scene.observations, variant_observations(scene, variant), strict=True))


def transfer_row(task: Task, shift_nm: float, optics: bool) -> dict[str, Any]:
    """How much of the reference spectrometer's wavelength offset the LED-only mapping takes up:
    the scene rendered with the offset forced to ``+shift_nm`` and ``−shift_nm`` (the same seed
    otherwise), each mapped, ``k = −Δmapping / Δoffset`` averaged over the grid's pixels (the
    spectrometer reports at λ the light of λ + offset, so a mapping that follows it fully moves by
    −offset: k = 1; one placed by the camera prior alone: k = 0)."""
    grid = task.settings.grid
    mappings, rows = [], []
    for offset in (shift_nm, -shift_nm):
        scene = task_scene(task, offset)
        led = led_lamps(scene, optics)[LED]
        solution = locate_mapping([led], task.basis.prior(), grid)
        mappings.append(solution.mapping)
        rows.append(
            {
                **mapping_errors(
                    solution.mapping,
                    led.pixel,
                    scene.true_wavelength_nm,
                    (grid.start_nm, grid.stop_nm),
                ),
                "ambiguous": solution.ambiguous,
                "scale_nm": solution.details.get("spectrometer_scale_sigma_nm", float("nan")),
            }
        )
    inside = (scene.true_wavelength_nm >= grid.start_nm) & (
        scene.true_wavelength_nm <= grid.stop_nm
    )
    pixel = led.pixel[inside]
    moved = np.asarray(mappings[0].wavelength_nm(pixel)) - np.asarray(
        mappings[1].wavelength_nm(pixel)
    )
    transfer = -moved / (2.0 * shift_nm)
    return {
        "k": float(np.mean(transfer)),
        "k_blue": float(transfer[0]),
        "k_red": float(transfer[-1]),
        # The RMS over the profile of the mapping's move per nm of offset (what a σ in RMS nm takes).
        "k_rms": float(np.sqrt(np.mean(transfer**2))),
        "mean_abs_nm": max(r["mean_abs_nm"] for r in rows),
        "max_abs_nm": max(r["max_abs_nm"] for r in rows),
        "ambiguous": any(r["ambiguous"] for r in rows),
        "scale_nm": rows[0]["scale_nm"],
        "stated_nm": rows[0]["stated_nm"],
        "ratio": rows[0]["ratio"],
        "cpu_s": 0.0,
    }


def run_one(
    job: tuple[Task, Task, int, str, bool, bool, float | None, bool],
) -> dict[str, Any] | None:
    """One camera's row (``None``: the calibration camera itself in the grating-file scenario)."""
    task, calibration, seed, scenario, grooves, optics, transfer, other_order = job
    name = task.camera.name
    try:
        if transfer is not None:
            return {
                "camera": name,
                "group": task.camera.group,
                **transfer_row(task, transfer, optics),
            }
        scene = task_scene(task)
    except (EstimationError, InputError) as exc:
        # A scene that cannot be rendered is a failed row, as in `calib validate`, not the run's end.
        return {"camera": task.camera.name, "group": task.camera.group, "failed": str(exc)}
    # The protocol's scenes carry the RAW files' optics; --no-optics measures them without.
    lamps = led_lamps(scene, optics)
    try:
        if scenario == "led":
            nominal = (
                nominal_grooves(scene, np.random.default_rng([seed, task.camera.stable_id, 2]))
                if grooves
                else None
            )
            row = led_row(task, scene, lamps, nominal, other_order)
        else:
            if task.camera.name == calibration.camera.name:
                return None
            row = grating_file_row(task, calibration, scene, lamps)
    except (EstimationError, InputError) as exc:
        return {"camera": name, "group": task.camera.group, "failed": str(exc)}
    return {"camera": name, "group": task.camera.group, **row}


def report(row: dict[str, Any] | None, rows: list[dict[str, Any]]) -> None:
    """Print one camera's line and keep its row."""
    if row is None:
        return
    rows.append(row)
    name = row["camera"]
    if "failed" in row:
        print(f"{name[:40]:40s} FAILED: {row['failed']}", flush=True)
        return
    if "k" in row:
        print(
            f"{name[:40]:40s} k {row['k']:5.2f} (blue {row['k_blue']:5.2f}, red {row['k_red']:5.2f},"
            f" RMS {row['k_rms']:5.2f})"
            f" mean {row['mean_abs_nm']:6.2f} max {row['max_abs_nm']:6.2f} nm amb "
            f"{int(row['ambiguous'])}",
            flush=True,
        )
        return
    extra = (
        f"amb {int(row['ambiguous'])}"
        if "ambiguous" in row
        else f"RE {row['re_x100']:5.2f} (true η {row['re_true_eta_x100']:5.2f}, η RMS error "
        f"{row['eta_rms_error']:.3f})"
    )
    print(
        f"{name[:40]:40s} mean {row['mean_abs_nm']:6.2f} max {row['max_abs_nm']:6.2f} nm "
        f"stated {row['stated_nm']:5.2f} ratio {row['ratio']:5.2f} {extra} "
        f"cpu {row['cpu_s']:.2f} s",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--split", choices=("validation", "test"), default="validation")
    parser.add_argument("--scenario", choices=("led", "grating-file"), default="led")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cameras", default=None, help="comma-separated indices (default all)")
    parser.add_argument(
        "--calibration-camera", type=int, default=0, help="index of the training camera"
    )
    parser.add_argument(
        "--grooves",
        action="store_true",
        help="led: the rig's configuration gives the line density (the true one within ±2 %%)",
    )
    parser.add_argument(
        "--no-lens-reuse",
        action="store_true",
        help="grating-file: reuse only the groove spacing for another body behind the same lens "
        "(the rule before same_lens; an A/B switch for the validation split)",
    )
    parser.add_argument(
        "--predictions",
        type=int,
        default=0,
        help="validation split: add this many of Solomatov & Akkaynak's predicted curves as extra "
        "synthetic cameras (drawn with --seed, as `calib validate --predictions`)",
    )
    parser.add_argument(
        "--only-predicted",
        action="store_true",
        help="with --predictions: run the predicted cameras only (not the 44 leave-one-out ones)",
    )
    parser.add_argument(
        "--transformed",
        type=int,
        default=0,
        help="validation split: add this many physically transformed validation cameras (as "
        "`calib validate --transformed`)",
    )
    parser.add_argument(
        "--only-transformed",
        action="store_true",
        help="with --transformed: run the transformed cameras only",
    )
    parser.add_argument(
        "--no-optics",
        action="store_true",
        help="led: the profiles as `calib validate` has them (no EXIF focal length or pitch)",
    )
    parser.add_argument(
        "--scale-transfer",
        type=float,
        default=None,
        metavar="NM",
        help="led: render each scene with the reference spectrometer's wavelength offset forced to "
        "+NM and −NM (the same seed otherwise) and report how much of it the mapping takes up "
        "(k = −Δmapping/Δoffset, per camera)",
    )
    parser.add_argument(
        "--other-order",
        action="store_true",
        help="led: the LED's −1 order in the frame too, rendered in the same bracket through the "
        "true grating's other order (decision 0197)",
    )
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    parser.add_argument("--csv", default=None)
    args = parser.parse_args()
    if args.no_lens_reuse:
        import calib.wavelength.rig_prior as rig_prior_module

        rig_prior_module.same_lens = lambda stored, new: None
    if args.predictions and args.split != "validation":
        parser.error("--predictions joins the validation split only")
    if args.transformed and args.split != "validation":
        parser.error("--transformed joins the validation split only")
    splits, _notes = load_splits(
        args.data_dir, predictions=args.predictions, seed=args.seed, transformed=args.transformed
    )
    split = splits.validation if args.split == "validation" else splits.test
    if args.only_predicted:
        split = replace(split, cameras=tuple(c for c in split.cameras if c.group == PREDICTION))
    if args.only_transformed:
        split = replace(split, cameras=tuple(c for c in split.cameras if c.group == TRANSFORMED))
    settings = ProtocolSettings(seed=args.seed)
    tasks = split_tasks(split, settings)
    if args.cameras is not None:
        tasks = [tasks[int(i)] for i in args.cameras.split(",")]
    # The calibration camera: a training camera with its leave-one-out basis (never a test one).
    calibration = split_tasks(splits.validation, settings)[args.calibration_camera]
    if args.no_optics and args.scenario != "led":
        parser.error("--no-optics: the grating-file scenario needs the capture's optics")
    if args.scale_transfer is not None and args.scenario != "led":
        parser.error("--scale-transfer: the led scenario only")
    jobs = [
        (
            task,
            calibration,
            args.seed,
            args.scenario,
            args.grooves,
            not args.no_optics,
            args.scale_transfer,
            args.other_order,
        )
        for task in tasks
    ]
    rows: list[dict[str, Any]] = []
    if args.jobs <= 1:
        results = map(run_one, jobs)
        for row in results:
            report(row, rows)
    else:
        # Spawned workers (no inherited BLAS pools); the rows do not depend on their number.
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=args.jobs, mp_context=context) as pool:
            for row in pool.map(run_one, jobs, chunksize=1):
                report(row, rows)
    done = [row for row in rows if "failed" not in row]
    failed = len(rows) - len(done)
    if args.scale_transfer is not None:
        transfer_summary(args, rows, done)
        return
    mean_abs = np.array([row["mean_abs_nm"] for row in done])
    worst = np.array([row["max_abs_nm"] for row in done])
    ratio = np.array([row["ratio"] for row in done])
    summary = (
        f"{args.split} split, {args.scenario}: {len(rows)} cameras ({failed} failed); "
        f"median mean|Δλ| {np.median(mean_abs):.2f} nm; mean|Δλ| > 3 nm: "
        f"{int(np.sum(mean_abs > 3))}; max|Δλ| > 3 nm: {int(np.sum(worst > 3))}"
    )
    if args.scenario == "led":
        flagged = np.array([row["ambiguous"] for row in done], dtype=bool)
        coverage = np.array([row["coverage"] for row in done])
        summary += (
            f" ({int(np.sum((worst > 3) & ~flagged))} without an ambiguity warning; mean|Δλ| > 3 "
            f"nm unwarned {int(np.sum((mean_abs > 3) & ~flagged))}), warnings "
            f"{int(flagged.sum())} ({int(np.sum(flagged & (worst <= 3)))} on mappings ≤ 3 nm); "
            f"±2σ coverage (pixels, as calib validate) {100.0 * float(np.nanmean(coverage)):.1f} %"
            # Decision 0118's false alarms: warned with the mapping right to within 1 nm.
            f"; warned with mean|Δλ| < 1 nm {int(np.sum(flagged & (mean_abs < 1)))} (max|Δλ| < 1 "
            f"nm {int(np.sum(flagged & (worst < 1)))})"
        )
        apart = np.array(
            [
                np.nan if r["other_order_apart_px"] is None else r["other_order_apart_px"]
                for r in done
            ]
        )
        paired = ~np.isnan(apart)
        if paired.any():
            warned_apart = apart[paired & flagged]
            summary += (
                f"; two grating basins in {int(paired.sum())} scenes: the other first order's "
                f"counterpart of a +1 pixel {np.median(apart[paired]):.0f} px apart (median; least "
                f"{np.min(apart[paired]):.1f} px, {int(np.sum(apart[paired] < 5))} below 5 px)"
            )
            if warned_apart.size:
                summary += (
                    f", in the {warned_apart.size} warned {np.median(warned_apart):.0f} px "
                    f"(least {np.min(warned_apart):.1f} px)"
                )
    else:
        re = np.array([row["re_x100"] for row in done])
        exact = np.array([row["re_true_eta_x100"] for row in done])
        summary += (
            f"; RE ×10⁻² mean {np.mean(re):.2f}, median {np.median(re):.2f} (through the true η: "
            f"mean {np.mean(exact):.2f}, median {np.median(exact):.2f})"
        )
    summary += (
        f"; σ ratio (actual/stated RMS) median {np.median(ratio):.2f}, within 2×: "
        f"{int(np.sum((ratio <= 2) & (ratio >= 0.5)))}/{ratio.size}{sigma_scales(done)}; median "
        f"CPU {np.median([row['cpu_s'] for row in done]):.2f} s"
    )
    print(summary, file=sys.stderr)
    if args.scenario == "led" and args.other_order:
        print(other_order_summary(done), file=sys.stderr)
    if args.scenario == "led" and len({row["group"] for row in done}) > 1:
        print("\n".join(group_summaries(done)), file=sys.stderr)
    if args.csv:
        with Path(args.csv).open("w", newline="") as handle:
            fields = sorted({key for row in rows for key in row})
            writer = csv.DictWriter(handle, fieldnames=fields)
            writer.writeheader()
            writer.writerows(rows)


def other_order_summary(done: list[dict[str, Any]]) -> str:
    """What both first orders measured of the geometry: how often, how often refused and why,
    and the measured incidence's and focal length's errors in their own stated σ (the σ the
    result states, widened: ±2σ holds 95 % when the 95th percentile is 2)."""
    measured = [row for row in done if row.get("other_measured")]
    used = [row for row in measured if not row.get("other_refused")]
    refused = [
        row["other_refused"].split(":")[0].split("(")[0].strip()
        for row in measured
        if row.get("other_refused")
    ]
    reasons = ", ".join(f"{refused.count(r)} {r}" for r in sorted(set(refused)))
    parts = [
        f"both orders: geometry measured in {len(measured)} of {len(done)} scenes, used in "
        f"{len(used)}" + (f" (refused: {reasons})" if reasons else "")
    ]
    for key, label in (
        ("other_incidence_error_sigmas", "incidence"),
        ("other_focal_error_sigmas", "focal length"),
    ):
        errors = np.abs([float(row[key]) for row in used if row.get(key) is not None])
        errors = errors[np.isfinite(errors)]
        if errors.size:
            parts.append(
                f"{label} |error|/σ median {np.median(errors):.2f}, 95th percentile "
                f"{np.percentile(errors, 95):.2f}"
            )
    return "; ".join(parts)


def transfer_summary(
    args: argparse.Namespace, rows: list[dict[str, Any]], done: list[dict[str, Any]]
) -> None:
    """The offset's transfer k over the cameras whose mappings were right (≤ 3 nm, unwarned, at
    both offsets: a basin jump is no linear response), and its spread."""
    right = [r for r in done if r["max_abs_nm"] <= 3 and not r["ambiguous"]]
    k = np.array([r["k"] for r in right])
    k_rms = np.array([r["k_rms"] for r in right])
    summary = (
        f"{args.split} split, spectrometer offset ±{args.scale_transfer:g} nm: {len(rows)} cameras "
        f"({len(rows) - len(done)} failed, {len(done) - len(right)} warned or > 3 nm left out); "
    )
    if k.size:
        q = np.percentile(k, [5, 16, 50, 84, 95])
        summary += (
            f"k = −Δmapping/Δoffset median {q[2]:.3f}, 16–84 % {q[1]:.3f}–{q[3]:.3f}, 5–95 % "
            f"{q[0]:.3f}–{q[4]:.3f}, mean {np.mean(k):.3f} (SD {np.std(k):.3f}); blue end median "
            f"{np.median([r['k_blue'] for r in right]):.3f}, red end "
            f"{np.median([r['k_red'] for r in right]):.3f}; RMS over the profile k_rms median "
            f"{np.median(k_rms):.3f}, 16–84 % {np.percentile(k_rms, 16):.3f}–"
            f"{np.percentile(k_rms, 84):.3f}, RMS over cameras {np.sqrt(np.mean(k_rms**2)):.3f}"
        )
    print(summary, file=sys.stderr)
    if args.csv:
        with Path(args.csv).open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=sorted({key for row in rows for key in row}))
            writer.writeheader()
            writer.writerows(rows)


if __name__ == "__main__":
    main()
