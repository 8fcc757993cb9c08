"""The camera inside an estimate's ``result.json`` (written by :mod:`calib.pipeline.outputs`).

``result.json`` holds the estimate on its own working grid: ``wavelength_nm``, ``sensitivity``
``{"R": […], "G": […], "B": […]}`` (maximum over all channels 1) and ``sensitivity_sigma`` with the
same keys, or ``null``. Format version 1 used the keys ``r, g, b``; both are read.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from calib.core.camera_curves import CHANNEL_LABELS, CameraCurves
from calib.core.errors import InputError
from calib.core.formats.json_file import read_json

RESULT_SCHEMA = "spectral-rig/estimate-result"
RESULT_FORMAT_VERSION = 2


def _channels(record: Any, path: Path, field: str) -> np.ndarray[Any, Any]:
    for keys in (CHANNEL_LABELS, ("r", "g", "b")):
        if isinstance(record, dict) and all(key in record for key in keys):
            return np.stack([np.asarray(record[k], dtype=np.float64) for k in keys], axis=1)
    raise InputError(f"{field} has no R, G, B entries", source=str(path))


def read_result_camera(path: str | Path) -> CameraCurves:
    """The estimated camera of a ``result.json`` (with σ when the method gave one).

    Raises
    ------
    InputError
        Not JSON, not a spectral-rig result, a newer format, or missing fields (the file is named).
    """
    path = Path(path)
    document = read_json(path)
    if not isinstance(document, dict) or document.get("schema") != RESULT_SCHEMA:
        raise InputError(f"not a {RESULT_SCHEMA} document", source=str(path))
    version = document.get("format_version")
    if not isinstance(version, int) or version > RESULT_FORMAT_VERSION:
        raise InputError(
            f"format_version {version!r}; this spectral-rig reads up to {RESULT_FORMAT_VERSION}",
            source=str(path),
        )
    values = _channels(document.get("sensitivity"), path, "sensitivity")
    sigma_record = document.get("sensitivity_sigma")
    sigma = None
    if sigma_record is not None:
        raw = _channels(sigma_record, path, "sensitivity_sigma")
        sigma = np.where(np.isfinite(raw), raw, np.nan)
    camera = (
        document.get("provenance", {}).get("camera", {})
        if isinstance(document.get("provenance"), dict)
        else {}
    )
    name = str(camera.get("camera") or path.parent.name or "estimate")
    try:
        return CameraCurves(
            np.asarray(document.get("wavelength_nm", []), dtype=np.float64),
            values,
            sigma,
            name=name,
        )
    except (InputError, TypeError, ValueError) as exc:
        raise InputError(f"bad sensitivity arrays ({exc})", source=str(path)) from None
