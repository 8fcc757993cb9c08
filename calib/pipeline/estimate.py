"""The one pipeline from files to an estimate, shared by ``calib estimate`` and ``rig estimate``.

1. Check every input before decoding anything: lamp names, kinds, spectra (readable, cover the grid),
   profile CSVs, the grating file.
2. RAW lamps: merge each bracket (streamed, darks subtracted), detect the geometry once on the
   brightest broadband lamp and extract every lamp with it (:mod:`calib.pipeline.brackets`).
   Profile lamps: read the profile CSV (the same :class:`~calib.core.observations.LampObservation` follows).
3. Estimate: with a direct (0th-order) measurement, :func:`calib.methods.estimate` with the chosen
   method (``auto`` by default) and its typed options; without one, or with a grating file and
   ``multilamp`` or ``known-grating``, the known-grating solve (:mod:`calib.methods.known_grating`)
   through the grating file given, or a flat grating and a warning.
4. Record what produced it (:class:`~calib.pipeline.provenance.Provenance`): input hashes, software,
   command line, camera, warnings.

Writing the files is :func:`calib.pipeline.run.run_offline`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread
from calib.core.errors import EstimationError, InputError
from calib.core.grating_file import GratingEfficiency, read_grating_file
from calib.core.mapping import QuadraticMapping
from calib.core.observations import CHANNEL_GAINS_KEY, LampObservation
from calib.core.result import EstimateResult, QualityFlag
from calib.core.spectra import DEFAULT_GRID, Spectrum, UnitsKind, WavelengthGrid
from calib.image.raw import read_raw_metadata
from calib.methods import (
    AUTO,
    MethodOptions,
    check_method,
    coarse_line_spectrum,
    estimate,
    unmeasured_line_spectrum,
)
from calib.methods.grating_models import AssumedGrating
from calib.methods.known_grating import KNOWN_GRATING_METHOD, KnownGratingOptions
from calib.methods.multilamp import MULTILAMP_METHOD
from calib.methods.uncertainty import DEFAULT_BUDGET, BudgetSettings, assumed_grating_flag
from calib.model.bases import CameraBasis, default_camera_basis
from calib.model.resolution import COARSE_SLIT_NM, coarse_slit
from calib.pipeline.brackets import BracketProfiles, bracket_profiles
from calib.pipeline.inputs import (
    ChannelGains,
    LampImages,
    LampInput,
    LampProfile,
    ProfileTable,
    check_bandwidth,
    describe_profile,
    describe_spectrum,
    load_spectrum,
    profile_files,
    read_profile_file,
    spectrum_files,
)
from calib.pipeline.progress import NoProgress, OfflineProgress
from calib.pipeline.provenance import FileHasher, InputFile, Provenance, repeated_file
from calib.wavelength import lamp_name
from calib.wavelength.peaks import narrow_line_width_nm, narrow_lines

__all__ = [
    "OfflineEstimate",
    "OfflineSettings",
    "basis_key",
    "estimate_offline",
    "resolve_basis",
]


@dataclass(frozen=True)
class StatedOptics:
    """The optics a user states (``calib estimate --grooves-per-mm/--focal-length-mm/
    --pixel-pitch-um``): the grating's nominal line density, and the focal length and pixel pitch
    where the RAW files record none (a stated value wins over EXIF)."""

    grooves_per_mm: float | None = None
    focal_length_mm: float | None = None
    pixel_pitch_um: float | None = None

    def over(self, optics: Mapping[str, Any]) -> dict[str, Any]:
        """``optics`` (an observation's ``"optics"`` metadata) with the stated values in."""
        stated = {
            "grooves_per_mm": self.grooves_per_mm,
            "focal_length_mm": self.focal_length_mm,
            "pixel_pitch_um": self.pixel_pitch_um,
        }
        out = dict(optics)
        out.update({key: value for key, value in stated.items() if value is not None})
        if self.pixel_pitch_um is not None:
            out["pitch_source"] = "stated"
        return out


@dataclass(frozen=True)
class OfflineSettings:
    """How to estimate.

    Parameters
    ----------
    method
        Estimation method (see :func:`calib.methods.estimate`; ``"auto"`` chooses by the lamps).
    method_options
        That method's typed options (e.g. ``MultilampOptions(weight_rule="typicality")``), or
        ``None`` for its defaults.
    grid
        Working wavelength grid.
    mapping_lamp
        The lamp the pixel→wavelength mapping is found with (default: the estimator's choice).
    data_dir
        Camera data directory for the basis (default: ``$SPECTRAL_RIG_DATA`` or the user cache;
        the offline colour-science basis when none is found).
    basis
        A camera basis to use instead (on ``grid``).
    exclude_cameras
        Name patterns of cameras to keep out of the default basis (the camera under test, when
        validating; :func:`calib.model.bases.default_camera_basis`); not with ``basis``.
    grating
        A grating efficiency (file or object) for lamps without a direct measurement.
    optics
        What the user states of the optics (line density, focal length, pitch): the mapping's
        physical prior, over what the RAW files say.
    use_region
        Merge RAW frames over a region of interest: ``None`` decides by frame size.
    assumed_grating
        What stands in for η when no lamp has a direct measurement and no grating file is given:
        ``"flat"`` or ``"physical"`` (:class:`calib.methods.known_grating.KnownGratingOptions`,
        decision 0074); ``None``: the method options' (default flat). Named in a warning when the
        data do not take that path.
    budget
        How the stated σ is made (:class:`calib.methods.uncertainty.BudgetSettings`, e.g. another
        ``model_floor`` for a validation-split tuning run); ``None``: the method's own σ only.
    command_line
        The command as typed, recorded in the result.
    typed_options
        The options the command line typed, by their inputs-file ``estimate:`` key (``grid``,
        ``method``, ``exclude_camera`` …): an input set's own settings do not override them
        (:func:`calib.pipeline.inputs_file.own_settings_over`, decision 0179).
    warnings, notes
        The caller's own warnings and notes (an incomplete session …), recorded with the result.
    """

    method: str = AUTO
    method_options: MethodOptions | None = None
    grid: WavelengthGrid = DEFAULT_GRID
    mapping_lamp: str | None = None
    data_dir: Path | None = None
    basis: CameraBasis | None = None
    exclude_cameras: tuple[str, ...] = ()
    grating: Path | GratingEfficiency | None = None
    optics: StatedOptics = field(default_factory=lambda: StatedOptics())
    use_region: bool | None = None
    budget: BudgetSettings | None = DEFAULT_BUDGET
    assumed_grating: AssumedGrating | None = None
    command_line: tuple[str, ...] | None = None
    typed_options: frozenset[str] = frozenset()
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class OfflineEstimate:
    """An estimate with everything needed to write and judge it.

    Attributes
    ----------
    result
        The estimator's result.
    observations
        The lamps as the estimator saw them (profiles, direct RGB, spectra).
    profiles
        The RAW part (geometry, extractions, merged images), or ``None`` for profile input.
    provenance
        Inputs with hashes, software, command line, camera, warnings, notes.
    grating
        The grating efficiency used (known-grating solve), or ``None``.
    timings
        Wall time per stage (s).
    """

    result: EstimateResult
    observations: tuple[LampObservation, ...]
    profiles: BracketProfiles | None
    provenance: Provenance
    grating: GratingEfficiency | None = None
    timings: Mapping[str, float] = field(default_factory=dict)

    @property
    def warnings(self) -> tuple[str, ...]:
        return self.provenance.warnings


@dataclass
class _Checked:
    """Inputs after the up-front checks."""

    spectra: dict[str, Spectrum]
    profiles: dict[str, ProfileTable]
    grating: GratingEfficiency | None
    warnings: list[str]
    bandwidths: dict[str, float | None] = field(default_factory=dict)
    #: Per profile lamp: the user's ``channel_gains``, or ``unknown`` where the file says so.
    channel_gains: dict[str, ChannelGains] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: Each lamp's spectrum units and what they measure, where its files say.
    units: dict[str, tuple[str, UnitsKind]] = field(default_factory=dict)


def _check_inputs(lamps: Sequence[LampInput], settings: OfflineSettings) -> _Checked:
    if not lamps:
        raise InputError("no lamps given; give at least one --lamp", source="lamps")
    names = [lamp.name for lamp in lamps]
    for name in names:
        if not name.strip():
            raise InputError("a lamp name is empty", source="--lamp")
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise InputError(f"lamp {duplicates[0]!r} is given twice", source="--lamp")
    check_method(settings.method, source="--method")
    if settings.mapping_lamp is not None:
        lamp_name(names, settings.mapping_lamp, source="--mapping-lamp")
    with_images = [lamp for lamp in lamps if isinstance(lamp, LampImages)]
    if with_images and len(with_images) != len(lamps):
        raise InputError(
            "give every lamp as RAW images or every lamp as a profile: a profile's pixel axis is "
            "not the images' (distance from the direct spot in sensor pixels)",
            source="lamps",
        )
    for lamp in with_images:
        if not lamp.images:
            raise InputError("no images", source=f"lamp {lamp.name!r}")
        if lamp.exposure_s is not None and len(lamp.exposure_s) != len(lamp.images):
            raise InputError(
                f"{len(lamp.exposure_s)} exposure times for {len(lamp.images)} images; give one "
                "per image, in the same order",
                source=f"lamp {lamp.name!r} --exposure",
            )
        if lamp.dark_exposure_s is not None and len(lamp.dark_exposure_s) != len(lamp.darks):
            raise InputError(
                f"{len(lamp.dark_exposure_s)} exposure times for {len(lamp.darks)} dark frames",
                source=f"lamp {lamp.name!r} --dark-exposure",
            )
        for path in (*lamp.images, *lamp.darks):
            if not path.is_file():
                raise InputError(
                    "file not found" if not path.exists() else "not a file", source=str(path)
                )
        repeated = repeated_file(lamp.images)
        if repeated is not None:
            first, second = repeated
            raise InputError(
                f"{first} and {second} are the same frame (same file or same content): a bracket "
                "needs each frame once; remove one",
                source=f"lamp {lamp.name!r}",
            )
    warnings: list[str] = []
    spectra: dict[str, Spectrum] = {}
    bandwidths: dict[str, float | None] = {}
    units: dict[str, tuple[str, UnitsKind]] = {}
    for given in lamps:
        if given.spectrum_bandwidth_nm is not None:
            check_bandwidth(
                given.spectrum_bandwidth_nm,
                given_as=(
                    f"--bandwidth {given.spectrum_bandwidth_nm:g} (or an --inputs file's "
                    "bandwidth_nm)"
                ),
                source=f"lamp {given.name!r}",
            )
        loaded = load_spectrum(given.spectrum, given.name, settings.grid)
        spectra[given.name] = loaded.spectrum
        warnings.extend(loaded.warnings)
        if loaded.units is not None and loaded.units_kind is not None:
            units[given.name] = (loaded.units, loaded.units_kind)
        bandwidths[given.name] = (
            given.spectrum_bandwidth_nm
            if given.spectrum_bandwidth_nm is not None
            else loaded.bandwidth_nm
        )
        if loaded.bandwidth_nm not in (None, bandwidths[given.name]):
            warnings.append(
                f"lamp {given.name!r}: --bandwidth {bandwidths[given.name]:g} nm overrides its "
                f"spectrum file's '# bandwidth_nm: {loaded.bandwidth_nm:g}'; the --bandwidth "
                "is used (drop it to use the file's)"
            )
    profiles = {
        lamp.name: read_profile_file(lamp.profile)
        for lamp in lamps
        if isinstance(lamp, LampProfile)
    }
    channel_gains: dict[str, ChannelGains] = {}
    notes: list[str] = []
    for given in lamps:
        if not isinstance(given, LampProfile):
            continue
        table = profiles[given.name]
        warnings.extend(table.warnings)
        notes.extend(table.notes)
        channel_gains[given.name] = given.channel_gains
        if table.channel_gains_unknown is not None and given.channel_gains == "raw":
            # The file says its gains are not the raw data's (a rawproc whitebalance:camera, an
            # input LibRaw processed): taken as raw the channels' balance would be silently wrong.
            channel_gains[given.name] = "unknown"
            warnings.append(
                f"lamp {given.name!r}: {table.channel_gains_unknown}, so the profile is taken with "
                "channel gains unknown (the channels' balance from the camera population, its "
                "spread in σ); to keep the raw gains, export with rawdata=crop and no white "
                "balance, or a whitebalance with stated multipliers (undone on reading)"
            )
    rgb_planes = [
        lamp.name
        for lamp in lamps
        if isinstance(lamp, LampProfile)
        and channel_gains[lamp.name] == "raw"
        and profiles[lamp.name].image_planes
    ]
    if rgb_planes:
        # FITS R, G, B planes are an RGB image's: raw gains only if nothing balanced them. Taken
        # as raw when they were white-balanced, the channels' balance is silently wrong (the
        # Canon 10D's planes: 30 % of the peak).
        warnings.append(
            f"the FITS profile of {', '.join(map(repr, rgb_planes))} is taken with the raw data's "
            "channel gains; FITS R, G, B planes usually come from a converted RGB image: if white "
            "balance or a colour conversion scaled them, give --channel-gains unknown (an inputs "
            "file's channel_gains: unknown)"
        )
    axes = {table.in_wavelength for table in profiles.values()}
    if len(axes) > 1:
        raise InputError(
            "some profiles are in pixels and some in wavelength_nm; give all lamps on one axis",
            source="--profile",
        )
    grating = settings.grating
    if isinstance(grating, Path):
        grating = read_grating_file(grating)
    if grating is not None:
        warnings.extend(grating.reuse_warnings())
    if grating is not None and not grating.covers(settings.grid):
        lo, hi = grating.range_nm
        raise InputError(
            f"the grating efficiency covers {lo:g}–{hi:g} nm, the grid needs "
            f"{settings.grid.start_nm:g}–{settings.grid.stop_nm:g} nm",
            source=grating.source,
        )
    return _Checked(spectra, profiles, grating, warnings, bandwidths, channel_gains, notes, units)


def _profile_observation(
    lamp: LampProfile, spectrum: Spectrum, table: ProfileTable, channel_gains: ChannelGains
) -> LampObservation:
    return LampObservation(
        name=lamp.name,
        spectrum=spectrum,
        pixel=table.axis,
        profile=table.profile,
        direct_rgb=None if lamp.direct_rgb is None else np.array(lamp.direct_rgb),
        profile_sigma=table.profile_sigma,
        kind=lamp.kind,
        profile_wavelength_nm=table.axis if table.in_wavelength else None,
        metadata={
            "profile_file": describe_profile(lamp.profile),
            "axis": "wavelength_nm" if table.in_wavelength else "pixel",
            # A conversion scaled the channels: the balance is the camera population's.
            **({CHANNEL_GAINS_KEY: "unknown"} if channel_gains == "unknown" else {}),
        },
    )


def import_estimation() -> None:
    """Import what the merge's noise fit, the detection and the estimate use (scipy: most of a
    second), e.g. in a thread while the first frames decode (LibRaw releases the GIL)."""
    import scipy.ndimage
    import scipy.optimize
    import scipy.signal  # noqa: F401


def _image_lamp_record(lamp: LampImages, extraction_frames: Sequence[Any]) -> dict[str, Any]:
    return {
        "name": lamp.name,
        "kind": lamp.kind,
        "input": "images",
        "spectrum": describe_spectrum(lamp.spectrum),
        "frames": [
            {
                "path": str(record.path),
                "exposure_s": record.exposure_s,
                "dark_frames": [str(dark) for dark in record.dark_paths],
                "saturated_fraction": list(record.saturated_fraction),
                # the merge's estimate of its actual exposure / exposure_s (decision 0089)
                "exposure_gain": record.gain,
                "exposure_gain_sigma": record.gain_sigma,
            }
            for record in extraction_frames
        ],
    }


def _camera_record(profiles: BracketProfiles) -> dict[str, Any]:
    image = profiles.extractions[0].merged.image
    first = image.frames[0].path if image.frames else None
    make = model = None
    focal_length_mm = pixel_pitch_um = None
    if first is not None:
        metadata = read_raw_metadata(first, exposure_s=image.frames[0].exposure_s)
        make, model = metadata.make, metadata.model
        focal_length_mm, pixel_pitch_um = metadata.focal_length_mm, metadata.pixel_pitch_um
    return {
        "camera": image.camera,
        "make": make,
        "model": model,
        "focal_length_mm": focal_length_mm,
        "pixel_pitch_um": pixel_pitch_um,
        "cfa_pattern": image.cfa_pattern,
        "iso": image.iso,
        "f_number": image.f_number,
        "sensor_shape_px": list(image.full_sensor_shape_px or image.sensor_shape_px),
        "noise_model": None
        if image.noise_model is None
        else {
            "gain_dn_per_electron": image.noise_model.gain_dn_per_electron,
            "read_noise_dn": list(image.noise_model.read_noise_dn),
            "source": image.noise_model.source,
        },
        "first_frame": None if first is None else str(first),
    }


@one_blas_thread
def estimate_offline(
    lamps: Sequence[LampInput],
    settings: OfflineSettings = OfflineSettings(),
    *,
    progress: OfflineProgress | None = None,
    known_inputs: Sequence[InputFile] = (),
    on_profiles: Callable[[BracketProfiles], object] | None = None,
) -> OfflineEstimate:
    """Run the pipeline from files to an estimate (see the module docstring).

    Parameters
    ----------
    lamps
        :class:`LampImages` (all lamps) or :class:`LampProfile` (all lamps).
    settings
        Method, grid, mapping lamp, basis, grating, region of interest, command line.
    progress
        Receives frame and stage events.
    known_inputs
        Files already hashed and verified by the caller (a session): not read again for the
        provenance.
    on_profiles
        Called with the RAW part's result as soon as the profiles are extracted (before the
        estimate), e.g. to draw the geometry while the estimate runs.

    Returns
    -------
    OfflineEstimate

    Raises
    ------
    InputError
        Any unusable input (named: file, field, lamp), including a direct spot saturated in every
        frame when no grating file allows estimating without it.
    EstimationError
        The estimator cannot produce a trustworthy result.
    """
    report = progress or NoProgress()
    timings: dict[str, float] = {}
    started = time.perf_counter()
    checked = _check_inputs(lamps, settings)
    warnings = [*settings.warnings, *checked.warnings]
    notes = [*settings.notes, *checked.notes]
    timings["checks_s"] = time.perf_counter() - started
    known = {record.path for record in known_inputs}
    image_lamps = [lamp for lamp in lamps if isinstance(lamp, LampImages)]
    # RAW files are hashed once decoded, while the estimate (one thread) leaves a core idle
    with FileHasher(paused=bool(image_lamps)) as hasher:
        for record in known_inputs:
            hasher.add_known(record)
        for lamp in lamps:
            if isinstance(lamp, LampImages):
                for path in lamp.images:
                    if str(path) not in known:
                        hasher.add(path, "frame", lamp.name)
                for path in lamp.darks:
                    if str(path) not in known:
                        hasher.add(path, "dark", lamp.name)
            else:
                for path in profile_files(lamp.profile):
                    hasher.add(path, "profile", lamp.name)
            for path in spectrum_files(lamp.spectrum):
                if str(path) not in known:
                    hasher.add(path, "spectrum", lamp.name)
        if isinstance(settings.grating, Path):
            hasher.add(settings.grating, "grating", None)

        report.start(sum(len(lamp.images) for lamp in image_lamps))
        profiles: BracketProfiles | None = None
        observations: list[LampObservation] = []
        lamp_records: list[dict[str, Any]] = []
        camera: dict[str, Any] = {}
        step = time.perf_counter()
        if image_lamps:
            profiles = bracket_profiles(
                image_lamps,
                use_region=settings.use_region,
                frame_done=report.frame_done,
                stage=report.stage,
            )
            hasher.start()
            if on_profiles is not None:
                on_profiles(profiles)
            notes.extend(profiles.notes)
            # A sharp direct spot whose colour rests on the planes' plain sums (decision 0114).
            warnings.extend(
                f"{item.merged.lamp.name}: {item.extraction.direct_note}"
                for item in profiles.extractions
                if item.extraction.direct_note is not None
            )
            # The other first order in the frame but unread (decision 0197).
            notes.extend(
                f"{item.merged.lamp.name}: {item.extraction.other_order_note}"
                for item in profiles.extractions
                if item.extraction.other_order_note is not None
            )
            notes.append(f"geometry detected on {profiles.geometry_lamp}")
            camera = _camera_record(profiles)
            # What the RAW files say of the optics: the mapping's physics starts from it.
            optics = {
                "camera": " ".join(part for part in (camera["make"], camera["model"]) if part)
                or None,
                "focal_length_mm": camera["focal_length_mm"],
                "pixel_pitch_um": camera["pixel_pitch_um"],
            }
            optics = settings.optics.over(optics)
            for item in profiles.extractions:
                lamp = item.merged.lamp
                extraction = item.extraction
                observation = replace(
                    extraction.to_observation(
                        lamp.name,
                        checked.spectra[lamp.name],
                        kind=lamp.kind,
                        metadata={
                            "geometry": profiles.geometry.to_dict(),
                            "geometry_lamp": profiles.geometry_lamp,
                            "optics": optics,
                        },
                    ),
                    spectrum_bandwidth_nm=checked.bandwidths[lamp.name],
                )
                observations.append(observation)
                lamp_records.append(_image_lamp_record(lamp, item.merged.image.frames))
            timings["profiles_s"] = time.perf_counter() - step
        else:
            for given in lamps:
                assert isinstance(given, LampProfile)
                table = checked.profiles[given.name]
                observations.append(
                    replace(
                        _profile_observation(
                            given,
                            checked.spectra[given.name],
                            table,
                            checked.channel_gains[given.name],
                        ),
                        spectrum_bandwidth_nm=checked.bandwidths[given.name],
                    )
                )
                lamp_records.append(
                    {
                        "name": given.name,
                        "kind": given.kind,
                        "input": "profile",
                        "profile": describe_profile(given.profile),
                        "channel_gains": checked.channel_gains[given.name],
                        # What the file's reader read of its making (a rawproc command's steps).
                        **({"profile_metadata": dict(table.metadata)} if table.metadata else {}),
                        "axis": "wavelength_nm" if table.in_wavelength else "pixel",
                        "direct_rgb": None if given.direct_rgb is None else list(given.direct_rgb),
                        "spectrum": describe_spectrum(given.spectrum),
                    }
                )
        for lamp_record in lamp_records:
            if lamp_record["name"] in checked.units:
                text, kind = checked.units[lamp_record["name"]]
                # What the spectrum's file said it measures (one in photons was converted).
                lamp_record["spectrum_units"] = {"units": text, "measures": kind}
        report.stage("estimating")
        step = time.perf_counter()
        flags = input_flags(observations, image_input=bool(image_lamps))
        flags.extend(spectrum_units_flags(checked.units))
        try:
            result, grating_used = _estimate(
                observations,
                settings,
                checked,
                image_input=bool(image_lamps),
                warnings=warnings,
                notes=notes,
            )
        except EstimationError as exc:
            # A failure on inputs already found unusable is that finding, said as an input error.
            serious = [flag for flag in flags if flag.severity == "serious"]
            if not serious:
                raise
            raise InputError(f"{serious[0].message} (the estimate then failed: {exc})") from None
        timings["estimate_s"] = time.perf_counter() - step
        # The spectrometer-scale check against the FL lamp's Hg lines (decision 0069): the report's
        # notes say whether the spectra were corrected, by how much, or why not.
        notes.extend(scale_check_notes(result))
        # The mapping's own flags came with the estimate (calib.methods.estimate).
        result = result.with_quality(*flags)
        warnings.extend(line for line in result.quality.warnings() if line not in warnings)
        inputs = hasher.results()
    timings["total_s"] = time.perf_counter() - started
    provenance = Provenance(
        inputs=inputs,
        command_line=settings.command_line,
        lamps=tuple(lamp_records),
        camera=camera,
        warnings=tuple(warnings),
        notes=tuple(notes),
    )
    return OfflineEstimate(
        result=result,
        observations=tuple(observations),
        profiles=profiles,
        provenance=provenance,
        grating=grating_used,
        timings=timings,
    )


def scale_check_notes(result: EstimateResult) -> list[str]:
    """The notes of the spectrometer-scale check the estimate made
    (``diagnostics["spectrometer_scale_check"]``, :mod:`calib.core.spectrometer_scale`)."""
    record = result.diagnostics.get("spectrometer_scale_check")
    if not isinstance(record, Mapping):
        return []
    return [str(note) for note in record.get("notes", [])]


def resolve_basis(settings: OfflineSettings) -> CameraBasis:
    """The camera basis an estimate with ``settings`` uses: the settings' own, else the default
    basis for their grid and data directory (:func:`basis_key` names what that depends on)."""
    if settings.basis is not None and settings.exclude_cameras:
        raise InputError(
            "excluded cameras apply to the default basis, not to a basis given", source="basis"
        )
    return settings.basis or default_camera_basis(
        settings.grid, data_dir=settings.data_dir, exclude=settings.exclude_cameras
    )


def basis_key(settings: OfflineSettings) -> Hashable:
    """What :func:`resolve_basis` reads of ``settings`` without a basis of their own: equal keys
    give the same basis (a batch worker resolves it once per key)."""
    return (settings.grid, settings.data_dir, tuple(settings.exclude_cameras))


#: A profile whose peak is below this many σ of its noise carries no first-order signal.
BLANK_PROFILE_SNR = 5.0
#: A channel's maximum repeated exactly at this many adjacent samples: the band was clipped (a
#: noisy or resampled peak repeats its value by chance at two samples at most).
CLIPPED_RUN = 3
#: A quantised (integer) channel repeats its maximum by chance over a flat top. There a run counts
#: as clipped only where the band's shoulders, fitted by a parabola, rise above it by more than
#: this many σ of that fit's prediction (plus one count): a clipped top is cut below the peak its
#: shoulders point to, a whole one is where they point.
CLIPPED_SHOULDER_SIGMAS = 4.0
#: The shoulders: the samples from this fraction of the maximum up, the run itself left out.
SHOULDER_FRACTION = 0.6


def _cut_below_its_shoulders(channel: FloatArray, run: NDArray[np.intp]) -> bool:
    """Whether a quantised channel's run of equal maxima lies below the peak its shoulders'
    parabola predicts at the run's centre (:data:`CLIPPED_SHOULDER_SIGMAS`)."""
    peak = float(channel[run[0]])
    # The band around the run down to SHOULDER_FRACTION of it, not other bands of the channel.
    below = np.flatnonzero(channel < SHOULDER_FRACTION * peak)
    before, after = below[below < run[0]], below[below > run[-1]]
    low = int(before.max()) + 1 if before.size else 0
    high = int(after.min()) - 1 if after.size else channel.size - 1
    index = np.arange(low, high + 1)
    shoulders = index[(index < run[0]) | (index > run[-1])]
    if shoulders.size < 6 or not (shoulders < run[0]).any() or not (shoulders > run[-1]).any():
        return True  # no shoulders to judge by: keep the exact-repeat verdict
    centre = 0.5 * (run[0] + run[-1])
    x = (shoulders - centre).astype(np.float64)
    design = np.stack([np.ones_like(x), x, x**2], axis=1)
    coefficients, *_ = np.linalg.lstsq(design, channel[shoulders], rcond=None)
    residual = channel[shoulders] - design @ coefficients
    dof = max(shoulders.size - 3, 1)
    noise = float(np.sqrt(np.sum(residual**2) / dof))
    covariance = noise**2 * np.linalg.pinv(design.T @ design)
    predicted_sigma = float(np.sqrt(max(covariance[0, 0], 0.0)))
    overshoot = float(coefficients[0]) - peak
    return overshoot > CLIPPED_SHOULDER_SIGMAS * predicted_sigma + 1.0


def clipped_band(obs: LampObservation) -> str | None:
    """Where a given profile's channels hold their maximum exactly over :data:`CLIPPED_RUN` or
    more adjacent samples (a saturated export), e.g. ``"FL (g 0.91 at px 512–530)"``; ``None``
    when none does. A quantised (integer) channel's run counts only when its shoulders point to
    a peak above it (:func:`_cut_below_its_shoulders`): an 8-bit export's flat top repeats its
    maximum by chance."""
    found = []
    for label, channel in zip("rgb", obs.profile.T, strict=True):
        peak = float(channel.max())
        at_peak = np.flatnonzero(channel == peak)
        runs = np.split(at_peak, np.flatnonzero(np.diff(at_peak) != 1) + 1)
        longest = max(runs, key=len)
        if peak <= 0 or longest.size < CLIPPED_RUN:
            continue
        quantised = bool(np.all(channel == np.round(channel)))
        if quantised and not _cut_below_its_shoulders(channel, longest):
            continue
        found.append(f"{label} {peak:g} at px {obs.pixel[longest[0]]:g}–{obs.pixel[longest[-1]]:g}")
    return f"{obs.name} ({', '.join(found)})" if found else None


#: Lamp kinds whose spectrum is a broad band (no narrow emission lines to map from).
BROADBAND_KINDS = ("led", "halogen")


def lamp_kind_mismatch(obs: LampObservation) -> str | None:
    """What to tell the user when ``obs``'s spectrum contradicts its declared kind
    (:func:`calib.wavelength.peaks.narrow_lines`, the spectrum alone): narrow emission lines in a
    lamp declared LED or halogen (its lines are then not used for the mapping), or none in one
    declared fluorescent (the mapping would be anchored on lines it does not have); ``None`` when
    they agree, or when the spectrometer's slit is too broad to tell."""
    width_nm = narrow_line_width_nm(obs.spectrum_bandwidth_nm)
    if width_nm is None or obs.kind not in (*BROADBAND_KINDS, "fluorescent"):
        return None
    lines = narrow_lines(obs.spectrum, width_nm=width_nm)
    if obs.kind in BROADBAND_KINDS and lines:
        shown = ", ".join(f"{peak.position:.0f} nm" for peak in lines[:4])
        return (
            f"lamp {obs.name!r} is declared --kind {obs.kind} but its spectrum has narrow "
            f"emission lines (at {shown}): it looks fluorescent: declare it --kind fluorescent "
            "(in a rig session, kind: fluorescent in config.yaml) to map from its lines"
        )
    if obs.kind == "fluorescent" and not lines:
        return (
            f"lamp {obs.name!r} is declared --kind fluorescent but its spectrum has no narrow "
            f"emission line (no peak under {width_nm:g} nm wide standing above its continuum): "
            "it looks broadband/LED; its lines cannot anchor the mapping: declare it --kind led "
            "or halogen (in a rig session, its kind in config.yaml), or check that the spectrum "
            "is this lamp's"
        )
    return None


def input_flags(observations: Sequence[LampObservation], *, image_input: bool) -> list[QualityFlag]:
    """The quality flags the inputs raise: a direct spot saturated in every frame, a blank first
    order, a given profile's band clipped, a lamp whose spectrum contradicts its kind, a line
    lamp's spectrum too coarse for its lines, a spectrometer slit too broad for the sensitivity's
    detail."""
    flags: list[QualityFlag] = []
    saturated = [obs.name for obs in observations if image_input and obs.direct_rgb is None]
    if saturated:
        flags.append(
            QualityFlag(
                "saturated_frames",
                f"the direct spot of {', '.join(saturated)} is saturated in every frame: no "
                "direct measurement (add a shorter exposure to the bracket)",
            )
        )
    blank = []
    for obs in observations:
        if obs.profile_sigma is None:
            continue
        snr = float(np.max(obs.profile / obs.profile_sigma))
        if snr < BLANK_PROFILE_SNR:
            blank.append(f"{obs.name} (peak {snr:.1f} σ)")
    if blank:
        flags.append(
            QualityFlag(
                "blank_frames",
                f"no first-order signal above the noise for {', '.join(blank)}: blank frames, a "
                "lamp that was off, or the band outside the crop",
                "serious",
            )
        )
    clipped = [] if image_input else [what for obs in observations if (what := clipped_band(obs))]
    if clipped:
        flags.append(
            QualityFlag(
                "saturated_frames",
                f"the first-order band is clipped in the profile of {'; '.join(clipped)}: a "
                "channel holds its maximum exactly over adjacent pixels, so the curve is too low "
                "there; export the profile from frames that do not saturate (or give the RAW "
                "bracket with --images)",
                "serious",
            )
        )
    flags.extend(
        QualityFlag("lamp_kind_mismatch", why)
        for obs in observations
        if (why := lamp_kind_mismatch(obs))
    )
    unmeasured: list[str] = []
    coarse: list[str] = []
    for obs in observations:
        if why := unmeasured_line_spectrum(obs):
            unmeasured.append(why)
        elif why := coarse_line_spectrum(obs):
            coarse.append(why)
    if unmeasured:
        flags.append(
            QualityFlag(
                "line_lamp_unmeasured",
                "; ".join(unmeasured) + ": it places the wavelengths (the mapping) and stays out "
                "of the solve; measure its spectrum to use it there too",
            )
        )
    if coarse:
        flags.append(QualityFlag("coarse_lamp_spectrum", "; ".join(coarse)))
    broad = [what for obs in observations if (what := coarse_slit(obs))]
    if broad:
        flags.append(
            QualityFlag(
                "coarse_spectrometer",
                f"the lamp spectra of {', '.join(broad)} come from a spectrometer whose slit is "
                f"broader than {COARSE_SLIT_NM:g} nm (an i1Pro-class instrument): the "
                "sensitivity's detail finer than the slit rests on the slit model and the camera "
                "prior: expect it to differ from an 8 nm spectroradiometer's by 1–3 ×10⁻² RE; "
                "measure the lamps with a spectroradiometer or a USB spectrometer (≤ 10 nm) for "
                "a reference-grade curve",
            )
        )
    return flags


def spectrum_units_flags(units: Mapping[str, tuple[str, UnitsKind]]) -> list[QualityFlag]:
    """A serious flag for the lamps whose spectrum is not the lamp's emission by its own units: a
    spectrometer's raw counts (its spectral response is in them, and so in the sensitivity), or a
    reflectance/transmittance (a sample's ratio, not a light)."""
    raw = [f"{lamp!r} ({text})" for lamp, (text, kind) in units.items() if kind == "counts"]
    ratio = [f"{lamp!r} ({text})" for lamp, (text, kind) in units.items() if kind == "ratio"]
    flags = []
    if raw:
        flags.append(
            QualityFlag(
                "lamp_spectrum_uncalibrated",
                f"the spectrum of lamp {', '.join(raw)} is in a spectrometer's raw counts: its "
                "spectral response is in them, so the sensitivity carries it too; give the lamp's "
                "irradiance-calibrated spectrum (rig calibrate-spectrometer makes an Ocean "
                "spectrometer's calibration)",
                "serious",
            )
        )
    if ratio:
        flags.append(
            QualityFlag(
                "lamp_spectrum_uncalibrated",
                f"the spectrum of lamp {', '.join(ratio)} is a reflectance or transmittance, not "
                "the lamp's emission: measure the lamp itself (emission, or irradiance mode)",
                "serious",
            )
        )
    return flags


def _wavelength_mapping(observations: Sequence[LampObservation]) -> QuadraticMapping | None:
    """The identity mapping when the profiles are already in wavelength."""
    if not observations or observations[0].profile_wavelength_nm is None:
        return None
    lows = [float(obs.pixel[0]) for obs in observations]
    highs = [float(obs.pixel[-1]) for obs in observations]
    return QuadraticMapping(
        0.0,
        1.0,
        0.0,
        method="given: profiles in wavelength_nm",
        pixel_range=(min(lows), max(highs)),
    )


def _known_grating_options(
    options: MethodOptions | None, warnings: list[str], *, assumed: AssumedGrating | None = None
) -> KnownGratingOptions:
    """The known-grating solve's options from another grating method's: those it shares are kept
    (none is lost on the way), the others, when set, are named in a warning; ``assumed``, when
    given, is what stands in for η without a grating file."""
    if options is None or isinstance(options, KnownGratingOptions):
        given = options or KnownGratingOptions()
        return given if assumed is None else replace(given, assumed_grating=assumed)
    # Every grating method's options share these (GratingMethodOptions).
    kept = KnownGratingOptions(
        prior_shrinkage=options.prior_shrinkage,
        refine_given_mapping=options.refine_given_mapping,
        slit_width_px=options.slit_width_px,
        psf_sigma_px=options.psf_sigma_px,
    )
    kept = kept if assumed is None else replace(kept, assumed_grating=assumed)
    defaults = type(options)()
    ignored = [
        name
        for name in type(options).__dataclass_fields__
        if name not in KnownGratingOptions.__dataclass_fields__
        and getattr(options, name) != getattr(defaults, name)
    ]
    if ignored:
        flags = ", ".join(f"--{name.replace('_', '-')}" for name in ignored)
        warnings.append(
            f"{flags} has no effect with a grating file: the grating efficiency is not estimated"
        )
    return kept


def _estimate(
    observations: Sequence[LampObservation],
    settings: OfflineSettings,
    checked: _Checked,
    *,
    image_input: bool,
    warnings: list[str],
    notes: list[str],
) -> tuple[EstimateResult, GratingEfficiency | None]:
    grid = settings.grid
    basis = resolve_basis(settings)
    warnings.extend(basis.warnings())
    method = check_method(settings.method, source="--method")
    where: dict[str, Any] = {}
    mapping = _wavelength_mapping(observations)
    if mapping is not None:
        where["mapping"] = mapping
    if settings.mapping_lamp is not None:
        where["mapping_lamp"] = settings.mapping_lamp
    with_direct = [obs.name for obs in observations if obs.direct_rgb is not None]
    moot = (
        "the grating file"
        if checked.grating is not None
        else "a direct measurement"
        if with_direct and method != KNOWN_GRATING_METHOD
        else None
    )
    if settings.assumed_grating is not None and moot is not None:
        warnings.append(f"--assume-grating has no effect: {moot} gives the grating efficiency")
    # The grating library: multilamp (or known-grating) through an earlier calibration's η.
    through_file = checked.grating is not None and method in (
        AUTO,
        MULTILAMP_METHOD,
        KNOWN_GRATING_METHOD,
    )
    if with_direct and not through_file and method != KNOWN_GRATING_METHOD:
        if checked.grating is not None:
            notes.append(
                f"grating file {checked.grating.source} not used: the direct measurement of "
                f"{', '.join(with_direct)} determines the grating efficiency"
            )
        if settings.method_options is not None:
            where["options"] = settings.method_options
        result = estimate(
            observations, method, grid=grid, basis=basis, budget=settings.budget, **where
        )
        return result, None
    if image_input and checked.grating is None and not with_direct:
        raise InputError(
            "no lamp has a direct (0th-order) measurement: the direct spot is saturated in every "
            "frame of every lamp; add a shorter exposure to the brackets, or give the grating's "
            "efficiency from an earlier calibration with --grating FILE",
            source="lamps",
        )
    advice: str | None = None
    if checked.grating is None:
        advice = (
            "; measure the direct RGB (--direct R,G,B) or give --grating FILE from an earlier "
            "calibration"
            if not with_direct
            else " (--method known-grating without --grating)"
        )
    if method not in (AUTO, MULTILAMP_METHOD, KNOWN_GRATING_METHOD):
        notes.append(
            f"method {settings.method!r} needs a direct measurement; used the known-grating solve"
        )
    # auto records its choice (and may keep a line lamp of unknown spectrum for the mapping only)
    result = estimate(
        observations,
        AUTO if method == AUTO else KNOWN_GRATING_METHOD,
        assume_flat_grating=True,
        grid=grid,
        basis=basis,
        budget=settings.budget,
        grating=checked.grating,
        options=_known_grating_options(
            settings.method_options, warnings, assumed=settings.assumed_grating
        ),
        **where,
    )
    if advice is not None and (flag := assumed_grating_flag(result, advice)) is not None:
        result = result.with_quality(flag)
    return result, checked.grating
