"""What a calibrated camera is for: its curves turned into the transforms colour work uses.

A stage between :mod:`calib.spd` and :mod:`calib.pipeline` (it needs only :mod:`calib.core`; the
pipeline's outputs and report use it):

* :mod:`~calib.use.colour_correction` — a colour-correction matrix per illuminant and the ΔE2000
  of a ColorChecker it predicts; with a known truth, the colour error the estimate costs;
* :mod:`~calib.use.idt` — the ACES IDT matrix (``colour.matrix_idt``) for D55, D65 and A;
* :mod:`~calib.use.raw_to_raw` — a 3×3 matrix between two cameras' raw RGB;
* :mod:`~calib.use.dcamprof` — DCP and ICC profiles through dcamprof when it is installed.

:func:`camera_uses` computes the first two for the report and ``result.json``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from calib.core.camera_curves import CameraCurves
from calib.core.colour_data import USE_ILLUMINANTS as ILLUMINANTS
from calib.core.formats import read_camera
from calib.core.formats.ampas import RAWTOACES_GRID, read_camera_json
from calib.model.extension import extend
from calib.use.colour_correction import (
    REPORT_ILLUMINANTS,
    ColourCorrection,
    TruthComparison,
    compare_with_truth,
    fit_colour_correction,
)
from calib.use.idt import IDT_ILLUMINANTS, AcesIdt, aces_idt

__all__ = ["CameraUses", "camera_for_uses", "camera_uses"]


@dataclass(frozen=True)
class CameraUses:
    """The IDTs, colour-correction matrices and (with a truth) the colour error of an estimate."""

    idts: tuple[AcesIdt, ...]
    corrections: tuple[ColourCorrection, ...]
    truth: tuple[TruthComparison, ...] = ()

    def correction(self, illuminant: str) -> ColourCorrection | None:
        return next((c for c in self.corrections if c.illuminant == illuminant), None)

    def to_dict(self) -> dict[str, Any]:
        return {
            "aces_idt": {idt.illuminant: idt.to_dict() for idt in self.idts},
            "colour_correction": {c.illuminant: c.to_dict() for c in self.corrections},
            "against_truth": {t.illuminant: t.to_dict() for t in self.truth} or None,
            "colorchecker": "ColorChecker N Ohta (colour-science), CIE 1931 2°, 380–780 nm / 5 nm",
        }


def camera_uses(camera: Any, *, truth: Any = None) -> CameraUses:
    """IDTs for :data:`~calib.use.idt.IDT_ILLUMINANTS`, colour-correction matrices for every
    illuminant of :data:`calib.core.colour_data.USE_ILLUMINANTS`, and, when ``truth`` is given, the
    truth comparison under D65 and A."""
    return CameraUses(
        idts=tuple(aces_idt(camera, name) for name in IDT_ILLUMINANTS),
        corrections=tuple(fit_colour_correction(camera, name) for name in ILLUMINANTS),
        truth=()
        if truth is None
        else tuple(compare_with_truth(camera, truth, name) for name in REPORT_ILLUMINANTS),
    )


def camera_for_uses(source: Any) -> tuple[CameraCurves, str]:
    """A camera on 380–780 nm / 5 nm for the uses, and a sentence saying where it comes from.

    An estimate's output directory gives its camera JSON (already extended, see
    :mod:`calib.model.extension`); any other camera (file or object,
    :func:`calib.core.formats.read_camera`) is extended when it does not cover 380–780 nm.
    """
    if isinstance(source, str | Path) and Path(source).is_dir():
        found = sorted(Path(source).glob("*_380_780_5.json"))
        if len(found) == 1:
            return read_camera_json(found[0]).curves, f"{found[0].name} (380–780 nm / 5 nm)"
    curves = read_camera(source)
    low, high = curves.range_nm
    if low <= RAWTOACES_GRID.start_nm and high >= RAWTOACES_GRID.stop_nm:
        return curves, f"{curves.name} ({low:g}–{high:g} nm)"
    extension = extend(curves)
    return extension.curves, f"{curves.name}: {extension.describe()}"
