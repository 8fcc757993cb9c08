"""The files an offline estimate leaves behind (``report.html`` is :mod:`calib.pipeline.report`).

On the estimate's own working grid:

``sensitivity.csv``
    ``wavelength_nm,R,G,B,R_sigma,G_sigma,B_sigma`` (σ columns only when the method gives σ), then
    ``#`` lines saying the units (relative), the normalisation (maximum over all channels 1), how
    many negative values of the solve were set to zero, and the camera; read by column name by
    colour-science (``colour.io.read_sds_from_csv_file``), numpy and spreadsheets.
``result.json``
    Everything about the estimate: method, sensitivity and σ (``R, G, B``: the curve of
    ``sensitivity.csv``, negative lobes of the solve set to zero, and its σ), mapping and
    its error estimate, grating efficiency, residuals per lamp, the camera's uses (ACES IDTs,
    colour-correction matrices and ColorChecker ΔE2000, the truth comparison when known), input files
    with sha256, software, command line, warnings.
``grating.json``
    The grating efficiency found (when the method estimates it, or the session measured it), in the :mod:`calib.core.grating_file`
    format, for a later ``--grating`` estimate without a direct measurement.

On 380–780 nm at 5 nm, the estimate extended honestly beyond its measured range
(:mod:`calib.model.extension`: predicted from alike measured cameras, with σ, and said so):

``<Make>_<Model>_380_780_5.json``
    The camera in the AMPAS spectral-data schema 1.0.0, checked against the schema and rawtoaces'
    loading rules (:mod:`calib.core.formats.ampas`); make and model as LibRaw names the RAW files
    (:mod:`calib.pipeline.camera_identity`). Drops into rawtoaces' ``data/camera/``.
``<Make>_<Model>_ssf.json``
    dcamprof's SSF JSON (strict JSON) for ``dcamprof make-target/make-profile -c``
    (:mod:`calib.core.formats.dcamprof`); ``calib profile`` runs dcamprof with it.
``<Make>_<Model>.txt``
    vkdt's ``λ R G B`` text for ``vkdt-mkclut`` (:mod:`calib.core.formats.vkdt`).
``dcamprof/<Make> <Model>.dcp``, ``dcamprof/<Make> <Model>.icc``
    Dual-illuminant DCP and ICC profiles, when dcamprof is installed (:mod:`calib.use.dcamprof`);
    without it ``result.json`` says so and ``calib profile DIR`` makes them later.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.camera_curves import CHANNEL_LABELS, CameraCurves
from calib.core.errors import CalibError, InputError
from calib.core.formats.ampas import AmpasHeader, camera_file_name, file_stem, write_camera_json
from calib.core.formats.dcamprof import write_ssf_json
from calib.core.formats.result_json import RESULT_FORMAT_VERSION, RESULT_SCHEMA
from calib.core.formats.rgb_csv import write_camera_csv
from calib.core.formats.vkdt import write_vkdt_txt
from calib.core.grating_file import GratingEfficiency, write_grating_file
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import format_re, relative_error
from calib.core.result import EstimateResult, json_safe
from calib.core.truth import GroundTruth
from calib.methods.multilamp import grating_model_fields
from calib.methods.uncertainty import efficiency_family
from calib.model.extension import Extension, extend
from calib.pipeline.camera_identity import CameraIdentity, camera_identity
from calib.pipeline.estimate import OfflineEstimate
from calib.use import CameraUses, camera_uses
from calib.use.dcamprof import DcamprofError, find_dcamprof, make_profiles
from calib.wavelength.rig_prior import rig_geometry

SENSITIVITY_FILE = "sensitivity.csv"
RESULT_FILE = "result.json"
GRATING_FILE = "grating.json"
DCAMPROF_DIR = "dcamprof"
#: The camera files carry a licence (the schema requires one); the measurement's owner decides it.
CAMERA_FILE_LICENSE = "unspecified: set by whoever measured the camera before sharing the file"
MEASUREMENT_EQUIPMENT = (
    "spectral-rig: transmission diffraction grating, lamps with spectrometer-measured spectra, "
    "the camera itself (Makabe et al. 2025)"
)


@dataclass(frozen=True, eq=False)
class DeliveredCamera:
    """The estimate as the files deliver it.

    Attributes
    ----------
    curves
        On the estimate's grid: negative values set to zero, maximum 1, σ on the same scale.
    negative_values
        How many values of the solve were negative (set to zero in the files and in result.json).
    extension
        On 380–780 nm at 5 nm (:func:`calib.model.extension.extend`).
    identity
        Make and model for the camera files.
    uses
        IDTs, colour-correction matrices, the truth comparison (``None`` when not computable).
    uses_error
        Why ``uses`` is ``None``.
    truth
        The known truth, when there is one.
    """

    curves: CameraCurves
    negative_values: int
    extension: Extension
    identity: CameraIdentity
    uses: CameraUses | None
    uses_error: str | None
    truth: GroundTruth | None

    def truth_relative_error(self) -> float | None:
        """RE (Eq. 16) of the curves against the known truth on the estimate's grid, or ``None``."""
        if self.truth is None:
            return None
        return relative_error(self.curves.values, self.truth.camera.at(self.curves.wavelength_nm))

    @property
    def stem(self) -> str:
        """``<Make>_<Model>``, the camera files' name."""
        return file_stem(self.identity.make, self.identity.model)

    def comments(self, result: EstimateResult) -> list[str]:
        """What the camera files say about where their numbers come from."""
        lines = [
            f"{self.identity.name}: spectral sensitivity estimated by spectral-rig "
            f"({result.method}) through an uncalibrated diffraction grating",
            "units: relative; normalisation: maximum over all channels = 1",
            self.extension.describe(),
        ]
        if self.negative_values:
            lines.append(
                f"{self.negative_values} negative value(s) of the solve set to zero "
                "(in result.json too)"
            )
        if result.sensitivity_sigma is None:
            lines.append(f"method {result.method} gives no per-wavelength sigma")
        else:
            lines.append("sigma: one standard deviation per wavelength, same scale")
        re_estimate = result.mapping_re_estimate
        if re_estimate is not None and math.isfinite(re_estimate):
            lines.append(f"pixel-to-wavelength mapping RE estimate {format_re(re_estimate)}")
        lines.append(f"make and model from {self.identity.source}")
        if self.identity.note:
            lines.append(self.identity.note)
        return lines


def _raw_file(estimate: OfflineEstimate) -> Path | None:
    first = estimate.provenance.camera.get("first_frame")
    return Path(first) if isinstance(first, str) and first else None


def deliver(estimate: OfflineEstimate, truth: GroundTruth | None = None) -> DeliveredCamera:
    """Everything the writers and the report share: computed once."""
    result = estimate.result
    curves = result.camera_curves(str(estimate.provenance.camera.get("camera") or "camera"))
    negative = int(np.count_nonzero(result.sensitivity < 0))
    extension = extend(curves, truth=None if truth is None else truth.camera)
    camera = estimate.provenance.camera
    identity = camera_identity(_raw_file(estimate), camera.get("make"), camera.get("model"))
    uses: CameraUses | None = None
    error: str | None = None
    try:
        uses = camera_uses(extension.curves, truth=None if truth is None else truth.camera)
    except (CalibError, ValueError, np.linalg.LinAlgError) as exc:
        error = f"the camera's uses could not be computed: {exc}"
    return DeliveredCamera(curves, negative, extension, identity, uses, error, truth)


def write_sensitivity_csv(
    path: Path, result: EstimateResult, comments: list[str] | None = None
) -> Path:
    """``wavelength_nm,R,G,B[,R_sigma,G_sigma,B_sigma]`` on the result's grid (maximum 1)."""
    lines = comments if comments is not None else ["units: relative; maximum over all channels = 1"]
    return write_camera_csv(path, result.camera_curves(), lines)


def _channels(values: FloatArray) -> dict[str, Any]:
    """``(f, 3)`` as ``{"R": [...], "G": [...], "B": [...]}`` (NaN → ``None``)."""
    return {channel: json_safe(values[:, k]) for k, channel in enumerate(CHANNEL_LABELS)}


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
    estimate: OfflineEstimate,
    files: Mapping[str, Path] | None = None,
    delivered: DeliveredCamera | None = None,
) -> dict[str, Any]:
    """The ``result.json`` document."""
    result = estimate.result
    base = result.to_dict()
    # The one curve users get: sensitivity.csv's (negative lobes set to zero, maximum 1).
    curves = result.camera_curves()
    negative = int(np.count_nonzero(result.sensitivity < 0))
    uncertainty_note = None
    if result.quality.uncertainty:
        uncertainty_note = (
            "one standard deviation: the σ budget (quality.uncertainty lists its components and "
            "their shares); the method's own σ is diagnostics.method_sigma"
        )
    elif result.sensitivity_sigma is None:
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
        "sensitivity": _channels(curves.values),
        "sensitivity_normalisation": "maximum over all channels = 1",
        "sensitivity_clipping": (
            f"{negative} negative value(s) of the solve set to zero, as in {SENSITIVITY_FILE} "
            "(a sensitivity is ≥ 0; the band and its coverage are judged on this curve)"
        ),
        "sensitivity_sigma": None if curves.sigma is None else _channels(curves.sigma),
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
        "quality": base["quality"],
        "method_choice": base["diagnostics"].get("method_choice"),
        "diagnostics": base["diagnostics"],
        "camera_files": None
        if delivered is None
        else {
            "make": delivered.identity.make,
            "model": delivered.identity.model,
            "names_from": delivered.identity.source,
            "names_note": delivered.identity.note,
            "grid": "380:780:5",
            "extension": delivered.extension.describe(),
            "extended_nm": list(delivered.extension.extended_nm),
            "negative_values_set_to_zero": delivered.negative_values,
        },
        "uses": None if delivered is None or delivered.uses is None else delivered.uses.to_dict(),
        "uses_error": None if delivered is None else delivered.uses_error,
        "truth": None if delivered is None or delivered.truth is None else delivered.truth.source,
        "provenance": estimate.provenance.to_dict(),
        "timings_s": json_safe(dict(estimate.timings)),
        "files": None if files is None else {key: path.name for key, path in files.items()},
    }


def write_result_json(
    path: Path,
    estimate: OfflineEstimate,
    files: Mapping[str, Path] | None = None,
    delivered: DeliveredCamera | None = None,
    *,
    dcamprof_note: str | None = None,
) -> Path:
    """Write :func:`result_document` as indented JSON (NaN and infinities as ``null``)."""
    document = json_safe(result_document(estimate, files, delivered))
    document["dcamprof"] = dcamprof_note
    path.write_text(json.dumps(document, indent=1, allow_nan=False) + "\n")
    return path


def camera_header(estimate: OfflineEstimate, delivered: DeliveredCamera) -> AmpasHeader:
    """The AMPAS header of the camera JSON (schema 1.0.0: every required field non-empty)."""
    software = estimate.provenance.software
    data = json.dumps(delivered.extension.curves.values.tolist()).encode()
    return AmpasHeader(
        manufacturer=delivered.identity.make,
        model=delivered.identity.model,
        description="camera spectral sensitivity data",
        document_creator=f"{software.get('name', 'spectral-rig')} {software.get('version', '')}".strip(),
        document_creation_date=estimate.provenance.created.strftime("%Y-%m-%dT%H:%M:%SZ"),
        license=CAMERA_FILE_LICENSE,
        comments="; ".join(delivered.comments(estimate.result)),
        measurement_equipment=MEASUREMENT_EQUIPMENT,
        unique_identifier=hashlib.sha256(data).hexdigest(),
    )


def grating_from_result(estimate: OfflineEstimate) -> GratingEfficiency | None:
    """The estimated grating efficiency as a :class:`GratingEfficiency`, when there is one."""
    result = estimate.result
    efficiency = result.grating_efficiency
    if efficiency is None or not np.all(np.isfinite(efficiency)) or np.any(efficiency < 0):
        return None
    if estimate.grating is not None:  # given, not estimated: nothing new to save, unless the
        # session measured it in the grating's beams (the file to reuse it by)
        return estimate.grating if estimate.grating.obtained == "measured" else None
    sigma = result.grating_efficiency_sigma
    if sigma is not None and not np.all(np.isfinite(sigma)):
        sigma = None
    geometry: dict[str, Any] = {"order": 1}
    if result.mapping is not None:
        geometry["mapping"] = json_safe(result.mapping.to_dict())
    if estimate.profiles is not None:
        geometry["diffraction"] = estimate.profiles.geometry.to_dict()
    if isinstance(result.mapping, QuadraticMapping) and estimate.observations:
        # The rig it was measured in (format version 2): a later camera reuses what holds.
        rig = rig_geometry(result.mapping.details, estimate.observations[0])
        if rig is not None:
            geometry["rig"] = rig.to_dict()
    provenance = {
        "created": estimate.provenance.created.isoformat(timespec="seconds"),
        "software": dict(estimate.provenance.software),
        "method": result.method,
        "camera": estimate.provenance.camera.get("camera"),
        "lamps": [obs.name for obs in estimate.observations],
        "source": "calib estimate",
    }
    fields = grating_model_fields(result.diagnostics.get("grating_model"))
    # What stood in for η is the family the solve records (one reading, shared with the σ budget).
    assumed = {"flat": "assumed flat", "assumed": "assumed physical"}.get(
        efficiency_family(result) or ""
    )
    if assumed is not None:
        fields = {"obtained": assumed}
    return GratingEfficiency(
        wavelength_nm=result.wavelength_nm,
        efficiency=efficiency,
        efficiency_sigma=sigma,
        geometry=geometry,
        provenance=provenance,
        source={
            "estimated": "estimated grating efficiency",
            "assumed physical": "assumed grating efficiency (physical families)",
        }.get(fields["obtained"], "assumed flat grating efficiency"),
        **fields,
    )


#: Files of an earlier estimate that ``--force`` allows to overwrite.
RESULT_MARKERS = ("result.json", "sensitivity.csv", "report.html")


def check_out_dir(
    out_dir: Path,
    force: bool,
    *,
    markers: Sequence[str] = RESULT_MARKERS,
    what: str = "an estimate",
) -> None:
    """Check, before any work, that the results can be written into ``out_dir``.

    It must be a directory or not exist yet, hold none of the files ``markers`` of an earlier run
    (``what`` it was, for the message) unless ``force`` (``--force``), and be writable (a file is created in it and removed again; a missing
    directory is checked through its nearest existing parent).

    Raises
    ------
    InputError
        Naming ``--out`` and what to do.
    """
    source = f"--out {out_dir}"
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("exists and is not a directory", source=source)
    existing = [name for name in markers if (out_dir / name).exists()]
    if existing and not force:
        raise InputError(
            f"already holds the results of {what} ({', '.join(existing)}); choose another "
            "--out or add --force to overwrite them",
            source=source,
        )
    probe_dir = out_dir
    while not probe_dir.exists() and probe_dir != probe_dir.parent:
        probe_dir = probe_dir.parent
    try:
        descriptor, probe = tempfile.mkstemp(prefix=".write-check-", dir=probe_dir)
    except OSError as exc:
        raise InputError(
            f"cannot be written ({exc.strerror or exc}); choose another --out", source=source
        ) from None
    os.close(descriptor)
    Path(probe).unlink()


def write_outputs(
    out_dir: Path, estimate: OfflineEstimate, delivered: DeliveredCamera | None = None
) -> dict[str, Path]:
    """Write every file of the module docstring into ``out_dir`` (created if missing).

    Returns
    -------
    dict
        ``{"sensitivity", "camera_json", "dcamprof", "vkdt", "dcp", "icc", "grating", "result"}``
        → path (``dcp``/``icc`` only with dcamprof installed, ``grating`` only when the efficiency
        was estimated).
    """
    delivered = delivered or deliver(estimate)
    out_dir.mkdir(parents=True, exist_ok=True)
    comments = delivered.comments(estimate.result)
    extended = delivered.extension.curves
    stem = delivered.stem
    files: dict[str, Path] = {
        "sensitivity": write_sensitivity_csv(
            out_dir / SENSITIVITY_FILE, estimate.result, comments[:2] + comments[3:]
        ),
        "camera_json": write_camera_json(
            out_dir / camera_file_name(delivered.identity.make, delivered.identity.model),
            extended,
            camera_header(estimate, delivered),
        ),
        "dcamprof": write_ssf_json(out_dir / f"{stem}_ssf.json", extended, delivered.identity.name),
        "vkdt": write_vkdt_txt(out_dir / f"{stem}.txt", extended),
    }
    profiles, note = dcamprof_profiles(files["dcamprof"], delivered, out_dir / DCAMPROF_DIR)
    files.update(profiles)
    grating = grating_from_result(estimate)
    if grating is not None:
        files["grating"] = write_grating_file(out_dir / GRATING_FILE, grating)
    files["result"] = out_dir / RESULT_FILE
    write_result_json(files["result"], estimate, files, delivered, dcamprof_note=note)
    return files


def dcamprof_profiles(
    ssf_json: Path, delivered: DeliveredCamera, out_dir: Path
) -> tuple[dict[str, Path], str]:
    """DCP and ICC through dcamprof when it is on ``PATH``; otherwise nothing, and why."""
    program = find_dcamprof()
    if program is None:
        return {}, "dcamprof is not installed: no DCP/ICC (calib profile DIR makes them later)"
    try:
        made = make_profiles(ssf_json, delivered.identity.name, out_dir, executable=program)
    except DcamprofError as exc:
        return {}, f"no DCP/ICC: {exc}"
    return {"dcp": made.dcp, "icc": made.icc}, f"made by {program}"
