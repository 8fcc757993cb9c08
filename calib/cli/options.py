"""Command-line options that more than one command declares (``calib compare`` and ``rig compare``,
``calib batch`` and ``rig estimate``).

Kept free of heavy imports: ``rig``'s command line imports it at start-up.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

#: Toivonen et al.'s ensemble size for comparisons.
EnsembleOption = Annotated[
    int | None, typer.Option(min=1, help="Toivonen ensemble size (default 16).")
]
#: Toivonen et al.'s Adam epochs for comparisons.
EpochsOption = Annotated[
    int | None, typer.Option(min=1, help="Toivonen Adam epochs (default 5000).")
]
#: ``--jobs``: local worker processes.
JobsOption = Annotated[
    int | None,
    typer.Option(
        "--jobs",
        "-j",
        min=1,
        help="Worker processes on this machine (default: the CPUs available; 1: in this process).",
    ),
]
#: ``--scheduler``: a Dask cluster instead of local workers.
SchedulerOption = Annotated[
    str | None,
    typer.Option(
        help="Run on the Dask cluster whose scheduler is at this address (tcp://host:8786) "
        "instead of local workers; paths must mean the same files on every worker. Needs "
        "the dask extra (pip install 'spectral-rig\\[dask]').",
    ),
]
#: ``--summary``: where the summary table is written.
SummaryOption = Annotated[
    list[Path] | None,
    typer.Option(
        help="Write the summary table to this file: .md (Markdown) or .csv (repeatable; default "
        "with --out: OUT/summary.md and OUT/summary.csv).",
    ),
]
#: ``--report/--no-report``.
ReportOption = Annotated[
    bool, typer.Option("--report/--no-report", help="Write report.html and its plots.")
]
