"""The report's plots, each a PNG (Matplotlib's Agg canvas only: no display, no pyplot state).

Every curve carries its ±2σ band when the estimate has one (and says so when it has none); the
known truth, when there is one, is drawn dotted over the estimate.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.figures import agg_figure, import_matplotlib, save_png, scientific_y_ticks
from calib.core.observations import LampObservation
from calib.core.spectra import MultiSpectrum, Spectrum
from calib.core.truth import GroundTruth
from calib.image.profiles import write_geometry_png
from calib.model.forward import render_observation
from calib.pipeline.brackets import BracketProfiles
from calib.pipeline.context import WarmupTrace
from calib.pipeline.estimate import OfflineEstimate
from calib.pipeline.outputs import DeliveredCamera

CHANNEL_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")
CHANNELS = ("R", "G", "B")
_TRUTH_STYLE = {"linestyle": ":", "linewidth": 1.6}


def _figure(width_in: float = 7.0, height_in: float = 3.6) -> Any:
    # fixed margins (a constrained layout doubles the drawing time of every plot), wide enough on
    # the left for a y label beside tick labels of up to five characters
    figure = agg_figure(width_in, height_in)
    figure.subplots_adjust(left=0.12, right=0.97, bottom=0.14, top=0.9, wspace=0.3, hspace=0.12)
    return figure


def _short_ticks(axes: Any) -> None:
    """Tick labels in scientific notation beyond 10⁴ (the power shown once), so they stay short."""
    scientific_y_ticks(axes, (-3, 4))


def _save(figure: Any, path: Path) -> Path:
    return save_png(figure, path, dpi=100)


def _title(axes: Any, text: str) -> None:
    """The axes' title on its top edge (``y=1.0``, the place Matplotlib's automatic placement keeps
    when nothing rises above the axes). Automatic placement lays the y axis out once more at every
    draw to find its offset text (``×10ⁿ``), a tenth of a plot's drawing; only plots without an
    offset text take this (:func:`plot_fit`, whose DN axis has one, keeps the automatic place).
    """
    axes.set_title(text, fontsize=9, y=1.0)


def _band(axes: Any, x: FloatArray, y: FloatArray, sigma: FloatArray | None, colour: str) -> None:
    if sigma is None:
        return
    known = np.isfinite(sigma)
    axes.fill_between(
        x,
        np.where(known, y - 2 * sigma, np.nan),
        np.where(known, y + 2 * sigma, np.nan),
        color=colour,
        alpha=0.2,
        linewidth=0,
    )


def plot_sensitivity(path: Path, estimate: OfflineEstimate, delivered: DeliveredCamera) -> Path:
    """The estimate on its grid (±2σ), its extension to 380–780 nm (dashed, ±2σ), the truth."""
    result = estimate.result
    curves = delivered.curves
    extended = delivered.extension.curves
    figure = _figure(7.0, 3.9)
    axes = figure.subplots()
    outside = ~extended.measured
    for channel, name in enumerate(CHANNELS):
        colour = CHANNEL_COLOURS[channel]
        axes.plot(curves.wavelength_nm, curves.values[:, channel], color=colour, label=name)
        _band(
            axes,
            curves.wavelength_nm,
            curves.values[:, channel],
            None if curves.sigma is None else curves.sigma[:, channel],
            colour,
        )
        if outside.any():
            for side in (
                (extended.wavelength_nm < curves.range_nm[0]),
                (extended.wavelength_nm > curves.range_nm[1]),
            ):
                if not side.any():
                    continue
                # join the extension to the measured end it continues
                index = np.flatnonzero(side)
                joined = np.union1d(
                    index, [max(index[0] - 1, 0), min(index[-1] + 1, side.size - 1)]
                )
                axes.plot(
                    extended.wavelength_nm[joined],
                    extended.values[joined, channel],
                    color=colour,
                    linestyle="--",
                    linewidth=1.0,
                )
                sigma = extended.sigma
                _band(
                    axes,
                    extended.wavelength_nm[side],
                    extended.values[side, channel],
                    None if sigma is None else sigma[side, channel],
                    colour,
                )
        if delivered.truth is not None:
            truth = delivered.truth.camera
            axes.plot(
                truth.wavelength_nm,
                truth.values[:, channel],
                color=colour,
                label=f"{name} truth" if channel == 0 else None,
                **_TRUTH_STYLE,
            )
    bands = (
        "±2σ bands" if result.sensitivity_sigma is not None else "no σ inside the measured range"
    )
    parts = [f"camera sensitivity ({result.method}; {bands}"]
    if outside.any():
        parts.append("dashed: extended to 380–780 nm, ±2σ")
    if delivered.truth is not None:
        parts.append("dotted: truth")
    _title(axes, "; ".join(parts) + ")")
    axes.set_xlabel("wavelength (nm)")
    axes.set_ylabel("relative sensitivity")
    axes.set_xlim(380.0, 780.0)
    axes.legend(fontsize=8, ncol=4)
    axes.grid(alpha=0.3)
    return _save(figure, path)


def plot_efficiency(
    path: Path, estimate: OfflineEstimate, delivered: DeliveredCamera
) -> Path | None:
    """η(λ) with its ±2σ band, and the truth's η scaled to the same maximum over the grid; with a
    physical grating model, η₀ and η₁ in absolute terms (:func:`plot_grating_orders`)."""
    result = estimate.result
    efficiency = result.grating_efficiency
    if efficiency is None or not np.any(np.isfinite(efficiency)):
        return None
    record = result.diagnostics.get("grating_model")
    if isinstance(record, dict) and "first_order_efficiency" in record:
        stated = result.grating_efficiency_sigma
        return plot_grating_orders(
            path,
            result.wavelength_nm,
            record,
            delivered.truth,
            first_order_sigma=None
            if stated is None
            else absolute_first_order_sigma(record, np.asarray(stated, dtype=np.float64)),
        )
    figure = _figure(7.0, 3.2)
    axes = figure.subplots()
    axes.plot(result.wavelength_nm, efficiency, color="black", label="estimate")
    _band(axes, result.wavelength_nm, efficiency, result.grating_efficiency_sigma, "grey")
    truth = None if delivered.truth is None else delivered.truth.grating_efficiency
    if truth is not None:
        on_grid = truth.at(result.wavelength_nm)
        peak = float(np.max(on_grid))
        if peak > 0:
            scale = float(np.nanmax(efficiency)) / peak
            axes.plot(
                truth.wavelength_nm,
                truth.values * scale,
                color="black",
                label="truth (same maximum)",
                **_TRUTH_STYLE,
            )
    origin = "given" if estimate.grating is not None else "estimated, η₀ taken flat"
    if estimate.grating is None and result.method == "known-grating":
        origin = "assumed flat"
    band = "±2σ band" if result.grating_efficiency_sigma is not None else "no σ from this method"
    _title(axes, f"first-order grating efficiency ({origin}, maximum 1; {band})")
    axes.set_xlabel("wavelength (nm)")
    axes.set_ylabel("relative efficiency")
    axes.legend(fontsize=8)
    axes.grid(alpha=0.3)
    return _save(figure, path)


def absolute_first_order_sigma(record: Mapping[str, Any], shape_sigma: FloatArray) -> FloatArray:
    """σ of η₁ on its absolute scale from the result's σ of η, which is the σ of the maximum-1 shape
    (decision 0042: zero at the peak, a common scale cancels): the shape's σ at η₁'s peak, joined
    in quadrature with the model's own σ of η₁, which carries the scale."""
    first_order = np.asarray(record["first_order_efficiency"], dtype=np.float64)
    own = np.asarray(
        record.get("first_order_efficiency_sigma", np.zeros_like(first_order)), dtype=np.float64
    )
    return np.asarray(np.hypot(own, shape_sigma * float(np.nanmax(first_order))), dtype=np.float64)


def plot_grating_orders(
    path: Path,
    wavelength_nm: FloatArray,
    record: Mapping[str, Any],
    truth: GroundTruth | None,
    *,
    first_order_sigma: FloatArray | None = None,
) -> Path:
    """η₁ and η₀ of a physical grating model (absolute fractions) with ±2σ bands, and the truth's
    orders where known (the twin's), on the same absolute scale. ``first_order_sigma`` (the
    result's stated σ of η, its budget) replaces the model's own σ of η₁ when given."""
    figure = _figure(7.0, 3.4)
    axes = figure.subplots()
    orders = (
        ("η₁ (first order)", "first_order_efficiency", "tab:blue"),
        ("η₀ (0th order, the direct spot)", "zeroth_order_efficiency", "tab:orange"),
    )
    for label, key, colour in orders:
        values = np.asarray(record[key], dtype=np.float64)
        sigma = np.asarray(record.get(f"{key}_sigma", np.zeros_like(values)), dtype=np.float64)
        if key == "first_order_efficiency" and first_order_sigma is not None:
            sigma = first_order_sigma
            label = "η₁ (first order; band: the σ budget's shape and the model's scale)"
        axes.plot(wavelength_nm, values, color=colour, label=label)
        _band(axes, wavelength_nm, values, sigma, colour)
    if truth is not None:
        for curve, colour in (
            (truth.grating_efficiency, "tab:blue"),
            (truth.zeroth_order_efficiency, "tab:orange"),
        ):
            if curve is not None:
                inside = (curve.wavelength_nm >= wavelength_nm[0]) & (
                    curve.wavelength_nm <= wavelength_nm[-1]
                )
                axes.plot(
                    curve.wavelength_nm[inside],
                    curve.values[inside],
                    color=colour,
                    label="truth" if colour == "tab:blue" else None,
                    **_TRUTH_STYLE,
                )
    parameters = record.get("parameters", {})
    described = ", ".join(
        f"{name} = {value:.4g} ± {parameters.get(f'{name}_sigma', float('nan')):.2g}"
        for name, value in parameters.items()
        if name in ("peak_phase_rad", "blaze_nm")
    )
    _title(axes, f"grating efficiency, {record.get('model')} model ({described}); ±2σ bands")
    axes.set_xlabel("wavelength (nm)")
    axes.set_ylabel("efficiency (fraction of the incident light)")
    axes.set_ylim(bottom=0.0)
    axes.legend(fontsize=8)
    axes.grid(alpha=0.3)
    return _save(figure, path)


def mapping_sigma_nm(mapping: Any, pixel: FloatArray) -> FloatArray | None:
    """The mapping's stated σ of g(p) at ``pixel`` (its covariance's and the extrapolation past its
    lines: :meth:`calib.core.mapping.QuadraticMapping.sigma_nm`), or ``None``."""
    sigma = getattr(mapping, "sigma_nm", None)
    return None if sigma is None else sigma(pixel)


def plot_mapping(
    path: Path,
    estimate: OfflineEstimate,
    delivered: DeliveredCamera,
    lines: Sequence[Mapping[str, Any]] = (),
) -> Path | None:
    """g(p) with ±2σ, matched lines when known, and the residuals (against the truth and the lines)."""
    mapping = estimate.result.mapping
    if mapping is None or not estimate.observations:
        return None
    pixel = np.asarray(estimate.observations[0].pixel, dtype=np.float64)
    wavelength = np.asarray(mapping.wavelength_nm(pixel), dtype=np.float64)
    sigma = mapping_sigma_nm(mapping, pixel)
    figure = _figure(7.0, 4.6)
    axes, residual_axes = figure.subplots(2, 1, sharex=True, height_ratios=(2.0, 1.2))
    axes.plot(pixel, wavelength, color="black", label="g(p)")
    if sigma is not None:
        _band(axes, pixel, wavelength, sigma, "orange")
    grid = estimate.result.wavelength_nm
    axes.axhspan(float(grid[0]), float(grid[-1]), color="blue", alpha=0.06, label="working grid")
    truth = None if delivered.truth is None else delivered.truth.mapping
    truth_nm = None if truth is None else np.asarray(truth.wavelength_nm(pixel), dtype=np.float64)
    if truth_nm is not None:
        axes.plot(pixel, truth_nm, color="black", label="truth", **_TRUTH_STYLE)
        residual_axes.plot(pixel, wavelength - truth_nm, color="black", label="g(p) − truth")
    if sigma is not None:
        residual_axes.fill_between(
            pixel, -2 * sigma, 2 * sigma, color="orange", alpha=0.3, linewidth=0, label="±2σ"
        )
    line_pixel = np.array([float(line["pixel"]) for line in lines if "pixel" in line])
    line_nm = np.array([float(line["wavelength_nm"]) for line in lines if "pixel" in line])
    if line_pixel.size:
        axes.plot(line_pixel, line_nm, "o", color="purple", markersize=4, label="matched lines")
        fitted = np.asarray(mapping.wavelength_nm(line_pixel), dtype=np.float64)
        residual_axes.plot(
            line_pixel, line_nm - fitted, "o", color="purple", markersize=4, label="line − g(p)"
        )
    residual_axes.axhline(0.0, color="grey", linewidth=0.6)
    axes.set_ylabel("wavelength (nm)")
    _title(
        axes,
        f"mapping ({getattr(mapping, 'method', 'given')}; "
        + ("±2σ band" if sigma is not None else "no σ for this mapping")
        + ")",
    )
    axes.legend(fontsize=7, ncol=2)
    axes.grid(alpha=0.3)
    residual_axes.set_ylabel("residual (nm)")
    residual_axes.set_xlabel("pixel (from the direct spot)")
    if truth_nm is not None or line_pixel.size or sigma is not None:
        residual_axes.legend(fontsize=7, ncol=3)
    residual_axes.grid(alpha=0.3)
    return _save(figure, path)


def _predicted_profile(
    estimate: OfflineEstimate, observation: LampObservation
) -> tuple[FloatArray, str] | None:
    """The lamp's profile as the estimate predicts it (one overall scale fitted), when possible."""
    result = estimate.result
    if result.mapping is None or observation.profile_wavelength_nm is not None:
        return None
    efficiency = result.efficiency_spectrum()
    rendered = render_observation(
        observation.spectrum,
        MultiSpectrum(result.wavelength_nm, np.clip(result.sensitivity, 0.0, None)),
        mapping=result.mapping,
        pixel=observation.pixel,
        grating_efficiency=efficiency,
    )
    model = rendered.clean_profile
    weights = (
        np.ones_like(model)
        if observation.profile_sigma is None
        else 1.0 / np.maximum(observation.profile_sigma, 1e-300) ** 2
    )
    denominator = float(np.sum(weights * model * model))
    if denominator <= 0:
        return None
    scale = float(np.sum(weights * model * observation.profile)) / denominator
    return model * scale, "predicted by the estimate (not in the solve; one scale fitted)"


def plot_fit(path: Path, estimate: OfflineEstimate, observation: LampObservation) -> Path | None:
    """Measured profile against the model, and the residuals (normalised by σ when known)."""
    residuals = estimate.result.residuals.get(observation.name)
    difference = None
    normalised = None
    how = "the solve's fit"
    if isinstance(residuals, Mapping) and residuals.get("profile") is not None:
        difference = np.asarray(residuals["profile"], dtype=np.float64)
        if difference.shape != observation.profile.shape:
            difference = None
        elif residuals.get("profile_normalised") is not None:
            normalised = np.asarray(residuals["profile_normalised"], dtype=np.float64)
    if difference is None:
        predicted = _predicted_profile(estimate, observation)
        if predicted is None:
            return None
        model, how = predicted
        difference = observation.profile - model
        if observation.profile_sigma is not None:
            normalised = difference / np.maximum(observation.profile_sigma, 1e-300)
    model = observation.profile - difference
    figure = _figure(7.0, 4.4)
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=(2.2, 1))
    pixel = observation.pixel
    for channel, name in enumerate(CHANNELS):
        colour = CHANNEL_COLOURS[channel]
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
        if observation.profile_sigma is not None:
            _band(
                top,
                pixel,
                observation.profile[:, channel],
                observation.profile_sigma[:, channel],
                colour,
            )
    top.set_ylabel("profile (DN)")
    _short_ticks(top)
    top.set_title(f"{observation.name}: profile and model ({how})", fontsize=9)
    top.legend(fontsize=7, ncol=3)
    top.grid(alpha=0.3)
    values = normalised if normalised is not None else difference
    for channel in range(3):
        bottom.plot(pixel, values[:, channel], color=CHANNEL_COLOURS[channel], linewidth=0.6)
    bottom.axhline(0.0, color="black", linewidth=0.6)
    if normalised is not None:
        bottom.axhspan(-2.0, 2.0, color="grey", alpha=0.15, linewidth=0)
    bottom.set_ylabel("residual / σ" if normalised is not None else "residual")
    _short_ticks(bottom)
    bottom.set_xlabel("pixel")
    bottom.grid(alpha=0.3)
    return _save(figure, path)


def plot_lamp_spectra(path: Path, observations: Sequence[LampObservation]) -> Path | None:
    """Each lamp's measured spectrum, normalised to its maximum."""
    spectra: list[Spectrum] = [obs.spectrum for obs in observations]
    if not spectra:
        return None
    figure = _figure(7.0, 3.2)
    axes = figure.subplots()
    for obs in observations:
        peak = float(np.max(obs.spectrum.values)) or 1.0
        axes.plot(
            obs.spectrum.wavelength_nm, obs.spectrum.values / peak, linewidth=0.9, label=obs.name
        )
    _title(axes, "lamp spectra as measured (each divided by its maximum)")
    axes.set_xlabel("wavelength (nm)")
    axes.set_ylabel("relative power")
    axes.legend(fontsize=8)
    axes.grid(alpha=0.3)
    return _save(figure, path)


def plot_warmup(path: Path, traces: Sequence[WarmupTrace]) -> Path | None:
    """Each lamp's change between successive warm-up spectra against the time since switch-on."""
    usable = [t for t in traces if np.any(np.isfinite(t.relative_change))]
    if not usable:
        return None
    figure = _figure(7.0, 3.2)
    axes = figure.subplots()
    for index, trace in enumerate(usable):
        colour = f"C{index}"
        change = np.asarray(trace.relative_change, dtype=np.float64)
        axes.plot(trace.elapsed_s, 100.0 * change, "o-", color=colour, label=trace.lamp)
        if trace.tolerance is not None:
            axes.axhline(100.0 * trace.tolerance, color=colour, linestyle=":", linewidth=1.0)
    axes.set_ylim(bottom=0.0)
    _title(axes, "lamp warm-up: change from the previous spectrum (dotted: tolerance)")
    axes.set_xlabel("time since the lamp was switched on (s)")
    axes.set_ylabel("change (%)")
    axes.legend(fontsize=8)
    axes.grid(alpha=0.3)
    return _save(figure, path)


def plot_geometry(path: Path, profiles: BracketProfiles) -> Path:
    """The detected geometry on the geometry lamp's image (:func:`calib.image.profiles.write_geometry_png`)."""
    image, geometry = profiles.geometry_image()
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_geometry_png(path, image, geometry)


def import_plotting() -> None:
    """Import matplotlib (about a second), e.g. in a thread while frames decode."""
    import_matplotlib()
