"""What a batch is made of: jobs, the plan they share, their rows, and the worker side.

A job is one input set (:mod:`calib.pipeline.input_sets`) and where its outputs go. A worker
(:mod:`calib.pipeline.batch` runs them) estimates a job with :func:`estimate_job`, exactly as the set
is estimated on its own (:meth:`~calib.pipeline.input_sets.InputSet.run` with the same settings),
and keeps the camera basis for its later jobs (:func:`worker_settings`): that, and the imports, are
what a batch pays once per worker instead of once per set. Whatever goes wrong in a job becomes its
row's one-line reason; the batch goes on.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import socket
import threading
import time
import traceback
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from multiprocessing.queues import SimpleQueue
from pathlib import Path
from typing import Literal

from calib.core.errors import CalibError, InputError
from calib.model.bases import CameraBasis
from calib.pipeline.batch_malloc import roomy_allocator
from calib.pipeline.estimate import OfflineSettings, basis_key, resolve_basis
from calib.pipeline.input_sets import InputSetReader, reader_for

#: Set in a worker's environment to show the traceback of an unexpected error in its row.
DEBUG_VARIABLES = ("CALIB_DEBUG", "RIG_DEBUG")


@dataclass(frozen=True)
class BatchJob:
    """One input set of a batch.

    Parameters
    ----------
    path
        The input set (absolute: workers may run elsewhere).
    reader
        The reader that recognised it.
    out_dir
        Where its outputs go; ``None``: the set's own default (a session's ``estimate/``).
    """

    path: Path
    reader: InputSetReader
    out_dir: Path | None = None

    @property
    def name(self) -> str:
        return self.reader.default_out_name(self.path)


@dataclass(frozen=True)
class BatchPlan:
    """What every job of a batch shares: the settings, whether reports are written, ``--force``."""

    settings: OfflineSettings
    report: bool = True
    force: bool = False


Status = Literal["ok", "failed", "not run"]


@dataclass(frozen=True)
class BatchRow:
    """One line of a batch's summary.

    Attributes
    ----------
    name, path
        The input set (its name in the summary, its path).
    status
        ``ok``, ``failed`` (``error`` says why), or ``not run`` (the batch was interrupted).
    out_dir
        Where its outputs are.
    camera
        The camera the RAW files name.
    method
        The method that estimated it (``auto``'s choice).
    truth_relative_error
        RE (Eq. 16) against the known truth (a twin session's camera), or ``None``.
    warnings
        The estimate's warnings.
    wall_s, cpu_s
        The job's wall and CPU time in its worker.
    worker
        ``host:pid`` of the process that ran it.
    error
        The one-line reason of a failure.
    detail
        The traceback of an unexpected error, when ``CALIB_DEBUG`` or ``RIG_DEBUG`` is set.
    """

    name: str
    path: str
    status: Status
    out_dir: str | None = None
    camera: str | None = None
    method: str | None = None
    truth_relative_error: float | None = None
    warnings: tuple[str, ...] = ()
    wall_s: float = 0.0
    cpu_s: float = 0.0
    worker: str = ""
    error: str | None = None
    detail: str | None = None


@dataclass(frozen=True)
class BatchOutcome:
    """Every job's row, in the order the jobs were given; ``interrupted`` after a Ctrl-C."""

    rows: tuple[BatchRow, ...]
    interrupted: bool = False

    @property
    def failed(self) -> tuple[BatchRow, ...]:
        return tuple(row for row in self.rows if row.status != "ok")


# ------------------------------------------------------------------------------ worker side

#: The bases this process resolved, by :func:`calib.pipeline.estimate.basis_key`.
_BASES: dict[Hashable, CameraBasis] = {}
_BASES_LOCK = threading.Lock()
#: Where a local pool's worker says which job it starts (see :func:`_run_pool`).
_STARTED: SimpleQueue[tuple[int, int]] | None = None


def worker_settings(settings: OfflineSettings) -> OfflineSettings:
    """``settings`` with the basis resolved once per process and key (kept for later jobs)."""
    if settings.basis is not None:
        return settings
    key = basis_key(settings)
    with _BASES_LOCK:  # a Dask worker may run tasks on several threads
        if key not in _BASES:
            _BASES[key] = resolve_basis(settings)
    return dataclasses.replace(settings, basis=_BASES[key])


def prepare_worker(
    plan: BatchPlan,
    *,
    local: bool = True,
    started: SimpleQueue[tuple[int, int]] | None = None,
) -> None:
    """A worker's initializer: import the pipeline (and the report's libraries when reports are
    written), resolve the basis.

    A local worker also runs its BLAS on one thread (one worker per core), leaves Ctrl-C to the
    parent (which stops the batch between jobs) and keeps the memory its jobs free for the next
    ones (:func:`calib.pipeline.batch_malloc.roomy_allocator`; a Dask worker does so task by task). The basis is resolved here for the first
    job's sake only: if that fails (a ``--data-dir`` without data), every job says why.
    """
    global _STARTED
    if local:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1, user_api="blas")
        roomy_allocator()
    _STARTED = started
    from calib.pipeline.estimate import import_estimation
    from calib.pipeline.report import import_plotting

    import_estimation()
    if plan.report:
        import_plotting()
    with contextlib.suppress(Exception):  # the job resolves it again and reports the error
        worker_settings(plan.settings)


def _one_line(exc: BaseException) -> str:
    message = " ".join(str(exc).split())
    if isinstance(exc, CalibError):
        return message or type(exc).__name__
    if isinstance(exc, OSError):
        return f"cannot read or write a file: {message}"
    return f"internal error: {type(exc).__name__}: {message}"


def _expected(exc: BaseException) -> bool:
    """An error the job's input explains (a message is all a person needs, not a traceback)."""
    return isinstance(exc, CalibError | OSError) or type(exc).__module__.startswith("rig.")


def estimate_job(job: BatchJob, plan: BatchPlan, index: int = -1) -> BatchRow:
    """Estimate one input set in this process: its row, ``ok`` or ``failed`` with the reason."""
    if _STARTED is not None and index >= 0:
        _STARTED.put((index, os.getpid()))
    wall = time.perf_counter()
    cpu = time.process_time()
    worker = f"{socket.gethostname()}:{os.getpid()}"
    try:
        inputs = job.reader.read(job.path, job.out_dir, force=plan.force)
        outcome = inputs.run(plan.settings, report=plan.report, prepare=worker_settings)
    except Exception as exc:
        debug = any(os.environ.get(name) for name in DEBUG_VARIABLES)
        return BatchRow(
            name=job.name,
            path=str(job.path),
            status="failed",
            wall_s=time.perf_counter() - wall,
            cpu_s=time.process_time() - cpu,
            worker=worker,
            error=_one_line(exc),
            detail=traceback.format_exc() if debug and not _expected(exc) else None,
        )
    estimate = outcome.estimate
    camera = estimate.provenance.camera.get("camera")
    return BatchRow(
        name=job.name,
        path=str(job.path),
        status="ok",
        out_dir=str(outcome.files["result"].parent),
        camera=str(camera) if camera else None,
        method=estimate.result.method,
        truth_relative_error=outcome.truth_relative_error,
        warnings=tuple(estimate.warnings),
        wall_s=time.perf_counter() - wall,
        cpu_s=time.process_time() - cpu,
        worker=worker,
    )


def not_run(job: BatchJob) -> BatchRow:
    """The row of a job an interrupted batch did not run."""
    return BatchRow(job.name, str(job.path), "not run", error="the batch was interrupted")


def batch_jobs(
    paths: Sequence[Path],
    readers: Sequence[InputSetReader],
    out_dir: Path | None = None,
) -> list[BatchJob]:
    """One job per path, each with the reader that recognises it; with ``out_dir``, each set's
    outputs go to ``out_dir/<name>``.

    Raises
    ------
    InputError
        A path no reader recognises; a set given twice; two sets with one name under ``out_dir``.
    """
    jobs: list[BatchJob] = []
    seen: dict[Path, Path] = {}
    names: dict[str, Path] = {}
    for given in paths:
        path = Path(os.path.normpath(Path(given).absolute()))
        reader = reader_for(path, readers)
        if path in seen:
            raise InputError("given twice: each input set is estimated once", source=str(given))
        seen[path] = path
        target = None
        if out_dir is not None:
            name = reader.default_out_name(path)
            if name in names:
                raise InputError(
                    f"{names[name]} and {path} would both write to {out_dir / name}: estimate "
                    "them in two batches, or without --out (each into its own directory)",
                    source="--out",
                )
            names[name] = path
            target = Path(os.path.normpath(out_dir.absolute())) / name
        jobs.append(BatchJob(path, reader, target))
    return jobs
