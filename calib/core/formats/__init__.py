"""Camera sensitivity files, one module per format, each writing what its consumer requires and
reading it back: :mod:`~calib.core.formats.ampas` (rawtoaces), :mod:`~calib.core.formats.dcamprof`,
:mod:`~calib.core.formats.vkdt`, :mod:`~calib.core.formats.rgb_csv`; :func:`read_camera` opens any of
them (and colour-science objects, through :func:`calib.core.camera_curves.as_camera`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from calib.core.camera_curves import CameraCurves, as_camera
from calib.core.errors import InputError
from calib.core.formats.ampas import read_camera_json
from calib.core.formats.dcamprof import read_ssf_json
from calib.core.formats.json_file import read_json
from calib.core.formats.result_json import RESULT_SCHEMA, read_result_camera
from calib.core.formats.rgb_csv import read_camera_csv
from calib.core.formats.vkdt import read_vkdt_txt

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
        A file that is none of these, or is malformed (the file is named).
    """
    if not isinstance(source, str | Path):
        return as_camera(source)
    path = Path(source)
    if path.is_dir():
        if not (path / RESULT_FILE).is_file():
            raise InputError(
                f"no {RESULT_FILE} here: give an estimate's output directory or a camera file",
                source=str(path),
            )
        return read_result_camera(path / RESULT_FILE)
    if not path.exists():
        raise InputError("file not found", source=str(path))
    suffix = path.suffix.lower()
    if suffix == ".json":
        kind = _json_kind(path)
        if kind == "result":
            return read_result_camera(path)
        if kind == "ampas":
            return read_camera_json(path).curves
        return read_ssf_json(path)
    if suffix == ".txt":
        return read_vkdt_txt(path)
    return read_camera_csv(path)
