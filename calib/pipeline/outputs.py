"""The files an offline estimate leaves behind (``report.html`` is :mod:`calib.pipeline.report`).

``sensitivity.csv``
    ``wavelength_nm,r,g,b`` on the working grid, the maximum over all channels 1 (negative wiggles of
    the estimate set to zero; ``result.json`` keeps them).
``result.json``
    Everything about the estimate: method, mapping coefficients and its error estimate, grating
    efficiency, per-wavelength uncertainty (``null`` with the reason when the method gives none),
    residuals per lamp, input files with sha256, software version, command line, warnings.
``<make>_<model>_<start>_<stop>_<step>.json``
    The camera in the AMPAS spectral-data schema (0.1.0) that rawtoaces reads from its camera data
    directory: ``header`` (manufacturer, model, …) and ``spectral_data.data.main["<nm>"] = [R, G, B]``.
``grating.json``
    The grating efficiency found (when the method estimates it), in the :mod:`calib.core.grating_file`
    format, for a later ``--grating`` estimate without a direct measurement.
"""

from __future__ import annotations

import csv
import json
import math
import re
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.grating_file import GratingEfficiency, write_grating_file
from calib.core.result import EstimateResult, json_safe
from calib.pipeline.estimate import OfflineEstimate

RESULT_SCHEMA = "spectral-rig/estimate-result"
RESULT_FORMAT_VERSION = 1
#: The AMPAS spectral-data schema version rawtoaces' camera files use.
AMPAS_SCHEMA_VERSION = "0.1.0"

SENSITIVITY_FILE = "sensitivity.csv"
RESULT_FILE = "result.json"
GRATING_FILE = "grating.json"


def _number(value: float) -> str:
    """Shortest text that round-trips a float64."""
    return repr(float(value))


def _wavelength_key(wavelength_nm: float) -> str:
    return str(round(wavelength_nm)) if float(wavelength_nm).is_integer() else repr(wavelength_nm)


def write_sensitivity_csv(path: Path, result: EstimateResult) -> Path:
    """``wavelength_nm,r,g,b`` on the result's grid (maximum over all channels = 1)."""
    curves = result.physical_sensitivity()
    with path.open("w", newline="") as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow(["wavelength_nm", "r", "g", "b"])
        for wavelength, row in zip(result.wavelength_nm, curves, strict=True):
            writer.writerow([_wavelength_key(float(wavelength)), *(_number(v) for v in row)])
    return path


def _residual_summary(residuals: Mapping[str, Any]) -> dict[str, Any]:
    """Per lamp: the residual arrays and their RMS (normalised residuals: ≈ 1 when the fit is good)."""
    summary: dict[str, Any] = {}
    for lamp, entries in residuals.items():
        record: dict[str, Any] = {}
        if isinstance(entries, Mapping):
            for key, value in entries.items():
                record[key] = json_safe(value)
            normalised = entries.get("profile_normalised")
            if normalised is not None:
                values = np.asarray(normalised, dtype=np.float64)
                record["profile_normalised_rms"] = json_safe(
                    float(np.sqrt(np.mean(values**2))) if values.size else None
                )
        else:
            record["value"] = json_safe(entries)
        summary[str(lamp)] = record
    return summary


def result_document(
    estimate: OfflineEstimate, files: Mapping[str, Path] | None = None
) -> dict[str, Any]:
    """The ``result.json`` document."""
    result = estimate.result
    base = result.to_dict()
    uncertainty_note = None
    if result.sensitivity_sigma is None:
        uncertainty_note = (
            f"method {result.method!r} does not estimate a per-wavelength uncertainty; "
            "sensitivity_sigma is null"
        )
    mapping = result.mapping
    mapping_record: dict[str, Any] | None = None
    if mapping is not None:
        mapping_record = dict(json_safe(mapping.to_dict()))
        if hasattr(mapping, "coefficients"):
            mapping_record["coefficients_nm"] = {
                "a_nm_per_px2": mapping.a,  # type: ignore[union-attr]
                "b_nm_per_px": mapping.b,  # type: ignore[union-attr]
                "c_nm": mapping.c,  # type: ignore[union-attr]
            }
        mapping_record["pixel_unit"] = (
            "sensor pixels from the direct spot centre along the first order"
            if estimate.profiles is not None
            else "the profile CSV's first column"
        )
    profiles = estimate.profiles
    geometry = None
    if profiles is not None:
        geometry = {
            "detected_on": profiles.geometry_lamp,
            "geometry": profiles.geometry.to_dict(),
            "region_of_interest": None
            if profiles.region_origin_px is None
            else {
                "origin_px": list(profiles.region_origin_px),
                "shape_px": list(profiles.region_shape_px or ()),
            },
        }
    return {
        "schema": RESULT_SCHEMA,
        "format_version": RESULT_FORMAT_VERSION,
        "method": result.method,
        "wavelength_nm": base["wavelength_nm"],
        "sensitivity": base["sensitivity"],
        "sensitivity_normalisation": "maximum over all channels = 1",
        "sensitivity_sigma": base["sensitivity_sigma"],
        "sensitivity_sigma_note": uncertainty_note,
        "grating_efficiency": base["grating_efficiency"],
        "grating_efficiency_sigma": base["grating_efficiency_sigma"],
        "mapping": mapping_record,
        "mapping_re_estimate": base["mapping_re_estimate"],
        "geometry": geometry,
        "residuals": _residual_summary(result.residuals),
        "lamps": [
            {
                "name": obs.name,
                "kind": obs.kind,
                "n_pixels": obs.n_pixels,
                "pixel": json_safe(obs.pixel),
                "profile": json_safe(obs.profile),
                "profile_sigma": json_safe(obs.profile_sigma),
                "direct_rgb": json_safe(obs.direct_rgb),
                "direct_sigma": json_safe(obs.direct_sigma),
            }
            for obs in estimate.observations
        ],
        "diagnostics": base["diagnostics"],
        "provenance": estimate.provenance.to_dict(),
        "timings_s": json_safe(dict(estimate.timings)),
        "files": None if files is None else {key: path.name for key, path in files.items()},
    }


def write_result_json(
    path: Path, estimate: OfflineEstimate, files: Mapping[str, Path] | None = None
) -> Path:
    """Write :func:`result_document` as indented JSON (NaN and infinities as ``null``)."""
    path.write_text(json.dumps(result_document(estimate, files), indent=1, allow_nan=False) + "\n")
    return path


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")


def camera_names(estimate: OfflineEstimate) -> tuple[str, str]:
    """``(manufacturer, model)`` for the camera file, from the RAW metadata when known."""
    camera = estimate.provenance.camera
    make = str(camera.get("make") or "").strip()
    model = str(camera.get("model") or "").strip()
    if make and model.lower().startswith(make.lower()):
        model = model[len(make) :].strip()
    return make or "unknown", model or "camera"


def camera_file_name(estimate: OfflineEstimate) -> str:
    """rawtoaces' naming: ``<manufacturer>_<model>_<start>_<stop>_<step>.json`` (lower case)."""
    make, model = camera_names(estimate)
    wavelength = estimate.result.wavelength_nm
    step = float(wavelength[1] - wavelength[0]) if wavelength.size > 1 else 0.0
    parts = [_slug(make), _slug(model)] + [
        _wavelength_key(v) for v in (float(wavelength[0]), float(wavelength[-1]), step)
    ]
    return "_".join(part for part in parts if part) + ".json"


def camera_document(estimate: OfflineEstimate) -> dict[str, Any]:
    """The camera in the AMPAS spectral-data schema (as rawtoaces' ``data/camera/*.json``)."""
    result = estimate.result
    make, model = camera_names(estimate)
    software = estimate.provenance.software
    curves = result.physical_sensitivity()
    mapping_re = result.mapping_re_estimate
    comments = (
        f"estimated by spectral-rig ({result.method}) from a diffraction grating; "
        f"sensitivities relative, maximum over channels 1"
    )
    if mapping_re is not None and math.isfinite(mapping_re):
        comments += f"; mapping RE estimate {mapping_re:.2e}"
    return {
        "header": {
            "schema_version": AMPAS_SCHEMA_VERSION,
            "manufacturer": make.lower(),
            "model": model.lower(),
            "catalog_number": f"camera_{_slug(make)}_{_slug(model)}_{AMPAS_SCHEMA_VERSION}",
            "description": "camera spectral sensitivity data",
            "document_creator": f"{software.get('name', 'spectral-rig')} {software.get('version', '')}".strip(),
            "unique_identifier": str(uuid.uuid4()),
            "measurement_equipment": "transmission diffraction grating, lamps with measured spectra",
            "laboratory": None,
            "document_creation_date": estimate.provenance.created.strftime("%Y-%m-%dT%H:%M:%SZ"),
            "comments": comments,
            "license": None,
        },
        "spectral_data": {
            "units": "relative",
            "reflection_geometry": None,
            "transmission_geometry": None,
            "bandwidth_FWHM": None,
            "bandwidth_corrected": None,
            "index": {"main": ["R", "G", "B"]},
            "data": {
                "main": {
                    _wavelength_key(float(wavelength)): [float(v) for v in row]
                    for wavelength, row in zip(result.wavelength_nm, curves, strict=True)
                }
            },
        },
    }


def write_camera_json(path: Path, estimate: OfflineEstimate) -> Path:
    """Write :func:`camera_document` (indented JSON)."""
    path.write_text(json.dumps(camera_document(estimate), indent=4) + "\n")
    return path


def grating_from_result(estimate: OfflineEstimate) -> GratingEfficiency | None:
    """The estimated grating efficiency as a :class:`GratingEfficiency`, when there is one."""
    result = estimate.result
    efficiency = result.grating_efficiency
    if efficiency is None or not np.all(np.isfinite(efficiency)) or np.any(efficiency < 0):
        return None
    if estimate.grating is not None:  # given, not estimated: nothing new to save
        return None
    sigma = result.grating_efficiency_sigma
    if sigma is not None and not np.all(np.isfinite(sigma)):
        sigma = None
    geometry: dict[str, Any] = {"order": 1}
    if result.mapping is not None:
        geometry["mapping"] = json_safe(result.mapping.to_dict())
    if estimate.profiles is not None:
        geometry["diffraction"] = estimate.profiles.geometry.to_dict()
    provenance = {
        "created": estimate.provenance.created.isoformat(timespec="seconds"),
        "software": dict(estimate.provenance.software),
        "method": result.method,
        "camera": estimate.provenance.camera.get("camera"),
        "lamps": [obs.name for obs in estimate.observations],
        "source": "calib estimate",
    }
    return GratingEfficiency(
        wavelength_nm=result.wavelength_nm,
        efficiency=efficiency,
        efficiency_sigma=sigma,
        geometry=geometry,
        provenance=provenance,
        source="estimated grating efficiency",
    )


def write_outputs(out_dir: Path, estimate: OfflineEstimate) -> dict[str, Path]:
    """Write ``sensitivity.csv``, the camera JSON, ``grating.json`` (if any) and ``result.json``.

    Returns
    -------
    dict
        ``{"sensitivity", "camera_json", "grating", "result"}`` → path (``grating`` only when the
        efficiency was estimated).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {
        "sensitivity": write_sensitivity_csv(out_dir / SENSITIVITY_FILE, estimate.result),
        "camera_json": write_camera_json(out_dir / camera_file_name(estimate), estimate),
    }
    grating = grating_from_result(estimate)
    if grating is not None:
        files["grating"] = write_grating_file(out_dir / GRATING_FILE, grating)
    files["result"] = out_dir / RESULT_FILE
    write_result_json(files["result"], estimate, files)
    return files
