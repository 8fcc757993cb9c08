"""Estimate many input sets at once: a local process pool by default, or a Dask cluster.

Every input set (a session directory, an inputs file: :mod:`calib.pipeline.input_sets`) is one job,
estimated exactly as on its own (:meth:`~calib.pipeline.input_sets.InputSet.run`, the same
settings), so a batch gives the files one-at-a-time estimates give. What a batch saves is what
every process paid again: the imports (about half of a ``rig estimate`` process's CPU) and the
camera basis, paid once per worker. A worker's initializer imports the pipeline and resolves the
basis (:func:`calib.pipeline.estimate.resolve_basis`) before its first job, and keeps it for every
later job with the same :func:`~calib.pipeline.estimate.basis_key`.

* Local (:func:`run_batch` with ``workers``): a :class:`concurrent.futures.ProcessPoolExecutor` of
  ``workers`` spawned processes. Workers run with one BLAS thread and ignore Ctrl-C: the parent
  stops the batch, lets the running jobs finish (their outputs are whole) and reports the others
  as not run. ``workers=1`` runs in this process.
* Dask (``scheduler``): :mod:`calib.pipeline.batch_dask`, on any ``dask.distributed`` scheduler.

A job never stops the batch: its error becomes a failed :class:`BatchRow` with the one-line reason.
A worker process that dies (a crash inside a library, killed for memory) breaks a local pool; the
jobs it was not running are run again in a new pool, and the ones it may have been running are run
again one at a time, alone, so the one that kills its worker is named and failed alone.
"""

from __future__ import annotations

import multiprocessing
import os
from collections import deque
from collections.abc import Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.queues import SimpleQueue

from calib.core.errors import InputError
from calib.pipeline.batch_display import BatchProgress, NoBatchProgress
from calib.pipeline.batch_jobs import (
    BatchJob,
    BatchOutcome,
    BatchPlan,
    BatchRow,
    estimate_job,
    not_run,
    prepare_worker,
)


def default_workers() -> int:
    """The CPUs this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def run_batch(
    jobs: Sequence[BatchJob],
    plan: BatchPlan,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: BatchProgress | None = None,
) -> BatchOutcome:
    """Estimate every job; a failure is a row, never the end of the batch.

    Parameters
    ----------
    jobs
        From :func:`calib.pipeline.batch_jobs.batch_jobs`.
    plan
        The shared settings.
    workers
        Local worker processes (default: the CPUs available); 1 runs in this process.
    scheduler
        A ``dask.distributed`` scheduler's address instead of the local pool (needs the ``dask``
        extra).
    progress
        Told the total and every finished row.

    Raises
    ------
    InputError
        ``workers`` below 1; the scheduler cannot be reached or its workers cannot run the jobs.
    """
    shown = progress or NoBatchProgress()
    shown.start(len(jobs))
    if scheduler is not None:
        from calib.pipeline.batch_dask import run_on_dask

        return run_on_dask(jobs, plan, scheduler, shown)
    count = default_workers() if workers is None else workers
    if count < 1:
        raise InputError(f"{count} workers; give at least 1", source="--jobs")
    count = min(count, len(jobs))
    if count <= 1:
        return _run_here(jobs, plan, shown)
    return _run_pool(jobs, plan, count, shown)


def _run_here(jobs: Sequence[BatchJob], plan: BatchPlan, progress: BatchProgress) -> BatchOutcome:
    rows: list[BatchRow] = []
    try:
        for job in jobs:
            rows.append(estimate_job(job, plan))
            progress.done(rows[-1])
    except KeyboardInterrupt:
        rows.extend(not_run(job) for job in jobs[len(rows) :])
        return BatchOutcome(tuple(rows), interrupted=True)
    return BatchOutcome(tuple(rows))


def _died(job: BatchJob) -> BatchRow:
    return BatchRow(
        job.name,
        str(job.path),
        "failed",
        error="the worker process died while estimating it (a crash inside a library, or "
        "killed for lack of memory); estimate it alone to see more",
    )


def _never_started(job: BatchJob) -> BatchRow:
    return BatchRow(
        job.name,
        str(job.path),
        "failed",
        error="the worker processes died while starting, before any estimate (importing the "
        "pipeline or resolving the camera basis); run with --jobs 1 to see why",
    )


def _run_pool(
    jobs: Sequence[BatchJob], plan: BatchPlan, workers: int, progress: BatchProgress
) -> BatchOutcome:
    # Spawned, not forked: the parent runs threads (the progress display), and a worker that is
    # this process's child is waited for, so its CPU time counts where the batch's is measured.
    context = multiprocessing.get_context("spawn")
    rows: dict[int, BatchRow] = {}
    waiting = list(range(len(jobs)))
    suspects: deque[int] = deque()
    while waiting or suspects:
        # After a worker died, the jobs it may have been running go one at a time, alone.
        alone = not waiting
        batch = [suspects.popleft()] if alone else waiting
        started: SimpleQueue[tuple[int, int]] = context.SimpleQueue()
        try:
            broken = _run_in_pool(
                jobs, batch, plan, 1 if alone else workers, context, started, rows, progress
            )
        except KeyboardInterrupt:
            ordered = [rows.get(index) or not_run(job) for index, job in enumerate(jobs)]
            return BatchOutcome(tuple(ordered), interrupted=True)
        unfinished = [index for index in batch if index not in rows]
        ran = set()
        while broken and not started.empty():
            ran.add(started.get()[0])
        started.close()
        if broken and not ran and not alone:
            # No job started: the workers died while starting (their initializer), and would
            # again in a new pool.
            for index in unfinished:
                rows[index] = _never_started(jobs[index])
                progress.done(rows[index])
            waiting = []
            continue
        if alone:
            for index in unfinished:
                rows[index] = _died(jobs[index])
                progress.done(rows[index])
        waiting = [index for index in unfinished if index not in ran and not alone]
        suspects.extend(index for index in unfinished if index in ran and not alone)
    return BatchOutcome(tuple(rows[index] for index in range(len(jobs))))


def _run_in_pool(
    jobs: Sequence[BatchJob],
    batch: Sequence[int],
    plan: BatchPlan,
    workers: int,
    context: multiprocessing.context.BaseContext,
    started: SimpleQueue[tuple[int, int]],
    rows: dict[int, BatchRow],
    progress: BatchProgress,
) -> bool:
    """Run ``batch`` (indices into ``jobs``) on one pool, filling ``rows``; whether a worker died.

    On Ctrl-C the jobs not started are cancelled and the running ones finish (their rows are
    kept) before the interrupt goes on.
    """
    pool = ProcessPoolExecutor(
        min(workers, len(batch)),
        mp_context=context,
        initializer=_prepare_pool_worker,
        initargs=(plan, started),
    )
    futures = {pool.submit(estimate_job, jobs[index], plan, index): index for index in batch}
    broken = False

    def collect(future: Future[BatchRow]) -> None:
        nonlocal broken
        try:
            rows[futures[future]] = future.result()
        except BrokenProcessPool:
            broken = True
            return
        progress.done(rows[futures[future]])

    try:
        remaining = set(futures)
        while remaining:
            done, remaining = wait(remaining, return_when=FIRST_COMPLETED)
            for future in done:
                collect(future)
    except KeyboardInterrupt:
        pool.shutdown(wait=True, cancel_futures=True)
        for future in futures:
            if futures[future] not in rows and future.done() and not future.cancelled():
                collect(future)
        raise
    finally:
        pool.shutdown(wait=True)
    return broken


def _prepare_pool_worker(plan: BatchPlan, started: SimpleQueue[tuple[int, int]]) -> None:
    prepare_worker(plan, local=True, started=started)
