"""``rig compare``: every grating method on captured twin sessions, judged against the twin's camera.

``calib compare`` runs the methods on the synthetic protocol; this runs them on sessions, which only
``rig`` can read (``calib`` imports nothing of ``rig``). Every session is checked before anything is
estimated, and trusted no more than ``rig estimate`` trusts it:

1. its log is read and every file it uses verified against the log (:func:`rig.estimate.session_lamps`);
2. its ``twin-truth.json`` (written by ``rig demo``; not one of the log's files) must be a regular
   file of the twin's truth format whose camera and seed are those of the session's configuration
   snapshot — RE needs the true camera, so a session without one is refused;
3. the camera basis leaves the true camera out, as ``rig demo``'s does
   (:func:`rig.demo.related_camera_names`).

Then per session the lamps go through the offline pipeline ``rig estimate`` runs
(:func:`calib.pipeline.estimate_offline`: HDR merge, geometry, profiles, direct RGB) and the
observations it extracted become a :class:`calib.evaluation.compare.GratingScene`; the columns are
:func:`calib.evaluation.compare.grating_adapters`, the rows :func:`calib.evaluation.compare.run_grating_comparison`, the
files (``compare.md``, ``compare.csv``, ``compare_sessions.png``) :mod:`calib.evaluation.compare_report`'s.
"""

from __future__ import annotations

import stat
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.errors import InputError
from calib.core.metrics import format_re, relative_error
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.evaluation.compare import (
    CompareRow,
    GratingScene,
    active_grating_adapters,
    grating_adapters,
    run_grating_comparison,
)
from calib.evaluation.compare_report import plot_panels, sessions_markdown_report, write_csv
from calib.model.bases import CameraBasis, default_camera_basis
from calib.pipeline import InputFile, LampImages, OfflineSettings, estimate_offline
from rig.demo import related_camera_names
from rig.errors import SessionFormatError
from rig.estimate import session_lamps
from rig.session import read_session
from rig.twin import TwinTruthRecord, digital_twin

MARKDOWN_FILE = "compare.md"
CSV_FILE = "compare.csv"
PLOT_FILE = "compare_sessions.png"


@dataclass(frozen=True, eq=False)
class CheckedSession:
    """A session whose files verify against its log, with the twin's truth that belongs to it.

    Attributes
    ----------
    path
        The session directory.
    lamps, known, warnings
        :func:`rig.estimate.session_lamps`' inputs for the pipeline, verified files and warnings.
    truth
        The twin's truth (:class:`rig.twin.TwinTruthRecord`).
    """

    path: Path
    lamps: list[LampImages]
    known: list[InputFile]
    warnings: list[str]
    truth: TwinTruthRecord


def _twin_truth(path: Path, config: Mapping[str, Any]) -> TwinTruthRecord:
    """The session's ``twin-truth.json``, refused unless it is the truth of this session's twin."""
    twin = digital_twin()
    truth_path = path / twin.truth_file_name
    try:
        mode = truth_path.lstat().st_mode
    except FileNotFoundError:
        raise InputError(
            "not found: RE needs the session's true camera, which only a digital-twin session "
            "holds (`rig demo` writes it next to the log)",
            source=str(truth_path),
        ) from None
    if not stat.S_ISREG(mode):
        raise SessionFormatError(f"{truth_path}: not a regular file")
    try:
        truth = twin.read_truth(truth_path)
    except twin.truth_error as exc:
        raise SessionFormatError(str(exc)) from None
    devices = config.get("devices")
    camera = devices.get("camera") if isinstance(devices, Mapping) else None
    if not isinstance(camera, Mapping) or camera.get("kind") != "twin":
        raise SessionFormatError(
            f"{path}: not a digital-twin session (the configuration's camera is not kind: twin), "
            f"so {truth_path.name} cannot be its truth"
        )
    recorded = (camera.get("sensitivity"), config.get("seed"))
    if (truth.camera, truth.seed) != recorded:
        raise SessionFormatError(
            f"{truth_path}: the truth of camera {truth.camera!r}, seed {truth.seed}; the session "
            f"was captured with camera {recorded[0]!r}, seed {recorded[1]}"
        )
    return truth


def check_session(path: str | Path) -> CheckedSession:
    """Read a session, verify its files against the log and read the twin's truth.

    Raises
    ------
    SessionFormatError
        Not a session, an invalid log, unsafe paths, files that differ from the log, a truth that
        is unreadable or belongs to another twin.
    InputError
        No twin truth, or no lamp with a captured bracket and spectra.
    """
    directory = Path(path)
    session = read_session(directory)
    start = session.start
    if start is None:
        raise SessionFormatError(f"{directory}: the log has no start record")
    truth = _twin_truth(directory, start.config)
    lamps, known, warnings = session_lamps(session)
    return CheckedSession(directory, lamps, known, warnings, truth)


def twin_basis(
    camera: str,
    grid: WavelengthGrid = DEFAULT_GRID,
    data_dir: Path | None = None,
    exclude: Sequence[str] = (),
) -> CameraBasis:
    """The camera basis without the twin's camera (as ``rig demo``'s estimate uses), nor the
    cameras ``exclude`` names."""
    return default_camera_basis(
        grid, data_dir=data_dir, exclude=[*related_camera_names(camera), *exclude]
    )


@dataclass(eq=False)
class TwinSessionSource:
    """Captured twin sessions as :class:`calib.evaluation.compare.GratingScene` records.

    Attributes
    ----------
    sessions
        Sessions already checked (:func:`check_session`).
    grid
        The working grid.
    data_dir
        Camera data for the basis.
    basis_for
        The basis of a true camera (default :func:`twin_basis`).
    exclude_cameras
        Name patterns of further cameras kept out of :func:`twin_basis`.
    notes
        Filled while scenes are made: per session, its lamps and the pipeline's warnings.
    """

    sessions: Sequence[CheckedSession]
    grid: WavelengthGrid = DEFAULT_GRID
    data_dir: Path | None = None
    basis_for: Callable[[str], CameraBasis] | None = None
    exclude_cameras: tuple[str, ...] = ()
    notes: list[str] = field(default_factory=list)
    _bases: list[str] = field(default_factory=list, init=False, repr=False)

    @property
    def description(self) -> str:
        bases = "; ".join(dict.fromkeys(self._bases)) or "(none built)"
        return (
            f"{len(self.sessions)} captured digital-twin session(s), each through the offline "
            f"pipeline of `rig estimate`, judged against the twin's true camera; basis without "
            f"the true camera: {bases}"
        )

    def scenes(self) -> Iterator[GratingScene]:
        for index, checked in enumerate(self.sessions):
            camera = checked.truth.camera
            basis = (
                self.basis_for(camera)
                if self.basis_for is not None
                else twin_basis(camera, self.grid, self.data_dir, self.exclude_cameras)
            )
            self._bases.append(basis.source)
            extracted = estimate_offline(
                checked.lamps,
                OfflineSettings(grid=self.grid, basis=basis, warnings=tuple(checked.warnings)),
                known_inputs=checked.known,
            )
            truth = checked.truth.sensitivity.resample(
                self.grid, "interpolate", out_of_range="zero"
            ).values
            truth = truth / np.max(truth)
            scene = GratingScene(
                camera=camera,
                session=checked.path.name,
                grid=self.grid,
                truth=truth,
                basis=basis,
                lamps=extracted.observations,
                mapping=checked.truth.mapping,
                seed=int(np.random.default_rng([checked.truth.seed, index]).integers(2**31)),
            )
            lamps = ", ".join(
                f"{lamp.name} ({lamp.kind}{'' if lamp.direct_rgb is not None else ', no direct'})"
                for lamp in scene.lamps
            )
            self.notes.append(
                f"{scene.label}: lamps {lamps}; single-lamp columns use {scene.solve_lamp.name}; "
                f"`rig estimate`'s own result RE "
                f"{format_re(relative_error(extracted.result.physical_sensitivity(), truth))}"
            )
            self.notes.extend(f"{scene.label}: {warning}" for warning in extracted.warnings)
            yield scene


@dataclass(frozen=True)
class SessionComparison:
    """What :func:`compare_sessions` produced: the rows, the report and the files written."""

    rows: list[CompareRow]
    report: str
    files: dict[str, Path]


def compare_sessions(
    sessions: Sequence[str | Path],
    out_dir: str | Path,
    *,
    methods: Sequence[str] | None = None,
    data_dir: str | Path | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
    toivonen: Mapping[str, Any] | None = None,
    basis_for: Callable[[str], CameraBasis] | None = None,
    exclude_cameras: Sequence[str] = (),
    command: str | None = None,
    progress: Callable[[CompareRow], None] | None = None,
) -> SessionComparison:
    """Every grating method on every session; write ``compare.md``, ``compare.csv`` and the plots.

    Parameters
    ----------
    sessions
        Session directories of the digital twin (with ``twin-truth.json``).
    out_dir
        Where to write.
    methods
        Registered methods to run (default: all; those a session cannot feed are listed as skipped).
    data_dir
        Camera data for the basis.
    grid
        Working wavelength grid.
    toivonen
        Options of the Toivonen column (``ensemble_size``, ``epochs`` …).
    basis_for
        The basis of a true camera (default :func:`twin_basis`).
    exclude_cameras
        Name patterns of further cameras kept out of the default basis.
    command
        The command line, recorded in the report.
    progress
        Called with every row as it is done.

    Raises
    ------
    SessionFormatError, InputError
        A bad session (checked for every session before anything is estimated), an unknown method.
    """
    if not sessions:
        raise InputError("give at least one session directory", source="SESSION")
    adapters, skipped = active_grating_adapters(
        grating_adapters(toivonen=dict(toivonen or {})), methods
    )
    checked = [check_session(path) for path in sessions]
    source = TwinSessionSource(
        checked,
        grid,
        None if data_dir is None else Path(data_dir),
        basis_for=basis_for,
        exclude_cameras=tuple(exclude_cameras),
    )
    rows = run_grating_comparison(source, adapters, grid=grid, progress=progress)
    report = sessions_markdown_report(
        rows,
        adapters,
        description=source.description,
        skipped=skipped,
        session_notes=source.notes,
        command=command,
    )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    markdown = out / MARKDOWN_FILE
    markdown.write_text(report, encoding="utf-8")
    files = {"markdown": markdown, "csv": write_csv(out / CSV_FILE, rows)}
    if rows:
        title = "estimated (solid) vs true (dotted) on captured twin sessions; RE ×10⁻²"
        files["plot"] = plot_panels(out / PLOT_FILE, rows, title, grid=grid)
    return SessionComparison(rows, report, files)
