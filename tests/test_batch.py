"""The batch engine without sessions: workers that die (isolated and named), workers that cannot
start, the summary on the terminal, in Markdown and in CSV, and a Dask scheduler that is missing or
unreachable."""

from __future__ import annotations

import csv
import io
import sys
from pathlib import Path

import pytest
from rich.console import Console
from typer.testing import CliRunner

from calib.cli.app import build_app
from calib.core.errors import InputError
from calib.model.bases import CameraBasis
from calib.pipeline.batch import run_batch
from calib.pipeline.batch_display import (
    summary_csv,
    summary_markdown,
    summary_table,
    write_summary,
)
from calib.pipeline.batch_jobs import BatchJob, BatchPlan, BatchRow
from calib.pipeline.estimate import OfflineSettings
from tests.batch_sets import CRASHING_READER, KillsOnArrival
from tests.synthetic_cameras import exact_basis


@pytest.fixture(scope="module")
def basis(tmp_path_factory: pytest.TempPathFactory) -> CameraBasis:
    """A small basis, so that no worker resolves the default one."""
    return exact_basis(tmp_path_factory.mktemp("basis"))[0]


class RecordedProgress:
    def __init__(self) -> None:
        self.total = -1
        self.rows: list[BatchRow] = []

    def start(self, total: int) -> None:
        self.total = total

    def done(self, row: BatchRow) -> None:
        self.rows.append(row)


def test_a_worker_that_dies_fails_its_own_set_only(basis: CameraBasis, tmp_path: Path) -> None:
    jobs = [BatchJob(tmp_path / name, CRASHING_READER) for name in ("a", "crash", "b")]
    progress = RecordedProgress()
    outcome = run_batch(
        jobs, BatchPlan(OfflineSettings(basis=basis), report=False), workers=2, progress=progress
    )
    statuses = {row.name: (row.status, row.error or "") for row in outcome.rows}
    assert statuses["crash"][0] == "failed"
    assert "worker process died while estimating it" in statuses["crash"][1]
    for name in ("a", "b"):  # run (again, if they shared the dead pool) and failed on their own
        assert statuses[name] == ("failed", f"{tmp_path / name / 'missing.dng'}: file not found")
    assert [row.name for row in outcome.rows] == ["a", "crash", "b"]  # the order given
    assert progress.total == 3 and sorted(row.name for row in progress.rows) == ["a", "b", "crash"]
    assert not outcome.interrupted and len(outcome.failed) == 3


def test_workers_that_die_before_any_job_fail_every_set_once(
    basis: CameraBasis, tmp_path: Path
) -> None:
    """Not a new pool after another (each worker would die again): every set fails, named."""
    settings = OfflineSettings(basis=basis, notes=(KillsOnArrival(),))  # type: ignore[arg-type]
    jobs = [BatchJob(tmp_path / name, CRASHING_READER) for name in ("a", "b", "c")]
    outcome = run_batch(jobs, BatchPlan(settings, report=False), workers=2)
    assert [row.status for row in outcome.rows] == ["failed"] * 3
    assert all("died while starting" in (row.error or "") for row in outcome.rows)


def test_a_batch_of_one_worker_runs_here_and_rejects_no_workers(
    basis: CameraBasis, tmp_path: Path
) -> None:
    jobs = [BatchJob(tmp_path / name, CRASHING_READER) for name in ("a", "b")]
    plan = BatchPlan(OfflineSettings(basis=basis), report=False)
    outcome = run_batch(jobs, plan, workers=1)
    assert {row.worker.rsplit(":", 1)[1] for row in outcome.rows} == {
        str(__import__("os").getpid())
    }
    with pytest.raises(InputError, match="0 workers; give at least 1"):
        run_batch(jobs, plan, workers=0)


# ------------------------------------------------------------------------------ the summary

ROWS = [
    BatchRow(
        "s1",
        "/x/s1",
        "ok",
        out_dir="/o/s1",
        camera="Canon EOS R5",
        method="prior",
        truth_relative_error=0.0431,
        warnings=("lamp 'FL' left out",),
        wall_s=3.21,
        cpu_s=2.5,
        worker="lab-pc:4242",
    ),
    BatchRow("s|2", "/x/s2", "failed", error="s2: sha256 differs"),
    BatchRow("s3", "/x/s3", "not run", error="the batch was interrupted"),
]


def test_the_summary_in_markdown_lists_every_set_with_its_reason_and_warnings() -> None:
    markdown = summary_markdown(ROWS)
    assert markdown.splitlines()[0].startswith("| session | status | camera | method |")
    assert "| s1 | ok | Canon EOS R5 | prior | 4.31 | 1 | 3.2 |" in markdown
    assert "| s\\|2 | failed | — | — | — | 0 | 0.0 |" in markdown
    assert "- **s|2** (/x/s2): failed: s2: sha256 differs" in markdown
    assert "- **s3** (/x/s3): not run: the batch was interrupted" in markdown
    assert "  - lamp 'FL' left out" in markdown
    assert markdown.rstrip().endswith("1 of 3 estimated.")


def test_the_summary_in_csv_keeps_plain_numbers() -> None:
    table = list(csv.DictReader(summary_csv(ROWS).splitlines()))
    assert [row["name"] for row in table] == ["s1", "s|2", "s3"]
    assert float(table[0]["truth_relative_error"]) == 0.0431
    assert table[0]["warnings"] == "lamp 'FL' left out"
    assert (table[0]["wall_s"], table[0]["cpu_s"]) == ("3.210", "2.500")
    assert (table[0]["worker"], table[1]["worker"]) == ("lab-pc:4242", "")
    assert table[1]["error"] == "s2: sha256 differs" and table[1]["truth_relative_error"] == ""
    assert table[2]["status"] == "not run"


def test_the_summary_on_the_terminal_puts_each_reason_under_its_set() -> None:
    stream = io.StringIO()
    Console(file=stream, width=120, color_system=None).print(summary_table(ROWS, label="input set"))
    lines = [line.rstrip() for line in stream.getvalue().splitlines()]
    assert lines[0].split()[:3] == ["input", "set", "status"]
    first = next(index for index, line in enumerate(lines) if line.startswith("s1 "))
    assert lines[first].split()[1:] == ["ok", "Canon", "EOS", "R5", "prior", "4.31", "1", "3.2"]
    second = next(index for index, line in enumerate(lines) if line.startswith("s|2 "))
    assert lines[second + 1].split() == ["s2:", "sha256", "differs"]


def test_summary_files_by_suffix(tmp_path: Path) -> None:
    assert write_summary(tmp_path / "a" / "s.md", ROWS).read_text() == summary_markdown(ROWS)
    assert write_summary(tmp_path / "s.CSV", ROWS).read_text() == summary_csv(ROWS)
    with pytest.raises(InputError, match=r"unknown summary format '.txt': name the file \*.md"):
        write_summary(tmp_path / "s.txt", ROWS)
    assert not (tmp_path / "s.txt").exists()


# ------------------------------------------------------------------------------ Dask, refused


def test_a_dask_batch_without_dask_names_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)
    jobs = [BatchJob(tmp_path / "a", CRASHING_READER)]
    with pytest.raises(InputError, match=r"pip install 'spectral-rig\[dask\]'"):
        run_batch(jobs, BatchPlan(OfflineSettings()), scheduler="tcp://127.0.0.1:8786")


def test_an_unreachable_scheduler_is_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("distributed")
    monkeypatch.setattr("calib.pipeline.batch_dask.CONNECT_TIMEOUT_S", 0.5)
    jobs = [BatchJob(tmp_path / "a", CRASHING_READER)]
    with pytest.raises(InputError, match=r"cannot reach a Dask scheduler at tcp://127.0.0.1:9"):
        run_batch(jobs, BatchPlan(OfflineSettings()), scheduler="tcp://127.0.0.1:9")


def test_the_help_names_the_extra_a_cluster_needs() -> None:
    result = CliRunner().invoke(build_app(), ["batch", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "pip install 'spectral-rig[dask]'" in result.output
