"""``calib spd``: the rig as a spectrometer — a lamp's SPD from its diffraction image.

With a calibrated camera (its sensitivity CSV, and the grating's efficiency when known), the lamp's
HDR bracket is merged (:mod:`calib.image.hdr`), the direct spot and first order found once
(:mod:`calib.image.profiles`) and reused for every image, the pixel→wavelength mapping found from a
fluorescent lamp's lines, and the SPD recovered, recognised, and summarised by CCT and
white-balance gains (:mod:`calib.spd.alvarez2014`, :mod:`calib.spd.light_sources`).

Outputs in ``--out``: ``spd.csv`` (``wavelength_nm,value``, maximum 1), ``spd.json`` (library
match and distance, CCT by each method, white-balance gains, mapping, settings, provenance),
``spd.png`` (the SPD, its uncertainty, the match) and ``geometry.png`` (what was detected).

Exit codes: 0 ok, 2 bad input (a file, a field, an image that does not show a spot and a band),
1 the estimation failed; the reason is printed on one line.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as distribution_version
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import typer

from calib.core.errors import CalibError, EstimationError, InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping, mapping_from_dict
from calib.core.result import json_safe
from calib.core.spectra import (
    MultiSpectrum,
    Spectrum,
    WavelengthGrid,
    read_multispectrum_csv,
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
    find_mapping,
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

#: The recovered SPD is computed over this range (further limited to where the camera responds).
RECOVERY_RANGE_NM = (380.0, 730.0)


# ------------------------------------------------------------------------------------- request


@dataclass(frozen=True)
class SpdRequest:
    """Everything ``calib spd`` needs, as paths and settings (see :func:`measure_spd`)."""

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


def read_camera(path: Path) -> MultiSpectrum:
    """A ``wavelength_nm,r,g,b`` sensitivity CSV (any header names; three value columns)."""
    camera = read_multispectrum_csv(path, name=path.name, negative="clip")
    if camera.values.shape[1] != 3:
        raise InputError(
            f"expected 3 sensitivity columns (R, G, B), found {camera.values.shape[1]} "
            f"{camera.channels}",
            source=str(path),
        )
    if float(camera.values.max()) <= 0:
        raise InputError("the sensitivities are zero everywhere", source=str(path))
    return camera.normalised()


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


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _software_version() -> str:
    try:
        return distribution_version("spectral-rig")
    except PackageNotFoundError:
        return "unknown"


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
    lamp_spectrum = (
        read_spectrum_csv(request.mapping_spectrum, negative="clip")
        if request.mapping_spectrum is not None
        else None
    )
    source_image, origin = (
        (mapping_image, "mapping lamp")
        if mapping_image is not None
        else (target, "the lamp itself")
    )
    try:
        mapping = find_mapping(
            _profile(source_image, geometry, "mapping lamp"),
            camera,
            grating_efficiency=efficiency,
            lamp_spectrum=lamp_spectrum,
        )
        wide = widened_geometry(geometry, mapping, RECOVERY_RANGE_NM)
        if lamp_spectrum is not None:
            # Refine again over the whole range, which the detected extent may not have covered.
            mapping = find_mapping(
                _profile(source_image, wide, "mapping lamp"),
                camera,
                grating_efficiency=efficiency,
                lamp_spectrum=lamp_spectrum,
                initial=mapping,
            )
            wide = widened_geometry(geometry, mapping, RECOVERY_RANGE_NM)
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
        read_spectrum_csv(request.grating_efficiency, negative="clip")
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
        "software": {"spectral-rig": _software_version()},
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
        return [{"path": str(path), "sha256": _sha256(path)} for path in paths]

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
        **{key: record([path])[0] if path else None for key, path in optional.items()},
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
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    spd = recovery.spectrum(name=name)
    sigma = recovery.sigma_spectrum()
    figure = Figure(figsize=(9, 5), layout="constrained")
    FigureCanvasAgg(figure)
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
    figure.savefig(path, dpi=110)
    return path


# ------------------------------------------------------------------------------------ command


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are :class:`InputError` (one line, exit code 2 via ``main``)."""

    def error(self, message: str) -> NoReturn:
        raise InputError(message, source="calib spd")


def _grid(text: str) -> WavelengthGrid:
    try:
        return WavelengthGrid.parse(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="calib spd",
        description="Measure a lamp's spectral power distribution with a calibrated camera and "
        "the diffraction grating (Alvarez et al. 2014).",
    )
    parser.add_argument(
        "--images",
        nargs="+",
        type=Path,
        required=True,
        metavar="RAW",
        help="the lamp's bracket (RAW files, any exposures)",
    )
    parser.add_argument(
        "--dark",
        nargs="+",
        type=Path,
        default=[],
        metavar="RAW",
        help="dark frames matching the lamp's exposures",
    )
    parser.add_argument(
        "--camera",
        type=Path,
        required=True,
        metavar="CSV",
        help="the camera's sensitivity: wavelength_nm,r,g,b",
    )
    parser.add_argument(
        "--grating-efficiency",
        type=Path,
        metavar="CSV",
        help="the grating's first-order efficiency: wavelength_nm,value (else assumed flat)",
    )
    parser.add_argument(
        "--mapping-lamp-images",
        nargs="+",
        type=Path,
        default=[],
        metavar="RAW",
        help="a fluorescent lamp's bracket in the same set-up, for the mapping",
    )
    parser.add_argument(
        "--mapping-lamp-dark",
        nargs="+",
        type=Path,
        default=[],
        metavar="RAW",
        help="its dark frames",
    )
    parser.add_argument(
        "--mapping-lamp-spectrum",
        type=Path,
        metavar="CSV",
        help="its measured spectrum (else its lines are taken from a reference "
        "list: a few nm less accurate)",
    )
    parser.add_argument(
        "--mapping",
        type=Path,
        metavar="JSON",
        help="a known mapping (a mapping record or a result.json with one)",
    )
    parser.add_argument("--name", default="lamp", help="the lamp's name in the outputs")
    parser.add_argument(
        "--source",
        choices=("auto", "point", "finite"),
        default="auto",
        help="finite: deconvolve the source's shape (auto: when it is wider than 1.5 samples)",
    )
    parser.add_argument(
        "--weighting",
        choices=("noise", "paper"),
        default="noise",
        help="paper: the median-distance weights alone",
    )
    parser.add_argument("--smoothness", type=float, default=50.0, help="w_s of the paper")
    parser.add_argument(
        "--metric",
        choices=("weighted", "l2"),
        default="weighted",
        help="distance for recognising the source",
    )
    parser.add_argument(
        "--grid",
        type=_grid,
        metavar="START:STOP:STEP",
        help="wavelengths of spd.csv in nm (default: 1 nm over the recovered range)",
    )
    parser.add_argument("--out", type=Path, required=True, metavar="DIR")
    parser.add_argument("--no-plots", action="store_true", help="skip spd.png and geometry.png")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    parser.add_argument("--json", action="store_true", help="print spd.json to stdout")
    return parser


def request_from_args(arguments: Sequence[str]) -> tuple[SpdRequest, argparse.Namespace]:
    options = build_parser().parse_args(list(arguments))
    if options.mapping is not None and options.mapping_lamp_images:
        raise InputError(
            "give either --mapping or --mapping-lamp-images, not both", source="calib spd"
        )
    if options.smoothness < 0:
        raise InputError(f"must be >= 0, got {options.smoothness}", source="--smoothness")
    request = SpdRequest(
        images=tuple(options.images),
        darks=tuple(options.dark),
        camera=options.camera,
        out=options.out,
        grating_efficiency=options.grating_efficiency,
        mapping_images=tuple(options.mapping_lamp_images),
        mapping_darks=tuple(options.mapping_lamp_dark),
        mapping_spectrum=options.mapping_lamp_spectrum,
        mapping_file=options.mapping,
        name=options.name,
        source=options.source,
        weighting=options.weighting,
        smoothness=options.smoothness,
        metric=options.metric,
        grid=options.grid,
        plots=not options.no_plots,
        command_line=("calib", "spd", *arguments),
    )
    return request, options


def _print_summary(measurement: SpdMeasurement, out: Path) -> None:
    from rich.console import Console
    from rich.table import Table

    summary = measurement.summary
    recognition = measurement.recognition
    table = Table(title=f"SPD of {summary['name']}", show_header=False)
    table.add_row("recovered range", "{:.0f}–{:.0f} nm".format(*measurement.recovery.range_nm))
    names = ", ".join(recognition.names)
    table.add_row(
        "library match",
        f"{names} (distance {recognition.distance:.4f}, margin {recognition.margin:.4f})",
    )
    cct = summary["cct"]["recovered (completed with the match)"]
    table.add_row("CCT", ", ".join(f"{k}: {v:.0f} K" for k, v in cct["cct_k"].items()))
    table.add_row("Duv", f"{cct['duv']:+.4f}")
    gains = summary["white_balance"]["camera_raw_gains"]["recovered"]
    table.add_row("camera WB gains", "R {:.3f}  G {:.3f}  B {:.3f}".format(*gains))
    for note in measurement.recovery.notes:
        table.add_row("note", note)
    table.add_row("outputs", str(out))
    Console(stderr=True).print(table)


def run(arguments: Sequence[str]) -> SpdMeasurement:
    """Parse, measure, report (used by the typer command; raises :class:`CalibError`)."""
    request, options = request_from_args(arguments)

    def progress(message: str) -> None:
        if not options.quiet:
            print(f"calib spd: {message}", file=sys.stderr)

    measurement = measure_spd(request, progress)
    if options.json:
        print(json.dumps(json_safe(measurement.summary), indent=2))
    if not options.quiet:
        _print_summary(measurement, request.out)
    return measurement


def register(app: typer.Typer) -> None:
    @app.command(
        "spd",
        context_settings={"allow_extra_args": True, "ignore_unknown_options": True},
        add_help_option=False,
        help="Measure a lamp's SPD with a calibrated camera (see calib spd --help).",
    )
    def spd(context: typer.Context) -> None:
        """Measure a lamp's spectral power distribution (calib spd --help for the options)."""
        try:
            run(context.args)
        except CalibError:
            raise
        except OSError as exc:
            raise InputError(f"{exc.strerror or exc}", source=str(exc.filename or "")) from None
