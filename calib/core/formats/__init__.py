"""Camera sensitivity files, one module per format, each writing what its consumer requires and
reading it back: :mod:`~calib.core.formats.ampas` (rawtoaces), :mod:`~calib.core.formats.dcamprof`,
:mod:`~calib.core.formats.vkdt`, :mod:`~calib.core.formats.rgb_csv`; :func:`read_camera` opens any of
them (and colour-science objects, through :func:`calib.core.camera_curves.as_camera`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from calib.core.camera_curves import CHANNEL_LABELS, CameraCurves, as_camera
from calib.core.errors import InputError
from calib.core.formats.ampas import read_camera_json
from calib.core.formats.dcamprof import read_ssf_json
from calib.core.formats.json_file import read_json
from calib.core.formats.result_json import RESULT_SCHEMA, read_result_camera
from calib.core.formats.rgb_csv import read_camera_csv
from calib.core.formats.vkdt import read_vkdt_txt
from calib.core.spectra import PLAUSIBLE_WAVELENGTH_NM

RESULT_FILE = "result.json"


def _json_kind(path: Path) -> str:
    document = read_json(path, comments=True)
    if isinstance(document, dict):
        if document.get("schema") == RESULT_SCHEMA:
            return "result"
        if "spectral_data" in document:
            return "ampas"
        if "red_ssf" in document or "camera_name" in document:
            return "dcamprof"
    raise InputError(
        "not a camera file: expected an AMPAS/rawtoaces camera JSON, a dcamprof SSF JSON or a "
        "spectral-rig result.json",
        source=str(path),
    )


def read_camera(source: Any) -> CameraCurves:
    """A camera from any file spectral-rig writes or reads, or from a camera-like object.

    ``source`` may be an estimate's output directory (its ``result.json``), a ``result.json``, an
    AMPAS/rawtoaces camera JSON, a dcamprof SSF JSON, a vkdt ``.txt``, a CSV with named columns,
    or an object :func:`~calib.core.camera_curves.as_camera` accepts (colour-science cameras).

    Raises
    ------
    InputError
        A file that is none of these, or is malformed (the file is named); a channel with no
        positive value (zero or negative everywhere: no camera's, and every use of it would be
        silently wrong, e.g. an identity IDT).
    """
    if not isinstance(source, str | Path):
        return _checked_camera(as_camera(source), str(getattr(source, "name", "camera")))
    path = Path(source)
    if path.is_dir():
        if not (path / RESULT_FILE).is_file():
            raise InputError(
                f"no {RESULT_FILE} here: give an estimate's output directory or a camera file",
                source=str(path),
            )
        return _checked_camera(read_result_camera(path / RESULT_FILE), str(path / RESULT_FILE))
    if not path.exists():
        raise InputError("file not found", source=str(path))
    suffix = path.suffix.lower()
    if suffix == ".json":
        kind = _json_kind(path)
        if kind == "result":
            curves = read_result_camera(path)
        elif kind == "ampas":
            curves = read_camera_json(path).curves
        else:
            curves = read_ssf_json(path)
    elif suffix == ".txt":
        curves = read_vkdt_txt(path)
    else:
        curves = read_camera_csv(path)
    return _checked_camera(curves, str(path))


def _checked_camera(curves: CameraCurves, source: str) -> CameraCurves:
    """``curves``, refused when its wavelengths are not nanometres (as a spectrum file's are,
    :data:`calib.core.spectra.PLAUSIBLE_WAVELENGTH_NM`) or a channel has no positive value (named,
    with what to check)."""
    low, high = PLAUSIBLE_WAVELENGTH_NM
    first, last = curves.range_nm
    if first < low or last > high:
        raise InputError(
            f"wavelengths run from {first:g} to {last:g}, outside {low:g}–{high:g} nm: is the "
            "first column in nanometres?",
            source=source,
        )
    for label, channel in zip(CHANNEL_LABELS, curves.values.T, strict=True):
        if not np.any(channel > 0):
            raise InputError(
                f"channel {label} has no positive value (zero or negative at every wavelength): "
                "not a camera's sensitivity; check the file's columns and the values' sign",
                source=source,
            )
    return curves
