"""``rig grating``: one grating file from several cameras' sessions shot through the same grating.

A grating sheet's efficiency η does not depend on the camera behind it, and every lamp's direct
equations constrain η alone, so sessions of several cameras through one grating (same sheet, same
slit and lamps) refine it together (:func:`calib.methods.multilamp.refine_grating`: η shared, one
sensitivity per camera). The file this writes is what ``calib estimate --grating FILE`` and
``OfflineSettings.grating`` take: the next camera then needs a single LED shot.

Each session is read and verified against its log first, every one of them before anything is
estimated (:func:`rig.estimate.session_lamps`); the lamps are extracted by the offline pipeline
``rig estimate`` runs (its per-camera estimate gives each camera's mapping); lamps whose direct spot
is saturated in every frame add no direct equations and are left out with a warning. The file
records which sessions, cameras and lamps it came from.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from calib.core.errors import InputError
from calib.core.grating_file import GratingEfficiency, write_grating_file
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.methods.multilamp import (
    DEFAULT_WEIGHT_RULE,
    MULTILAMP_METHOD,
    WeightRule,
    refine_grating,
    weight_rule_option,
)
from calib.model.bases import CameraBasis, default_camera_basis
from calib.pipeline import OfflineSettings, estimate_offline
from rig.errors import SessionFormatError
from rig.estimate import session_lamps
from rig.session import Session, read_session


@dataclass(frozen=True)
class SessionCamera:
    """What one session added to the grating: its camera and the lamps with direct equations."""

    session: str
    session_id: str
    camera: str
    lamps: tuple[str, ...]


@dataclass(frozen=True)
class GratingOutcome:
    """The refined grating, where it was written, and what it came from."""

    grating: GratingEfficiency
    path: Path
    cameras: tuple[SessionCamera, ...]
    warnings: tuple[str, ...]


def _camera_of(session: Session) -> str:
    """The session's camera as its start record names it (model and serial), or ``"unknown"``."""
    start = session.start
    record = None if start is None else start.devices.get("camera")
    return "unknown" if record is None else record.describe()


def _with_direct(
    name: str, observations: Sequence[LampObservation], warnings: list[str]
) -> list[LampObservation]:
    usable = [obs for obs in observations if obs.direct_rgb is not None]
    for obs in observations:
        if obs.direct_rgb is None:
            warnings.append(
                f"{name}: lamp {obs.name!r} left out (its direct spot is saturated in every frame)"
            )
    if not usable:
        raise InputError(
            "no lamp has a direct (0th-order) measurement, so the session says nothing about "
            "the grating; capture a bracket with a shorter exposure",
            source=name,
        )
    return usable


def refine_session_grating(
    sessions: Sequence[str | Path],
    out_file: str | Path,
    *,
    data_dir: str | Path | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
    weight_rule: str | None = None,
    basis: CameraBasis | None = None,
    exclude_cameras: Sequence[str] = (),
    description: str = "",
    force: bool = False,
) -> GratingOutcome:
    """Refine one grating efficiency over ``sessions`` and write it to ``out_file``.

    Parameters
    ----------
    sessions
        Session directories, one or more cameras through the same grating.
    out_file
        The grating file to write (refused if it exists, unless ``force``).
    data_dir
        Camera data for the prior (default: ``$SPECTRAL_RIG_DATA``, the cache, else the offline
        basis); or give ``basis``.
    grid
        Working wavelength grid.
    weight_rule
        How the camera prior is weighted (:data:`calib.methods.multilamp.PRIOR_WEIGHT_RULES`).
    exclude_cameras
        Name patterns of cameras kept out of the default basis (not with ``basis``).
    description
        Free text recorded in the file's geometry (e.g. the sheet and slit).
    force
        Replace an existing ``out_file``.

    Raises
    ------
    SessionFormatError
        A path that is not a session, files that differ from the log, a session given twice.
    InputError
        No session, an existing output, a session with no direct measurement, any input problem
        the pipeline finds.
    """
    if not sessions:
        raise InputError("give at least one session directory", source="SESSION")
    out = Path(out_file)
    if out.exists() and not force:
        raise InputError("exists; pass --force to replace it", source=str(out))
    options = weight_rule_option(MULTILAMP_METHOD, weight_rule)
    rule: WeightRule = DEFAULT_WEIGHT_RULE if options is None else options.weight_rule
    # Every session is verified before anything is estimated.
    checked = []
    seen: dict[str, str] = {}
    for path in map(Path, sessions):
        session = read_session(path)
        inputs = session_lamps(session)  # checks the start record, verifies every file
        start = session.start
        assert start is not None
        if start.session_id in seen:
            raise SessionFormatError(
                f"{path}: the same session as {seen[start.session_id]}; give each session once"
            )
        seen[start.session_id] = str(path)
        checked.append((path, start.session_id, _camera_of(session), inputs))
    chosen = (
        basis
        if basis is not None
        else default_camera_basis(grid, data_dir=data_dir, exclude=exclude_cameras)
    )
    warnings = chosen.warnings()
    cameras: list[list[LampObservation]] = []
    mappings = []
    summaries = []
    software: dict[str, str] = {}
    for path, session_id, camera, (lamps, known, session_warnings) in checked:
        warnings.extend(f"{path.name}: {warning}" for warning in session_warnings)
        # The pipeline of rig estimate: its own estimate gives this camera's mapping.
        extracted = estimate_offline(
            lamps,
            OfflineSettings(
                method=MULTILAMP_METHOD, method_options=options, grid=grid, basis=chosen
            ),
            known_inputs=known,
        )
        software = dict(extracted.provenance.software)
        usable = _with_direct(path.name, extracted.observations, warnings)
        cameras.append(usable)
        mappings.append(extracted.result.mapping)
        summaries.append(
            SessionCamera(path.name, session_id, camera, tuple(o.name for o in usable))
        )
    grating, _ = refine_grating(
        cameras, basis=chosen, grid=grid, mappings=mappings, weight_rule=rule
    )
    grating = replace(
        grating,
        geometry={
            **grating.geometry,
            "description": description,
            "mappings": [None if m is None else m.to_dict() for m in mappings],
        },
        provenance={
            "method": MULTILAMP_METHOD,
            "prior_weight": grating.provenance["prior_weight"],
            "weight_rule": rule,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "software": software,
            "sessions": [
                {
                    "directory": summary.session,
                    "session_id": summary.session_id,
                    "camera": summary.camera,
                    "lamps": list(summary.lamps),
                }
                for summary in summaries
            ],
            "basis": chosen.to_dict(),
        },
        source=str(out),
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    return GratingOutcome(
        grating, write_grating_file(out, grating), tuple(summaries), tuple(warnings)
    )


def median_relative_sigma(grating: GratingEfficiency) -> float | None:
    """The median of σ/η over the file's wavelengths (``None`` without σ)."""
    if grating.efficiency_sigma is None:
        return None
    efficiency = np.asarray(grating.efficiency, dtype=np.float64)
    sigma = np.asarray(grating.efficiency_sigma, dtype=np.float64)
    inside = efficiency > 0
    return float(np.median(sigma[inside] / efficiency[inside]))
