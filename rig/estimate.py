"""Estimate the camera from a captured session: the session's files through ``calib``'s pipeline.

:func:`estimate_session` reads a session with :mod:`rig.session` and trusts none of it: every file it
uses is opened through :meth:`rig.session.Session.file_path` (plain relative names inside the session,
no symlinks) and its size and sha256 are checked against the log before it is read. Per lamp of the
recorded configuration it takes

* the bracket: the files of the ``done`` capture steps ``lamp/<name>/scene/NNN`` (the last record of a
  step wins, as after a resume);
* the dark frames ``lamp/<name>/dark/NNN``, when there is one for every exposure of the bracket;
* the spectrum: the mean of the reference spectra ``lamp/<name>/reference/NNN``;
* the grating's beams, when the session measured them (``lamp/<name>/grating/<beam>/NNN``, the
  ``measure_grating`` step): the grating's efficiency measured with the spectrometer
  (:func:`calib.methods.measured_grating.grating_from_beams`), which the estimate then uses as a
  known grating; its ``grating.json`` says ``obtained: measured``;

and hands them to :func:`calib.pipeline.run_offline`, which writes ``sensitivity.csv``,
``result.json``, ``report.html``, the rawtoaces camera JSON and ``grating.json`` (by default into
``<session>/estimate``). An interrupted or failed session is estimated from the lamps whose bracket
and spectra are complete, with a warning in the result.
"""

from __future__ import annotations

import itertools
import math
import os
import re
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.errors import InputError, SpectrumError
from calib.core.observations import LAMP_KINDS, LampKind
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid, read_spectrum_csv
from calib.core.truth import GroundTruth
from calib.methods.measured_grating import BeamSpectra, grating_from_beams
from calib.pipeline import (
    InputFile,
    LampImages,
    OfflineOutcome,
    OfflineProgress,
    OfflineSettings,
)
from calib.pipeline.context import EstimateContext, WarmupTrace
from calib.pipeline.input_sets import InputSet
from calib.pipeline.outputs import check_out_dir
from drivers.local_files import (
    UnsafeLocalPath,
    checked_directory,
    describe_entry,
    entries_below,
    is_plain,
)
from rig.config import LAMP_NAME_PATTERN
from rig.errors import RigError, SessionFormatError
from rig.plan import relative_change
from rig.records import LOG_NAME, FileRecord
from rig.session import Session, read_session
from rig.steps import SpectrumMeasured
from rig.twin import read_twin_truth

#: What ``rig demo`` writes beside a twin session (``mocks.bench.TRUTH_FILE_NAME``).
TWIN_TRUTH_FILE = "twin-truth.json"

#: Where ``rig estimate`` writes by default, inside the session directory.
DEFAULT_OUT_NAME = "estimate"
#: Relative difference within which a dark frame's exposure matches a scene frame's.
_EXPOSURE_RTOL = 0.02
_KEY = re.compile(r"^lamp/(?P<lamp>[^/]+)/(?P<stream>scene|dark|reference)/(?P<index>\d+)$")


@dataclass(frozen=True)
class _SessionFile:
    """A verified file of the session: its record and its path on disk."""

    record: FileRecord
    path: Path
    index: int


@dataclass
class _LampFiles:
    scene: list[_SessionFile]
    dark: list[_SessionFile]
    reference: list[_SessionFile]


def _recorded_lamps(session: Session) -> list[tuple[str, LampKind]]:
    """``(name, kind)`` of every lamp in the session's configuration snapshot, validated."""
    start = session.start
    if start is None:
        raise SessionFormatError(f"{session.path}: the log has no start record")
    lamps = start.config.get("lamps")
    if not isinstance(lamps, list) or not lamps:
        raise SessionFormatError(f"{session.path}: the start record's config has no lamps")
    recorded: list[tuple[str, LampKind]] = []
    for position, lamp in enumerate(lamps):
        name = lamp.get("name") if isinstance(lamp, Mapping) else None
        kind = str(lamp.get("kind", "other")).lower() if isinstance(lamp, Mapping) else ""
        if not isinstance(name, str) or not re.fullmatch(LAMP_NAME_PATTERN, name):
            raise SessionFormatError(
                f"{session.path}: config lamps[{position}].name {name!r} is not a plain lamp name"
            )
        if kind not in LAMP_KINDS:
            raise SessionFormatError(
                f"{session.path}: config lamps[{position}].kind {kind!r} is not one of {LAMP_KINDS}"
            )
        recorded.append((name, kind))
    return recorded


def _done_files(session: Session) -> dict[str, FileRecord]:
    """The last file record of every key whose step is done (later records win, as after resume)."""
    done = set(session.done_steps())
    latest: dict[str, FileRecord] = {}
    for record in session.files():
        if record.key in done and record.role in ("frame", "dark", "spectrum"):
            latest[record.key] = record
    return latest


def _verify(session: Session, record: FileRecord) -> Path:
    """The file's path once its size and sha256 match the log (a :class:`SessionFormatError` if not)."""
    problem = session.file_problem(record)
    if problem is not None:
        raise SessionFormatError(
            f"{session.path}: {record.path}: {problem}; the file changed after capture"
        )
    return session.file_path(record.path)


def _collect(session: Session, lamps: Sequence[str]) -> dict[str, _LampFiles]:
    records = _done_files(session)
    selected: list[tuple[str, str, int, FileRecord]] = []
    for key, record in records.items():
        match = _KEY.fullmatch(key)
        if match is None or match["lamp"] not in lamps:
            continue
        selected.append((match["lamp"], match["stream"], int(match["index"]), record))
    with ThreadPoolExecutor(max_workers=2, thread_name_prefix="verify") as pool:
        paths = list(pool.map(lambda item: _verify(session, item[3]), selected))
    files = {name: _LampFiles([], [], []) for name in lamps}
    for (lamp, stream, index, record), path in zip(selected, paths, strict=True):
        getattr(files[lamp], stream).append(_SessionFile(record, path, index))
    for entry in files.values():
        for items in (entry.scene, entry.dark, entry.reference):
            items.sort(key=lambda item: item.index)
    return files


def _bandwidth(references: Sequence[_SessionFile]) -> float | None:
    """The spectrometer bandwidth the reference spectra were recorded with (the largest, if any)."""
    values = [item.record.bandwidth_nm for item in references if item.record.bandwidth_nm]
    return max(values) if values else None


def _step_exposures(session: Session, keys: Sequence[str]) -> list[float | None]:
    """The exposure each step asked for (``params.exposure_s``), from its done record."""
    done = session.done_steps()
    exposures: list[float | None] = []
    for key in keys:
        value = done[key].params.get("exposure_s") if key in done else None
        exposures.append(float(value) if isinstance(value, int | float) else None)
    return exposures


def _darks_cover(session: Session, files: _LampFiles) -> bool:
    """Every scene exposure has a dark frame at the same exposure (as the HDR merge needs)."""
    scene = _step_exposures(session, [f.record.key for f in files.scene])
    dark = [t for t in _step_exposures(session, [f.record.key for f in files.dark]) if t]
    return all(
        t is not None and any(math.isclose(t, d, rel_tol=_EXPOSURE_RTOL) for d in dark)
        for t in scene
    )


def session_lamps(session: Session) -> tuple[list[LampImages], list[InputFile], list[str]]:
    """The session's lamps as pipeline inputs, their verified files, and warnings.

    Raises
    ------
    SessionFormatError
        Unsafe paths, files that differ from the log, an invalid configuration snapshot.
    InputError
        No lamp has a complete bracket and spectrum.
    """
    recorded = _recorded_lamps(session)
    files = _collect(session, [name for name, _ in recorded])
    warnings: list[str] = []
    if session.status != "complete":
        stop = session.stop
        reason = stop.reason if stop is not None else "no stop record"
        warnings.append(
            f"the session is {session.status} ({reason}); estimated from the lamps whose bracket "
            "and spectra were captured"
        )
    lamps: list[LampImages] = []
    known: list[InputFile] = []
    for name, kind in recorded:
        entry = files[name]
        if not entry.scene or not entry.reference:
            missing = "bracket" if not entry.scene else "reference spectra"
            warnings.append(f"lamp {name!r} left out: the session has no {missing} for it")
            continue
        darks = entry.dark
        if darks and not _darks_cover(session, entry):
            warnings.append(
                f"lamp {name!r}: dark frames left out (not one for every exposure of the bracket)"
            )
            darks = []
        lamps.append(
            LampImages(
                name=name,
                kind=kind,
                spectrum=tuple(item.path for item in entry.reference),
                images=tuple(item.path for item in entry.scene),
                darks=tuple(item.path for item in darks),
                spectrum_bandwidth_nm=_bandwidth(entry.reference),
            )
        )
        for role, items in (("frame", entry.scene), ("dark", darks), ("spectrum", entry.reference)):
            known.extend(
                InputFile(str(item.path), role, name, item.record.size, item.record.sha256)  # type: ignore[arg-type]
                for item in items
            )
    if not lamps:
        raise InputError(
            "no lamp of the session has a captured bracket and reference spectra",
            source=str(session.path),
        )
    return lamps, known, warnings


_BEAM_KEY = re.compile(
    r"^lamp/(?P<lamp>[^/]+)/grating/(?P<target>direct|order0|order1-\d+nm)/(?P<index>\d+)$"
)


def session_grating_beams(session: Session) -> BeamSpectra | None:
    """The spectra the session measured in the grating's beams (verified), or ``None`` when it
    measured none, or not all three kinds (direct, 0th order, 1st order).

    Raises
    ------
    SessionFormatError
        A beam's file differs from the log, or its step's parameters are not a beam's.
    """
    done = session.done_steps()
    files = _done_files(session)
    spectra: dict[tuple[str, float | None], list[tuple[int, Any]]] = {}
    lamp = ""
    bandwidths: list[float] = []
    for key, record in sorted(files.items()):
        match = _BEAM_KEY.fullmatch(key)
        if match is None:
            continue
        params = done[key].params
        beam, centre = params.get("beam"), params.get("centre_nm")
        if beam not in ("direct", "order0", "order1") or not (
            centre is None or isinstance(centre, int | float)
        ):
            raise SessionFormatError(f"{session.path}: step {key}: its parameters are not a beam's")
        lamp = match["lamp"]
        spectrum = read_spectrum_csv(_verify(session, record))
        spectra.setdefault((str(beam), None if centre is None else float(centre)), []).append(
            (int(match["index"]), spectrum)
        )
        if record.bandwidth_nm:
            bandwidths.append(float(record.bandwidth_nm))
    direct, order0 = spectra.pop(("direct", None), None), spectra.pop(("order0", None), None)
    if direct is None or order0 is None or not spectra:
        return None
    axis = direct[0][1].wavelength_nm

    def stacked(items: list[tuple[int, Any]]) -> Any:
        return np.stack([s.at(axis) for _, s in sorted(items, key=lambda item: item[0])])

    return BeamSpectra(
        wavelength_nm=axis,
        direct=stacked(direct),
        order0=stacked(order0),
        order1=[(centre or 0.0, stacked(items)) for (_, centre), items in sorted(spectra.items())],
        bandwidth_nm=max(bandwidths) if bandwidths else None,
        lamp=lamp,
    )


#: The wavelengths a measured grating is tabulated on: a spectroradiometer's usual range (PR-655,
#: CS-2000: 380–780 nm), so that any working grid inside it is covered.
MEASURED_GRATING_GRID = WavelengthGrid(380.0, 780.0, 5.0)


def measured_grating_settings(
    session: Session, notes: list[str], warnings: list[str]
) -> dict[str, Any]:
    """The estimate's ``grating`` when the session measured it (else nothing); a note says so,
    a warning when no physical model describes the measurement."""
    beams = session_grating_beams(session)
    if beams is None:
        return {}
    grating = grating_from_beams(
        beams,
        MEASURED_GRATING_GRID,
        provenance={"session": str(session.path.name), "lamp": beams.lamp},
    )
    model = grating.model or {}
    notes.append(
        f"the grating's efficiency was measured with the spectrometer in its beams ({beams.lamp}, "
        f"{len(beams.order1)} first-order aims): the estimate uses it as a known grating "
        f"({model.get('model')} model, reduced χ² {model.get('reduced_chi2', float('nan')):.3g})"
    )
    if "warning" in model:
        warnings.append(f"measured grating: {model['warning']}")
    return {"grating": grating}


def _warmup_traces(session: Session) -> tuple[WarmupTrace, ...]:
    """Each lamp's warm-up from the log: the change between successive warm-up spectra
    (:func:`rig.plan.relative_change`, as the plan judged it) against the time since switch-on."""
    done = session.done_steps()
    start = session.start
    lamps = start.config.get("lamps", []) if start is not None else []
    traces: list[WarmupTrace] = []
    for lamp in lamps if isinstance(lamps, list) else []:
        name = lamp.get("name") if isinstance(lamp, Mapping) else None
        switched = done.get(f"lamp/{name}/switch-on")
        keys = sorted(
            key for key in done if re.fullmatch(rf"lamp/{re.escape(str(name))}/warmup/\d+", key)
        )
        if not isinstance(name, str) or switched is None or switched.result is None or not keys:
            continue

        def load(relative: str) -> tuple[Any, Any]:
            spectrum = read_spectrum_csv(session.file_path(relative), negative="clip")
            return spectrum.wavelength_nm, spectrum.values

        try:
            spectra = [SpectrumMeasured.from_json(done[key].result or {}, load) for key in keys]
        except (SpectrumError, SessionFormatError, KeyError, TypeError, ValueError):
            continue  # the report says the warm-up is not available
        on_s = float(switched.result.get("time_s", 0.0))
        changes = [math.nan] + [relative_change(a, b) for a, b in itertools.pairwise(spectra)]
        policy = lamp.get("warmup")
        tolerance = policy.get("tolerance") if isinstance(policy, Mapping) else None
        traces.append(
            WarmupTrace(
                lamp=name,
                elapsed_s=tuple(spectrum.time_s - on_s for spectrum in spectra),
                relative_change=tuple(changes),
                tolerance=float(tolerance) if isinstance(tolerance, int | float) else None,
            )
        )
    return tuple(traces)


def _twin_truth(session_path: Path, warnings: list[str]) -> GroundTruth | None:
    """The digital twin's truth written beside the session (``rig demo``), if there is one."""
    path = session_path / TWIN_TRUTH_FILE
    if not path.is_file():
        return None
    try:
        truth = read_twin_truth(path)
    except (ValueError, RigError) as exc:
        warnings.append(f"{path.name} not used: {exc}")
        return None
    return GroundTruth(
        truth.sensitivity,
        grating_efficiency=truth.grating_efficiency,
        zeroth_order_efficiency=truth.zeroth_order_efficiency,
        mapping=truth.mapping,
        source=f"{path.name}: the digital twin's camera {truth.camera} (not a verified session file)",
    )


def check_estimate_out(session_dir: Path, out_dir: Path | None, *, force: bool) -> Path:
    """The directory ``rig estimate`` writes to, checked before any work is done.

    ``out_dir`` defaults to ``<session>/estimate``. The session may come from anyone, so where the
    directory lies inside it every directory on the way must be a real directory, and nothing in an
    existing one may be a symbolic link: the outputs are never written through a link planted
    there. Results of an earlier estimate are replaced only with ``force`` (as ``calib estimate
    --force``), and the directory must be writable.

    Raises
    ------
    SessionFormatError
        A link or special file is planted on the way or in the directory (named).
    calib.errors.InputError
        Earlier results without ``force``; a directory that cannot be written.
    """
    target = out_dir if out_dir is not None else Path(session_dir) / DEFAULT_OUT_NAME
    # Compared by name, never resolved: resolving would follow the very link to be refused.
    session_root = Path(os.path.normpath(Path(session_dir).absolute()))
    absolute = Path(os.path.normpath(target.absolute()))
    try:
        if absolute != session_root and absolute.is_relative_to(session_root):
            checked_directory(session_root, str(absolute.relative_to(session_root)), create=False)
        if target.is_dir():
            for entry in entries_below(target):
                if not is_plain(entry):
                    raise UnsafeLocalPath(Path(entry.path), describe_entry(Path(entry.path)))
    except UnsafeLocalPath as exc:
        raise SessionFormatError(
            f"{exc.path} is {exc.problem}; the estimate is never written through it: remove it, "
            "or choose another --out"
        ) from None
    except FileNotFoundError:
        pass  # created by the estimate
    check_out_dir(target, force)
    return target


class SessionInputs:
    """Session directories as batch input sets (:class:`calib.pipeline.input_sets.InputSetReader`;
    the ``spectral_rig.inputs`` entry point ``session``)."""

    kind = "session"
    description = "a session directory (with log.jsonl)"

    def recognises(self, path: Path) -> bool:
        """A directory holding a ``log.jsonl``."""
        return (Path(path) / LOG_NAME).is_file()

    def default_out_name(self, path: Path) -> str:
        return Path(path).name

    def read(self, path: Path, out_dir: Path | None, *, force: bool) -> InputSet:
        """The session's verified lamps, its warnings and notes, the twin's truth and the lamps'
        warm-up; where the estimate goes checked first (:func:`check_estimate_out`).

        Raises
        ------
        SessionFormatError
            Not a session, an invalid log, unsafe paths (a link planted where the estimate is
            written too), files that differ from the log.
        InputError
            No usable lamp; earlier results without ``force``; an output directory that cannot be
            written.
        """
        session_path = Path(path)
        destination = check_estimate_out(session_path, out_dir, force=force)
        session = read_session(session_path)
        lamps, known, warnings = session_lamps(session)
        context = EstimateContext(_twin_truth(session_path, warnings), _warmup_traces(session))
        start = session.start
        assert start is not None
        notes = [f"session {start.session_id} ({session_path.name}), status {session.status}"]
        measured = measured_grating_settings(session, notes, warnings)
        return InputSet(
            name=session_path.name,
            lamps=tuple(lamps),
            out_dir=destination,
            known_inputs=tuple(known),
            warnings=tuple(warnings),
            notes=tuple(notes),
            context=context,
            settings=measured,
        )


#: The reader of session directories (the ``spectral_rig.inputs`` entry point ``session``).
SESSION_INPUTS = SessionInputs()


def session_settings(
    *,
    method: str = "auto",
    data_dir: str | Path | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
    mapping_lamp: str | None = None,
    command_line: Sequence[str] | None = None,
    settings: Mapping[str, Any] | None = None,
) -> OfflineSettings:
    """The :class:`calib.pipeline.OfflineSettings` of ``rig estimate`` (one session or many)."""
    options: dict[str, Any] = {
        "method": method,
        "grid": grid,
        "mapping_lamp": mapping_lamp,
        "data_dir": None if data_dir is None else Path(data_dir),
        "command_line": None if command_line is None else tuple(command_line),
        **dict(settings or {}),
    }
    return OfflineSettings(**options)


def estimate_session(
    session_dir: str | Path,
    out_dir: str | Path | None = None,
    *,
    method: str = "auto",
    data_dir: str | Path | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
    mapping_lamp: str | None = None,
    progress: OfflineProgress | None = None,
    command_line: Sequence[str] | None = None,
    settings: Mapping[str, Any] | None = None,
    force: bool = False,
    report: bool = True,
) -> OfflineOutcome:
    """Estimate the camera from a session and write the outputs.

    Where it writes is checked first (:func:`check_estimate_out`), before any work.

    Parameters
    ----------
    session_dir
        The session directory (with ``log.jsonl``).
    out_dir
        Where to write (default ``<session>/estimate``).
    method
        Estimation method (:func:`calib.methods.estimate`; ``"auto"`` chooses by the lamps).
    data_dir
        Camera data directory for the basis.
    grid
        Working wavelength grid.
    mapping_lamp
        The lamp for the pixel→wavelength mapping (default: the estimator's choice).
    progress
        Receives frame and stage events (e.g. :class:`calib.pipeline.RichFrameProgress`).
    command_line
        The command as typed, recorded in the result.
    settings
        Further :class:`calib.pipeline.OfflineSettings` fields (``basis``, ``use_region`` …).
    report
        Also write ``report.html``.

    Returns
    -------
    calib.pipeline.OfflineOutcome
        The estimate and the files written.

    Raises
    ------
    SessionFormatError
        Not a session, an invalid log, unsafe paths (a link planted where the estimate is written
        too), files that differ from the log.
    InputError
        No usable lamp; any input problem the pipeline finds; earlier results without ``force``;
        an output directory that cannot be written.
    """
    inputs = SESSION_INPUTS.read(
        Path(session_dir), None if out_dir is None else Path(out_dir), force=force
    )
    offline = session_settings(
        method=method,
        data_dir=data_dir,
        grid=grid,
        mapping_lamp=mapping_lamp,
        command_line=command_line,
        settings=settings,
    )
    return inputs.run(offline, progress=progress, report=report)
