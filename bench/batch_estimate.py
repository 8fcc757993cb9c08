"""Batch estimation of twin sessions: one batch against one ``rig estimate`` process per session.

Issue 19's targets: N twin sessions estimated on 2 cores as one batch cost ≤ 55 % of the CPU of N
separate ``rig estimate`` processes, both cores busy, the wall time linear in N; the same through a
Dask ``LocalCluster`` of 2 workers. Every mode runs the ``rig`` command of this environment as a
child process, so a timer of the whole process (``/usr/bin/time``, or any harness that reads the
children's rusage) sees all the CPU: the batch's parent, its spawned workers, a cluster's workers.

Steps:

1. ``python bench/batch_estimate.py capture DIR --sessions 20`` captures 20 twin sessions into
   ``DIR`` with this environment's code: ``rig init --twin`` writes the packaged twin configuration
   into ``DIR`` (``--config`` for another), and session ``i`` is captured with its ``seed``
   replaced by ``--seed + i`` (default 20251121), so the same command makes the same sessions, and
   the sessions differ in their noise as a lab's would. A directory captured by an older
   spectral-rig is not comparable (its twin may not be today's): capture afresh.
2. Time the modes side by side on the same sessions (outputs go to a temporary directory that is
   removed afterwards; each mode prints its N, wall time and CPU time):

   * ``python bench/batch_estimate.py separate DIR`` — one ``rig estimate SESSION`` process per
     session, 2 at a time (``--parallel``), as ``xargs -P2`` would;
   * ``python bench/batch_estimate.py pool DIR`` — ``rig estimate SESSION… --jobs 2``;
   * ``python bench/batch_estimate.py dask DIR`` — a ``LocalCluster`` of 2 single-threaded worker
     processes and ``rig estimate SESSION… --scheduler ADDRESS`` (needs the ``dask`` extra;
     ``--dask-config default`` for Dask's default worker settings instead of
     :data:`BATCH_DASK_CONFIG`).

   ``--limit N`` takes the first N sessions (wall linear in N: compare the wall per session at
   ``--limit 20`` and at 100); ``--no-report`` passes ``--no-report`` to ``rig estimate``.
   Modes joined by commas (``separate,pool,dask``) run in turn in one call, which then prints each
   mode's CPU as a ratio to ``separate``'s: the figures of one run, on the same machine state.

Whether both cores were kept busy is printed three ways per mode: the CPU time over the wall time
("cores busy", at most 2, and lower whenever other jobs share the machine: the load average before
and after is printed beside it); the sessions' summed wall time over the mode's ("sessions in
progress on average": 2 when both workers always had a session, whatever else runs); and, for a
batch, how many workers estimated sessions and their CPU time each (from its ``summary.csv``).
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

RIG = str(Path(sys.executable).with_name("rig"))


def sessions_in(directory: Path, limit: int | None) -> list[Path]:
    """The session directories (with ``log.jsonl``) directly in ``directory``, by name."""
    found = sorted(path for path in directory.iterdir() if (path / "log.jsonl").is_file())
    if not found:
        raise SystemExit(f"{directory}: no session directory inside (run the capture step first)")
    if limit is not None:
        if limit > len(found):
            raise SystemExit(f"{directory}: {len(found)} sessions, fewer than --limit {limit}")
        found = found[:limit]
    return found


def capture(directory: Path, sessions: int, config: Path | None, seed: int) -> None:
    """Capture ``sessions`` twin sessions into ``directory``, session ``i`` with seed ``seed + i``
    (the configuration: ``config``, or ``rig init --twin``'s written into ``directory``)."""
    directory.mkdir(parents=True, exist_ok=True)
    if config is None:
        config = directory / "config.yaml"
        init = [RIG, "init", "--twin", "--out", str(config), "--force"]
        subprocess.run(init, check=True, stdout=subprocess.DEVNULL)
    text = config.read_text(encoding="utf-8")
    if not re.search(r"^seed: \d+", text, flags=re.MULTILINE):
        raise SystemExit(f"{config}: no top-level `seed: N` line to vary")
    for number in range(sessions):
        seeded = directory / f".config-seed-{seed + number}.yaml"
        seeded.write_text(
            re.sub(r"^seed: \d+", f"seed: {seed + number}", text, count=1, flags=re.MULTILINE),
            encoding="utf-8",
        )
        command = [RIG, "capture", "--config", str(seeded), "--out", str(directory), "-q"]
        try:
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
        finally:
            seeded.unlink()
        print(f"captured {number + 1}/{sessions} (seed {seed + number})", flush=True)


def _estimate_options(report: bool) -> list[str]:
    return ["-q", "--force"] + ([] if report else ["--no-report"])


def separate(sessions: Sequence[Path], out: Path, parallel: int, report: bool) -> float:
    """One ``rig estimate`` process per session, ``parallel`` at a time; the processes' summed
    wall time."""
    running: list[tuple[subprocess.Popen[bytes], float]] = []
    busy_s = 0.0
    failed = []

    def finish(process: subprocess.Popen[bytes], started: float) -> None:
        nonlocal busy_s
        if process.wait() != 0:
            failed.append(process.args)
        busy_s += time.perf_counter() - started

    for session in sessions:
        while len(running) >= parallel:
            finish(*running.pop(0))
        command = [RIG, "estimate", str(session), "--out", str(out / session.name)]
        running.append(
            (
                subprocess.Popen([*command, *_estimate_options(report)], stdout=subprocess.DEVNULL),
                time.perf_counter(),
            )
        )
    for process, started in running:
        finish(process, started)
    if failed:
        raise SystemExit(f"rig estimate failed: {failed}")
    return busy_s


def batch(sessions: Sequence[Path], out: Path, report: bool, where: Sequence[str]) -> float:
    """One ``rig estimate`` process for all sessions (``where``: ``--jobs`` or ``--scheduler``);
    the sessions' summed wall time in their workers, from the batch's ``summary.csv``, which
    also says how many workers estimated sessions (printed)."""
    command = [RIG, "estimate", *map(str, sessions), "--out", str(out), *where]
    subprocess.run([*command, *_estimate_options(report)], check=True, stdout=subprocess.DEVNULL)
    with (out / "summary.csv").open(newline="", encoding="utf-8") as table:
        rows = list(csv.DictReader(table))
    workers: dict[str, list[float]] = {}
    for row in rows:
        # (a summary without the column, from an older spectral-rig: one entry)
        workers.setdefault(row.get("worker", "not recorded"), []).append(float(row["cpu_s"]))
    if "not recorded" in workers:
        print("  workers not recorded (a summary.csv without the worker column)", flush=True)
        return sum(float(row["wall_s"]) for row in rows)
    print(
        f"  {len(workers)} workers estimated sessions: "
        + ", ".join(
            f"{len(cpu)} sessions, {sum(cpu):.1f} s CPU"
            for cpu in sorted(workers.values(), key=len)
        ),
        flush=True,
    )
    return sum(float(row["wall_s"]) for row in rows)


#: The workers' settings of a cluster made for batch estimates (``--dask-config batch``): no
#: statistical profiler (a stack sample every 10 ms), event-loop ticks and system/memory monitors
#: at 1–5 s instead of 20–500 ms. An idle ``LocalCluster`` of 2 workers costs 0.073 cores with
#: Dask's defaults and 0.014 with these (measured for 20 s); a batch pays that for its whole wall
#: time, which a loaded machine stretches.
BATCH_DASK_CONFIG: dict[str, object] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
}


@contextmanager
def local_cluster(workers: int, *, settings: str = "batch") -> Iterator[str]:
    """A ``LocalCluster`` of ``workers`` single-threaded worker processes (this process's
    children, so their CPU time counts in this process's), with Dask's default worker settings
    (``settings="default"``) or :data:`BATCH_DASK_CONFIG` (``"batch"``).
    """
    import dask
    import distributed

    cluster_type: Any = distributed.LocalCluster  # untyped
    config = BATCH_DASK_CONFIG if settings == "batch" else {}
    with (
        dask.config.set(config),
        cluster_type(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
    ):
        yield str(cluster.scheduler_address)


def _cpu_s() -> float:
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    own = resource.getrusage(resource.RUSAGE_SELF)
    return children.ru_utime + children.ru_stime + own.ru_utime + own.ru_stime


def run_mode(mode: str, sessions: Sequence[Path], arguments: argparse.Namespace) -> float:
    """Run ``mode``; the sessions' summed wall time (a process's, or a job's in its worker)."""
    with tempfile.TemporaryDirectory(prefix="batch-bench-") as directory:
        out = Path(directory)
        if mode == "separate":
            return separate(sessions, out, arguments.parallel, arguments.report)
        if mode == "pool":
            return batch(sessions, out, arguments.report, ["--jobs", str(arguments.workers)])
        with local_cluster(arguments.workers, settings=arguments.dask_config) as address:
            return batch(sessions, out, arguments.report, ["--scheduler", address])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "mode",
        help="capture, or one or more of separate, pool, dask joined by commas (run in turn)",
    )
    parser.add_argument("directory", type=Path, help="the twin sessions")
    parser.add_argument("--sessions", type=int, default=20, help="capture: how many")
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="capture: a twin configuration (rig init --twin's)",
    )
    parser.add_argument("--seed", type=int, default=20251121, help="capture: the first seed")
    parser.add_argument("--limit", type=int, default=None, help="the first N sessions only")
    parser.add_argument("--parallel", type=int, default=2, help="separate: processes at a time")
    parser.add_argument("--workers", type=int, default=2, help="pool/dask: worker processes")
    parser.add_argument("--no-report", dest="report", action="store_false")
    parser.add_argument(
        "--dask-config",
        choices=("batch", "default"),
        default="batch",
        help="dask: the workers' settings (BATCH_DASK_CONFIG, or Dask's defaults)",
    )
    arguments = parser.parse_args()
    if arguments.mode == "capture":
        capture(arguments.directory, arguments.sessions, arguments.config, arguments.seed)
        return
    modes = arguments.mode.split(",")
    unknown = sorted(set(modes) - {"separate", "pool", "dask"})
    if unknown:
        raise SystemExit(f"unknown mode {', '.join(unknown)}: give separate, pool or dask")
    sessions = sessions_in(arguments.directory, arguments.limit)
    measured: dict[str, tuple[float, float]] = {}
    for mode in modes:
        load_before = os.getloadavg()[0]
        started = time.perf_counter()
        cpu_started = _cpu_s()
        busy_s = run_mode(mode, sessions, arguments)
        wall_s = time.perf_counter() - started
        cpu_s = _cpu_s() - cpu_started
        measured[mode] = (wall_s, cpu_s)
        print(
            f"{mode}: {len(sessions)} sessions, wall {wall_s:.1f} s ({wall_s / len(sessions):.2f} s "
            f"a session), CPU {cpu_s:.1f} s ({cpu_s / len(sessions):.2f} s a session, "
            f"{cpu_s / wall_s:.2f} cores busy on average; {os.cpu_count()} CPUs); "
            f"{busy_s / wall_s:.2f} sessions in progress on average; machine load average "
            f"{load_before:.1f} before, {os.getloadavg()[0]:.1f} after",
            flush=True,
        )
    if "separate" in measured:
        for mode, (_, cpu_s) in measured.items():
            if mode != "separate":
                ratio = cpu_s / measured["separate"][1]
                print(f"CPU {mode} / separate: {ratio:.3f} (target ≤ 0.55)")


if __name__ == "__main__":
    main()
