"""Run the validation protocol: every camera of a split × scenes × method variants, scored.

For each camera and scene the plan is drawn from ``SeedSequence([seed, camera id, scene])`` (the
camera id is a hash of its name, so adding a camera changes no other camera's scenes), rendered
once (:mod:`~calib.evaluation.validation.scenes`), and every method variant estimates from its own
lamps of that one scene through the registry (:func:`calib.methods.estimate`) with the camera's
basis (:meth:`~calib.evaluation.validation.splits.Split.basis_records`). Scenes run in worker
processes; each task's result depends on its seed alone, so the rows are the same for any number
of jobs (only the wall times differ).

Scores per estimate (:class:`ValidationRow`):

- RE per channel (Makabe et al. 2025 Eq. 16's terms, :func:`calib.core.metrics.channel_relative_errors`)
  of the delivered curves (:meth:`calib.core.result.EstimateResult.physical_sensitivity`);
- ±2σ coverage per channel: the share of grid wavelengths where the truth lies within twice the
  stated σ of the delivered curves (the same curve, negative lobes set to zero; both normalised to
  a maximum of 1);
- σ ratio per channel: RMS of the actual error over RMS of the stated σ (1 when σ is honest, > 1
  when it is too small); the stated σ is the budget's (:mod:`calib.methods.uncertainty`), and the
  coverage of the method's own σ (``diagnostics["method_sigma"]``) is kept beside it;
- the mapping: mean ``|Δλ|`` over the profile's pixels inside the grid (nm), its RE
  (Supp. Eq. 1), the share of those pixels with ``|Δλ| ≤ 2σ_λ(p)`` (σ from the mapping's
  covariance) and RMS ``Δλ`` over RMS ``σ_λ``.

Tuning: :func:`tune_rows` and :func:`tuning_score` take only the validation split
(:func:`~calib.evaluation.validation.splits.require_validation`); :func:`run_split` reports any
split.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.lamp_specs import RGB_LEDS, lamp_from_spec
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.metrics import channel_relative_errors, mapping_relative_error
from calib.core.observations import LampObservation
from calib.core.result import EstimateResult, mapping_warned
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.evaluation.validation.rig_errors import RigErrors
from calib.evaluation.validation.scenes import (
    GeometryRanges,
    RenderedScene,
    ScenePlan,
    draw_scene_plan,
    render_scene,
    with_exif_optics,
)
from calib.evaluation.validation.splits import (
    Split,
    SplitCamera,
    ValidationSplit,
    load_splits,
    require_validation,
)
from calib.methods import MethodOptions
from calib.methods.known_grating import KnownGratingOptions
from calib.model.bases import DEFAULT_N_VECTORS, CameraBasis, camera_basis
from calib.model.gratings import CatalogueGrating, GratingKind

#: Registry names the variants run (what ``auto`` chooses for their lamps: the prior solve below
#: three lamps with a direct measurement, multilamp from three); a rename is a change here, once.
TWO_LAMP_METHOD = "prior"
MULTILAMP_METHOD = "multilamp"
#: The paper's own solve (Makabe et al. 2025, Eq. 12), for comparison.
PAPER_METHOD = "makabe2025"
#: The registry's own choice (:func:`calib.methods.choose_method`), as ``calib estimate`` makes it.
AUTO_METHOD = "auto"
PixelOrigin = Literal["direct_spot", "arbitrary"]
CHANNELS = ("r", "g", "b")


@dataclass(frozen=True)
class MethodVariant:
    """A method of the registry with its lamps and options: one column of results.

    Attributes
    ----------
    label
        The name in the tables (``"LED+FL"``).
    method
        Registry name (:data:`calib.methods.ESTIMATION_METHODS`).
    lamps
        Lamp specs (:func:`calib.core.lamp_specs.lamp_from_spec`) it is given, from one scene.
    options
        The method's typed options (:data:`calib.methods.MethodOptions`), ``None`` for its defaults.
    exif_optics
        Whether its profiles carry the optics a RAW capture records (the lens' focal length and
        the pixel pitch, :func:`~calib.evaluation.validation.scenes.exif_optics`); ``False``
        measures the case of profile CSVs or RAW files without those tags.
    direct
        Whether its lamps come with their direct (0th-order) measurement; ``False`` measures a
        capture of the first order alone (no grating file either: ``auto`` then goes through
        the known-grating solve with the grating's efficiency assumed, ``assume_flat_grating``).
    unmeasured
        ``(lamp, nominal spec)`` pairs: lamps whose spectrum nobody measured, given to the
        estimator as the nominal spectrum (a built-in line list) marked
        ``spectrum_known=False`` (``auto`` uses them for the mapping only), while the scene
        renders the lamp as it really shines.
    """

    label: str
    method: str
    lamps: tuple[str, ...]
    options: MethodOptions | None = None
    exif_optics: bool = True
    direct: bool = True
    unmeasured: tuple[tuple[str, str], ...] = ()


FIVE_LAMPS: tuple[str, ...] = ("LED-B1", "LED-B3", "LED-B5", "FL2", "A")
DEFAULT_VARIANTS: tuple[MethodVariant, ...] = (
    MethodVariant("LED+FL", TWO_LAMP_METHOD, ("LED-B3", "FL2")),
    MethodVariant("LED only", TWO_LAMP_METHOD, ("LED-B3",)),
    MethodVariant("LED only, no EXIF", TWO_LAMP_METHOD, ("LED-B3",), exif_optics=False),
    MethodVariant("5 lamps", MULTILAMP_METHOD, FIVE_LAMPS),
    MethodVariant("3 lamps + RGB LEDs", MULTILAMP_METHOD, ("LED-B3", "FL2", "A", *RGB_LEDS)),
)


#: The nominal spectrum a user gives for a fluorescent lamp nobody measured: its mercury lines,
#: the ones every fluorescent lamp has at physical wavelengths (the real D7000 pair's CFL, a
#: tri-phosphor lamp, gets ``builtin:cfl-triphosphor``; FL2 is a halophosphate lamp, whose only
#: lines are mercury's).
UNMEASURED_FL_SPEC = "builtin:hg"
#: The real D7000 set-up (``bench/real_grating.py``, Butcher's August pair) as a variant: a
#: halogen lamp with its measured spectrum and a fluorescent lamp whose spectrum nobody measured
#: (for the mapping only), the first order alone — no direct measurement, no grating file.
NO_DIRECT_VARIANT = MethodVariant(
    "A + FL unmeasured, no direct",
    AUTO_METHOD,
    ("FL2", "A"),
    direct=False,
    unmeasured=(("FL2", UNMEASURED_FL_SPEC),),
)
#: The same set-up with η₁ marginalised over the physical grating families and the flat
#: candidate instead of flat (``KnownGratingOptions(assumed_grating="physical")``, decisions 0074
#: and 0088; ``bench/assumed_eta.py`` takes the population apart).
NO_DIRECT_PHYSICAL_VARIANT = replace(
    NO_DIRECT_VARIANT,
    label="A + FL unmeasured, no direct, physical η",
    options=KnownGratingOptions(assumed_grating="physical"),
)

#: Variants a run may ask for besides the defaults.
EXTRA_VARIANTS: tuple[MethodVariant, ...] = (
    MethodVariant("LED+FL, paper's solve", PAPER_METHOD, ("LED-B3", "FL2")),
    NO_DIRECT_VARIANT,
    NO_DIRECT_PHYSICAL_VARIANT,
)


def protocol_gratings(
    text: str, catalogue: Path | str | None
) -> tuple[tuple[GratingKind, ...], CatalogueGrating | None]:
    """The grating kinds a run draws from (``--grating``: ``mix``, a kind, or a comma-separated
    list) and the maker's curve ``catalogue`` gives (a file, or ``None``). ``mix`` without a curve
    leaves the catalogue kind out; asking for it by name without one, or for an unknown kind, is an
    :class:`~calib.core.errors.InputError` naming ``--grating`` (``calib validate``, the budget
    and the benches share this one reading)."""
    from calib.core.errors import InputError
    from calib.model.gratings import GRATING_KINDS

    if text == "mix":
        kinds: tuple[GratingKind, ...] = GRATING_KINDS
    else:
        asked = tuple(part.strip() for part in text.split(",") if part.strip())
        unknown = [kind for kind in asked if kind not in GRATING_KINDS]
        if unknown or not asked:
            raise InputError(
                f"unknown grating kind {', '.join(unknown) or 'none'}; use "
                f"{', '.join(GRATING_KINDS)}, a comma-separated list of them, or mix",
                source="--grating",
            )
        kinds = tuple(kind for kind in GRATING_KINDS if kind in asked)
    curve = None if catalogue is None else CatalogueGrating.from_file(catalogue)
    if "catalogue" in kinds and curve is None:
        if text != "mix":
            raise InputError(
                "the catalogue grating needs the maker's curve: --catalogue FILE",
                source="--grating",
            )
        kinds = tuple(kind for kind in kinds if kind != "catalogue")
    return kinds, curve


def scene_lamps(variants: Sequence[MethodVariant]) -> tuple[str, ...]:
    """Every lamp the default variants and ``variants`` use, in first-use order (one scene renders
    them all).

    The defaults' lamps come first whichever variants run, so a run of some variants
    (``calib validate --variant …``) draws the same scenes, to the bit, as the full run: its rows
    can be compared with that run's.
    """
    chosen = (*DEFAULT_VARIANTS, *variants)
    return tuple(dict.fromkeys(lamp for variant in chosen for lamp in variant.lamps))


@dataclass(frozen=True, eq=False)
class ProtocolSettings:
    """What a run draws and runs (decision 0023 explains the defaults).

    Attributes
    ----------
    seed
        Master seed.
    scenes
        Scenes per camera.
    grating_kinds
        Each scene's grating kind is drawn uniformly from these.
    catalogue
        The maker's curve, for ``"catalogue"``.
    errors, geometry
        The rig's errors and the geometry's ranges.
    variants
        The methods run on every scene.
    pixel_origin
        ``"direct_spot"`` (profiles as the rig extracts them) or ``"arbitrary"`` (a profile CSV
        whose pixels have no known origin).
    """

    seed: int = 0
    scenes: int = 1
    grid: WavelengthGrid = DEFAULT_GRID
    grating_kinds: tuple[GratingKind, ...] = ("sinusoidal",)
    catalogue: CatalogueGrating | None = None
    errors: RigErrors = field(default_factory=RigErrors)
    geometry: GeometryRanges = field(default_factory=GeometryRanges)
    variants: tuple[MethodVariant, ...] = DEFAULT_VARIANTS
    n_vectors: int = DEFAULT_N_VECTORS
    pixel_origin: PixelOrigin = "direct_spot"

    def describe(self) -> str:
        """One line for the report."""
        errors = [name for name, value in self.errors.to_dict().items() if value is not None]
        return (
            f"seed {self.seed}, {self.scenes} scene(s) per camera, gratings "
            f"{'/'.join(self.grating_kinds)}, errors: {', '.join(errors)}, profile pixels "
            f"{self.pixel_origin.replace('_', ' ')}, grid {self.grid}, {self.n_vectors} basis "
            "vectors per channel"
        )


@dataclass(frozen=True)
class ValidationRow:
    """One estimate of one variant on one scene of one camera, scored (module docstring).

    Per-channel values are ``(r, g, b)``; ``None`` where the estimate gives no σ or no mapping.
    """

    split: str
    camera: str
    body: str
    group: str
    collection: str
    scene: int
    variant: str
    method: str
    channel_re: tuple[float, float, float] | None
    coverage: tuple[float, float, float] | None
    sigma_ratio: tuple[float, float, float] | None
    mapping_mean_abs_nm: float | None
    mapping_re: float | None
    mapping_coverage: float | None
    mapping_sigma_ratio: float | None
    time_s: float
    scene_record: str = ""
    failure: str | None = None
    method_coverage: tuple[float, float, float] | None = None
    #: The mapping stage warned that it may be off (:data:`calib.core.result.MAPPING_WARNING_CODES`).
    mapping_warned: bool | None = None

    @property
    def relative_error(self) -> float:
        """RE (Eq. 16): the channels' mean; NaN for a failed estimate."""
        return float("nan") if self.channel_re is None else float(np.mean(self.channel_re))


def scene_seed(seed: int, camera: SplitCamera, scene: int) -> np.random.SeedSequence:
    """The seed of one camera's scene (shared by the 1-D protocol and the twin's renderer)."""
    return np.random.SeedSequence([seed, camera.stable_id, scene])


def sensitivity_scores(
    result: EstimateResult, truth: FloatArray, *, width: float = 2.0
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """Per channel: RE, ±``width``σ coverage and σ ratio (``None`` without σ); see the module."""
    # Scored on the curve and σ users get (sensitivity.csv, result.json): negative lobes set to 0.
    curves = result.camera_curves()
    channel_re = channel_relative_errors(curves.values, truth)
    if curves.sigma is None:
        return channel_re, None, None
    difference = np.asarray(curves.values - truth, dtype=np.float64)
    sigma = np.asarray(curves.sigma, dtype=np.float64)
    coverage = np.mean(np.abs(difference) <= width * sigma, axis=0)
    stated = np.sqrt(np.mean(sigma**2, axis=0))
    actual = np.sqrt(np.mean(difference**2, axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(stated > 0, actual / stated, np.inf)
    return channel_re, np.asarray(coverage, dtype=np.float64), np.asarray(ratio, dtype=np.float64)


def mapping_sigma_nm(
    mapping: QuadraticMapping | GratingGeometry, pixel: FloatArray
) -> FloatArray | None:
    """The stated σ of ``g(p)`` at each pixel (the mapping's own: its covariance's and the
    extrapolation past its lines, :meth:`calib.core.mapping.QuadraticMapping.sigma_nm`), or
    ``None``."""
    if not isinstance(mapping, QuadraticMapping):
        return None
    return mapping.sigma_nm(pixel)


def mapping_scores(
    result: EstimateResult,
    pixel: FloatArray,
    true_nm: FloatArray,
    grid: WavelengthGrid,
    *,
    width: float = 2.0,
) -> tuple[float | None, float | None, float | None, float | None]:
    """Mean ``|Δλ|`` (nm), mapping RE, ±``width``σ coverage and σ ratio over the grid's pixels."""
    if result.mapping is None:
        return None, None, None, None
    inside = (true_nm >= grid.start_nm) & (true_nm <= grid.stop_nm)
    estimated = np.asarray(result.mapping.wavelength_nm(pixel[inside]), dtype=np.float64)
    error = estimated - true_nm[inside]
    mean_abs = float(np.mean(np.abs(error)))
    relative = mapping_relative_error(
        estimated, true_nm[inside], range_nm=(grid.start_nm, grid.stop_nm)
    )
    sigma = mapping_sigma_nm(result.mapping, pixel[inside])
    if sigma is None:
        return mean_abs, relative, None, None
    coverage = float(np.mean(np.abs(error) <= width * sigma))
    stated = float(np.sqrt(np.mean(sigma**2)))
    ratio = float(np.sqrt(np.mean(error**2)) / stated) if stated > 0 else math.inf
    return mean_abs, relative, coverage, ratio


def _triple(values: FloatArray | None) -> tuple[float, float, float] | None:
    if values is None:
        return None
    return (float(values[0]), float(values[1]), float(values[2]))


@dataclass(frozen=True, eq=False)
class Task:
    """One camera's scene with the basis its estimates use (what a worker process receives)."""

    split: str
    camera: SplitCamera
    basis: CameraBasis
    scene: int
    settings: ProtocolSettings


def draw_task_plan(task: Task) -> tuple[ScenePlan, np.random.Generator]:
    """The task's scene plan and the generator its noise comes from (both from its seed alone).

    The 1-D renderer here and the twin's 2-D one (``bench/validate_twin.py``) share it.
    """
    settings = task.settings
    plan_seed, noise_seed = scene_seed(settings.seed, task.camera, task.scene).spawn(2)
    plan = draw_scene_plan(
        np.random.default_rng(plan_seed),
        scene_lamps(settings.variants),
        grating_kinds=settings.grating_kinds,
        catalogue=settings.catalogue,
        errors=settings.errors,
        geometry=settings.geometry,
        grid=settings.grid,
    )
    return plan, np.random.default_rng(noise_seed)


def render_task_scene(task: Task) -> RenderedScene:
    """The task's scene, drawn and rendered (a function of the task's seed alone).

    Profiles measured from the direct spot come from RAW files, so they carry the optics those
    files record (:func:`~calib.evaluation.validation.scenes.exif_optics`, from a third child of
    the scene's seed); profiles of arbitrary origin (CSVs) carry none.
    """
    plan, noise = draw_task_plan(task)
    scene = render_scene(plan, task.camera.sensitivity, scene_lamps(task.settings.variants), noise)
    if task.settings.pixel_origin == "direct_spot":
        optics_seed = scene_seed(task.settings.seed, task.camera, task.scene).spawn(3)[2]
        observations = with_exif_optics(
            scene.observations, plan.geometry, np.random.default_rng(optics_seed)
        )
    else:
        observations = {
            name: replace(obs, pixel_origin=task.settings.pixel_origin)
            for name, obs in scene.observations.items()
        }
    return replace(scene, observations=observations)


def variant_observations(scene: RenderedScene, variant: MethodVariant) -> list[LampObservation]:
    """The observations ``variant`` estimates from: its lamps of ``scene``, without the RAW
    files' optics when it measures that case (``exif_optics=False``)."""
    observations = [scene.observations[lamp] for lamp in variant.lamps]
    if not variant.direct:
        observations = [replace(obs, direct_rgb=None, direct_sigma=None) for obs in observations]
    nominal = dict(variant.unmeasured)
    if nominal:
        observations = [
            obs
            if obs.name not in nominal
            else replace(
                obs,
                spectrum=lamp_from_spec(nominal[obs.name]),
                spectrum_bandwidth_nm=None,
                metadata={**dict(obs.metadata), "spectrum_known": False},
            )
            for obs in observations
        ]
    if variant.exif_optics:
        return observations
    return [
        replace(obs, metadata={k: v for k, v in obs.metadata.items() if k != "optics"})
        for obs in observations
    ]


def variant_arguments(variant: MethodVariant) -> dict[str, Any]:
    """The keywords :func:`calib.methods.estimate` takes for ``variant`` besides its
    observations, grid and basis: its options, and — for ``auto`` on lamps without a direct
    measurement — ``assume_flat_grating`` (as ``calib estimate`` passes it)."""
    extra: dict[str, Any] = {} if variant.options is None else {"options": variant.options}
    if not variant.direct and variant.method == AUTO_METHOD:
        extra["assume_flat_grating"] = True
    return extra


def variant_inputs(
    task: Task, scene: RenderedScene, variant: MethodVariant
) -> tuple[list[LampObservation], dict[str, Any]]:
    """What :func:`calib.methods.estimate` is given for ``variant`` on the task's ``scene``: its
    observations (:func:`variant_observations`) and its keywords — method, grid, the task's basis
    and :func:`variant_arguments` — as :func:`evaluate_task` runs it."""
    keywords = {
        "method": variant.method,
        "grid": task.settings.grid,
        "basis": task.basis,
        **variant_arguments(variant),
    }
    return variant_observations(scene, variant), keywords


def named_task(data_dir: str | None, camera: str, split: str = "test", seed: int = 0) -> Task:
    """The protocol's task for the camera named ``camera`` in ``split`` ("validation" or "test";
    default settings, ``seed``): one camera's scene for a bench."""
    splits, _ = load_splits(data_dir, seed=seed)
    tasks = split_tasks(getattr(splits, split), ProtocolSettings(seed=seed))
    found = [task for task in tasks if task.camera.name == camera]
    if not found:
        raise ValueError(f"no camera named {camera!r} in the {split} split")
    return found[0]


def row_identity(
    task: Task, variant: MethodVariant, scene_record: str = "", split: str | None = None
) -> dict[str, Any]:
    """The fields of a :class:`ValidationRow` that say what was estimated."""
    camera = task.camera
    return {
        "split": split or task.split,
        "camera": camera.name,
        "body": camera.body,
        "group": camera.group,
        "collection": camera.collection,
        "scene": task.scene,
        "variant": variant.label,
        "method": variant.method,
        "scene_record": scene_record,
    }


def scored_row(
    identity: dict[str, Any],
    result: EstimateResult,
    truth: FloatArray,
    pixel: FloatArray,
    true_nm: FloatArray,
    started: float,
) -> ValidationRow:
    """A row scoring ``result`` against the true curves ``(f, 3)`` and the true wavelength at
    each profile ``pixel`` (module docstring); ``started`` the estimate's ``perf_counter``."""
    grid = WavelengthGrid(
        float(result.wavelength_nm[0]),
        float(result.wavelength_nm[-1]),
        float(result.wavelength_nm[1] - result.wavelength_nm[0]),
    )
    channel_re, coverage, ratio = sensitivity_scores(result, truth)
    own_sigma = result.diagnostics.get("method_sigma")
    own_coverage = (
        None
        if own_sigma is None
        else sensitivity_scores(replace(result, sensitivity_sigma=own_sigma), truth)[1]
    )
    mapping = mapping_scores(result, pixel, true_nm, grid)
    return ValidationRow(
        **identity,
        channel_re=_triple(channel_re),
        coverage=_triple(coverage),
        sigma_ratio=_triple(ratio),
        mapping_mean_abs_nm=mapping[0],
        mapping_re=mapping[1],
        mapping_coverage=mapping[2],
        mapping_sigma_ratio=mapping[3],
        time_s=time.perf_counter() - started,
        method_coverage=_triple(own_coverage),
        mapping_warned=None if result.mapping is None else _ambiguity_warned(result.mapping),
    )


def _ambiguity_warned(mapping: object) -> bool:
    """Whether the mapping's result carries a warning that it may be off by more than 3 nm
    (:func:`calib.core.result.mapping_warned`)."""
    details = getattr(mapping, "details", None) or {}
    return mapping_warned(details.get("warning_codes", ()))


def failed_row(identity: dict[str, Any], error: Exception, started: float) -> ValidationRow:
    """A row for an estimate that raised: its type and first line."""
    return ValidationRow(
        **identity,
        channel_re=None,
        coverage=None,
        sigma_ratio=None,
        mapping_mean_abs_nm=None,
        mapping_re=None,
        mapping_coverage=None,
        mapping_sigma_ratio=None,
        time_s=time.perf_counter() - started,
        failure=f"{type(error).__name__}: {error}".splitlines()[0],
    )


def evaluate_task(task: Task) -> list[ValidationRow]:
    """Render the task's scene and score every variant on it (module docstring).

    A method that raises yields a row with ``failure`` set (its type and message); the run goes on.
    """
    from calib.methods import estimate

    settings = task.settings
    started = time.perf_counter()
    try:
        scene = render_task_scene(task)
    except Exception as exc:  # a scene that cannot be rendered fails its estimates, not the run
        return [failed_row(row_identity(task, v), exc, started) for v in settings.variants]
    record = json.dumps(scene.plan.to_dict(), default=float)
    rows: list[ValidationRow] = []
    for variant in settings.variants:
        observations, keywords = variant_inputs(task, scene, variant)
        started = time.perf_counter()
        identity = row_identity(task, variant, record)
        try:
            result = estimate(observations, **keywords)
            pixel = observations[0].pixel
            rows.append(
                scored_row(identity, result, scene.truth, pixel, scene.true_wavelength_nm, started)
            )
        except Exception as exc:  # a method's failure is a result, not the end of the run
            rows.append(failed_row(identity, exc, started))
    return rows


def split_tasks(
    split: Split, settings: ProtocolSettings, *, cache_dir: Path | None = None
) -> list[Task]:
    """The split's tasks in a fixed order: cameras × scenes, each with its basis."""
    bases: dict[tuple[str, ...], CameraBasis] = {}
    tasks: list[Task] = []
    for camera in split.cameras:
        records = split.basis_records(camera)
        key = tuple(record.name for record in records)
        if key not in bases:
            bases[key] = camera_basis(
                [record.sensitivity for record in records],
                grid=settings.grid,
                n_vectors=settings.n_vectors,
                source=f"{split.role} basis: {len(records)} training curves",
                camera_names=list(key),
                cache_dir=cache_dir,
            )
        tasks.extend(
            Task(split.role, camera, bases[key], scene, settings)
            for scene in range(settings.scenes)
        )
    return tasks


def spread_tasks(
    data_dir: Path | None,
    role: Literal["validation", "test"],
    settings: ProtocolSettings,
    cameras: int,
) -> list[Task]:
    """At most ``cameras`` of a split's tasks, spread evenly over its camera order: the sample the
    benches that look at a few cameras of the protocol (``bench/eta_band.py``,
    ``bench/grating_physics.py``) share."""
    loaded, _ = load_splits(data_dir)
    split = loaded.validation if role == "validation" else loaded.test
    tasks = split_tasks(split, settings)
    return tasks[:: max(1, len(tasks) // cameras)][:cameras]


def run_split(
    split: Split,
    settings: ProtocolSettings,
    *,
    jobs: int = 1,
    progress: Callable[[ValidationRow], None] | None = None,
    cache_dir: Path | None = None,
) -> list[ValidationRow]:
    """Every camera × scene × variant of ``split`` (for reporting; tuning goes through
    :func:`tune_rows`). ``jobs`` worker processes; the rows do not depend on it."""
    tasks = split_tasks(split, settings, cache_dir=cache_dir)
    rows: list[ValidationRow] = []
    if jobs <= 1 or len(tasks) <= 1:
        for task in tasks:
            for row in evaluate_task(task):
                rows.append(row)
                if progress is not None:
                    progress(row)
        return rows
    # Spawned workers: no inherited locks or BLAS thread pools; each task carries what it needs.
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
        for task_rows in pool.map(evaluate_task, tasks, chunksize=1):
            for row in task_rows:
                rows.append(row)
                if progress is not None:
                    progress(row)
    return rows


def tune_rows(
    split: ValidationSplit,
    settings: ProtocolSettings,
    *,
    jobs: int = 1,
    cache_dir: Path | None = None,
) -> list[ValidationRow]:
    """:func:`run_split` for a tuning decision: the validation split only (else
    :class:`~calib.evaluation.validation.splits.SplitRoleError`)."""
    return run_split(require_validation(split), settings, jobs=jobs, cache_dir=cache_dir)


def tuning_score(
    split: ValidationSplit,
    settings: ProtocolSettings,
    variant: str,
    *,
    jobs: int = 1,
    cache_dir: Path | None = None,
) -> float:
    """Mean RE (Eq. 16) of one variant over the validation split; failures count as RE = 1.

    The one number a tuning loop compares between settings; refuses any split but validation.
    """
    labels = [v.label for v in settings.variants]
    if variant not in labels:
        from calib.core.errors import InputError

        raise InputError(f"no variant {variant!r}; the settings run {labels}", source="variant")
    chosen = replace(settings, variants=tuple(v for v in settings.variants if v.label == variant))
    rows = tune_rows(split, chosen, jobs=jobs, cache_dir=cache_dir)
    errors = [1.0 if row.channel_re is None else row.relative_error for row in rows]
    return float(np.mean(errors))
