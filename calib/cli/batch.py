"""``calib batch``: estimate many input sets at once, and the batch front end ``rig estimate`` shares.

Input sets are what the installed readers recognise (:mod:`calib.pipeline.input_sets`): session
directories (``rig`` declares their reader) and inputs files (``calib estimate --inputs``'s YAML,
named ``<folder>-<stem>`` in the summary); a directory that is none of them stands for the input
sets directly inside it. They run on a local process pool (``--jobs``, default the CPUs) or on a
Dask cluster (``--scheduler``), see :mod:`calib.pipeline.batch`. A failed set is named with its
reason and the batch goes on. At the end a summary table is printed, and written as Markdown and
CSV (``--summary FILE``; by default ``OUT/summary.md`` and ``OUT/summary.csv`` with ``--out``).

Exit codes: 0 every set estimated; 1 at least one failed (the others' outputs are written); 2 bad
input before anything ran (an unknown path, two sets writing to one place, a bad option); 130
interrupted (the running sets finish first).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console

from calib.cli.command_line import ARGUMENTS
from calib.cli.options import (
    DataDirOption,
    ExcludeCameraOption,
    ForceOption,
    GridOption,
    JobsOption,
    MethodOption,
    QuietOption,
    ReportOption,
    SchedulerOption,
    SummaryOption,
    WeightRuleOption,
    checked_grid,
    checked_method,
)
from calib.core.errors import InputError

if TYPE_CHECKING:
    from calib.pipeline.batch_jobs import BatchOutcome
    from calib.pipeline.estimate import OfflineSettings
    from calib.pipeline.input_sets import InputSetReader

# The pipeline (numpy, the estimation stages) is imported by the functions that run a batch, not
# here: ``calib --help`` and every other command load this module too.


def expand_inputs(paths: Sequence[Path], readers: Sequence[InputSetReader]) -> list[Path]:
    """``paths`` with each directory no reader recognises replaced by the input sets inside it.

    Raises
    ------
    InputError
        A directory holding no input set (named).
    """
    expanded: list[Path] = []
    for path in paths:
        if path.is_dir() and not any(reader.recognises(path) for reader in readers):
            inside = sorted(
                child
                for child in path.iterdir()
                if any(reader.recognises(child) for reader in readers)
            )
            if not inside:
                accepted = ", ".join(reader.description for reader in readers)
                raise InputError(
                    f"holds no input set: neither {accepted}, nor a directory of them",
                    source=str(path),
                )
            expanded.extend(inside)
        else:
            expanded.append(path)
    return expanded


def run_batch_command(
    paths: Sequence[Path],
    readers: Sequence[InputSetReader],
    settings: OfflineSettings,
    *,
    program: str,
    out: Path | None = None,
    jobs: int | None = None,
    scheduler: str | None = None,
    report: bool = True,
    force: bool = False,
    quiet: bool = False,
    summary: Sequence[Path] | None = None,
    label: str = "session",
) -> int:
    """Run a batch from a command line: progress on stderr, the summary table on stdout and in
    files, each failure on its own line on stderr. Returns the exit code.

    Raises
    ------
    InputError
        Before anything runs: an option in conflict, a path that is no input set, two sets
        writing to one place, a summary file of unknown format, a cluster that cannot be used.
    """
    from calib.pipeline.batch import run_batch
    from calib.pipeline.batch_display import RichBatchProgress, check_summary_path
    from calib.pipeline.batch_jobs import BatchPlan, batch_jobs

    if jobs is not None and scheduler is not None:
        raise InputError(
            "give --jobs (local workers) or --scheduler (a Dask cluster's workers), not both",
            source="--jobs",
        )
    targets = list(summary or ())
    if not targets and out is not None:
        targets = [out / "summary.md", out / "summary.csv"]
    for target in targets:
        check_summary_path(target)
    batch = batch_jobs(paths, readers, out)
    plan = BatchPlan(settings, report=report, force=force)
    if quiet:
        outcome = run_batch(batch, plan, workers=jobs, scheduler=scheduler)
    else:
        with RichBatchProgress(sys.stderr) as progress:
            outcome = run_batch(batch, plan, workers=jobs, scheduler=scheduler, progress=progress)
    return _report(outcome, targets, program=program, label=label)


def _report(outcome: BatchOutcome, targets: Sequence[Path], *, program: str, label: str) -> int:
    from calib.pipeline.batch_display import summary_table, write_summary
    from calib.pipeline.batch_jobs import DEBUG_VARIABLES

    console = Console()
    if not console.is_terminal:  # a log file or a pipe: rows whole, not wrapped at 80 columns
        console = Console(width=max(console.width, 200))
    console.print(summary_table(outcome.rows, label=label))
    for target in targets:
        write_summary(target, outcome.rows, label=label)
        print(f"summary: {target}")
    debug = any(os.environ.get(name) for name in DEBUG_VARIABLES)
    for row in outcome.rows:
        if row.status == "failed":
            print(f"{program}: failed: {row.name}: {row.error}", file=sys.stderr)
            if debug and row.detail:
                print(row.detail, file=sys.stderr, end="")
    done = len(outcome.rows) - len(outcome.failed)
    if outcome.interrupted:
        print(
            f"{program}: interrupted: {done} of {len(outcome.rows)} estimated, the others not run",
            file=sys.stderr,
        )
        return 130
    if outcome.failed:
        print(f"{program}: {done} of {len(outcome.rows)} estimated", file=sys.stderr)
        return 1
    return 0


def register(app: typer.Typer) -> None:
    """Add ``calib batch`` to the ``calib`` app."""

    @app.command("batch")
    def batch_command(
        ctx: typer.Context,
        inputs: Annotated[
            list[Path],
            typer.Argument(
                help="Input sets: session directories, inputs files (calib estimate --inputs's "
                "YAML), or directories holding them.",
                show_default=False,
            ),
        ],
        out: Annotated[
            Path | None,
            typer.Option(
                "--out",
                "-o",
                help="Write each set's outputs to OUT/<name>/ and the summary to OUT (default: "
                "each session into its own estimate/).",
            ),
        ] = None,
        method: MethodOption = "auto",
        data_dir: DataDirOption = None,
        weight_rule: WeightRuleOption = None,
        grid: GridOption = None,
        exclude_camera: ExcludeCameraOption = None,
        jobs: JobsOption = None,
        scheduler: SchedulerOption = None,
        report: ReportOption = True,
        summary: SummaryOption = None,
        quiet: QuietOption = False,
        force: ForceOption = False,
    ) -> None:
        """Estimate many input sets (sessions …) on local workers or a Dask cluster, with a
        summary table."""
        from calib.cli.estimate import typed_options
        from calib.methods.multilamp import MULTILAMP_METHOD, weight_rule_option
        from calib.pipeline.estimate import OfflineSettings
        from calib.pipeline.input_sets import input_set_readers

        method = checked_method(method)
        readers = input_set_readers()
        typed = typed_options(ctx)
        # A typed --weight-rule goes with each set's method (an inputs file's, unless --method
        # is typed): the rule is checked here, its method once each set's settings are merged.
        settings = OfflineSettings(
            method=method,
            data_dir=data_dir,
            grid=checked_grid(grid),
            method_options=weight_rule_option(
                method if "method" in typed else MULTILAMP_METHOD, weight_rule
            ),
            exclude_cameras=tuple(exclude_camera or ()),
            command_line=("calib", "batch", *ctx.meta.get(ARGUMENTS, ())),
            typed_options=typed,
        )
        code = run_batch_command(
            expand_inputs(inputs, readers),
            readers,
            settings,
            program="calib batch",
            out=out,
            jobs=jobs,
            scheduler=scheduler,
            report=report,
            force=force,
            quiet=quiet,
            summary=summary,
            label="input set",
        )
        raise typer.Exit(code)
