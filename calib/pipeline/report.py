"""``report.html``: one self-contained page (plots embedded) to judge an offline estimate.

Plots (also written as PNG files next to the page): the sensitivity with its uncertainty band, the
grating efficiency, the pixel→wavelength mapping with its error band, each lamp's profile against the
model fit with normalised residuals, and the detected geometry (:func:`calib.image.profiles.
write_geometry_png`). Tables: the warnings first, then the method, camera, mapping coefficients, fit
quality, timings, and every input file with its sha256. Matplotlib runs with the Agg canvas only
(no display, no pyplot state).
"""

from __future__ import annotations

import base64
import html
import math
import re
import shlex
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.figures import agg_figure, import_matplotlib
from calib.core.mapping import QuadraticMapping
from calib.image.profiles import write_geometry_png
from calib.pipeline.brackets import BracketProfiles
from calib.pipeline.estimate import OfflineEstimate

REPORT_FILE = "report.html"
PLOTS_DIR = "plots"
_CHANNEL_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")
_CHANNELS = ("R", "G", "B")


def _figure(width_in: float = 7.0, height_in: float = 3.6) -> Any:
    # fixed margins: a constrained layout doubles the drawing time of every plot
    figure = agg_figure(width_in, height_in)
    figure.subplots_adjust(left=0.1, right=0.97, bottom=0.14, top=0.9, wspace=0.3, hspace=0.12)
    return figure


def _save(figure: Any, path: Path) -> Path:
    figure.savefig(path, dpi=100)
    return path


def plot_sensitivity(path: Path, estimate: OfflineEstimate) -> Path:
    result = estimate.result
    figure = _figure()
    axes = figure.subplots()
    curves = result.physical_sensitivity()
    scale = float(np.max(result.sensitivity)) or 1.0
    for channel, name in enumerate(_CHANNELS):
        axes.plot(
            result.wavelength_nm, curves[:, channel], color=_CHANNEL_COLOURS[channel], label=name
        )
        if result.sensitivity_sigma is not None:
            sigma = result.sensitivity_sigma[:, channel] / scale
            axes.fill_between(
                result.wavelength_nm,
                curves[:, channel] - 2 * sigma,
                curves[:, channel] + 2 * sigma,
                color=_CHANNEL_COLOURS[channel],
                alpha=0.2,
                linewidth=0,
            )
    band = "±2σ band" if result.sensitivity_sigma is not None else "no uncertainty estimate"
    axes.set_title(f"camera sensitivity ({result.method}; {band})", fontsize=10, y=1.0)
    axes.set_xlabel("wavelength (nm)")
    axes.set_ylabel("relative sensitivity")
    axes.legend(fontsize=8)
    axes.grid(alpha=0.3)
    return _save(figure, path)


def plot_efficiency(path: Path, estimate: OfflineEstimate) -> Path | None:
    result = estimate.result
    efficiency = result.grating_efficiency
    if efficiency is None or not np.any(np.isfinite(efficiency)):
        return None
    figure = _figure(7.0, 3.0)
    axes = figure.subplots()
    axes.plot(result.wavelength_nm, efficiency, color="black")
    if result.grating_efficiency_sigma is not None:
        sigma = result.grating_efficiency_sigma
        axes.fill_between(
            result.wavelength_nm,
            efficiency - 2 * sigma,
            efficiency + 2 * sigma,
            color="grey",
            alpha=0.3,
        )
    origin = "given" if estimate.grating is not None else "estimated"
    if estimate.grating is None and result.method == "known-grating":
        origin = "assumed flat"
    axes.set_title(f"first-order grating efficiency ({origin}, maximum 1)", fontsize=10, y=1.0)
    axes.set_xlabel("wavelength (nm)")
    axes.set_ylabel("relative efficiency")
    axes.grid(alpha=0.3)
    return _save(figure, path)


def _mapping_sigma_nm(mapping: Any, pixel: FloatArray) -> FloatArray | None:
    covariance = getattr(mapping, "covariance", None)
    if covariance is None:
        return None
    design = np.stack([pixel**2, pixel, np.ones_like(pixel)], axis=1)
    variance = np.einsum("ij,jk,ik->i", design, np.asarray(covariance, dtype=np.float64), design)
    return np.asarray(np.sqrt(np.clip(variance, 0.0, None)), dtype=np.float64)


def plot_mapping(path: Path, estimate: OfflineEstimate) -> Path | None:
    mapping = estimate.result.mapping
    if mapping is None or not estimate.observations:
        return None
    pixel = np.asarray(estimate.observations[0].pixel, dtype=np.float64)
    wavelength = np.asarray(mapping.wavelength_nm(pixel), dtype=np.float64)
    figure = _figure(7.0, 3.2)
    axes, dispersion_axes = figure.subplots(1, 2, width_ratios=(1.6, 1))
    axes.plot(pixel, wavelength, color="black", label="g(p)")
    sigma = _mapping_sigma_nm(mapping, pixel)
    if sigma is not None:
        axes.fill_between(
            pixel,
            wavelength - 2 * sigma,
            wavelength + 2 * sigma,
            color="orange",
            alpha=0.4,
            label="±2σ",
        )
    grid = estimate.result.wavelength_nm
    axes.axhspan(float(grid[0]), float(grid[-1]), color="blue", alpha=0.06, label="working grid")
    axes.set_xlabel("pixel")
    axes.set_ylabel("wavelength (nm)")
    axes.set_title(f"mapping ({getattr(mapping, 'method', 'given')})", fontsize=10, y=1.0)
    axes.legend(fontsize=8)
    axes.grid(alpha=0.3)
    dispersion = np.gradient(wavelength, pixel)
    dispersion_axes.plot(pixel, dispersion, color="black")
    dispersion_axes.set_xlabel("pixel")
    dispersion_axes.set_ylabel("nm per pixel")
    dispersion_axes.set_title("dispersion", fontsize=10, y=1.0)
    dispersion_axes.grid(alpha=0.3)
    return _save(figure, path)


def plot_fit(path: Path, estimate: OfflineEstimate, lamp: str) -> Path | None:
    residuals = estimate.result.residuals.get(lamp)
    observation = next((obs for obs in estimate.observations if obs.name == lamp), None)
    if (
        observation is None
        or not isinstance(residuals, Mapping)
        or residuals.get("profile") is None
    ):
        return None
    difference = np.asarray(residuals["profile"], dtype=np.float64)
    if difference.shape != observation.profile.shape:
        return None
    model = observation.profile - difference
    figure = _figure(7.0, 4.4)
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=(2.2, 1))
    pixel = observation.pixel
    for channel, name in enumerate(_CHANNELS):
        colour = _CHANNEL_COLOURS[channel]
        top.plot(
            pixel,
            observation.profile[:, channel],
            color=colour,
            linewidth=0.8,
            label=f"{name} measured",
        )
        top.plot(
            pixel,
            model[:, channel],
            color=colour,
            linestyle="--",
            linewidth=1.2,
            label=f"{name} model",
        )
    top.set_ylabel("profile")
    top.set_title(f"{lamp}: profile and model", fontsize=10, y=1.0)
    top.legend(fontsize=7, ncol=3)
    top.grid(alpha=0.3)
    normalised = residuals.get("profile_normalised")
    values = np.asarray(normalised if normalised is not None else difference, dtype=np.float64)
    for channel in range(3):
        bottom.plot(pixel, values[:, channel], color=_CHANNEL_COLOURS[channel], linewidth=0.6)
    bottom.axhline(0.0, color="black", linewidth=0.6)
    bottom.set_ylabel("residual / σ" if normalised is not None else "residual")
    bottom.set_xlabel("pixel")
    bottom.grid(alpha=0.3)
    return _save(figure, path)


def plot_geometry(path: Path, profiles: BracketProfiles) -> Path:
    """The detected geometry on the geometry lamp's image (:func:`calib.image.profiles.write_geometry_png`)."""
    image, geometry = profiles.geometry_image()
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_geometry_png(path, image, geometry)


def import_plotting() -> None:
    """Import matplotlib's Agg canvas (about a second), e.g. in a thread while frames decode."""
    import_matplotlib()


# ---------------------------------------------------------------------------------------- HTML


def _escape(value: object) -> str:
    return html.escape(str(value), quote=True)


def _format(value: object, digits: int = 4) -> str:
    if value is None:
        return "—"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "—"
        return f"{value:.{digits}g}"
    return str(value)


def _table(rows: Sequence[tuple[str, object]]) -> str:
    body = "".join(f"<tr><th>{_escape(k)}</th><td>{_escape(_format(v))}</td></tr>" for k, v in rows)
    return f"<table class='facts'>{body}</table>"


def _image(path: Path, caption: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (
        f"<figure><img alt='{_escape(caption)}' src='data:image/png;base64,{data}'>"
        f"<figcaption>{_escape(caption)} ({_escape(path.parent.name + '/' + path.name)})</figcaption></figure>"
    )


def _file_stem(lamp: str) -> str:
    return re.sub(r"[^A-Za-z0-9._+-]+", "_", lamp).strip("._") or "lamp"


_STYLE = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:72em;color:#222}
h1{font-size:1.5em}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.5em 0}th,td{padding:.2em .8em;text-align:left;
vertical-align:top;border-bottom:1px solid #eee}table.facts th{color:#555;font-weight:normal}
.warning{background:#fff4e5;border-left:4px solid #f0a020;padding:.5em 1em;margin:.4em 0}
figure{margin:1em 0}img{max-width:100%}figcaption{color:#666;font-size:.9em}
code{font-size:.85em;word-break:break-all}
"""


def _summary_rows(estimate: OfflineEstimate) -> list[tuple[str, object]]:
    result = estimate.result
    mapping = result.mapping
    diagnostics = result.diagnostics
    camera = estimate.provenance.camera
    rows: list[tuple[str, object]] = [
        ("method", result.method),
        ("camera", camera.get("camera", "— (profile input)")),
        ("lamps", ", ".join(f"{obs.name} ({obs.kind})" for obs in estimate.observations)),
        (
            "working grid",
            f"{result.wavelength_nm[0]:g}–{result.wavelength_nm[-1]:g} nm, {result.wavelength_nm.size} wavelengths",
        ),
    ]
    if isinstance(mapping, QuadraticMapping):
        a, b, c = mapping.coefficients
        rows.append(
            (
                "mapping g(p) = a p² + b p + c",
                f"a = {a:.6g} nm/px², b = {b:.6g} nm/px, c = {c:.6g} nm",
            )
        )
        rows.append(("mapping found by", getattr(mapping, "method", "—")))
    rows.append(("mapping RE estimate", result.mapping_re_estimate))
    rows.append(("reduced χ² of the fit", diagnostics.get("reduced_chi2")))
    basis = diagnostics.get("basis")
    if isinstance(basis, Mapping):
        rows.append(("camera basis", basis.get("source")))
    if estimate.profiles is not None:
        rows.append(("geometry detected on", estimate.profiles.geometry_lamp))
        rows.append(("dispersion angle", f"{estimate.profiles.geometry.primary.angle_deg:.3f}°"))
    rows.append(
        (
            "uncertainty",
            "per wavelength (±2σ band)"
            if result.sensitivity_sigma is not None
            else "not estimated by this method",
        )
    )
    timings = estimate.timings
    if timings:
        rows.append(
            ("time", ", ".join(f"{k.removesuffix('_s')} {v:.2f} s" for k, v in timings.items()))
        )
    return rows


def write_report(
    out_dir: Path,
    estimate: OfflineEstimate,
    files: Mapping[str, Path] | None = None,
    *,
    prepared: Mapping[str, Path] | None = None,
) -> dict[str, Path]:
    """Write the plots (``plots/*.png``) and ``report.html`` into ``out_dir``.

    ``prepared`` holds plots already drawn (``{"plot:geometry": path}``), which are reused.

    Returns
    -------
    dict
        ``{"report": path, "plot:<name>": path, …}``.
    """
    plots_dir = out_dir / PLOTS_DIR
    plots_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    figures: list[tuple[Path, str]] = []

    def add(name: str, path: Path | None, caption: str) -> None:
        if path is not None:
            written[f"plot:{name}"] = path
            figures.append((path, caption))

    add(
        "sensitivity",
        plot_sensitivity(plots_dir / "sensitivity.png", estimate),
        "estimated camera sensitivity",
    )
    add("efficiency", plot_efficiency(plots_dir / "efficiency.png", estimate), "grating efficiency")
    add("mapping", plot_mapping(plots_dir / "mapping.png", estimate), "pixel → wavelength mapping")
    for observation in estimate.observations:
        stem = _file_stem(observation.name)
        add(
            f"fit:{observation.name}",
            plot_fit(plots_dir / f"fit-{stem}.png", estimate, observation.name),
            f"{observation.name}: profile vs. model",
        )
    geometry = (prepared or {}).get("plot:geometry")
    if geometry is None and estimate.profiles is not None:
        geometry = plot_geometry(plots_dir / "geometry.png", estimate.profiles)
    add(
        "geometry",
        geometry,
        "detected geometry (direct spot, first order, background strips)",
    )

    provenance = estimate.provenance
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        "<title>spectral-rig estimate</title>",
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>Camera spectral sensitivity — {_escape(provenance.camera.get('camera', 'profile input'))}</h1>",
        f"<p>{_escape(provenance.created.strftime('%Y-%m-%d %H:%M:%S UTC'))} · "
        f"{_escape(provenance.software.get('name'))} {_escape(provenance.software.get('version'))}</p>",
    ]
    if provenance.warnings:
        parts.append("<h2>Warnings</h2>")
        parts.extend(f"<div class='warning'>{_escape(w)}</div>" for w in provenance.warnings)
    parts.append("<h2>Summary</h2>")
    parts.append(_table(_summary_rows(estimate)))
    if files:
        parts.append(
            "<p>Files: "
            + ", ".join(f"<code>{_escape(p.name)}</code>" for p in files.values())
            + "</p>"
        )
    parts.append("<h2>Plots</h2>")
    parts.extend(_image(path, caption) for path, caption in figures)
    if provenance.notes:
        parts.append("<h2>Notes</h2><ul>")
        parts.extend(f"<li>{_escape(note)}</li>" for note in provenance.notes)
        parts.append("</ul>")
    parts.append(
        "<h2>Inputs</h2><table><tr><th>role</th><th>lamp</th><th>file</th><th>bytes</th><th>sha256</th></tr>"
    )
    parts.extend(
        f"<tr><td>{_escape(r.role)}</td><td>{_escape(r.lamp or '')}</td><td><code>{_escape(r.path)}</code></td>"
        f"<td>{r.size}</td><td><code>{_escape(r.sha256)}</code></td></tr>"
        for r in provenance.inputs
    )
    parts.append("</table>")
    if provenance.command_line:
        parts.append(
            f"<h2>Command</h2><p><code>{_escape(shlex.join(provenance.command_line))}</code></p>"
        )
    parts.append("</body></html>\n")
    report = out_dir / REPORT_FILE
    report.write_text("".join(parts), encoding="utf-8")
    written["report"] = report
    return written
