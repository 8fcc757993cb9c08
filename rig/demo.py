"""``rig demo``: a whole measurement on the digital twin — capture, estimate, report, and the error.

1. Capture with the given configuration (the shipped ``config.yaml``: every device the twin) into
   ``<out>/sessions/`` — the real runner, plan and drivers, on simulated hardware.
2. Write the twin's truth (``twin-truth.json``: the camera it really has, its grating and mapping)
   into the session directory. The session's log does not acknowledge it, so it is never one of the
   session's trusted files.
3. Estimate from the session (``rig.estimate.estimate_session``: HDR merge, profiles, the
   estimator, ``sensitivity.csv``, ``result.json``, ``report.html``) into
   ``<out>/estimate/<session>/``.
4. Compare ``sensitivity.csv`` with the truth: RE (Makabe et al. 2025, Eq. 16) on the estimate's
   own wavelengths, both normalised to their maximum.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.core.errors import InputError
from calib.core.formats.rgb_csv import read_camera_csv
from calib.core.metrics import relative_error
from calib.model.bases import default_camera_basis
from rig.capture import run_capture
from rig.config import RigConfig
from rig.estimate import estimate_session
from rig.progress import ProgressReporter
from rig.runner import RunOutcome
from rig.twin import digital_twin, read_twin_truth, write_twin_truth

SESSIONS_DIR = "sessions"
ESTIMATE_DIR = "estimate"
SENSITIVITY_FILE = "sensitivity.csv"
REPORT_FILE = "report.html"

SessionEstimator = Callable[[Path, Path], object]
"""Estimates a session into an output directory (writes ``sensitivity.csv``, ``report.html`` …)."""


@dataclass(frozen=True)
class DemoResult:
    """What the demo produced.

    Attributes
    ----------
    capture
        How the capture ended (with the session's path).
    truth
        The twin's ``twin-truth.json``.
    estimate_dir
        Where the estimate's files are (``None`` when the capture failed).
    report
        The HTML report, when the estimate wrote one.
    relative_error
        RE of the estimated sensitivity against the twin's camera.
    colour_error
        Per illuminant (D65, A): mean and max ΔE2000 of the ColorChecker between the twin's
        camera developed with the estimate's colour-correction matrix and with its own.
    capture_s, estimate_s
        Wall time of the two stages.
    """

    capture: RunOutcome
    truth: Path
    estimate_dir: Path | None = None
    report: Path | None = None
    relative_error: float | None = None
    colour_error: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    capture_s: float = 0.0
    estimate_s: float = 0.0


def default_estimator() -> SessionEstimator:
    """:func:`rig.estimate.estimate_session` with a camera prior that leaves the twin's own camera
    out (read from the session's truth file)."""

    def estimate(session: Path, out_dir: Path) -> object:
        # The camera prior must not contain the twin's own camera: the RE would flatter us.
        camera = read_twin_truth(session / digital_twin().truth_file_name).camera
        basis = default_camera_basis(exclude=related_camera_names(camera))
        return estimate_session(session, out_dir, settings={"basis": basis})

    return estimate


def related_camera_names(camera: str) -> list[str]:
    """Names under which the twin's camera may appear in a camera collection.

    ``"Nikon 5100 (NPL)"`` → ``["Nikon 5100", "Nikon D5100"]`` (collections name Nikon DSLRs with
    and without the ``D``); each names a body (:func:`calib.core.camera_bodies.names_camera`).
    """
    base = camera.split(" (")[0].strip()
    names = [base]
    parts = base.split(" ", 1)
    if len(parts) == 2 and parts[1][:1].isdigit():
        names.append(f"{parts[0]} D{parts[1]}")
    return names


def sensitivity_error(estimate_csv: Path, truth_json: Path) -> float:
    """RE of the sensitivity in ``estimate_csv`` against the twin's truth, on the estimate's grid.

    Raises
    ------
    InputError
        When the estimate lies outside the truth's wavelength range.
    """
    estimated = read_camera_csv(estimate_csv)
    truth = read_twin_truth(truth_json).sensitivity
    low, high = truth.range_nm
    wavelength = estimated.wavelength_nm
    if wavelength[0] < low or wavelength[-1] > high:
        raise InputError(
            f"the estimate covers {wavelength[0]:g}–{wavelength[-1]:g} nm, the twin's camera "
            f"{low:g}–{high:g} nm",
            source=str(estimate_csv),
        )
    reference = np.stack(
        [np.interp(wavelength, truth.wavelength_nm, truth.values[:, k]) for k in range(3)], axis=1
    )
    return relative_error(estimated.values, reference)


def colour_error(result_json: Path) -> dict[str, tuple[float, float]]:
    """``{illuminant: (mean, max)}`` ΔE2000 against the truth that ``result.json`` records."""
    try:
        document = json.loads(result_json.read_text(encoding="utf-8"))
        against = (document.get("uses") or {}).get("against_truth") or {}
        return {
            name: (
                float(entry["estimate_vs_truth"]["mean"]),
                float(entry["estimate_vs_truth"]["max"]),
            )
            for name, entry in against.items()
        }
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def run_demo(
    config: RigConfig,
    out_dir: Path,
    *,
    progress: ProgressReporter | None = None,
    estimator: SessionEstimator | None = None,
) -> DemoResult:
    """Capture on the twin, estimate, and measure the estimate against the twin's camera.

    Parameters
    ----------
    config
        A configuration whose devices are the twin.
    out_dir
        Receives ``sessions/<session>/`` and ``estimate/<session>/``.
    progress
        Progress of the capture.
    estimator
        The estimate step (default :func:`default_estimator`).

    Raises
    ------
    InputError
        When the configuration's devices are not the twin.
    """
    if len(config.devices.twin_roles()) != 3:
        raise InputError(
            "rig demo runs on the digital twin: set every device's kind to 'twin' (as the "
            "shipped config.yaml does), or use `rig capture` on real hardware",
            source="devices",
        )
    estimate = estimator or default_estimator()
    started = time.perf_counter()
    outcome = run_capture(config, out_dir=out_dir / SESSIONS_DIR, progress=progress)
    capture_s = time.perf_counter() - started
    truth = write_twin_truth(config, outcome.session)
    if outcome.exit_status != "success":
        return DemoResult(outcome, truth, capture_s=capture_s)
    estimate_dir = out_dir / ESTIMATE_DIR / outcome.session.name
    started = time.perf_counter()
    estimate(outcome.session, estimate_dir)
    estimate_s = time.perf_counter() - started
    sensitivity = estimate_dir / SENSITIVITY_FILE
    report = estimate_dir / REPORT_FILE
    return DemoResult(
        capture=outcome,
        truth=truth,
        estimate_dir=estimate_dir,
        report=report if report.is_file() else None,
        relative_error=sensitivity_error(sensitivity, truth) if sensitivity.is_file() else None,
        colour_error=colour_error(estimate_dir / "result.json"),
        capture_s=capture_s,
        estimate_s=estimate_s,
    )
