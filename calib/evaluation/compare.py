"""Every registered method side by side on the same data: RE per camera × method, with wall times.

Data source (a :class:`SceneSource`): :class:`SyntheticSource`, the synthetic protocol of Makabe et al.
(2025) §4.1 — for each test camera and noise level a scene with

* the broadband lamp (D65) and a fluorescent lamp (FL2) through the grating (direct RGB + first-order
  profile, random quadratic mapping, random smooth grating efficiency: :func:`calib.evaluation.synthetic.render_scene`),
* the 24-patch ColorChecker (colour-science, BabelColor average) under the broadband lamp,
* the camera's colour matrices for illuminants A and D65, as a maker would fit them
  (:func:`calib.methods.baselines.solomatov2023.simulate_color_matrix`),
* ``n`` Gaussian transmissive filters in front of the broadband lamp (Makabe et al. Supp. G),

with Gaussian noise of the same fraction of the peak on profiles, direct RGB and patch values. Scene
``(camera i, noise j, repeat r)`` draws from ``default_rng([seed, i, j, r])`` (the same scenes as
``calib synthetic``); the charts' noise from ``default_rng([seed, i, j, r, k])``.

Methods: :func:`synthetic_adapters` says, per column, which registered method runs on which inputs
(observations, and the keywords that method declares: basis, mapping, its typed options …) through
the front function :func:`calib.methods.estimate`, which refuses any input the method does not
declare. A method registered in :data:`calib.methods.ESTIMATION_METHODS` without a column here is
listed in the report as skipped.

Captured sessions (the digital twin's, whose truth file says which camera it really has) hold only
the lamps seen through the grating: no chart, no colour matrices. They come as :class:`GratingScene`
records (``rig.compare`` reads the sessions: ``calib`` imports nothing of ``rig``), run through
:data:`grating_adapters`' columns; :func:`active_grating_adapters` lists the methods and columns
that need data a grating capture does not hold (:data:`GRATING_SKIP_REASONS`) as skipped, with the
reason.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.colour_data import colorchecker
from calib.core.errors import CalibError, InputError
from calib.core.lamp_specs import colour_lamp
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.metrics import relative_error
from calib.core.observations import (
    ChartObservation,
    ColorMatrixObservation,
    LampObservation,
    Observation,
)
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, WavelengthGrid
from calib.evaluation.synthetic import FLUORESCENT_LAMP, render_scene
from calib.methods import ESTIMATION_METHODS, PriorOptions, estimate, method_names
from calib.methods.baselines.han2012 import render_fluorescent_chart, synthetic_fluorescent_paints
from calib.methods.baselines.solomatov2023 import simulate_color_matrix
from calib.methods.baselines.toivonen2020 import ToivonenSettings
from calib.model.bases import CameraBasis
from calib.model.charts import gaussian_filters, render_chart

#: Noise levels of the comparison by default (fractions of the peak): ideal data, and 1 %.
DEFAULT_NOISE_LEVELS: tuple[float, ...] = (0.0, 0.01)
#: Gaussian transmissive filters for the many-patch Toivonen column ("stable for N > 10").
DEFAULT_TRANSMISSIVE_PATCHES = 16
#: Calibration illuminants of the simulated colour matrices (DNG ColorMatrix1/2 are usually these).
MATRIX_ILLUMINANTS: tuple[str, ...] = ("A", "D65")


@dataclass(frozen=True, eq=False)
class CompareScene:
    """One camera's data for every method.

    Attributes
    ----------
    camera
        Camera name.
    sensitivity
        The camera's measured curves as given (for adapters that render data of their own).
    grid
        The working grid.
    truth
        Shape ``(f, 3)``: the true sensitivity on the grid, maximum 1.
    basis
        The camera basis for this scene (trained without this camera).
    broadband, fluorescent
        The lamps seen through the grating.
    mapping
        The true pixel→wavelength mapping.
    chart
        ColorChecker under the broadband lamp.
    transmissive
        Gaussian transmissive filters in front of the broadband lamp.
    color_matrices
        The camera's XYZ→camera matrices.
    noise
        Noise fraction of the scene; ``repeat`` its repeat index.
    seed
        An integer seed derived from the scene's, for methods with random starts (and for adapters
        that draw data of their own).
    """

    camera: str
    sensitivity: MultiSpectrum
    grid: WavelengthGrid
    truth: FloatArray
    basis: CameraBasis
    broadband: LampObservation
    fluorescent: LampObservation
    mapping: QuadraticMapping
    chart: ChartObservation
    transmissive: ChartObservation
    color_matrices: ColorMatrixObservation
    noise: float
    repeat: int
    seed: int


#: How a scene becomes a method's input: ``(observations, options for calib.methods.estimate)``.
SceneBuilder = Callable[[CompareScene], tuple[list[Observation], dict[str, Any]]]


@dataclass(frozen=True)
class SyntheticAdapter:
    """One column of the comparison.

    Attributes
    ----------
    label
        Column name (``"jiang2013 (CC)"``).
    method
        Registry name.
    build
        The scene → input function.
    note
        What the column means (shown under the table).
    """

    label: str
    method: str
    build: SceneBuilder
    note: str = ""


def _lamps_led_flu(scene: CompareScene) -> tuple[list[Observation], dict[str, Any]]:
    return [scene.broadband, scene.fluorescent], {
        "basis": scene.basis,
        "options": PriorOptions(solve_lamps=(scene.broadband.name,)),
    }


def _lamp_true_mapping(scene: CompareScene) -> tuple[list[Observation], dict[str, Any]]:
    return [scene.broadband], {"basis": scene.basis, "mapping": scene.mapping}


def _colour_checker(scene: CompareScene) -> tuple[list[Observation], dict[str, Any]]:
    return [scene.chart], {"basis": scene.basis}


def _fluorescent_chart(scene: CompareScene) -> tuple[list[Any], dict[str, Any]]:
    rng = np.random.default_rng([scene.seed, 2012])
    chart = render_fluorescent_chart(
        synthetic_fluorescent_paints(rng),
        colorchecker(),
        scene.sensitivity,
        colour_lamp(scene.broadband.name),
        rng=rng,
        noise_fraction=scene.noise,
    )
    # The method's default, the paper's Fourier basis: it needs neither the light nor measured
    # cameras.
    return [chart], {}


def _matrices_and_checker(scene: CompareScene) -> tuple[list[Observation], dict[str, Any]]:
    return [scene.color_matrices, scene.chart], {"basis": scene.basis}


def toivonen_settings(overrides: Mapping[str, Any] | None) -> ToivonenSettings:
    """:class:`~calib.methods.baselines.toivonen2020.ToivonenSettings` with a command line's
    overrides (``ensemble_size``, ``epochs`` …), checked once."""
    return replace(ToivonenSettings(), **dict(overrides or {}))


def _toivonen(
    n_patches: int, settings: ToivonenSettings
) -> Callable[[CompareScene], tuple[list[Observation], dict[str, Any]]]:
    def build(scene: CompareScene) -> tuple[list[Observation], dict[str, Any]]:
        options = {
            "basis": scene.basis,
            "mapping": scene.mapping,
            "seed": scene.seed,
            "settings": settings,
        }
        if n_patches <= 1:
            return [scene.broadband], {**options, "direct_as_patch": True}
        return [scene.broadband, scene.transmissive], {**options, "direct_as_patch": False}

    return build


def _multilamp(scene: CompareScene) -> tuple[list[Observation], dict[str, Any]]:
    return [scene.broadband, scene.fluorescent], {"basis": scene.basis}


def synthetic_adapters(
    *, n_patches: int = DEFAULT_TRANSMISSIVE_PATCHES, toivonen: Mapping[str, Any] | None = None
) -> tuple[SyntheticAdapter, ...]:
    """The adapter table: one entry per column, in table order.

    Parameters
    ----------
    n_patches
        Gaussian transmissive filters in the many-patch Toivonen column.
    toivonen
        Overrides of the Toivonen columns' settings (``ensemble_size``, ``epochs`` …).
    """
    settings = toivonen_settings(toivonen)
    return (
        SyntheticAdapter(
            "prior (LED+Flu)",
            "prior",
            _lamps_led_flu,
            "the prior solve: mapping from the fluorescent lamp, solve with the broadband lamp",
        ),
        SyntheticAdapter(
            "prior (true mapping)",
            "prior",
            _lamp_true_mapping,
            "the prior solve alone, given the true mapping",
        ),
        SyntheticAdapter(
            "makabe2025 (true mapping)",
            "makabe2025",
            _lamp_true_mapping,
            "the paper's closed-form solve as printed, given the true mapping",
        ),
        SyntheticAdapter(
            "multilamp",
            "multilamp",
            _multilamp,
            "broadband and fluorescent lamps solved jointly",
        ),
        SyntheticAdapter(
            "jiang2013 (CC)", "jiang2013", _colour_checker, "ColorChecker under the broadband lamp"
        ),
        SyntheticAdapter(
            "han2012 (fluorescent chart)",
            "han2012",
            _fluorescent_chart,
            "16 synthetic fluorescent paints + a ColorChecker under the broadband lamp, which the "
            "method is not told; the paper's Fourier basis",
        ),
        SyntheticAdapter(
            "solomatov2023 (Exif+CC)",
            "solomatov2023",
            _matrices_and_checker,
            "colour matrices for A and D65, channel scales from the ColorChecker",
        ),
        SyntheticAdapter(
            "toivonen2020 (1 patch)",
            "toivonen2020",
            _toivonen(1, settings),
            "broadband profile, its direct light as the only patch, true mapping",
        ),
        SyntheticAdapter(
            f"toivonen2020 ({n_patches} patches)",
            "toivonen2020",
            _toivonen(n_patches, settings),
            f"broadband profile + {n_patches} Gaussian transmissive patches, true mapping",
        ),
    )


def _wanted_methods(methods: Sequence[str] | None) -> list[str]:
    """Registry names asked for (default: all registered), refusing unknown ones."""
    registered = sorted(ESTIMATION_METHODS)
    wanted = registered if methods is None else [m.lower() for m in methods]
    unknown = [m for m in wanted if m not in method_names()]
    if unknown:
        raise InputError(
            f"unknown methods {unknown}; registered: {', '.join(method_names())}",
            source="--method",
        )
    return wanted


def active_adapters(
    adapters: Sequence[SyntheticAdapter], methods: Sequence[str] | None = None
) -> tuple[list[SyntheticAdapter], list[str]]:
    """The columns to run, and the registered methods without a way to feed them synthetic data.

    Parameters
    ----------
    adapters
        The adapter table.
    methods
        Restrict to these registry names (default: every registered method).
    """
    wanted = _wanted_methods(methods)
    chosen = [adapter for adapter in adapters if adapter.method in wanted]
    covered = {adapter.method for adapter in adapters}
    skipped = [method for method in wanted if method not in covered]
    return chosen, skipped


# ---------------------------------------------------------------------------------- scenes


class SceneSource(Protocol):
    """Where comparison scenes come from (synthetic protocol now; twin sessions later)."""

    @property
    def description(self) -> str:
        """One line for the report (what the data are, which basis)."""
        ...

    def scenes(self) -> Iterator[CompareScene]:
        """Every scene, in a fixed order."""
        ...


@dataclass(frozen=True, eq=False)
class SyntheticSource:
    """The synthetic protocol of Makabe et al. (2025) §4.1 extended with the chart methods' data.

    Attributes
    ----------
    cameras
        ``(name, sensitivity)`` pairs (the 5 test cameras, or colour-science's offline).
    basis
        The camera basis, or a function of the camera name giving one (offline: each camera
        left out of its own basis).
    noise_levels, repeats, seed
        Scenes per camera; master seed.
    broadband_lamp, fluorescent_lamp
        colour-science names.
    n_patches
        Gaussian transmissive filters.
    colorchecker_name
        colour-science ColorChecker data.
    grid
        Working grid.
    basis_description
        For the report.
    """

    cameras: Sequence[tuple[str, MultiSpectrum]]
    basis: CameraBasis | Callable[[str], CameraBasis]
    noise_levels: Sequence[float] = DEFAULT_NOISE_LEVELS
    repeats: int = 1
    seed: int = 0
    broadband_lamp: str = "D65"
    fluorescent_lamp: str = FLUORESCENT_LAMP
    n_patches: int = DEFAULT_TRANSMISSIVE_PATCHES
    colorchecker_name: str = "BabelColor Average"
    grid: WavelengthGrid = DEFAULT_GRID
    basis_description: str = ""

    @property
    def description(self) -> str:
        noise = ", ".join(f"{n * 100:g} %" for n in self.noise_levels)
        return (
            f"synthetic protocol (Makabe et al. 2025 §4.1): {len(self.cameras)} cameras, lamps "
            f"{self.broadband_lamp} + {self.fluorescent_lamp}, ColorChecker "
            f"({self.colorchecker_name}), {self.n_patches} Gaussian filters, noise {noise}, "
            f"{self.repeats} repeat(s), seed {self.seed}; basis: {self.basis_description}"
        )

    def scenes(self) -> Iterator[CompareScene]:
        if self.repeats < 1:
            raise InputError(f"repeats must be >= 1, got {self.repeats}", source="repeats")
        broadband = colour_lamp(self.broadband_lamp)
        fluorescent = colour_lamp(self.fluorescent_lamp)
        checker = colorchecker(self.colorchecker_name)
        filters = gaussian_filters(self.n_patches, range_nm=(self.grid.start_nm, self.grid.stop_nm))
        for camera_index, (name, sensitivity) in enumerate(self.cameras):
            scene_basis = self.basis(name) if callable(self.basis) else self.basis
            on_grid = sensitivity.resample(self.grid, "interpolate", out_of_range="zero").values
            matrices = ColorMatrixObservation(
                name,
                np.stack(
                    [
                        simulate_color_matrix(on_grid, light, self.grid)
                        for light in MATRIX_ILLUMINANTS
                    ]
                ),
                MATRIX_ILLUMINANTS,
                source="simulated (least squares over ColorChecker N Ohta + CIE 2024 TCS)",
            )
            for noise_index, noise in enumerate(self.noise_levels):
                for repeat in range(self.repeats):
                    key = [self.seed, camera_index, noise_index, repeat]
                    rendered = render_scene(
                        name,
                        sensitivity,
                        np.random.default_rng(key),
                        grid=self.grid,
                        broadband_lamp=broadband,
                        fluorescent_lamp=fluorescent,
                        noise_fraction=noise,
                    )
                    chart = render_chart(
                        checker,
                        broadband,
                        sensitivity,
                        noise_fraction=noise,
                        rng=np.random.default_rng([*key, 1]),
                    )
                    transmissive = render_chart(
                        filters,
                        broadband,
                        sensitivity,
                        kind="transmissive",
                        noise_fraction=noise,
                        rng=np.random.default_rng([*key, 2]),
                    )
                    yield CompareScene(
                        camera=name,
                        sensitivity=sensitivity,
                        grid=self.grid,
                        truth=rendered.truth,
                        basis=scene_basis,
                        broadband=rendered.broadband.observation,
                        fluorescent=rendered.fluorescent.observation,
                        mapping=rendered.mapping,
                        chart=chart,
                        transmissive=transmissive,
                        color_matrices=matrices,
                        noise=noise,
                        repeat=repeat,
                        seed=int(np.random.default_rng([*key, 3]).integers(2**31)),
                    )


# ---------------------------------------------------------------------------------- running


@dataclass(frozen=True, eq=False)
class CompareRow:
    """One method on one scene.

    Attributes
    ----------
    camera, label, method, noise, repeat
        Which scene and column.
    relative_error
        RE (Makabe et al. Eq. 16, a fraction); NaN when the method failed.
    time_s
        Wall time of the estimate call (s).
    failure
        The error message when the method failed.
    estimate
        The estimated curves ``(f, 3)`` (max 1) and ``truth`` ``(f, 3)``, for the plots.
    """

    camera: str
    label: str
    method: str
    noise: float
    repeat: int
    relative_error: float
    time_s: float
    failure: str | None = None
    estimate: FloatArray | None = field(default=None, repr=False)
    truth: FloatArray | None = field(default=None, repr=False)


def run_scene(scene: CompareScene, adapter: SyntheticAdapter, grid: WavelengthGrid) -> CompareRow:
    """Run one adapter on one scene, timing only the estimate call."""
    return _run_adapter(
        adapter, adapter.build(scene), grid, scene.camera, scene.noise, scene.repeat, scene.truth
    )


def _run_adapter(
    adapter: SyntheticAdapter | GratingAdapter,
    inputs: tuple[list[Observation], dict[str, Any]],
    grid: WavelengthGrid,
    camera: str,
    noise: float,
    repeat: int,
    truth: FloatArray,
) -> CompareRow:
    """The row of one adapter on its built ``inputs`` (the scene's ``truth`` scores it)."""
    observations, options = inputs
    curves, elapsed, failure = _timed_estimate(observations, adapter.method, grid, options)
    return CompareRow(
        camera,
        adapter.label,
        adapter.method,
        noise,
        repeat,
        float("nan") if curves is None else relative_error(curves, truth),
        elapsed,
        failure=failure,
        estimate=curves,
        truth=truth,
    )


def _timed_estimate(
    observations: Sequence[Observation], method: str, grid: WavelengthGrid, options: dict[str, Any]
) -> tuple[FloatArray | None, float, str | None]:
    """The estimated curves (``None`` on failure), the call's wall time and the failure message."""
    started = time.perf_counter()
    failure: str | None = None
    curves: FloatArray | None = None
    try:
        result: EstimateResult = estimate(observations, method=method, grid=grid, **options)
        curves = result.physical_sensitivity()  # what `calib estimate` writes
    except CalibError as exc:
        failure = str(exc)
    return curves, time.perf_counter() - started, failure


def run_comparison(
    source: SceneSource,
    adapters: Sequence[SyntheticAdapter],
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    progress: Callable[[CompareRow], None] | None = None,
) -> list[CompareRow]:
    """Every adapter on every scene of ``source``, in order (scene-major)."""
    rows: list[CompareRow] = []
    for scene in source.scenes():
        for adapter in adapters:
            row = run_scene(scene, adapter, grid)
            rows.append(row)
            if progress is not None:
                progress(row)
    return rows


# ---------------------------------------------------------------------------------- captured sessions


@dataclass(frozen=True, eq=False)
class GratingScene:
    """One captured session's data: the lamps seen through the grating, and the true camera.

    Attributes
    ----------
    camera
        The true camera's name.
    session
        The session's name (its directory), to tell scenes of one camera apart.
    grid
        The working grid.
    truth
        Shape ``(f, 3)``: the true sensitivity on the grid, maximum 1.
    basis
        The camera basis (trained without the true camera).
    lamps
        Every lamp as the offline pipeline extracted it (profile, direct RGB, spectrum).
    mapping
        The true pixel→wavelength mapping on the profiles' axis, or ``None`` when unknown.
    seed
        An integer seed for methods with random starts.
    """

    camera: str
    session: str
    grid: WavelengthGrid
    truth: FloatArray
    basis: CameraBasis
    lamps: tuple[LampObservation, ...]
    mapping: QuadraticMapping | GratingGeometry | None
    seed: int = 0

    @property
    def label(self) -> str:
        """The scene's row in the table: camera and session."""
        return f"{self.camera} · {self.session}"

    @property
    def solve_lamp(self) -> LampObservation:
        """The lamp the single-lamp columns use: the first non-fluorescent lamp with a direct
        measurement, else the first lamp with one, else the first lamp."""
        direct = [lamp for lamp in self.lamps if lamp.direct_rgb is not None]
        broadband = [lamp for lamp in direct if lamp.kind != "fluorescent"]
        return (broadband or direct or list(self.lamps))[0]


#: How a grating scene becomes a method's input: ``(observations, options for calib.methods.estimate)``.
GratingSceneBuilder = Callable[[GratingScene], tuple[list[Observation], dict[str, Any]]]


@dataclass(frozen=True)
class GratingAdapter:
    """One column of a comparison on captured sessions (see :class:`SyntheticAdapter`)."""

    label: str
    method: str
    build: GratingSceneBuilder
    note: str = ""


#: Methods that need data a grating capture does not hold: registry name → why it is skipped.
GRATING_SKIP_REASONS: dict[str, str] = {
    "jiang2013": "needs a ColorChecker image under a known illuminant; a grating session has none",
    "solomatov2023": (
        "needs the camera's colour matrices and a ColorChecker image; a grating session has neither"
    ),
    "han2012": "needs an image of a fluorescent chart and a reference chart; a grating session "
    "has none",
}


def _session_all_lamps(scene: GratingScene) -> tuple[list[Observation], dict[str, Any]]:
    return list(scene.lamps), {"basis": scene.basis}


def _session_true_mapping(scene: GratingScene) -> tuple[list[Observation], dict[str, Any]]:
    return [scene.solve_lamp], {"basis": scene.basis, "mapping": scene.mapping}


def _session_toivonen(
    settings: ToivonenSettings,
) -> Callable[[GratingScene], tuple[list[Observation], dict[str, Any]]]:
    def build(scene: GratingScene) -> tuple[list[Observation], dict[str, Any]]:
        return [scene.solve_lamp], {
            "basis": scene.basis,
            "mapping": scene.mapping,
            "seed": scene.seed,
            "direct_as_patch": True,
            "settings": settings,
        }

    return build


def grating_adapters(*, toivonen: Mapping[str, Any] | None = None) -> tuple[GratingAdapter, ...]:
    """The columns a grating capture can feed, in table order.

    Parameters
    ----------
    toivonen
        Overrides of the Toivonen column's settings (``ensemble_size``, ``epochs`` …).
    """
    return (
        GratingAdapter(
            "prior (all lamps)",
            "prior",
            _session_all_lamps,
            "the prior solve on every lamp of the session (the estimator finds the mapping); "
            "what `rig estimate` runs when fewer than 3 lamps have a direct measurement",
        ),
        GratingAdapter(
            "prior (true mapping)",
            "prior",
            _session_true_mapping,
            "the prior solve alone on one lamp (the broadband one when its direct spot was "
            "measured), given the twin's true mapping",
        ),
        GratingAdapter(
            "makabe2025 (true mapping)",
            "makabe2025",
            _session_true_mapping,
            "the paper's closed-form solve as printed on the same lamp, given the twin's true "
            "mapping",
        ),
        GratingAdapter(
            "multilamp", "multilamp", _session_all_lamps, "every lamp of the session solved jointly"
        ),
        GratingAdapter(
            "toivonen2020 (1 patch)",
            "toivonen2020",
            _session_toivonen(toivonen_settings(toivonen)),
            "the same lamp's profile, its direct light as the only patch, the twin's true mapping",
        ),
    )


def active_grating_adapters(
    adapters: Sequence[GratingAdapter],
    methods: Sequence[str] | None = None,
    *,
    n_patches: int = DEFAULT_TRANSMISSIVE_PATCHES,
) -> tuple[list[GratingAdapter], list[tuple[str, str]]]:
    """The columns to run on captured sessions, and the skipped ones with the reason.

    Parameters
    ----------
    adapters
        The adapter table (:func:`grating_adapters`).
    methods
        Restrict to these registry names (default: every registered method).
    n_patches
        The synthetic comparison's many-patch Toivonen column, named as skipped.

    Returns
    -------
    tuple
        The adapters to run, and ``(column or method, reason)`` for everything skipped.
    """
    wanted = _wanted_methods(methods)
    chosen = [adapter for adapter in adapters if adapter.method in wanted]
    covered = {adapter.method for adapter in adapters}
    skipped: list[tuple[str, str]] = []
    for method in wanted:
        if method == "toivonen2020":
            skipped.append(
                (
                    f"toivonen2020 ({n_patches} patches)",
                    "needs transmissive filter patches in front of the broadband lamp; a grating "
                    "session holds only the direct light as a patch",
                )
            )
        elif method not in covered:
            skipped.append(
                (method, GRATING_SKIP_REASONS.get(method, "no adapter for captured sessions"))
            )
    return chosen, skipped


class GratingSceneSource(Protocol):
    """Where grating scenes come from (``rig.compare``: captured twin sessions)."""

    @property
    def description(self) -> str:
        """One line for the report (what the data are, which basis)."""
        ...

    def scenes(self) -> Iterator[GratingScene]:
        """Every scene, in a fixed order."""
        ...


def run_grating_comparison(
    source: GratingSceneSource,
    adapters: Sequence[GratingAdapter],
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    progress: Callable[[CompareRow], None] | None = None,
) -> list[CompareRow]:
    """Every adapter on every grating scene, in order (scene-major).

    The rows' ``camera`` is the scene's :attr:`GratingScene.label`; ``noise`` is NaN (a capture's
    noise is whatever the sensor gave, not a protocol parameter) and ``repeat`` 0.
    """
    rows: list[CompareRow] = []
    for scene in source.scenes():
        for adapter in adapters:
            row = _run_adapter(
                adapter, adapter.build(scene), grid, scene.label, float("nan"), 0, scene.truth
            )
            rows.append(row)
            if progress is not None:
                progress(row)
    return rows
