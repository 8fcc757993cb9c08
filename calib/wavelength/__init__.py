"""Stage 4, the pixel→wavelength mapping: every way to find it, and nowhere else, behind one front
function :func:`find_mapping`. ``calib.wavelength`` imports only :mod:`calib.core` and
:mod:`calib.model`.

The strategies, by what is known about the camera:

``"search"`` (a camera prior) — :func:`calib.wavelength.locate.locate_mapping`: physics first (the
    grating equation through the lens when the pixels are measured from the 0th order, with the
    rig's line density, the lens' focal length and pitch, a grating file's stored geometry as its
    prior), the lines of a built-in list or a resolved source's absorption dips where the lamps
    have them, else whole profiles under the camera prior with batched scans, analytic Jacobians
    and every basin's likelihood — an ambiguous mapping is stated, never hidden (decision 0025;
    the estimators' default).
``"icp"`` (a camera prior) — :func:`calib.wavelength.peaks.icp_mapping`: Makabe et al.'s (2025)
    point-to-plane ICP against the mean camera from a flat start, kept to reproduce the paper.
``"lines"`` (a calibrated camera) — :func:`calib.wavelength.calibrated.lines_mapping`: a fluorescent
    lamp's lines with the camera and the grating known (the rig as a spectrometer, Alvarez et al.
    2014), from the lamp's measured spectrum or a reference line list.

Estimators choose which lamps to hand over (:func:`lamps_named` picks the one a user named); the
mapping itself is found here and nowhere else.

Examples
--------
>>> import numpy as np
>>> from calib.core.datasets import colour_science_cameras, find_camera
>>> from calib.core.lamp_specs import colour_lamp
>>> from calib.core.mapping import QuadraticMapping
>>> from calib.model.bases import fallback_camera_basis
>>> from calib.model.forward import render_observation
>>> camera = find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity
>>> prior = fallback_camera_basis(exclude=["Canon EOS 5D Mark II"]).prior()
>>> truth = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))
>>> lamp = render_observation(
...     colour_lamp("FL2"), camera, mapping=truth, pixel=800, kind="fluorescent"
... ).observation
>>> found = find_mapping([lamp], camera=prior)
>>> error_nm = found.wavelength_nm(lamp.pixel) - truth.wavelength_nm(lamp.pixel)
>>> bool(np.max(np.abs(error_nm)) < 0.5)
True
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, Spectrum, WavelengthGrid
from calib.model.bases import CameraPrior
from calib.wavelength.calibrated import CalibratedCamera, SpectrometerProfile, lines_mapping
from calib.wavelength.locate import locate_mapping
from calib.wavelength.peaks import icp_mapping
from calib.wavelength.rig_prior import RigGeometry

MappingMethod = Literal["search", "icp", "lines"]
#: The strategies of :func:`find_mapping`.
MAPPING_METHODS: tuple[MappingMethod, ...] = ("search", "icp", "lines")

__all__ = [
    "MAPPING_METHODS",
    "CalibratedCamera",
    "MappingMethod",
    "RigGeometry",
    "SpectrometerProfile",
    "find_mapping",
    "lamp_name",
    "lamps_named",
]


def lamp_name(names: Sequence[str], wanted: str, *, source: str = "mapping_lamp") -> str:
    """The one of ``names`` that ``wanted`` names: itself, else the one equal to it ignoring case.

    Raises
    ------
    InputError
        None does (the lamps it could be are listed), or several do ignoring case.

    Examples
    --------
    >>> lamp_name(["FL", "LED"], "fl")
    'FL'
    """
    if wanted in names:
        return wanted
    folded = [name for name in names if name.casefold() == wanted.casefold()]
    if len(folded) == 1:
        return folded[0]
    if folded:
        raise InputError(
            f"{wanted!r} names lamps {', '.join(map(repr, folded))} ignoring case; give one "
            "exactly as spelt",
            source=source,
        )
    raise InputError(
        f"no lamp named {wanted!r} (ignoring case); it can be one of {', '.join(names)}",
        source=source,
    )


def lamps_named(
    observations: Sequence[LampObservation], mapping_lamp: str
) -> list[LampObservation]:
    """The lamp called ``mapping_lamp`` (:func:`lamp_name`: ignoring case when no lamp has that
    exact name), as a one-element list, else an :class:`InputError`."""
    name = lamp_name([obs.name for obs in observations], mapping_lamp)
    return [obs for obs in observations if obs.name == name]


def _quadratic_start(
    start: QuadraticMapping | GratingGeometry, grid: WavelengthGrid
) -> QuadraticMapping:
    if isinstance(start, QuadraticMapping):
        return start
    return start.quadratic((grid.start_nm, grid.stop_nm))


def find_mapping(
    lamps: Sequence[LampObservation] | SpectrometerProfile,
    *,
    camera: CameraPrior | CalibratedCamera,
    grid: WavelengthGrid = DEFAULT_GRID,
    method: MappingMethod | None = None,
    start: QuadraticMapping | GratingGeometry | None = None,
    kernel: FloatArray | None = None,
    lamp_spectrum: Spectrum | None = None,
    rig: RigGeometry | None = None,
    grooves_per_mm: float | None = None,
) -> QuadraticMapping:
    """The pixel→wavelength mapping of one geometry's profiles (see the module docstring).

    Parameters
    ----------
    lamps
        ``"search"``/``"icp"``: the lamps (:class:`~calib.core.observations.LampObservation`, their
        measured spectra included), all in one pixel frame; ICP uses the first. ``"lines"``: one
        profile read by a calibrated camera (:class:`SpectrometerProfile`).
    camera
        What is known of the camera: a :class:`~calib.model.bases.CameraPrior` (``"search"``,
        ``"icp"``) or a :class:`CalibratedCamera` (``"lines"``).
    grid
        Working grid; the mapping must cover it (``"lines"``: the range searched for lines).
    method
        The strategy (:data:`MAPPING_METHODS`); default ``"search"`` with a prior, ``"lines"`` with
        a calibrated camera.
    start
        A mapping to refine instead of the strategy's own starts (``"search"``, ``"lines"``).
    kernel
        ``"search"``: the camera's line spread in profile samples (default: the lamps' own).
    lamp_spectrum
        ``"lines"``: the mapping lamp's measured spectrum; ``None`` matches a reference line list.
    rig
        ``"search"``: the geometry a grating file of the same rig stored (``geometry.rig``).
    grooves_per_mm
        ``"search"``: the grating's nominal line density, when the rig's configuration gives it.

    Returns
    -------
    QuadraticMapping
        With the strategy's record in ``method`` and ``details``.

    Raises
    ------
    InputError
        A strategy given what it cannot use (naming the argument), or unusable lamps.
    EstimationError
        No mapping found.
    """
    chosen: MappingMethod = method or (
        "lines" if isinstance(camera, CalibratedCamera) else "search"
    )
    if chosen not in MAPPING_METHODS:
        raise InputError(
            f"unknown mapping method {chosen!r}; choose from {', '.join(MAPPING_METHODS)}",
            source="mapping_method",
        )
    if chosen == "lines":
        if not isinstance(camera, CalibratedCamera):
            raise InputError(
                "the 'lines' mapping needs the calibrated camera (CalibratedCamera), not a prior",
                source="camera",
            )
        if isinstance(lamps, Sequence):
            raise InputError("the 'lines' mapping reads one profile", source="lamps")
        if kernel is not None:
            raise InputError("the 'lines' mapping takes the profile's own kernel", source="kernel")
        return lines_mapping(
            lamps,
            camera.sensitivity,
            grating_efficiency=camera.grating_efficiency,
            lamp_spectrum=lamp_spectrum,
            grid=grid,
            initial=None if start is None else _quadratic_start(start, grid),
        )
    if not isinstance(camera, CameraPrior):
        raise InputError(
            f"the {chosen!r} mapping needs a camera prior, not a calibrated camera", source="camera"
        )
    if not isinstance(lamps, Sequence):
        raise InputError(f"the {chosen!r} mapping takes lamp observations", source="lamps")
    if lamp_spectrum is not None:
        raise InputError(
            f"the {chosen!r} mapping reads each lamp's own spectrum", source="lamp_spectrum"
        )
    if chosen == "icp":
        if start is not None or kernel is not None:
            raise InputError(
                "the paper's ICP starts flat and models no blur",
                source="start" if start is not None else "kernel",
            )
        if not lamps:
            raise InputError("no lamp observations to find the mapping with", source="lamps")
        return icp_mapping(lamps[0], camera.mean, grid)
    return locate_mapping(
        lamps,
        camera,
        grid,
        starts=None if start is None else [_quadratic_start(start, grid)],
        kernel=kernel,
        stored=rig,
        grooves_per_mm=grooves_per_mm,
    ).mapping
