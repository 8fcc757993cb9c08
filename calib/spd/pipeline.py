"""The rig as a spectrometer: a lamp's SPD from its diffraction image, with a calibrated camera.

With the camera's sensitivity (and the grating's efficiency when known), :func:`measure_spd` merges
the lamp's HDR bracket (:mod:`calib.image.hdr`), finds the direct spot and first order once
(:mod:`calib.image.profiles`) and reuses them for every image, finds the pixel→wavelength mapping
from a fluorescent lamp's lines (or reads it from a file), recovers the SPD
(:func:`calib.spd.alvarez2014.recover_spd_alvarez2014`), recognises the source and summarises it by
CCT and white-balance gains (:mod:`calib.spd.light_sources`).

Outputs in ``request.out``: ``spd.csv`` (``wavelength_nm,value``, maximum 1), ``spd.json`` (library
match and distance, CCT by each method, white-balance gains, mapping, settings, provenance: the
software (:func:`calib.core.software.current_software`) and every input with its sha256),
``spd.png`` (the SPD, its uncertainty, the match) and ``geometry.png`` (what was detected).
``calib spd`` (:mod:`calib.cli.spd`) is its command line.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.checksums import file_sha256
from calib.core.errors import EstimationError, InputError
from calib.core.figures import agg_figure, save_png
from calib.core.formats import read_camera as read_camera_file
from calib.core.grating_file import read_grating_file
from calib.core.lamp_specs import is_spectrum_file, lamp_from_spec
from calib.core.line_lists import is_builtin
from calib.core.mapping import GratingGeometry, QuadraticMapping, mapping_from_dict
from calib.core.result import json_safe
from calib.core.software import current_software
from calib.core.spectra import (
    MultiSpectrum,
    Spectrum,
    WavelengthGrid,
    read_spectrum_csv,
    write_csv,
)
from calib.image.hdr import HdrImage, merge_bracket
from calib.image.profiles import DiffractionGeometry, detect_geometry, extract, write_geometry_png
from calib.image.profiles.geometry import DetectionError
from calib.spd.alvarez2014 import (
    DiffractedProfile,
    SourceMode,
    SpdRecovery,
    Weighting,
    instrument_view,
    recover_spd_alvarez2014,
    source_kernel_from_image,
    widened_geometry,
)
from calib.spd.light_sources import (
    CCT_METHODS,
    Metric,
    Recognition,
    camera_white_balance,
    colour_library,
    complete_outside_range,
    correlated_colour_temperature,
    recognise_light_source,
    srgb_white_balance_from_cct,
)
from calib.wavelength import CalibratedCamera, find_mapping

#: The recovered SPD is computed over this range (further limited to where the camera responds).
RECOVERY_RANGE_NM = (380.0, 730.0)


# ------------------------------------------------------------------------------------- request


@dataclass(frozen=True)
class SpdRequest:
    """Everything a measurement needs, as paths and settings (see :func:`measure_spd`)."""

    images: tuple[Path, ...]
    camera: Path
    out: Path
    darks: tuple[Path, ...] = ()
    grating_efficiency: Path | None = None
    mapping_images: tuple[Path, ...] = ()
    mapping_darks: tuple[Path, ...] = ()
    mapping_spectrum: Path | None = None
    mapping_file: Path | None = None
    name: str = "lamp"
    source: SourceMode = "auto"
    weighting: Weighting = "noise"
    smoothness: float = 50.0
    metric: Metric = "weighted"
    grid: WavelengthGrid | None = None
    plots: bool = True
    command_line: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class SpdMeasurement:
    """The outcome of :func:`measure_spd` (what the files hold)."""

    recovery: SpdRecovery
    spd: Spectrum
    sigma: Spectrum | None
    recognition: Recognition
    summary: dict[str, Any]
    geometry: DiffractionGeometry
    image: HdrImage
    files: dict[str, Path] = field(default_factory=dict)


# -------------------------------------------------------------------------------------- inputs


def _read_mapping_file(path: Path) -> QuadraticMapping | GratingGeometry:
    """A mapping JSON: a ``to_dict`` record, or a result file with a ``"mapping"`` entry."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("file not found", source=str(path)) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not a readable JSON file ({exc})", source=str(path)) from None
    record = data.get("mapping") if isinstance(data, dict) and "type" not in data else data
    if not isinstance(record, dict):
        raise InputError(
            "no mapping record (expected {'type': 'quadratic', 'a': …} or a 'mapping' entry)",
            source=str(path),
        )
    try:
        return mapping_from_dict(record)
    except InputError as exc:
        raise InputError(str(exc), source=str(path)) from None


def _merge(frames: Sequence[Path], darks: Sequence[Path], what: str) -> HdrImage:
    if not frames:
        raise InputError(f"no images for the {what}", source="--images")
    return merge_bracket(list(frames), darks=list(darks))


def _detect(images: Sequence[tuple[str, HdrImage]]) -> DiffractionGeometry:
    """Detect on every image and keep the geometry whose first order is the longest.

    A line lamp can show its first order as separate pieces; the longest band (usually a
    broadband lamp's) gives the best direction and extent, and is applied to every image.
    """
    found: list[DiffractionGeometry] = []
    first_error: DetectionError | None = None
    for _, image in images:
        try:
            found.append(detect_geometry(image))
        except DetectionError as exc:
            first_error = first_error or exc
    if not found:
        assert first_error is not None
        raise first_error
    return max(found, key=lambda g: g.primary.stop_px - g.primary.start_px)


def _profile(image: HdrImage, geometry: DiffractionGeometry, name: str) -> DiffractedProfile:
    extraction = extract(image, geometry)
    kernel = source_kernel_from_image(
        image, geometry, background_rgb=extraction.direct_background_rgb
    )
    return DiffractedProfile.from_extraction(extraction, name=name, source_kernel=kernel)


# ------------------------------------------------------------------------------------ pipeline


def _find_mapping(
    request: SpdRequest,
    target: HdrImage,
    mapping_image: HdrImage | None,
    geometry: DiffractionGeometry,
    camera: MultiSpectrum,
    efficiency: Spectrum | None,
) -> tuple[QuadraticMapping | GratingGeometry, DiffractionGeometry, str]:
    """The mapping, the geometry widened to the recovery range, and where the mapping came from."""
    if request.mapping_file is not None:
        mapping = _read_mapping_file(request.mapping_file)
        origin = f"file {request.mapping_file}"
        return mapping, widened_geometry(geometry, mapping, RECOVERY_RANGE_NM), origin
    lamp_spectrum, lines = (
        mapping_lamp_spectrum(request.mapping_spectrum)
        if request.mapping_spectrum is not None
        else (None, None)
    )
    source_image, origin = (
        (mapping_image, "mapping lamp")
        if mapping_image is not None
        else (target, "the lamp itself")
    )
    try:
        mapping = find_mapping(
            _profile(source_image, geometry, "mapping lamp"),
            camera=CalibratedCamera(camera, efficiency),
            lamp_spectrum=lamp_spectrum,
        )
        wide = widened_geometry(geometry, mapping, RECOVERY_RANGE_NM)
        if lamp_spectrum is not None:
            # Refine again over the whole range, which the detected extent may not have covered.
            mapping = find_mapping(
                _profile(source_image, wide, "mapping lamp"),
                camera=CalibratedCamera(camera, efficiency),
                lamp_spectrum=lamp_spectrum,
                start=mapping,
            )
            wide = widened_geometry(geometry, mapping, RECOVERY_RANGE_NM)
            mapping = mapping.with_details(details={**dict(mapping.details), "lines": lines})
    except EstimationError as exc:
        if mapping_image is None:
            raise InputError(
                "no pixel→wavelength mapping: give a fluorescent lamp's images "
                "(--mapping-lamp-images) or a mapping file (--mapping); the lamp itself shows "
                f"no fluorescent lines ({exc})",
                source="--mapping-lamp-images",
            ) from None
        raise EstimationError(f"mapping from the fluorescent lamp failed: {exc}") from None
    return mapping, wide, origin


def read_camera(path: Path) -> MultiSpectrum:
    """The camera's R, G, B sensitivity, channels by name (any camera file, :func:`read_camera_file`,
    which refuses a channel with no positive value)."""
    return read_camera_file(path).to_multispectrum().normalised()


def mapping_lamp_spectrum(source: Path) -> tuple[Spectrum, str]:
    """The mapping lamp's spectrum and what it is, as the result's ``mapping.details.lines`` says:
    a measured CSV (``"measured spectrum"``), or a named one (a colour-science light source such
    as FL11, ``builtin:NAME`` for a line list, as ``calib estimate --spectrum`` takes them), which
    is not a measurement of this lamp."""
    if is_spectrum_file(source):
        return read_spectrum_csv(source, negative="clip"), "measured spectrum"
    if is_builtin(str(source)):
        label = f"built-in line list {source} (not a measurement of the lamp)"
    else:
        label = f"named spectrum {source} (a reference table, not a measurement of the lamp)"
    return lamp_from_spec(str(source)), label


def read_grating_efficiency(path: Path) -> Spectrum:
    """The grating's first-order efficiency: a grating file (``.json``, as ``calib estimate`` and
    ``rig grating`` write it) or a table ``wavelength_nm,value`` (a maker's curve, or one measured),
    both through :func:`calib.core.grating_file.read_grating_file`."""
    grating = read_grating_file(path)
    return Spectrum(grating.wavelength_nm, grating.efficiency, name=path.name)


def measure_spd(
    request: SpdRequest, progress: Callable[[str], None] | None = None
) -> SpdMeasurement:
    """Run the whole measurement and write the outputs into ``request.out``.

    Raises
    ------
    InputError
        Unreadable or inconsistent files; images without a spot and a band; no way to a mapping.
    EstimationError
        The mapping or the recovery failed on the data.
    """
    say = progress or (lambda message: None)
    camera = read_camera(request.camera)
    efficiency = (
        read_grating_efficiency(request.grating_efficiency)
        if request.grating_efficiency is not None
        else None
    )
    say("merging the lamp's bracket")
    target = _merge(request.images, request.darks, "lamp")
    mapping_image = None
    if request.mapping_images:
        say("merging the mapping lamp's bracket")
        mapping_image = _merge(request.mapping_images, request.mapping_darks, "mapping lamp")
    elif request.mapping_spectrum is not None:
        raise InputError(
            "a mapping-lamp spectrum needs that lamp's images (--mapping-lamp-images)",
            source="--mapping-lamp-spectrum",
        )
    say("finding the direct spot and the first order")
    candidates = [("lamp", target)] + ([("mapping", mapping_image)] if mapping_image else [])
    geometry = _detect(candidates)
    say("finding the pixel→wavelength mapping")
    mapping, wide, mapping_origin = _find_mapping(
        request, target, mapping_image, geometry, camera, efficiency
    )
    say("recovering the SPD")
    profile = _profile(target, wide, request.name)
    recovery = recover_spd_alvarez2014(
        profile,
        camera,
        mapping,
        grating_efficiency=efficiency,
        source=request.source,
        weighting=request.weighting,
        smoothness=request.smoothness,
        range_nm=RECOVERY_RANGE_NM,
    )
    spd = recovery.spectrum(name=request.name)
    sigma = recovery.sigma_spectrum()
    say("recognising the source")
    recognition = recognise_light_source(
        spd,
        sigma=sigma,
        metric=request.metric,
        view=lambda entry: instrument_view(
            entry, recovery, profile, camera, grating_efficiency=efficiency
        ),
    )
    match = colour_library().entry(recognition.name).spectrum
    completed = complete_outside_range(spd, match)
    temperatures = {
        "recovered (measured range)": correlated_colour_temperature(spd),
        "recovered (completed with the match)": correlated_colour_temperature(completed),
        "library match (paper)": correlated_colour_temperature(match),
    }
    best_cct = temperatures["recovered (completed with the match)"].cct_k["Ohno 2013"]
    grid = request.grid or _output_grid(recovery)
    on_grid = recovery.on_grid(grid)
    summary: dict[str, Any] = {
        "name": request.name,
        "software": current_software().to_dict(),
        "command_line": list(request.command_line),
        "spd": {
            "file": "spd.csv",
            "grid": str(grid),
            "normalisation": "maximum = 1",
            "recovered_range_nm": list(recovery.range_nm),
        },
        "recognition": recognition.to_dict(),
        "cct": {key: value.to_dict() for key, value in temperatures.items()},
        "cct_methods": list(CCT_METHODS),
        "white_balance": {
            "camera_raw_gains": {
                "recovered": camera_white_balance(completed, camera).tolist(),
                "library_match": camera_white_balance(match, camera).tolist(),
                "meaning": "multipliers for the camera's raw R, G, B that make this lamp neutral",
            },
            "srgb_gains_from_cct": {
                "cct_k": best_cct,
                **_srgb_gains(best_cct),
                "meaning": "the paper's Eq. 14: linear sRGB, blackbody at the CCT vs. D65 white",
            },
        },
        "mapping": {"origin": mapping_origin, **json_safe(mapping.to_dict())},
        "geometry": geometry.to_dict(),
        "recovery": {
            "source": recovery.source,
            "settings": json_safe(dict(recovery.settings)),
            "notes": list(recovery.notes),
        },
        "direct_check": _direct_check(profile, completed, camera),
        "inputs": _inputs(request),
    }
    files = _write_outputs(request.out, on_grid, summary)
    if request.plots:
        files["spd.png"] = _plot(
            request.out / "spd.png", recovery, recognition, match, request.name
        )
        files["geometry.png"] = write_geometry_png(request.out / "geometry.png", target, wide)
    return SpdMeasurement(recovery, spd, sigma, recognition, summary, wide, target, files)


def _srgb_gains(cct_k: float) -> dict[str, Any]:
    """The paper's sRGB gains, or why there are none (a very warm CCT leaves the sRGB gamut)."""
    try:
        return {"gains": srgb_white_balance_from_cct(cct_k).tolist()}
    except InputError as exc:
        return {"gains": None, "reason": str(exc)}


def _output_grid(recovery: SpdRecovery, step_nm: float = 1.0) -> WavelengthGrid:
    lo, hi = recovery.range_nm
    return WavelengthGrid(
        float(np.ceil(lo / step_nm) * step_nm), float(np.floor(hi / step_nm) * step_nm), step_nm
    )


def _direct_check(
    profile: DiffractedProfile, spd: Spectrum, camera: MultiSpectrum
) -> dict[str, Any] | None:
    """The direct spot's chromaticity against the recovered SPD's (no grating in that path).

    A disagreement means the assumed grating efficiency (or the camera file) is off.
    """
    if profile.direct_rgb is None or np.any(profile.direct_rgb <= 0):
        return None
    gains = camera_white_balance(spd, camera)
    predicted = gains[1] / gains  # ∝ ∫ e s_c
    measured = profile.direct_rgb
    predicted_chroma = predicted / predicted.sum()
    measured_chroma = measured / measured.sum()
    cosine = float(predicted @ measured / (np.linalg.norm(predicted) * np.linalg.norm(measured)))
    return {
        "measured_rgb_chromaticity": measured_chroma.tolist(),
        "predicted_rgb_chromaticity": predicted_chroma.tolist(),
        "angular_error_deg": float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))),
    }


def _inputs(request: SpdRequest) -> dict[str, Any]:
    def record(paths: Sequence[Path]) -> list[dict[str, str]]:
        return [{"path": str(path), "sha256": file_sha256(path)[1]} for path in paths]

    def one(path: Path | None) -> dict[str, str] | None:
        if path is None:
            return None
        # A named spectrum (FL11, builtin:NAME) is no file: recorded by its name.
        return record([path])[0] if is_spectrum_file(path) else {"name": str(path)}

    optional = {
        "grating_efficiency": request.grating_efficiency,
        "mapping_spectrum": request.mapping_spectrum,
        "mapping_file": request.mapping_file,
    }
    return {
        "images": record(request.images),
        "darks": record(request.darks),
        "camera": record([request.camera])[0],
        "mapping_images": record(request.mapping_images),
        "mapping_darks": record(request.mapping_darks),
        **{key: one(path) for key, path in optional.items()},
    }


def _write_outputs(out: Path, on_grid: Spectrum, summary: dict[str, Any]) -> dict[str, Path]:
    out.mkdir(parents=True, exist_ok=True)
    csv_path = write_csv(out / "spd.csv", on_grid)
    json_path = out / "spd.json"
    json_path.write_text(json.dumps(json_safe(summary), indent=2) + "\n", encoding="utf-8")
    return {"spd.csv": csv_path, "spd.json": json_path}


def _plot(
    path: Path, recovery: SpdRecovery, recognition: Recognition, match: Spectrum, name: str
) -> Path:
    spd = recovery.spectrum(name=name)
    sigma = recovery.sigma_spectrum()
    figure = agg_figure(9, 5, layout="constrained")
    axes = figure.subplots()
    wavelength = spd.wavelength_nm
    if sigma is not None:
        axes.fill_between(
            wavelength,
            spd.values - 2 * sigma.values,
            spd.values + 2 * sigma.values,
            color="tab:blue",
            alpha=0.25,
            label="±2σ",
        )
    axes.plot(wavelength, spd.values, color="tab:blue", label="recovered")
    inside = match.at(wavelength)
    scale = float(spd.values @ inside) / max(float(inside @ inside), 1e-300)
    axes.plot(
        match.wavelength_nm,
        scale * match.values,
        color="black",
        linewidth=0.8,
        label=f"match: {recognition.name} (d = {recognition.distance:.3f})",
    )
    for k, colour_name in enumerate(("tab:red", "tab:green", "tab:purple")):
        axes.plot(
            wavelength,
            recovery.quotients[:, k] / max(float(np.clip(recovery.spd, 0, None).max()), 1e-300),
            color=colour_name,
            linewidth=0.5,
            alpha=0.5,
            label=f"{'RGB'[k]} quotient",
        )
    axes.set_xlim(wavelength[0] - 10, wavelength[-1] + 10)
    axes.set_ylim(-0.05, 1.15)
    axes.set_xlabel("wavelength (nm)")
    axes.set_ylabel("relative spectral power")
    axes.set_title(f"SPD of {spd.name} (source: {recovery.source})")
    axes.legend(loc="upper left", fontsize="small")
    save_png(figure, path, dpi=110)
    return path
