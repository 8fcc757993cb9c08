"""Validation cameras changed the way another lab's cameras differ: physically, never from a test result.

The validation split's cameras (leave-one-body-out training curves, Solomatov & Akkaynak's
predictions) are one collection; measured cameras of other collections differ from it in ways a
camera's optics explain (decision 0094). Each transformed camera is a validation camera with one of:

``ir-cut``
    The IR-cut filter's edge moved by ±20–40 nm: the long-wavelength tail of every channel (beyond
    the red channel's peak) is stretched or compressed so that the summed signal's red edge (3 % of
    its peak) moves by that much. IR-cut (hot-mirror) filters are specified at their 50 % point
    anywhere from ~630 to ~690 nm, and a body's filter stack differs between makers.
``blue-edge``
    The short-wavelength cut-off (UV filter, blue dye, microlens absorption) moved by ±10–20 nm
    likewise below the blue channel's peak.
``dyes``
    Each colour-filter-array dye shifted on its own by ±2–8 nm (makers' pigment sets differ).
``blue-filter``
    Behind a blue (cooling, Wratten-80-like) filter whose edge is anywhere from 540 to 640 nm
    (:func:`calib.evaluation.synthetic.colour_filter`'s shape).
``yellow-filter``
    Behind a yellow (UV/haze, Wratten-2/8-like) filter cutting the blue below 420–470 nm.

A transformed camera (:func:`calib.evaluation.validation.splits.transformed_cameras`) keeps its body (its basis leaves that body out, as for the camera it came
from), so it stays a validation camera: tuning may look at it; no test camera is used.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.spectra import MultiSpectrum

TransformKind = Literal["ir-cut", "blue-edge", "dyes", "blue-filter", "yellow-filter"]
TRANSFORM_KINDS: tuple[TransformKind, ...] = (
    "ir-cut",
    "blue-edge",
    "dyes",
    "blue-filter",
    "yellow-filter",
)
#: Sampling (nm) the transforms work at.
STEP_NM = 1.0
#: The edge of a summed signal: where it falls to this fraction of its peak (as the mapping's red
#: edge, :data:`calib.wavelength.profile_search.RED_EDGE_FRACTION`).
EDGE_FRACTION = 0.03


def _fine(camera: MultiSpectrum) -> tuple[FloatArray, FloatArray]:
    axis = camera.wavelength_nm
    fine = np.arange(axis[0], axis[-1] + 0.5 * STEP_NM, STEP_NM)
    values = np.stack([np.interp(fine, axis, camera.values[:, c]) for c in range(3)], axis=1)
    return fine, values


def _resample(fine: FloatArray, values: FloatArray, where: FloatArray) -> FloatArray:
    """``values`` (on ``fine``) at ``where``; zero beyond the measured range's ends."""
    return np.stack(
        [np.interp(where, fine, values[:, c], left=0.0, right=0.0) for c in range(3)], axis=1
    )


def move_edge(camera: MultiSpectrum, shift_nm: float, side: Literal["red", "blue"]) -> FloatArray:
    """The camera's curves (on a 1 nm axis from its first wavelength) with the red (blue) edge of the
    summed signal moved by ``shift_nm``: the tail beyond the red (below the blue) channel's peak is
    scaled linearly about that peak."""
    fine, values = _fine(camera)
    total = values.sum(axis=1)
    above = np.flatnonzero(total >= EDGE_FRACTION * total.max())
    if side == "red":
        pivot = float(fine[int(np.argmax(values[:, 0]))])
        edge = float(fine[above[-1]])
    else:
        pivot = float(fine[int(np.argmax(values[:, 2]))])
        edge = float(fine[above[0]])
    span = edge - pivot
    if abs(span) < 5.0:
        return values
    scale = span / (span + shift_nm)
    beyond = (fine > pivot) if side == "red" else (fine < pivot)
    where = fine.copy()
    where[beyond] = pivot + (fine[beyond] - pivot) * scale
    return _resample(fine, values, where)


def shift_dyes(camera: MultiSpectrum, shifts_nm: Sequence[float]) -> FloatArray:
    """Each channel moved along the wavelength axis by its own shift."""
    fine, values = _fine(camera)
    return np.stack(
        [
            np.interp(fine - shift, fine, values[:, c], left=0.0, right=0.0)
            for c, shift in enumerate(shifts_nm)
        ],
        axis=1,
    )


def filtered(camera: MultiSpectrum, kind: Literal["blue", "yellow"], edge_nm: float) -> FloatArray:
    """Behind a smooth-step colour filter: blue ``0.12 + 0.8/(1 + exp((λ − edge)/25))`` (as
    :func:`calib.evaluation.synthetic.colour_filter`), yellow ``0.05 + 0.9/(1 + exp((edge − λ)/12))``."""
    fine, values = _fine(camera)
    if kind == "blue":
        transmission = 0.12 + 0.8 / (1.0 + np.exp((fine - edge_nm) / 25.0))
    else:
        transmission = 0.05 + 0.9 / (1.0 + np.exp((edge_nm - fine) / 12.0))
    return values * transmission[:, None]


def transform_camera(
    camera: MultiSpectrum, kind: TransformKind, rng: np.random.Generator
) -> tuple[MultiSpectrum, str]:
    """``camera`` transformed by one draw of ``kind`` (maximum 1), and a description of it."""
    sign = 1.0 if rng.uniform() < 0.5 else -1.0
    if kind == "ir-cut":
        shift = sign * float(rng.uniform(20.0, 40.0))
        values = move_edge(camera, shift, "red")
        text = f"IR cut {shift:+.0f} nm"
    elif kind == "blue-edge":
        shift = sign * float(rng.uniform(10.0, 20.0))
        values = move_edge(camera, -shift, "blue")
        text = f"blue edge {-shift:+.0f} nm"
    elif kind == "dyes":
        shifts = [sgn * float(rng.uniform(2.0, 8.0)) for sgn in rng.choice([-1.0, 1.0], 3)]
        values = shift_dyes(camera, shifts)
        text = "dyes " + "/".join(f"{s:+.0f}" for s in shifts) + " nm"
    elif kind == "blue-filter":
        edge = float(rng.uniform(540.0, 640.0))
        values = filtered(camera, "blue", edge)
        text = f"blue filter {edge:.0f} nm"
    else:
        edge = float(rng.uniform(420.0, 470.0))
        values = filtered(camera, "yellow", edge)
        text = f"yellow filter {edge:.0f} nm"
    axis = np.arange(camera.wavelength_nm[0], camera.wavelength_nm[-1] + 0.5 * STEP_NM, STEP_NM)
    values = np.clip(values, 0.0, None)
    values = values / float(np.max(values))
    return MultiSpectrum(axis, values, camera.channels, name=f"{camera.name} · {text}"), text
