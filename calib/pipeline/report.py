"""``report.html``: one self-contained page (plots embedded) to judge an offline estimate.

From the top: a quality banner (the result's verdict, its flags and every other warning), the
summary (RE as ×10⁻², as the paper), what the camera is for (ColorChecker ΔE2000 under D50, D55,
D65 and A with the colour-correction matrix each gives, the ACES IDT matrices, and with a known
truth the colour error the estimate costs under D65 and A), the files written with where each drops
in (linked), then the plots (:mod:`calib.pipeline.report_plots`: sensitivity, grating efficiency,
mapping with its residuals and matched lines, a fit per lamp, the lamp spectra, the warm-up, the
detected geometry; truth dotted, ±2σ bands), the matched lines' table, notes, inputs with sha256
and the command.
"""

from __future__ import annotations

import base64
import html
import math
import os
import re
import shlex
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.mapping import QuadraticMapping
from calib.core.metrics import format_re, mapping_relative_error
from calib.pipeline.context import EstimateContext
from calib.pipeline.estimate import OfflineEstimate
from calib.pipeline.outputs import DeliveredCamera, deliver
from calib.pipeline.report_plots import (
    import_plotting,
    plot_efficiency,
    plot_fit,
    plot_geometry,
    plot_lamp_spectra,
    plot_mapping,
    plot_sensitivity,
    plot_warmup,
)

__all__ = ["PLOTS_DIR", "REPORT_FILE", "import_plotting", "plot_geometry", "write_report"]

REPORT_FILE = "report.html"
PLOTS_DIR = "plots"

#: Where each written file drops in (keys of :func:`calib.pipeline.outputs.write_outputs`).
FILE_USES = {
    "sensitivity": "colour-science (colour.io.read_sds_from_csv_file), numpy, spreadsheets",
    "camera_json": "rawtoaces: put it in a directory on RAWTOACES_DATA_PATH, under camera/",
    "dcamprof": "dcamprof make-target / make-profile -c (calib profile runs them: DCP, ICC)",
    "vkdt": "vkdt-mkclut: writes the .lut that vkdt's colour module reads",
    "dcp": "Adobe Camera Raw / Lightroom, RawTherapee: a dual-illuminant (A, D65) camera profile",
    "icc": "raw converters taking ICC input profiles (darktable, RawTherapee)",
    "grating": "a later calib estimate / rig estimate --grating without a direct measurement",
    "result": "everything above; calib idt, calib ccm and calib raw-to-raw read it",
}


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
td.num{text-align:right;font-variant-numeric:tabular-nums}
.banner{border:1px solid #bbb;border-left:6px solid #888;padding:.6em 1em;margin:1em 0}
.warning{background:#fff4e5;border-left:4px solid #f0a020;padding:.5em 1em;margin:.4em 0}
figure{margin:1em 0}img{max-width:100%}figcaption{color:#666;font-size:.9em}
code{font-size:.85em;word-break:break-all}pre{font-size:.85em}
"""


def _summary_rows(
    estimate: OfflineEstimate, delivered: DeliveredCamera
) -> list[tuple[str, object]]:
    result = estimate.result
    mapping = result.mapping
    diagnostics = result.diagnostics
    camera = estimate.provenance.camera
    rows: list[tuple[str, object]] = [
        ("method", result.method),
        ("camera", camera.get("camera", "— (profile input)")),
        (
            "camera files name it",
            f"{delivered.identity.name} (from {delivered.identity.source})"
            + (f"; {delivered.identity.note}" if delivered.identity.note else ""),
        ),
        ("lamps", ", ".join(f"{obs.name} ({obs.kind})" for obs in estimate.observations)),
        (
            "working grid",
            f"{result.wavelength_nm[0]:g}–{result.wavelength_nm[-1]:g} nm, "
            f"{result.wavelength_nm.size} wavelengths",
        ),
        ("camera files (380–780 nm / 5 nm)", delivered.extension.describe()),
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
        ends = mapping.sigma_at_wavelength_nm(result.wavelength_nm[[0, -1]])
        if ends is not None:
            reach = mapping.line_reach
            rows.append(
                (
                    "mapping σ at the grid's ends",
                    f"{ends[0]:.2g} nm at {result.wavelength_nm[0]:g} nm, {ends[1]:.2g} nm at "
                    f"{result.wavelength_nm[-1]:g} nm"
                    + (
                        ""
                        if reach is None
                        else f" (lines reach {reach.wavelength_range_nm[0]:.0f}–"
                        f"{reach.wavelength_range_nm[1]:.0f} nm)"
                    ),
                )
            )
    rows.append(("mapping RE estimate", format_re(result.mapping_re_estimate)))
    truth = delivered.truth
    if truth is not None:
        rows.append(
            (
                "RE against the truth (Eq. 16, estimate's grid)",
                format_re(delivered.truth_relative_error()),
            )
        )
        if truth.mapping is not None and mapping is not None and estimate.observations:
            pixel = estimate.observations[0].pixel
            rows.append(
                (
                    "mapping RE against the truth (Supp. Eq. 1)",
                    format_re(
                        mapping_relative_error(
                            mapping.wavelength_nm(pixel),
                            truth.mapping.wavelength_nm(pixel),
                            range_nm=(
                                float(result.wavelength_nm[0]),
                                float(result.wavelength_nm[-1]),
                            ),
                        )
                    ),
                )
            )
        rows.append(("truth from", truth.source))
    rows.append(("reduced χ² of the fit", diagnostics.get("reduced_chi2")))
    if delivered.negative_values:
        rows.append(
            (
                "negative values of the solve",
                f"{delivered.negative_values}, set to zero in the files",
            )
        )
    basis = diagnostics.get("basis")
    if isinstance(basis, Mapping):
        rows.append(("camera basis", basis.get("source")))
    if estimate.profiles is not None:
        rows.append(("geometry detected on", estimate.profiles.geometry_lamp))
        rows.append(("dispersion angle", f"{estimate.profiles.geometry.primary.angle_deg:.3f}°"))
    measured = _both_orders(mapping)
    if measured is not None:
        rows.append(("both first orders measure", measured))
    rows.append(("uncertainty", _uncertainty_row(estimate)))
    choice = diagnostics.get("method_choice")
    if isinstance(choice, Mapping):
        rows.append(("method chosen", f"{choice.get('method')}: {choice.get('reason')}"))
    timings = estimate.timings
    if timings:
        rows.append(
            ("time", ", ".join(f"{k.removesuffix('_s')} {v:.2f} s" for k, v in timings.items()))
        )
    return rows


#: A σ at least this large (degrees; ln F) says the two orders do not hold that quantity: at
#: normal incidence they mirror each other at any focal length.
_NOT_HELD = {"incidence_sigma_deg": 5.0, "log_focal_sigma": 0.5}


def _both_orders(mapping: object) -> str | None:
    """What the two first orders measured of the lens and the grating's tilt (decision 0197), as
    a sentence; ``None`` when the −1 order was not in the frame."""
    details = getattr(mapping, "details", None)
    measured = details.get("other_order") if isinstance(details, Mapping) else None
    if not isinstance(measured, Mapping):
        return None
    if "focal_length_px" not in measured:
        return f"not measured: {measured.get('refused')}"

    def held(key: str) -> float | None:
        value = measured.get(key)
        return float(value) if isinstance(value, int | float) and value < _NOT_HELD[key] else None

    focal = float(measured["focal_length_px"])
    focal_sigma, tilt_sigma = held("log_focal_sigma"), held("incidence_sigma_deg")
    parts = [
        "focal length not held"
        if focal_sigma is None
        else f"focal length {focal:.0f} ± {focal * focal_sigma:.0f} px",
        "grating tilt not held"
        if tilt_sigma is None
        else f"grating tilt (incidence) {float(measured['incidence_deg']):+.2f} ± {tilt_sigma:.2g}°",
    ]
    text = ", ".join(parts) + "; reported, not used by the mapping"
    refused = measured.get("refused")
    return text if refused is None else f"{text}; not trusted: {refused}"


def _quality_banner(estimate: OfflineEstimate) -> str:
    """The result's verdict (:class:`calib.core.result.Quality`), its flags, and every other
    warning."""
    quality = estimate.result.quality
    flagged = [flag.line() for flag in quality.flags]
    parts = [f"<div class='banner'>Quality: <strong>{_escape(quality.verdict)}</strong>"]
    parts.extend(f"<div class='warning'>{_escape(line)}</div>" for line in flagged)
    others = [w for w in estimate.provenance.warnings if w not in flagged]
    if others:
        parts.append(f"<br>{len(others)} warning(s):")
        parts.extend(f"<div class='warning'>{_escape(w)}</div>" for w in others)
    elif not flagged:
        parts.append("<br>No warnings.")
    parts.append("</div>")
    return "".join(parts)


def _uncertainty_row(estimate: OfflineEstimate) -> str:
    """What the ±2σ band holds: the budget's components by share of the variance."""
    result = estimate.result
    if result.sensitivity_sigma is None:
        return "not estimated by this method"
    budget = result.quality.uncertainty
    share = budget.get("share_of_variance") if budget else None
    if not isinstance(share, Mapping):
        return "per wavelength (±2σ band): the method's own σ"
    named = ", ".join(
        f"{name} {100 * float(value):.0f} %"
        for name, value in sorted(share.items(), key=lambda item: -float(item[1]))
        if float(value) >= 0.005
    )
    chi2 = budget.get("reduced_chi2")
    fit = f"; reduced χ² {float(chi2):.3g}" if isinstance(chi2, int | float) else ""
    return f"per wavelength (±2σ band); variance: {named}{fit}"


def _number_cell(value: float, digits: int = 2) -> str:
    return f"<td class='num'>{value:.{digits}f}</td>" if math.isfinite(value) else "<td>—</td>"


def _matrix(values: Any) -> str:
    rows = np.asarray(values, dtype=np.float64)
    return "<pre>" + "\n".join("  ".join(f"{v:+.4f}" for v in row) for row in rows) + "</pre>"


def _colour_section(delivered: DeliveredCamera) -> list[str]:
    """ΔE2000 of the ColorChecker under each illuminant, the truth comparison, the IDTs."""
    parts = ["<h2>What the camera is for: colour</h2>"]
    uses = delivered.uses
    if uses is None:
        parts.append(f"<p>{_escape(delivered.uses_error or 'not computed')}</p>")
        return parts
    if uses.truth:
        parts.append(
            "<p>Against the truth: the real camera's ColorChecker developed with the "
            "colour-correction matrix fitted to the estimate, compared with the same RGB developed "
            "with the matrix fitted to the truth (what the estimate costs), and with colorimetry. "
            "ΔE2000, mean / max over the 24 patches.</p><table><tr><th>illuminant</th>"
            "<th>estimate vs truth</th><th>worst patch</th><th>estimate's matrix vs colorimetry"
            "</th><th>truth's own matrix vs colorimetry</th></tr>"
        )
        for comparison in uses.truth:
            parts.append(
                f"<tr><td>{_escape(comparison.illuminant)}</td>"
                f"<td class='num'>{comparison.estimate_vs_truth.mean:.2f} / "
                f"{comparison.estimate_vs_truth.max:.2f}</td>"
                f"<td>{_escape(comparison.estimate_vs_truth.worst)}</td>"
                f"<td class='num'>{comparison.estimate_vs_colorimetry.mean:.2f} / "
                f"{comparison.estimate_vs_colorimetry.max:.2f}</td>"
                f"<td class='num'>{comparison.truth_vs_colorimetry.mean:.2f} / "
                f"{comparison.truth_vs_colorimetry.max:.2f}</td></tr>"
            )
        parts.append("</table>")
    parts.append(
        "<p>Colour-correction matrix per illuminant (white-balanced camera RGB → CIE XYZ, the "
        "white exact) and the ΔE2000 of the ColorChecker it predicts from the estimated curves "
        "(how close a 3×3 matrix brings this camera to colorimetry).</p><table><tr>"
        "<th>illuminant</th><th>mean ΔE2000</th><th>max</th><th>worst patch</th>"
        "<th>white balance R, G, B</th><th>matrix</th></tr>"
    )
    for correction in uses.corrections:
        parts.append(
            f"<tr><td>{_escape(correction.illuminant)}</td>"
            + _number_cell(correction.delta_e.mean)
            + _number_cell(correction.delta_e.max)
            + f"<td>{_escape(correction.delta_e.worst)}</td><td>"
            + ", ".join(f"{v:.3f}" for v in correction.white_balance)
            + f"</td><td>{_matrix(correction.matrix)}</td></tr>"
        )
    parts.append(
        "</table><p>ACES IDT (colour.matrix_idt, rawtoaces' method): white-balanced "
        "camera RGB → ACES2065-1.</p><table><tr><th>illuminant</th>"
        "<th>white balance</th><th>matrix</th></tr>"
    )
    for idt in uses.idts:
        parts.append(
            f"<tr><td>{_escape(idt.illuminant)}</td><td>"
            + ", ".join(f"{v:.3f}" for v in idt.white_balance)
            + f"</td><td>{_matrix(idt.matrix)}</td></tr>"
        )
    parts.append("</table>")
    return parts


def matched_lines(estimate: OfflineEstimate) -> list[dict[str, Any]] | None:
    """The mapping's matched emission lines, when the mapping search records them."""
    result = estimate.result
    candidates: list[Any] = [getattr(result.mapping, "matched_lines", None)]
    details = getattr(result.mapping, "details", None)
    if isinstance(details, Mapping):
        candidates.append(details.get("matched_lines"))
    diagnostics = result.diagnostics
    candidates.append(diagnostics.get("matched_lines"))
    mapping_info = diagnostics.get("mapping")
    if isinstance(mapping_info, Mapping):
        candidates.append(mapping_info.get("matched_lines"))
    for lines in candidates:
        if lines is None or isinstance(lines, str | bytes) or not isinstance(lines, Sequence):
            continue
        records = []
        for line in lines:
            if hasattr(line, "to_dict"):
                line = line.to_dict()
            if isinstance(line, Mapping):
                records.append(dict(line))
        return records
    return None


def _lines_section(lines: list[dict[str, Any]] | None) -> list[str]:
    parts = ["<h2>Matched lines</h2>"]
    if lines is None:
        return [
            *parts,
            "<p>Not available: this mapping search does not record the lines it matched.</p>",
        ]
    if not lines:
        return [*parts, "<p>The mapping search matched no lines.</p>"]
    columns = list(dict.fromkeys(key for line in lines for key in line))
    parts.append("<table><tr>" + "".join(f"<th>{_escape(c)}</th>" for c in columns) + "</tr>")
    for line in lines:
        parts.append(
            "<tr>"
            + "".join(f"<td>{_escape(_format(line.get(c), 7))}</td>" for c in columns)
            + "</tr>"
        )
    parts.append("</table>")
    return parts


def _files_section(files: Mapping[str, Path], out_dir: Path) -> list[str]:
    parts = ["<h2>Files</h2><table><tr><th>file</th><th>drops into</th></tr>"]
    for key, path in files.items():
        if key.startswith("plot:") or key == "report":
            continue
        link = Path(os.path.relpath(path, out_dir)).as_posix()
        parts.append(
            f"<tr><td><a href='{_escape(link)}'><code>{_escape(path.name)}</code></a></td>"
            f"<td>{_escape(FILE_USES.get(key, ''))}</td></tr>"
        )
    parts.append("</table>")
    if "dcp" not in files:
        parts.append(
            "<p>DCP and ICC profiles: not made here (dcamprof was not found on PATH, or failed: "
            "result.json's <code>dcamprof</code> entry says which); <code>calib profile "
            "DIR</code> makes them with dcamprof installed.</p>"
        )
    return parts


def write_report(
    out_dir: Path,
    estimate: OfflineEstimate,
    files: Mapping[str, Path] | None = None,
    *,
    prepared: Mapping[str, Path] | None = None,
    delivered: DeliveredCamera | None = None,
    context: EstimateContext | None = None,
) -> dict[str, Path]:
    """Write the plots (``plots/*.png``) and ``report.html`` into ``out_dir``.

    Parameters
    ----------
    out_dir
        Where the other outputs are.
    estimate
        The estimate.
    files
        The files written for it (linked from the page).
    prepared
        Plots already drawn (``{"plot:geometry": path}``), reused.
    delivered
        :func:`calib.pipeline.outputs.deliver`'s result (computed here when not given).
    context
        The truth and the session's warm-up records, when known.

    Returns
    -------
    dict
        ``{"report": path, "plot:<name>": path, …}``.
    """
    context = context or EstimateContext()
    delivered = delivered or deliver(estimate, context.truth)
    plots_dir = out_dir / PLOTS_DIR
    plots_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    figures: list[tuple[Path, str]] = []

    def add(name: str, path: Path | None, caption: str) -> None:
        if path is not None:
            written[f"plot:{name}"] = path
            figures.append((path, caption))

    lines = matched_lines(estimate)
    add(
        "sensitivity",
        plot_sensitivity(plots_dir / "sensitivity.png", estimate, delivered),
        "camera sensitivity",
    )
    add(
        "efficiency",
        plot_efficiency(plots_dir / "efficiency.png", estimate, delivered),
        "grating efficiency",
    )
    add(
        "mapping",
        plot_mapping(plots_dir / "mapping.png", estimate, delivered, lines or ()),
        "pixel → wavelength mapping and its residuals",
    )
    for observation in estimate.observations:
        stem = _file_stem(observation.name)
        add(
            f"fit:{observation.name}",
            plot_fit(plots_dir / f"fit-{stem}.png", estimate, observation),
            f"{observation.name}: profile vs. model",
        )
    add(
        "lamps",
        plot_lamp_spectra(plots_dir / "lamp-spectra.png", estimate.observations),
        "lamp spectra",
    )
    add("warmup", plot_warmup(plots_dir / "warmup.png", context.warmup), "lamp warm-up")
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
        _quality_banner(estimate),
        "<h2>Summary</h2>",
        _table(_summary_rows(estimate, delivered)),
        *_colour_section(delivered),
    ]
    if files:
        parts.extend(_files_section(files, out_dir))
    parts.append("<h2>Plots</h2>")
    if not context.warmup:
        parts.append(
            "<p>Lamp warm-up: not recorded with these inputs (rig sessions record it).</p>"
        )
    parts.extend(_image(path, caption) for path, caption in figures)
    parts.extend(_lines_section(lines))
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
