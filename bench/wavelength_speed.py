"""CPU time of mapping + estimate, and the ratio to the solve alone, for one camera.

Four figures per scene, measured in one process one after the other (median of ``--repeats`` after
a warm-up; ``time.process_time``, one BLAS thread):

``solve alone``          :func:`calib.methods.estimate` given the true mapping (the yardstick), its
                         σ budget included (decision 0029: the re-solves of the perturbations);
``no σ budget``          the same with ``budget=None``: the method's own solve, what the budget adds
                         is the difference;
``mapping + estimate``   :func:`calib.methods.estimate` finding its mapping
                         (:func:`calib.wavelength.find_mapping` → :mod:`calib.wavelength.locate`),
                         with the search's evaluation count (a count: the work, free of noise);
``before``               ``bench/mapping_before.py``'s ``search_mapping`` (what the estimators
                         used before this engine), then the estimate with its mapping.

Scenes: the paper's synthetic protocol (§4.1) for the Canon 600D (a test camera: reported, never
tuned on) with the 44 training cameras' basis — LED only (D65) and LED + fluorescent (FL2), profiles
whose origin is arbitrary (the quadratic family) —; with ``--protocol``, the same camera in
``calib validate``'s scene (seed 0: the rig's errors, profiles measured from the direct spot with
the RAW files' optics, so the physical family's scan over the ends) for its "LED only",
"LED only, no EXIF" and "LED+FL" variants, the method and options the protocol gives them; and,
with ``--real DIR``, the real Nikon D7000 pair (2474 columns: the CFL through the built-in
tri-phosphor line list, the halogen lamp measured).

With ``--solve-only`` only the first two figures (the estimate after the mapping: decision 0083),
and ``--profile N`` then profiles the solve alone. Where the search's evaluations go, stage by
stage, for the same scenes: ``bench/search_stages.py`` (decision 0105).

    python bench/wavelength_speed.py --data-dir ../shared/data/camera_sensitivities [--protocol] [--real ../shared/data/real-grating] [--skip-before] [--profile 12] [--solve-only]
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from mapping_before import search_mapping

from calib.core.blas import one_blas_thread
from calib.core.datasets import find_camera, makabe2025_split
from calib.core.lamp_specs import colour_lamp, lamp_from_spec
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, read_spectrum_csv
from calib.evaluation.synthetic import render_scene
from calib.methods import estimate
from calib.model.bases import CameraBasis, camera_basis
from calib.model.resolution import camera_kernel


def cpu_median(function: Callable[[], object], repeats: int) -> float:
    return timed(function, repeats)[0]


def timed(function: Callable[[], object], repeats: int) -> tuple[float, object]:
    """The median CPU time of ``repeats`` calls after a warm-up, and the last call's result."""
    function()  # warm-up: imports, caches
    times = []
    result = None
    for _ in range(repeats):
        started = time.process_time()
        result = function()
        times.append(time.process_time() - started)
    return statistics.median(times), result


def searched(function: Callable[[], object], repeats: int) -> tuple[float, int | None]:
    """:func:`cpu_median` of an estimate that finds its mapping, and the search's evaluation
    count (its details' ``evaluations``: trial mappings costed in the scans and residuals of the
    descents): a count, so a change of the search's work shows beside the noisy CPU time."""
    median, result = timed(function, repeats)
    details = getattr(getattr(result, "mapping", None), "details", None) or {}
    count = details.get("evaluations")
    return median, None if count is None else int(count)


@one_blas_thread
def before_path(observations: Sequence[LampObservation], basis: CameraBasis) -> None:
    mapping = search_mapping(
        observations, basis.prior(), DEFAULT_GRID, kernel=camera_kernel(observations)
    )
    estimate(observations, basis=basis, mapping=mapping)


def report(
    label: str,
    solve_s: float,
    new_s: float | None,
    old_s: float | None,
    bare_s: float | None = None,
    evaluations: int | None = None,
) -> None:
    old = "" if old_s is None else f"; before {old_s:.3f} s ({old_s / solve_s:.1f}×)"
    bare = "" if bare_s is None else f" (no σ budget {bare_s:.4f} s)"
    count = "" if evaluations is None else f", {evaluations} search evaluations"
    new = (
        ""
        if new_s is None
        else f"; mapping + estimate {new_s:.3f} s ({new_s / solve_s:.1f}× the solve{count})"
    )
    print(f"{label:24s} solve alone {solve_s:.4f} s{bare}{new}{old}", flush=True)


def paper_scene(data_dir: str | None, noise: float = 0.01) -> tuple[Any, Any, Any]:
    """The bench's scene (module docstring): the paper's synthetic protocol for the Canon 600D, a
    test camera, with the 44 training cameras' basis, an LED (D65) and a fluorescent lamp (FL2) at
    ``noise`` (of the peak). Returns the camera, the basis and the rendered scene; the speed
    benches (``bench/search_stages.py``, ``bench/evaluation_cost.py``) time the same one."""
    train, test = makabe2025_split(data_dir)
    camera = find_camera(test, "Canon 600D")
    basis = camera_basis([r.sensitivity for r in train], source="Makabe 2025 train (44)")
    scene = render_scene(
        camera.name,
        camera.sensitivity.resample(DEFAULT_GRID, "interpolate"),
        np.random.default_rng(0),
        broadband_lamp=colour_lamp("D65"),
        fluorescent_lamp=colour_lamp("FL2"),
        noise_fraction=noise,
    )
    return camera, basis, scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--noise", type=float, default=0.01)
    parser.add_argument("--real", type=Path, default=None, help="the real-grating data directory")
    parser.add_argument("--skip-before", action="store_true", help="leave out the old engine")
    parser.add_argument(
        "--protocol",
        action="store_true",
        help="also the camera in calib validate's scene (profiles from the direct spot)",
    )
    parser.add_argument(
        "--profile",
        type=int,
        default=0,
        metavar="N",
        help="after each scene, the N functions with the most own time in one profiled "
        "mapping + estimate (with --solve-only: the solve alone; cProfile: its overhead "
        "inflates many small calls)",
    )
    parser.add_argument(
        "--solve-only",
        action="store_true",
        help="time only the estimate given the true mapping (with and without its σ budget)",
    )
    args = parser.parse_args()
    camera, basis, scene = paper_scene(args.data_dir, args.noise)
    led, fluorescent = scene.broadband.observation, scene.fluorescent.observation
    for label, lamps in (("LED only", [led]), ("LED + fluorescent", [led, fluorescent])):

        def solve(lamps: list[LampObservation] = lamps) -> object:
            return estimate(lamps, basis=basis, mapping=scene.mapping)

        def bare(lamps: list[LampObservation] = lamps) -> object:
            return estimate(lamps, basis=basis, mapping=scene.mapping, budget=None)

        def new(lamps: list[LampObservation] = lamps) -> object:
            return estimate(lamps, basis=basis)

        def old(lamps: list[LampObservation] = lamps) -> object:
            before_path(lamps, basis)
            return None

        solve_s = cpu_median(solve, args.repeats)
        new_s, count = (None, None) if args.solve_only else searched(new, args.repeats)
        report(
            f"{camera.camera}, {label}",
            solve_s,
            new_s,
            None if args.skip_before or args.solve_only else cpu_median(old, args.repeats),
            cpu_median(bare, args.repeats),
            count,
        )
        if args.profile:
            profile_top(solve if args.solve_only else new, args.profile)
    if args.protocol:
        protocol_scene(args.data_dir, camera.name, args.repeats, args.profile)
    if args.real is not None:
        real_pair(args.real, args.data_dir, args.repeats, args.profile)


#: The ``calib validate`` variants the speed benches time in the protocol's scene.
PROTOCOL_VARIANTS = ("LED only", "LED only, no EXIF", "LED+FL")


def protocol_estimates(
    data_dir: str | None, name: str, labels: Sequence[str]
) -> list[tuple[str, list[LampObservation], dict[str, Any], Any]]:
    """The camera's ``calib validate`` scene (test split, seed 0): per variant in ``labels``, its
    label, what :func:`calib.methods.estimate` is given for it and the scene's true mapping."""
    from calib.evaluation.validation.protocol import (
        DEFAULT_VARIANTS,
        named_task,
        render_task_scene,
        variant_inputs,
    )

    task = named_task(data_dir, name)
    scene = render_task_scene(task)
    return [
        (variant.label, *variant_inputs(task, scene, variant), scene.plan.geometry.mapping)
        for variant in DEFAULT_VARIANTS
        if variant.label in labels
    ]


def protocol_scene(data_dir: str | None, name: str, repeats: int, profile: int = 0) -> None:
    """The camera in ``calib validate``'s scene (test split, seed 0, its basis: all training
    cameras), each default variant with one lamp set as the protocol runs it; the solve alone is
    given the scene's true grating."""
    for label, lamps, keywords, truth in protocol_estimates(data_dir, name, PROTOCOL_VARIANTS):

        def solve(
            lamps: list[LampObservation] = lamps,
            keywords: dict[str, Any] = keywords,
            truth: Any = truth,
        ) -> object:
            return estimate(lamps, mapping=truth, **keywords)

        def bare(
            lamps: list[LampObservation] = lamps,
            keywords: dict[str, Any] = keywords,
            truth: Any = truth,
        ) -> object:
            return estimate(lamps, mapping=truth, budget=None, **keywords)

        def new(
            lamps: list[LampObservation] = lamps, keywords: dict[str, Any] = keywords
        ) -> object:
            return estimate(lamps, **keywords)

        solve_s = cpu_median(solve, repeats)
        new_s, count = searched(new, repeats)
        report(
            f"spot scene, {label}",
            solve_s,
            new_s,
            None,
            cpu_median(bare, repeats),
            count,
        )
        if profile:
            profile_top(new, profile)


def profile_top(function: Callable[[], object], count: int) -> None:
    """Where one run's time goes: the ``count`` functions with the most own time, and their
    share of the run (cProfile's, so the shares, not the seconds, are what to read)."""
    profiler = cProfile.Profile()
    profiler.enable()
    function()
    profiler.disable()
    stats = pstats.Stats(profiler)
    entries = getattr(stats, "stats", {})
    total = sum(entry[2] for entry in entries.values()) or 1.0
    ranked = sorted(entries.items(), key=lambda item: -item[1][2])[:count]
    for (filename, line, name), (_, calls, own, cumulative, _) in ranked:
        where = f"{Path(filename).parent.name}/{Path(filename).name}:{line}({name})"
        print(
            f"    {100 * own / total:5.1f} % own, {100 * cumulative / total:5.1f} % with callees, "
            f"{calls:6d} calls  {where}",
            flush=True,
        )


def real_pair(real: Path, data_dir: str | None, repeats: int, profile: int = 0) -> None:
    """The Nikon D7000 pair (2474 columns): the CFL through ``builtin:cfl-triphosphor`` and the
    halogen lamp measured, through a flat grating (no efficiency is known for it), the profiles'
    origin arbitrary (either orientation is tried)."""
    from calib.image.profile_files import read_rawproc_dat
    from calib.methods.known_grating import estimate_known_grating
    from calib.model.bases import default_camera_basis

    folder = real / "butcher-nikon-d7000-2020-08"
    lamps = [
        read_rawproc_dat(folder / "D7000_calibration.dat").to_observation(
            "CFL", lamp_from_spec("builtin:cfl-triphosphor"), kind="fluorescent"
        ),
        read_rawproc_dat(folder / "D7000_spectrum.dat").to_observation(
            "halogen", read_spectrum_csv(folder / "Dedolight_5nm.csv"), kind="halogen"
        ),
    ]
    basis = default_camera_basis(data_dir=data_dir)
    found = estimate_known_grating(lamps, grating=None, basis=basis)

    def solve() -> object:
        return estimate_known_grating(lamps, grating=None, basis=basis, mapping=found.mapping)

    def new() -> object:
        return estimate_known_grating(lamps, grating=None, basis=basis)

    solve_s = cpu_median(solve, repeats)
    new_s, count = searched(new, repeats)
    report("Nikon D7000 real pair", solve_s, new_s, None, evaluations=count)
    if profile:
        profile_top(new, profile)


if __name__ == "__main__":
    main()
