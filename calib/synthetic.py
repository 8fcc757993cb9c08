"""The synthetic protocol of Makabe et al. (2025) §4.1, as a library.

For each test camera: render the direct RGB and first-order profile of a broadband lamp (D65 as in the
paper, or LED-B3) and of a fluorescent lamp (FL2) with :mod:`calib.forward`, through a random
pixel→wavelength mapping that covers 400–700 nm and a random low-frequency grating efficiency (7
Fourier terms); add Gaussian noise of a fraction of each profile's peak; estimate with

``true mapping``  the broadband lamp and the true mapping (isolates the solve),
``LED+Flu``       mapping from the fluorescent lamp's lines, solve with the broadband lamp,
``LED only``      mapping and solve from the broadband lamp alone;

and report RE (Eq. 16) and mapping RE (Supp. Eq. 1). Every random draw comes from one seeded
``numpy.random.Generator`` per (camera, noise level, repeat), so all variants see the same scene.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calib.bases import CameraBasis, fourier_basis
from calib.errors import EstimationError, InputError
from calib.forward import PeakFractionNoise, RenderedObservation, render_observation
from calib.makabe2025 import Solver, estimate_makabe2025
from calib.mapping import QuadraticMapping
from calib.metrics import mapping_relative_error, relative_error
from calib.observations import LampKind
from calib.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum, WavelengthGrid

FloatArray = NDArray[np.float64]

VARIANTS: tuple[str, ...] = ("true mapping", "LED+Flu", "LED only", "LED only (paper ICP)")
NOISE_LEVELS: tuple[float, ...] = (0.0, 0.003, 0.01, 0.03)
BROADBAND_LAMPS: tuple[str, ...] = ("D65", "LED-B3")
FLUORESCENT_LAMP = "FL2"


def colour_lamp(name: str) -> Spectrum:
    """A colour-science illuminant (``SDS_ILLUMINANTS``) or light source (``SDS_LIGHT_SOURCES``)."""
    import colour  # deferred: importing colour costs ~1 s

    for table in (colour.SDS_ILLUMINANTS, colour.SDS_LIGHT_SOURCES):
        if name in table:
            return Spectrum.from_colour(table[name], name=name)
    raise InputError(
        f"colour-science has no illuminant or light source named {name!r}", source="lamp"
    )


def random_mapping(
    rng: np.random.Generator, grid: WavelengthGrid = DEFAULT_GRID, *, n_pixels: int | None = None
) -> QuadraticMapping:
    """A random monotonic quadratic mapping whose pixels cover the grid with margins.

    ``n_pixels`` ∈ [600, 1000] (drawn when not given), ``g(0)`` 5–30 nm below the grid, ``g(n−1)``
    5–40 nm above it, and a curvature bending the middle by up to ±6 nm.
    """
    n = int(rng.integers(600, 1001)) if n_pixels is None else n_pixels
    first = grid.start_nm - rng.uniform(5.0, 30.0)
    last = grid.stop_nm + rng.uniform(5.0, 40.0)
    middle = 0.5 * (first + last) + rng.uniform(-6.0, 6.0)
    anchors = np.array([0.0, (n - 1) / 2, n - 1.0])
    a, b, c = np.linalg.solve(
        np.stack([anchors**2, anchors, np.ones(3)], axis=1), [first, middle, last]
    )
    return QuadraticMapping(
        float(a), float(b), float(c), method="truth", pixel_range=(0.0, n - 1.0)
    )


def random_efficiency(
    rng: np.random.Generator, grid: WavelengthGrid = DEFAULT_GRID, *, n_terms: int = 7
) -> Callable[[FloatArray], FloatArray]:
    """A random smooth grating efficiency (``n_terms`` Fourier terms over the grid), between ~0.3 and 1."""
    weights = rng.standard_normal(n_terms) / (1.0 + np.arange(n_terms))
    low = rng.uniform(0.3, 0.7)
    probe = np.linspace(grid.start_nm, grid.stop_nm, 301)

    def raw(wavelength_nm: FloatArray) -> FloatArray:
        position = (np.asarray(wavelength_nm) - grid.start_nm) / (grid.stop_nm - grid.start_nm)
        columns = [np.ones_like(position)]
        for k in range(1, n_terms):
            trig = np.cos if k % 2 == 1 else np.sin
            columns.append(trig(2 * np.pi * ((k + 1) // 2) * position))
        return np.asarray(np.stack(columns, axis=-1) @ weights, dtype=np.float64)

    values = raw(probe)
    lo, hi = float(values.min()), float(values.max())

    def efficiency(wavelength_nm: FloatArray) -> FloatArray:
        return np.asarray(
            low + (1 - low) * (raw(wavelength_nm) - lo) / max(hi - lo, 1e-12), dtype=np.float64
        )

    return efficiency


@dataclass(frozen=True, eq=False)
class SyntheticScene:
    """One camera rendered under the protocol's lamps."""

    camera: str
    truth: FloatArray
    mapping: QuadraticMapping
    broadband: RenderedObservation
    fluorescent: RenderedObservation


def render_scene(
    camera_name: str,
    sensitivity: MultiSpectrum,
    rng: np.random.Generator,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    broadband_lamp: Spectrum,
    fluorescent_lamp: Spectrum,
    noise_fraction: float = 0.0,
) -> SyntheticScene:
    """Render the broadband and fluorescent observations of one camera (see module docstring)."""
    mapping = random_mapping(rng, grid)
    efficiency = random_efficiency(rng, grid)
    n = round(mapping.pixel_range[1]) + 1 if mapping.pixel_range else 800
    noise = PeakFractionNoise(noise_fraction) if noise_fraction > 0 else None
    lamps: tuple[tuple[LampKind, Spectrum], ...] = (
        ("led", broadband_lamp),
        ("fluorescent", fluorescent_lamp),
    )
    rendered = {
        kind: render_observation(
            lamp,
            sensitivity,
            mapping=mapping,
            pixel=n,
            grating_efficiency=efficiency,
            noise=noise,
            rng=rng,
            kind=kind,
        )
        for kind, lamp in lamps
    }
    truth = sensitivity.resample(grid, "interpolate", out_of_range="zero").values
    return SyntheticScene(
        camera_name, truth / truth.max(), mapping, rendered["led"], rendered["fluorescent"]
    )


@dataclass(frozen=True)
class SyntheticRow:
    """One estimate of the protocol: RE and mapping RE (fractions) and the wall time."""

    camera: str
    variant: str
    noise: float
    relative_error: float
    mapping_relative_error: float | None
    mapping_re_estimate: float | None
    time_s: float
    repeat: int = 0
    failure: str | None = None


def evaluate_scene(
    scene: SyntheticScene,
    basis: CameraBasis,
    variant: str,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    solver: Solver = "prior",
    noise: float = 0.0,
    repeat: int = 0,
) -> SyntheticRow:
    """Estimate one variant on a rendered scene and score it against the truth."""
    started = time.perf_counter()
    led = scene.broadband.observation
    observations = [led] if variant != "LED+Flu" else [led, scene.fluorescent.observation]
    try:
        result = estimate_makabe2025(
            observations,
            basis=basis,
            grid=grid,
            mapping=scene.mapping if variant == "true mapping" else None,
            solver=solver,
            mapping_method="icp" if variant == "LED only (paper ICP)" else "search",
            solve_lamps=[led.name],
        )
    except EstimationError as exc:
        return SyntheticRow(
            scene.camera,
            variant,
            noise,
            float("nan"),
            None,
            None,
            time.perf_counter() - started,
            repeat,
            str(exc),
        )
    elapsed = time.perf_counter() - started
    mapping_re = None
    if variant != "true mapping" and result.mapping is not None:
        pixels = led.pixel
        true_nm = scene.mapping.wavelength_nm(pixels)
        inside = (true_nm >= grid.start_nm) & (true_nm <= grid.stop_nm)
        mapping_re = mapping_relative_error(
            result.mapping.wavelength_nm(pixels[inside]),
            true_nm[inside],
            range_nm=(grid.start_nm, grid.stop_nm),
        )
    return SyntheticRow(
        scene.camera,
        variant,
        noise,
        relative_error(result.sensitivity, scene.truth),
        mapping_re,
        result.mapping_re_estimate if variant != "true mapping" else None,
        elapsed,
        repeat,
    )


def run_protocol(
    cameras: Sequence[tuple[str, MultiSpectrum]],
    basis: CameraBasis | Callable[[str], CameraBasis],
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    variants: Sequence[str] = VARIANTS,
    noise_levels: Sequence[float] = NOISE_LEVELS,
    broadband_lamp: str = "D65",
    fluorescent_lamp: str = FLUORESCENT_LAMP,
    solver: Solver = "prior",
    repeats: int = 1,
    seed: int = 0,
    progress: Callable[[SyntheticRow], None] | None = None,
) -> list[SyntheticRow]:
    """Run the protocol over cameras × noise levels × repeats × variants (see module docstring).

    Parameters
    ----------
    cameras
        ``(name, sensitivity)`` pairs, e.g. the 5 test cameras of :func:`calib.datasets.makabe2025_split`.
    basis
        Camera basis (e.g. from the 44 training cameras) on ``grid``, or a function of the camera's
        name giving one (e.g. the offline basis excluding that camera).
    seed
        Master seed; scene ``(camera i, noise j, repeat r)`` uses ``default_rng([seed, i, j, r])``.
    """
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        raise InputError(f"unknown variants {unknown}; choose from {VARIANTS}", source="variants")
    broadband = colour_lamp(broadband_lamp)
    fluorescent = colour_lamp(fluorescent_lamp)
    _ = fourier_basis(grid)  # validates the grid early
    rows: list[SyntheticRow] = []
    for camera_index, (name, sensitivity) in enumerate(cameras):
        for noise_index, noise in enumerate(noise_levels):
            for repeat in range(repeats):
                rng = np.random.default_rng([seed, camera_index, noise_index, repeat])
                scene = render_scene(
                    name,
                    sensitivity,
                    rng,
                    grid=grid,
                    broadband_lamp=broadband,
                    fluorescent_lamp=fluorescent,
                    noise_fraction=noise,
                )
                scene_basis = basis(name) if callable(basis) else basis
                for variant in variants:
                    row = evaluate_scene(
                        scene,
                        scene_basis,
                        variant,
                        grid=grid,
                        solver=solver,
                        noise=noise,
                        repeat=repeat,
                    )
                    rows.append(row)
                    if progress is not None:
                        progress(row)
    return rows
