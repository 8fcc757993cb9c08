"""dcamprof's camera spectral sensitivity JSON (``dcamprof make-target -c``, ``make-profile -c``).

Fields (dcamprof's ``data-examples/camera-ssf.json``): ``camera_name`` (should match the raw
converters' make and model), ``ssf_bands`` (``[start, end, step]`` in whole nm that come out even,
or an explicit list), ``red_ssf``, ``green_ssf``, ``blue_ssf`` (one value per band, one common scale,
normalised by dcamprof on reading). dcamprof's own examples carry ``//`` comments, which its reader
accepts but JSON does not; spectral-rig writes strict JSON (every JSON parser reads it) and reads
both.
"""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.camera_curves import CameraCurves
from calib.core.errors import InputError
from calib.core.formats.json_file import read_json

_FIELDS = ("red_ssf", "green_ssf", "blue_ssf")


class DcamprofFormatError(InputError):
    """Not a dcamprof SSF document (the message says which field)."""


def _bands(curves: CameraCurves) -> list[int] | list[float]:
    """``[start, end, step]`` when the axis is uniform in whole nm, else the explicit list."""
    axis = curves.wavelength_nm
    steps = np.diff(axis)
    whole = np.allclose(axis, np.round(axis), atol=1e-9)
    if whole and np.allclose(steps, steps[0], atol=1e-9):
        return [round(float(axis[0])), round(float(axis[-1])), round(float(steps[0]))]
    return [float(w) for w in axis]


def ssf_document(curves: CameraCurves, camera_name: str) -> dict[str, Any]:
    """The SSF document for ``curves`` (σ is not part of the format)."""
    return {
        "camera_name": camera_name,
        "ssf_bands": _bands(curves),
        **{field: [float(v) for v in curves.values[:, k]] for k, field in enumerate(_FIELDS)},
    }


def ssf_problems(document: Any) -> list[str]:
    """Where ``document`` breaks dcamprof's rules for an SSF file (empty when it follows them)."""
    if not isinstance(document, dict):
        return ["the document is not a JSON object"]
    problems: list[str] = []
    name = document.get("camera_name")
    if not isinstance(name, str) or not name.strip():
        problems.append("camera_name must be a non-empty string")
    bands = document.get("ssf_bands")
    count: int | None = None
    if isinstance(bands, list) and len(bands) == 3 and all(isinstance(b, int) for b in bands):
        start, end, step = bands
        if step <= 0 or end <= start or (end - start) % step:
            problems.append(f"ssf_bands {bands}: [start, end, step] in whole nm must come out even")
        else:
            count = (end - start) // step + 1
    elif (
        isinstance(bands, list)
        and len(bands) > 3
        and all(isinstance(b, int | float) for b in bands)
    ):
        if not all(b < c for b, c in itertools.pairwise(bands)):
            problems.append("ssf_bands must increase")
        count = len(bands)
    else:
        problems.append("ssf_bands must be [start, end, step] (whole nm) or a list of wavelengths")
    for field in _FIELDS:
        values = document.get(field)
        if not isinstance(values, list) or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in values
        ):
            problems.append(f"{field} must be a list of finite numbers")
        elif count is not None and len(values) != count:
            problems.append(f"{field} has {len(values)} values for {count} bands")
    return problems


def write_ssf_json(path: Path, curves: CameraCurves, camera_name: str) -> Path:
    """Write :func:`ssf_document` as strict JSON, after checking it (:func:`ssf_problems`)."""
    document = ssf_document(curves, camera_name)
    problems = ssf_problems(document)
    if problems:
        raise DcamprofFormatError(problems[0], source=str(path))
    path.write_text(json.dumps(document, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return path


def read_ssf_json(path: str | Path) -> CameraCurves:
    """Read a dcamprof SSF file (strict JSON or with dcamprof's ``//`` comments).

    Raises
    ------
    DcamprofFormatError
        Not JSON, or a rule of :func:`ssf_problems` broken (the file and field are named).
    """
    path = Path(path)
    document = read_json(path, comments=True, error=DcamprofFormatError)
    problems = ssf_problems(document)
    if problems:
        raise DcamprofFormatError(problems[0], source=str(path))
    bands = document["ssf_bands"]
    if len(bands) == 3 and all(isinstance(b, int) for b in bands):
        axis = np.arange(bands[0], bands[1] + bands[2] / 2, bands[2], dtype=np.float64)
    else:
        axis = np.asarray(bands, dtype=np.float64)
    values = np.stack([np.asarray(document[f], dtype=np.float64) for f in _FIELDS], axis=1)
    return CameraCurves(axis, values, name=str(document["camera_name"]))
