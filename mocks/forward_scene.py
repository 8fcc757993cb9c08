"""Feed :mod:`mocks.scene` with the image formation model of :mod:`calib.model.forward`.

:func:`calib.model.forward.render_observation` gives the first order as a spectral density ``e·η·s`` per nm
on a fine axis (1 nm), and its ``profile`` as *integrals* over pixel intervals. :class:`mocks.scene.
SceneSignal` wants a radiance *density* per sensor pixel along the dispersion, which the scene samples
at every sensor pixel's centre by linear interpolation. Handing it the per-pixel integrals would
smooth spiky lamps twice (once by the integral, once by the interpolation) and scale them by the
pixel width; so :func:`first_order_signal` converts the spectral density exactly: the mean density per
sensor pixel over cells of ``step_px`` (a fraction of a pixel) is the difference of the density's
cumulative integral at the cells' edge wavelengths, divided by the cell width. Interpolating between
those cell means is then exact to second order in ``step_px``, also for fluorescent lines.

Examples
--------
>>> from calib.model.forward import render_observation                     # doctest: +SKIP
>>> rendered = render_observation(lamp, camera, mapping=mapping, pixel=2)  # doctest: +SKIP
>>> signal = first_order_signal(rendered, mapping, pixel_range_px=(200, 1000))  # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from calib.core.observations import LampKind
from calib.core.spectra import MultiSpectrum, Spectrum, write_csv
from calib.model.forward import (
    EfficiencyLike,
    PiecewiseLinearDensity,
    RenderedObservation,
    WavelengthMapping,
    render_observation,
)
from mocks.scene import (
    SceneLayout,
    SceneSignal,
    SensorModel,
    render_mosaic_radiance,
    write_bracket,
)


def first_order_signal(
    rendered: RenderedObservation,
    mapping: WavelengthMapping,
    *,
    pixel_range_px: tuple[float, float],
    step_px: float = 0.25,
    slit_length_px: float,
    slit_width_px: float = 0.0,
    dn_per_s: float = 1.0,
    direct_throughput: float = 1.0,
) -> SceneSignal:
    """The scene signal of one lamp: direct total and first-order density per sensor pixel.

    Parameters
    ----------
    rendered
        From :func:`calib.model.forward.render_observation` (its ``spectral_image`` and ``clean_direct``
        are used; its pixel sampling is not).
    mapping
        Sensor-pixel distance from the direct spot's centre along the dispersion → wavelength (nm).
    pixel_range_px
        ``(first, last)`` distances over which the first order is defined (zero outside).
    slit_length_px
        Length of the slit's image across the dispersion (sensor pixels). Every row of the band
        receives the density of one slit row, so the direct spot sums the light of this many rows.
    slit_width_px
        Width of the slit's image along the dispersion (sensor pixels): the first order is the
        per-pixel integrals convolved with this box — the same image the direct spot is, as
        physics has it (0: an infinitely narrow slit).
    step_px
        Cell width of the sampled density (sensor pixels).
    dn_per_s
        Scale from the rendered units to DN/s on the sensor.
    direct_throughput
        Ratio of the direct path's throughput to the first order's (the 0th-order efficiency).

    Returns
    -------
    SceneSignal
        ``pixel`` at the cell centres, ``profile`` ``(n, 3)`` in DN/s per sensor pixel,
        ``direct_rgb`` ``(3,)`` in DN/s summed over the spot.
    """
    first, last = pixel_range_px
    if not (step_px > 0 and last - first >= 2 * step_px):
        raise ValueError(
            f"need step_px > 0 and a range of at least two cells, got {pixel_range_px}"
        )
    n_cells = int(np.floor((last - first) / step_px))
    edges_px = first + step_px * np.arange(n_cells + 1, dtype=np.float64)
    edges_nm = np.asarray(mapping.wavelength_nm(edges_px), dtype=np.float64)
    density = PiecewiseLinearDensity.on_axis(rendered.spectral_axis_nm, rendered.spectral_image)
    cumulative = density.cumulative_at(edges_nm)
    # |Δ cumulative| / Δpixel: the mapping may run towards shorter wavelengths
    per_pixel = np.abs(np.diff(cumulative, axis=0)) / step_px
    cells = round(slit_width_px / step_px)
    if cells > 1:
        box = np.full(cells, 1.0 / cells)
        per_pixel = np.stack(
            [np.convolve(per_pixel[:, c], box, mode="same") for c in range(per_pixel.shape[1])],
            axis=1,
        )
    centres_px = 0.5 * (edges_px[1:] + edges_px[:-1])
    return SceneSignal(
        direct_rgb=dn_per_s
        * direct_throughput
        * slit_length_px
        * np.asarray(rendered.clean_direct),
        pixel=centres_px,
        profile=dn_per_s * per_pixel,
    )


@dataclass(frozen=True)
class RenderedLamp:
    """One lamp of a rendered capture: its bracket, dark frames, spectrum CSV and the truth."""

    name: str
    kind: LampKind
    frames: tuple[Path, ...]
    darks: tuple[Path, ...]
    spectrum_csv: Path
    signal: SceneSignal


def write_capture(
    directory: Path,
    lamps: Sequence[tuple[str, LampKind, Spectrum]],
    camera: MultiSpectrum,
    *,
    mapping: WavelengthMapping,
    sensor: SensorModel,
    layout: SceneLayout,
    exposures_s: Sequence[float],
    rng: np.random.Generator,
    grating_efficiency: EfficiencyLike = None,
    pixel_range_px: tuple[float, float],
    band_peak_dn_per_s: float = 3000.0,
    direct_throughput: float = 0.5,
    dark_frames: bool = False,
    **dng_fields: str | int | float | None,
) -> list[RenderedLamp]:
    """Render every lamp through :mod:`calib.model.forward` and write its bracket as DNG files.

    Each lamp gets ``directory/<name>/scene_NNNN.dng`` at ``exposures_s`` (brightest first-order
    sample at ``band_peak_dn_per_s``), its spectrum as ``directory/<name>.csv`` and, with
    ``dark_frames``, one dark frame per exposure ``dark_NNNN.dng`` (the sensor's dark current and
    noise only).

    Parameters
    ----------
    directory
        Existing directory.
    lamps
        ``(name, kind, spectrum)`` per lamp.
    camera
        The true sensitivity (3 channels).
    mapping
        Sensor-pixel distance from the spot along the dispersion → wavelength.
    sensor, layout
        The sensor and where spot and orders fall (:mod:`mocks.scene`).
    exposures_s
        The bracket.
    rng
        Seeded generator for every random number.
    grating_efficiency
        η(λ) (``None``: flat).
    pixel_range_px
        Distances from the spot over which the first order is rendered.
    band_peak_dn_per_s
        Radiance of the brightest first-order sample.
    direct_throughput
        0th-order over first-order throughput.
    dark_frames
        Also write dark frames.
    **dng_fields
        Extra :class:`mocks.dng.DngMetadata` fields (``make``, ``model``, ``iso`` …).
    """
    written = []
    slit_length_px = 2.0 * layout.spot_half_size_px[1]
    # The direct spot is the slit's image; the first order is blurred by the same image.
    slit_width_px = 2.0 * layout.spot_half_size_px[0]
    for name, kind, spectrum in lamps:
        rendered = render_observation(
            spectrum, camera, mapping=mapping, pixel=2, grating_efficiency=grating_efficiency
        )
        unit = first_order_signal(
            rendered,
            mapping,
            pixel_range_px=pixel_range_px,
            slit_length_px=slit_length_px,
            slit_width_px=slit_width_px,
        )
        scale = band_peak_dn_per_s / float(unit.profile.max())
        signal = first_order_signal(
            rendered,
            mapping,
            pixel_range_px=pixel_range_px,
            slit_length_px=slit_length_px,
            slit_width_px=slit_width_px,
            dn_per_s=scale,
            direct_throughput=direct_throughput,
        )
        fields = cast(dict[str, Any], dng_fields)
        folder = directory / name
        folder.mkdir(parents=True, exist_ok=True)
        mosaic = render_mosaic_radiance(layout, signal, sensor)
        frames = write_bracket(folder, mosaic, sensor, exposures_s, rng, prefix="scene", **fields)
        darks: list[Path] = []
        if dark_frames:
            darks = write_bracket(
                folder, np.zeros_like(mosaic), sensor, exposures_s, rng, prefix="dark", **fields
            )
        spectrum_csv = write_csv(directory / f"{name}.csv", spectrum)
        written.append(RenderedLamp(name, kind, tuple(frames), tuple(darks), spectrum_csv, signal))
    return written
