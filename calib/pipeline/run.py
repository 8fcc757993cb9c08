"""Estimate and write every output file: the function both command lines call."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from calib.pipeline.brackets import BracketProfiles
from calib.pipeline.context import EstimateContext
from calib.pipeline.estimate import (
    OfflineEstimate,
    OfflineSettings,
    estimate_offline,
    import_estimation,
)
from calib.pipeline.inputs import LampImages, LampInput
from calib.pipeline.progress import OfflineProgress
from calib.pipeline.provenance import InputFile


@dataclass(frozen=True, eq=False)
class OfflineOutcome:
    """An estimate and the files written for it (``sensitivity``, ``result``, ``report`` …)."""

    estimate: OfflineEstimate
    files: Mapping[str, Path]
    timings: Mapping[str, float]


def run_offline(
    lamps: Sequence[LampInput],
    out_dir: Path,
    settings: OfflineSettings | None = None,
    *,
    progress: OfflineProgress | None = None,
    known_inputs: Sequence[InputFile] = (),
    report: bool = True,
    context: EstimateContext | None = None,
) -> OfflineOutcome:
    """Run :func:`calib.pipeline.estimate_offline` and write its outputs into ``out_dir``.

    Parameters
    ----------
    lamps, settings, progress, known_inputs
        As for :func:`calib.pipeline.estimate_offline`.
    out_dir
        Created if missing.
    report
        Also write ``report.html`` with its plots.
    context
        The known truth and the session's warm-up records, for the outputs and the report.

    Returns
    -------
    OfflineOutcome
    """
    from calib.pipeline.outputs import deliver, write_outputs
    from calib.pipeline.report import PLOTS_DIR, import_plotting, plot_geometry, write_report

    started = time.perf_counter()
    # The estimator's and the report's libraries are imported, and the geometry drawn, in a
    # background thread while frames decode and the estimate runs (both mostly release the GIL).
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="report") as background:
        drawn: dict[str, Future[Path]] = {}
        # with RAW input only: there is nothing to overlap the imports with otherwise
        imported = (
            background.submit(import_estimation)
            if any(isinstance(lamp, LampImages) for lamp in lamps)
            else None
        )

        def profiles_done(profiles: BracketProfiles) -> None:
            # The estimate starts once the thread has imported its modules: no module is then
            # imported by two threads at once.
            if imported is not None:
                imported.result()
            if report:
                drawn["plot:geometry"] = background.submit(
                    plot_geometry, out_dir / PLOTS_DIR / "geometry.png", profiles
                )

        if report:
            background.submit(import_plotting)
        estimate = estimate_offline(
            lamps,
            settings or OfflineSettings(),
            progress=progress,
            known_inputs=known_inputs,
            on_profiles=profiles_done,
        )
        if progress is not None:
            progress.stage("writing the results")
        step = time.perf_counter()
        context = context or EstimateContext()
        delivered = deliver(estimate, context.truth)
        files = dict(write_outputs(out_dir, estimate, delivered))
        timings = dict(estimate.timings)
        timings["outputs_s"] = time.perf_counter() - step
        if report:
            if progress is not None:
                progress.stage("writing the report")
            step = time.perf_counter()
            prepared = {key: future.result() for key, future in drawn.items()}
            files.update(
                write_report(
                    out_dir,
                    estimate,
                    files,
                    prepared=prepared,
                    delivered=delivered,
                    context=context,
                )
            )
            timings["report_s"] = time.perf_counter() - step
    timings["total_s"] = time.perf_counter() - started
    return OfflineOutcome(estimate, files, timings)
