"""The synthetic protocol of Makabe et al. (2025) §4.1, as a library.

For each test camera: render the direct RGB and first-order profile of a broadband lamp (D65 as in the
paper, or LED-B3) and of a fluorescent lamp (FL2) with :mod:`calib.model.forward`, through a random
pixel→wavelength mapping that covers 400–700 nm and a random low-frequency grating efficiency (7
Fourier terms); add Gaussian noise of a fraction of each profile's peak; estimate with

``true mapping``  the broadband lamp and the true mapping (isolates the solve),
``LED+Flu``       mapping from the fluorescent lamp's lines, solve with the broadband lamp,
``LED only``      mapping and solve from the broadband lamp alone;

and report RE (Eq. 16) and mapping RE (Supp. Eq. 1). Every random draw comes from one seeded
``numpy.random.Generator`` per (camera, noise level, repeat), so all variants see the same scene.

Beyond the paper (:mod:`calib.methods.multilamp`, opt-in variants): the same scene also seen under the lamp
sets of :data:`LAMP_SETS` (rendered after the paper's two lamps, so their draws are unchanged),

``multilamp: 5 lamps``             LED-B1, LED-B3, LED-B5, FL2, A jointly, mapping estimated,
``multilamp: 3 lamps + RGB LEDs``  LED-B3, FL2, A and three narrow-band (Gaussian) LEDs,
``multilamp: 5 lamps, true mapping``,
``grating file: 1 LED``            η calibrated with the 5 lamps on the *other* cameras through the same
                                   grating (jointly, :func:`calib.methods.multilamp.refine_grating`), then this
                                   camera from one LED-B3 shot (:func:`calib.methods.known_grating.estimate_known_grating`).

The paper's variants run the prior solve (:func:`calib.methods.prior_solve.estimate_prior`) or, given
:class:`calib.methods.makabe2025.Makabe2025Options`, the paper's own.

Every variant is estimated through :func:`calib.methods.estimate`, the front function ``calib
estimate`` and ``rig estimate`` run, so the ±2σ band judged (:attr:`SyntheticRow.coverage`) is the
one users are given: the σ budget (:mod:`calib.methods.uncertainty`, ``budget``) — not the method's
own σ, which is kept beside it (:attr:`SyntheticRow.method_coverage`). The protocol draws no
spectrometer error (its lamp spectra are the true ones and state no bandwidth), so the budget's
spectrometer components are what it assumes of an instrument nobody described (decision 0129).

Out-of-basis cameras (:func:`out_of_basis_cameras`): colour-science's Sigma SDMerill (NPL, a Foveon
sensor) and a camera behind a colour filter (:func:`colour_filter`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.datasets import colour_science_cameras
from calib.core.errors import EstimationError, InputError
from calib.core.lamp_specs import RGB_LEDS, colour_lamp, lamp_from_spec
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import mapping_relative_error, relative_error
from calib.core.observations import LampKind, LampObservation
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum, WavelengthGrid
from calib.methods import estimate
from calib.methods.closed_form import SearchMethod
from calib.methods.known_grating import KNOWN_GRATING_METHOD
from calib.methods.makabe2025 import MAKABE2025_METHOD, Makabe2025Options
from calib.methods.multilamp import MULTILAMP_METHOD, MultilampOptions, refine_grating
from calib.methods.prior_solve import PRIOR_METHOD, PriorOptions
from calib.methods.uncertainty import DEFAULT_BUDGET, BudgetSettings
from calib.model.bases import CameraBasis, fourier_basis
from calib.model.forward import PeakFractionNoise, RenderedObservation, render_observation

PAPER_VARIANTS: tuple[str, ...] = ("true mapping", "LED+Flu", "LED only", "LED only (paper ICP)")
#: Lamp sets of the multi-lamp variants (lamp specs of :func:`calib.core.lamp_specs.lamp_from_spec`).
FIVE_LAMPS = "5 lamps"
LAMP_SETS: dict[str, tuple[str, ...]] = {
    FIVE_LAMPS: ("LED-B1", "LED-B3", "LED-B5", "FL2", "A"),
    "3 lamps + RGB LEDs": ("LED-B3", "FL2", "A", *RGB_LEDS),
}
#: The lamp a new camera is shot with once the grating is known.
GRATING_FILE_LAMP = "LED-B3"
MULTILAMP_VARIANTS: tuple[str, ...] = (
    "multilamp: 5 lamps, true mapping",
    "multilamp: 5 lamps",
    "multilamp: 3 lamps + RGB LEDs",
    "grating file: 1 LED",
)
VARIANTS: tuple[str, ...] = PAPER_VARIANTS + MULTILAMP_VARIANTS
NOISE_LEVELS: tuple[float, ...] = (0.0, 0.003, 0.01, 0.03)
BROADBAND_LAMPS: tuple[str, ...] = ("D65", "LED-B3")
FLUORESCENT_LAMP = "FL2"
#: How the paper's variants solve: the prior solve's options, or the paper's solve's.
PaperSolve = PriorOptions | Makabe2025Options


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
    """One camera rendered under the protocol's lamps (``efficiency``: the true grating efficiency,
    for experiments that give a solve the truth)."""

    camera: str
    truth: FloatArray
    mapping: QuadraticMapping
    broadband: RenderedObservation
    fluorescent: RenderedObservation
    lamp_sets: dict[str, tuple[LampObservation, ...]] = field(default_factory=dict)
    calibration: tuple[tuple[LampObservation, ...], ...] = ()
    efficiency: Callable[[FloatArray], FloatArray] | None = None


def lamp_kind(spec: str) -> LampKind:
    """The kind a lamp spec stands for (fluorescent lines start the mapping search)."""
    if spec.startswith("FL"):
        return "fluorescent"
    if spec.lower().startswith("gauss:"):
        return "narrowband"
    return "halogen" if spec == "A" else "led"


def colour_filter(grid_nm: FloatArray | None = None) -> Spectrum:
    """A blue (cooling, Wratten-80-like) colour filter's transmission, modelled as a smooth step.

    ``T(λ) = 0.12 + 0.8 / (1 + exp((λ − 560 nm) / 25 nm))``: passes blue and green, cuts most red.
    """
    axis = np.arange(360.0, 831.0) if grid_nm is None else np.asarray(grid_nm, dtype=np.float64)
    values = 0.12 + 0.8 / (1.0 + np.exp((axis - 560.0) / 25.0))
    return Spectrum(axis, values, name="blue colour filter")


def behind_filter(camera: MultiSpectrum, transmission: Spectrum) -> MultiSpectrum:
    """A camera behind a filter: its sensitivity times the filter's transmission."""
    axis = camera.wavelength_nm
    return MultiSpectrum(
        axis,
        camera.values * transmission.at(axis)[:, None],
        name=f"{camera.name} behind a {transmission.name}",
    )


#: colour-science's Foveon camera (three stacked photodiodes: broad, overlapping curves).
FOVEON_CAMERA = "Sigma SDMerill (NPL)"


def out_of_basis_cameras(
    filtered_name: str, filtered: MultiSpectrum
) -> list[tuple[str, MultiSpectrum]]:
    """Cameras unlike any basis: the Foveon camera and ``filtered`` behind :func:`colour_filter`."""
    (foveon,) = (r.sensitivity for r in colour_science_cameras() if r.name == FOVEON_CAMERA)
    return [
        (FOVEON_CAMERA, foveon),
        (f"{filtered_name} + blue filter", behind_filter(filtered, colour_filter())),
    ]


def render_lamps(
    specs: Sequence[str],
    sensitivity: MultiSpectrum,
    mapping: QuadraticMapping,
    efficiency: Callable[[FloatArray], FloatArray],
    rng: np.random.Generator,
    noise_fraction: float,
    direct_noise_fraction: float | None = None,
) -> tuple[LampObservation, ...]:
    """One camera's observations of lamps (specs) through one grating and mapping."""
    noise = PeakFractionNoise(noise_fraction, direct_noise_fraction) if noise_fraction > 0 else None
    return tuple(
        _render(
            lamp_from_spec(spec), lamp_kind(spec), sensitivity, mapping, efficiency, noise, rng
        ).observation
        for spec in specs
    )


def _render(
    lamp: Spectrum,
    kind: LampKind,
    sensitivity: MultiSpectrum,
    mapping: QuadraticMapping,
    efficiency: Callable[[FloatArray], FloatArray],
    noise: PeakFractionNoise | None,
    rng: np.random.Generator,
) -> RenderedObservation:
    """One lamp through the scene's grating, on the mapping's pixels."""
    n = round(mapping.pixel_range[1]) + 1 if mapping.pixel_range else 800
    return render_observation(
        lamp,
        sensitivity,
        mapping=mapping,
        pixel=n,
        grating_efficiency=efficiency,
        noise=noise,
        rng=rng,
        kind=kind,
    )


def render_scene(
    camera_name: str,
    sensitivity: MultiSpectrum,
    rng: np.random.Generator,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    broadband_lamp: Spectrum,
    fluorescent_lamp: Spectrum,
    noise_fraction: float = 0.0,
    lamp_sets: Sequence[str] = (),
    calibration_cameras: Sequence[MultiSpectrum] = (),
    direct_noise_fraction: float | None = None,
) -> SyntheticScene:
    """Render the broadband and fluorescent observations of one camera (see module docstring).

    ``lamp_sets`` (keys of :data:`LAMP_SETS`) and ``calibration_cameras`` (other cameras seen
    through the same grating under the 5 lamps) are rendered afterwards from the same generator.
    ``direct_noise_fraction`` sets their direct measurement's noise apart from the profile's (the
    direct spot sums many pixels); ``None`` keeps the protocol's (the same fraction).
    """
    mapping = random_mapping(rng, grid)
    efficiency = random_efficiency(rng, grid)
    noise = PeakFractionNoise(noise_fraction) if noise_fraction > 0 else None
    lamps: tuple[tuple[LampKind, Spectrum], ...] = (
        ("led", broadband_lamp),
        ("fluorescent", fluorescent_lamp),
    )
    rendered = {
        kind: _render(lamp, kind, sensitivity, mapping, efficiency, noise, rng)
        for kind, lamp in lamps
    }
    truth = sensitivity.resample(grid, "interpolate", out_of_range="zero").values
    sets = {
        name: render_lamps(
            LAMP_SETS[name],
            sensitivity,
            mapping,
            efficiency,
            rng,
            noise_fraction,
            direct_noise_fraction,
        )
        for name in lamp_sets
    }
    calibration = tuple(
        render_lamps(
            LAMP_SETS[FIVE_LAMPS],
            camera,
            mapping,
            efficiency,
            rng,
            noise_fraction,
            direct_noise_fraction,
        )
        for camera in calibration_cameras
    )
    return SyntheticScene(
        camera_name,
        truth / truth.max(),
        mapping,
        rendered["led"],
        rendered["fluorescent"],
        sets,
        calibration,
        efficiency,
    )


@dataclass(frozen=True)
class SyntheticRow:
    """One estimate of the protocol: RE and mapping RE (fractions) and the wall time.

    ``coverage`` is the share of the truth inside the stated ±2σ band (the budget's σ, as users get
    it; the method's own when the protocol ran without a budget), ``method_coverage`` the same for
    the method's own σ (``diagnostics["method_sigma"]``), ``None`` when there is none.
    """

    camera: str
    variant: str
    noise: float
    relative_error: float
    mapping_relative_error: float | None
    mapping_re_estimate: float | None
    time_s: float
    repeat: int = 0
    failure: str | None = None
    coverage: float | None = None
    method_coverage: float | None = None


#: ``on_result(scene, row, result)``: what :func:`evaluate_scene` shows a caller of each estimate.
ResultHook = Callable[[SyntheticScene, SyntheticRow, EstimateResult], None]


def _uses_true_mapping(variant: str) -> bool:
    """``true mapping`` and ``multilamp: … , true mapping`` are given the scene's mapping."""
    return variant == "true mapping" or variant.endswith(", true mapping")


def evaluate_scene(
    scene: SyntheticScene,
    basis: CameraBasis,
    variant: str,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    paper_solve: PaperSolve = PriorOptions(),
    noise: float = 0.0,
    repeat: int = 0,
    multilamp_options: MultilampOptions = MultilampOptions(),
    budget: BudgetSettings | None = DEFAULT_BUDGET,
    on_result: ResultHook | None = None,
) -> SyntheticRow:
    """Estimate one variant on a rendered scene and score it against the truth.

    ``budget`` is the σ budget :func:`calib.methods.estimate` states (``None``: the method's own σ);
    ``on_result(scene, row, result)`` sees each estimate and its row (e.g. its budget's components).
    """
    started = time.perf_counter()
    led = scene.broadband.observation
    try:
        result = _estimate_variant(
            scene,
            basis,
            variant,
            grid=grid,
            paper_solve=paper_solve,
            multilamp_options=multilamp_options,
            budget=budget,
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
    true_mapping = _uses_true_mapping(variant)
    if not true_mapping and result.mapping is not None:
        pixels = led.pixel
        true_nm = scene.mapping.wavelength_nm(pixels)
        inside = (true_nm >= grid.start_nm) & (true_nm <= grid.stop_nm)
        mapping_re = mapping_relative_error(
            result.mapping.wavelength_nm(pixels[inside]),
            true_nm[inside],
            range_nm=(grid.start_nm, grid.stop_nm),
        )
    row = SyntheticRow(
        scene.camera,
        variant,
        noise,
        relative_error(result.physical_sensitivity(), scene.truth),
        mapping_re,
        None if true_mapping else result.mapping_re_estimate,
        elapsed,
        repeat,
        coverage=None if result.sensitivity_sigma is None else band_coverage(result, scene.truth),
        method_coverage=_method_coverage(result, scene.truth),
    )
    if on_result is not None:
        on_result(scene, row, result)
    return row


def _method_coverage(result: EstimateResult, truth: FloatArray) -> float | None:
    """:func:`band_coverage` of the method's own σ: ``diagnostics["method_sigma"]`` when a budget
    replaced it, else the σ the result states."""
    own = result.diagnostics.get("method_sigma", result.sensitivity_sigma)
    if own is None:
        return None
    return band_coverage(replace(result, sensitivity_sigma=np.asarray(own)), truth)


def band_coverage(result: EstimateResult, truth: FloatArray, *, width: float = 2.0) -> float:
    """Fraction of (wavelength, channel) cells whose true value lies within ±``width`` σ.

    ``truth`` ``(f, 3)`` is normalised like the estimate (maximum 1). Judged on the curve users
    get (:meth:`~calib.core.result.EstimateResult.camera_curves`: negative lobes set to zero).
    """
    curves = result.camera_curves()
    if curves.sigma is None:
        raise InputError("the estimate carries no σ", source=result.method)
    inside = np.abs(curves.values - truth) <= width * curves.sigma
    return float(np.mean(inside))


def efficiency_coverage(
    result: EstimateResult, truth: ArrayLike, *, width: float = 2.0
) -> tuple[float, float]:
    """Share of grid nodes whose true grating efficiency lies within ±``width`` σ of the estimate,
    and the ratio of the stated σ's RMS to the actual error's RMS.

    ``truth`` ``(f,)`` is η on the result's grid, in any units: it is normalised to its maximum
    over the grid, as the estimate is (only η's shape is estimated).

    Raises
    ------
    InputError
        When the estimate carries no η or no σ of it.
    """
    if result.grating_efficiency is None or result.grating_efficiency_sigma is None:
        raise InputError("the estimate carries no grating efficiency σ", source=result.method)
    reference = np.asarray(truth, dtype=np.float64)
    reference = reference / float(np.max(reference))
    error = np.asarray(result.grating_efficiency) - reference
    sigma = np.asarray(result.grating_efficiency_sigma)
    ratio = float(np.sqrt(np.nanmean(sigma**2)) / max(np.sqrt(np.mean(error**2)), 1e-300))
    return float(np.mean(np.abs(error) <= width * sigma)), ratio


def _estimate_variant(
    scene: SyntheticScene,
    basis: CameraBasis,
    variant: str,
    *,
    grid: WavelengthGrid,
    paper_solve: PaperSolve,
    multilamp_options: MultilampOptions,
    budget: BudgetSettings | None = DEFAULT_BUDGET,
) -> EstimateResult:
    """The variant's estimate, through :func:`calib.methods.estimate` with ``budget``."""
    led = scene.broadband.observation
    if variant in PAPER_VARIANTS:
        lamps = [led] if variant != "LED+Flu" else [led, scene.fluorescent.observation]
        mapping = scene.mapping if _uses_true_mapping(variant) else None
        mapping_method: SearchMethod = "icp" if variant == "LED only (paper ICP)" else "search"
        method = MAKABE2025_METHOD if isinstance(paper_solve, Makabe2025Options) else PRIOR_METHOD
        return estimate(
            lamps,
            method,
            basis=basis,
            grid=grid,
            budget=budget,
            mapping=mapping,
            options=replace(paper_solve, mapping_method=mapping_method, solve_lamps=(led.name,)),
        )
    if variant == "grating file: 1 LED":
        if not scene.calibration:
            raise InputError(
                "the grating-file variant needs calibration cameras in the scene",
                source="variant",
            )
        # The pooled η solve takes the multi-lamp rule and model (its terms follow the equations).
        grating, _ = refine_grating(
            scene.calibration,
            basis=basis,
            grid=grid,
            prior_weight=multilamp_options.prior_weight,
            efficiency_model=multilamp_options.efficiency_model,
            weight_rule=multilamp_options.weight_rule,
        )
        (single,) = (obs for obs in scene.lamp_sets[FIVE_LAMPS] if obs.name == GRATING_FILE_LAMP)
        return estimate(
            [single], KNOWN_GRATING_METHOD, basis=basis, grid=grid, budget=budget, grating=grating
        )
    set_name = variant.removeprefix("multilamp: ").removesuffix(", true mapping")
    return estimate(
        scene.lamp_sets[set_name],
        MULTILAMP_METHOD,
        basis=basis,
        grid=grid,
        budget=budget,
        mapping=scene.mapping if _uses_true_mapping(variant) else None,
        options=multilamp_options,
    )


def run_protocol(
    cameras: Sequence[tuple[str, MultiSpectrum]],
    basis: CameraBasis | Callable[[str], CameraBasis],
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    variants: Sequence[str] = PAPER_VARIANTS,
    noise_levels: Sequence[float] = NOISE_LEVELS,
    broadband_lamp: str = "D65",
    fluorescent_lamp: str = FLUORESCENT_LAMP,
    paper_solve: PaperSolve = PriorOptions(),
    repeats: int = 1,
    seed: int = 0,
    progress: Callable[[SyntheticRow], None] | None = None,
    direct_noise: float | None = None,
    multilamp_options: MultilampOptions = MultilampOptions(),
    budget: BudgetSettings | None = DEFAULT_BUDGET,
    on_result: ResultHook | None = None,
    only: Callable[[str, float], bool] | None = None,
) -> list[SyntheticRow]:
    """Run the protocol over cameras × noise levels × repeats × variants (see module docstring).

    Parameters
    ----------
    cameras
        ``(name, sensitivity)`` pairs, e.g. the 5 test cameras of :func:`calib.core.datasets.makabe2025_split`.
    basis
        Camera basis (e.g. from the 44 training cameras) on ``grid``, or a function of the camera's
        name giving one (e.g. the offline basis excluding that camera).
    paper_solve
        How the paper's variants solve: :class:`~calib.methods.prior_solve.PriorOptions` (the
        prior solve, default) or :class:`~calib.methods.makabe2025.Makabe2025Options` (the paper's).
    seed
        Master seed; scene ``(camera i, noise j, repeat r)`` uses ``default_rng([seed, i, j, r])``.

    The multi-lamp variants render their lamp sets after the paper's lamps, their direct
    measurements with noise ``direct_noise`` (fraction of the peak; ``None``: the profile's); the
    grating-file variant calibrates the grating with every *other* camera of ``cameras`` under the
    5 lamps. ``multilamp_options`` go to the multi-lamp solves (the grating-file variant's pooled
    η solve takes their rule, model and fixed weight). ``budget``: the σ budget every estimate
    states (:func:`calib.methods.estimate`; ``None``: the methods' own σ); ``on_result`` as for
    :func:`evaluate_scene`.
    """
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        raise InputError(f"unknown variants {unknown}; choose from {VARIANTS}", source="variants")
    broadband = colour_lamp(broadband_lamp)
    fluorescent = colour_lamp(fluorescent_lamp)
    _ = fourier_basis(grid)  # validates the grid early
    grating_variant = "grating file: 1 LED" in variants
    lamp_sets = [
        name
        for name in LAMP_SETS
        if any(v.startswith(f"multilamp: {name}") for v in variants)
        or (grating_variant and name == FIVE_LAMPS)
    ]
    rows: list[SyntheticRow] = []
    for camera_index, (name, sensitivity) in enumerate(cameras):
        for noise_index, noise in enumerate(noise_levels):
            if only is not None and not only(name, noise):
                continue
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
                    lamp_sets=lamp_sets,
                    calibration_cameras=[
                        other for index, (_, other) in enumerate(cameras) if index != camera_index
                    ]
                    if grating_variant
                    else (),
                    direct_noise_fraction=direct_noise,
                )
                scene_basis = basis(name) if callable(basis) else basis
                for variant in variants:
                    row = evaluate_scene(
                        scene,
                        scene_basis,
                        variant,
                        grid=grid,
                        paper_solve=paper_solve,
                        noise=noise,
                        repeat=repeat,
                        multilamp_options=multilamp_options,
                        budget=budget,
                        on_result=on_result,
                    )
                    rows.append(row)
                    if progress is not None:
                        progress(row)
    return rows
