"""Batch estimation: ``rig estimate SESSION…`` and ``calib batch`` on a local pool and on a Dask
``LocalCluster``; results identical to one-at-a-time estimates, failures as rows, progress, the
summary."""

from __future__ import annotations

import csv
import json
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from calib.cli.app import build_app
from calib.core.errors import InputError
from rig.cli import app
from rig.demo import sensitivity_error
from rig.twin import write_twin_truth
from tests.rendered_capture import Capture, shared_capture
from tests.rig.test_estimate_session import write_session
from tests.rig.twin_setup import twin_config

#: result.json entries that say when, where and how fast, not what was estimated.
CIRCUMSTANTIAL = {"timings_s", "files", "created", "command_line", "path", "first_frame", "timings"}


def _numbers(document: Any) -> Any:
    """``document`` without its circumstantial entries, and with the paths of its input files
    reduced to their names (a batch records them absolute)."""
    if isinstance(document, dict):
        return {
            key: _numbers(value) for key, value in document.items() if key not in CIRCUMSTANTIAL
        }
    if isinstance(document, list):
        return [_numbers(value) for value in document]
    if isinstance(document, str) and "/frames/" in document:
        return Path(document).name
    return document


def _result(directory: Path) -> Any:
    return _numbers(json.loads((directory / "result.json").read_text()))


def _assert_same_estimate(document: Any, expected: Any) -> None:
    """The same estimate as ``expected`` (another session of the same frames: notes and truth
    may differ)."""
    for key in ("method", "sensitivity", "sensitivity_sigma", "mapping", "grating_efficiency"):
        assert document[key] == expected[key], key
    assert document["provenance"]["inputs"] == expected["provenance"]["inputs"]


@pytest.fixture(scope="module")
def capture() -> Capture:
    return shared_capture()


@pytest.fixture(scope="module")
def sessions(capture: Capture, tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three sessions of the rendered capture; the first with the twin's truth beside it."""
    parent = tmp_path_factory.mktemp("sessions")
    written = [write_session(parent, capture) for _ in range(3)]
    write_twin_truth(twin_config(), written[0])
    return written


@pytest.fixture(scope="module")
def one_at_a_time(sessions: list[Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``rig estimate`` of the first session alone (the default basis, as the workers')."""
    out = tmp_path_factory.mktemp("single") / "estimate"
    arguments = ["estimate", str(sessions[0]), "--out", str(out), "-q", "--no-report"]
    result = CliRunner().invoke(app, arguments)
    assert result.exit_code == 0, result.output
    return out


def test_a_pool_batch_gives_the_one_at_a_time_results_and_names_its_failure(
    sessions: list[Path], one_at_a_time: Path, tmp_path: Path
) -> None:
    broken = write_session(tmp_path / "broken", shared_capture(), lamps=("LED",), darks=False)
    frame = broken / "frames" / "LED" / "scene-001.dng"
    frame.write_bytes(frame.read_bytes()[:-10] + b"0123456789")
    out = tmp_path / "out"
    arguments = [*map(str, sessions[:2]), str(broken), "--out", str(out), "-j", "2", "--no-report"]
    result = CliRunner().invoke(app, ["estimate", *arguments])
    assert result.exit_code == 1, result.output
    # the good sessions: the same numbers as alone, whichever worker ran them
    expected = _result(one_at_a_time)
    assert _result(out / sessions[0].name) == expected
    _assert_same_estimate(_result(out / sessions[1].name), expected)
    # the broken one: named with its reason, on stderr and in the summary; nothing written
    assert f"rig: failed: {broken.name}: " in result.stderr
    assert "scene-001.dng: sha256 differs from the log" in result.stderr
    assert not (out / broken.name / "result.json").exists()
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [row["name"] for row in rows] == [sessions[0].name, sessions[1].name, broken.name]
    assert [row["status"] for row in rows] == ["ok", "ok", "failed"]
    assert "sha256 differs" in rows[2]["error"]
    # each estimated set names the worker process that ran it (host:pid), none this one
    for row in rows[:2]:
        host, _, pid = row["worker"].rpartition(":")
        assert host and pid.isdigit() and int(pid) != os.getpid()
    # the truth beside the first session gives its RE, as the report computes it
    truth = sessions[0] / "twin-truth.json"
    re_truth = float(rows[0]["truth_relative_error"])
    assert re_truth == pytest.approx(
        sensitivity_error(out / sessions[0].name / "sensitivity.csv", truth), rel=1e-3
    )
    assert rows[1]["truth_relative_error"] == ""
    assert "1 failed" not in result.stdout  # the progress went to stderr
    # progress (not a terminal): one line per finished session, on stderr
    finished = [line for line in result.stderr.splitlines() if line.startswith("[")]
    assert len(finished) == 3 and all(line[1] in "123" for line in finished)
    assert "2 of 3 estimated" in result.stderr
    assert (out / "summary.md").read_text().count("| ok |") == 2


@pytest.fixture
def local_cluster() -> Iterator[str]:
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        yield str(cluster.scheduler_address)


@pytest.mark.slow  # the pool batch covers the batch path in the default suite (make test-all)
def test_a_dask_batch_gives_the_same_results_quietly(
    sessions: list[Path], one_at_a_time: Path, tmp_path: Path, local_cluster: str
) -> None:
    out = tmp_path / "out"
    arguments = [
        "estimate",
        *map(str, sessions[:2]),
        "--out",
        str(out),
        "--scheduler",
        local_cluster,
    ]
    result = CliRunner().invoke(app, [*arguments, "-q", "--no-report"])
    assert result.exit_code == 0, result.output
    assert result.stderr == ""  # --quiet: no progress
    assert result.stdout.count(" ok ") == 2
    expected = _result(one_at_a_time)
    for session in sessions[:2]:
        _assert_same_estimate(_result(out / session.name), expected)
        assert not (out / session.name / "report.html").exists()


# ------------------------------------------------------------------------------ refused


def test_bad_batches_are_refused_before_any_work(sessions: list[Path], tmp_path: Path) -> None:
    runner = CliRunner()
    two = [str(sessions[0]), str(sessions[1])]
    cases = {
        "not a session directory (with log.jsonl)": [*two, str(tmp_path)],
        "no such file or directory": [*two, str(tmp_path / "nowhere")],
        "given twice": [*two, str(sessions[0])],
        "not both": [*two, "--jobs", "2", "--scheduler", "tcp://127.0.0.1:1"],
        "unknown summary format '.txt'": [*two, "--summary", str(tmp_path / "s.txt")],
    }
    for expected, arguments in cases.items():
        result = runner.invoke(app, ["estimate", *arguments])
        assert isinstance(result.exception, InputError), (expected, result.output)
        assert expected in str(result.exception), (expected, result.exception)
    twins = tmp_path / "twins"
    (twins / "a").mkdir(parents=True)
    (twins / "b").mkdir()
    for parent in ("a", "b"):
        (twins / parent / sessions[0].name).symlink_to(sessions[0])
    result = runner.invoke(
        app,
        [
            "estimate",
            str(twins / "a" / sessions[0].name),
            str(twins / "b" / sessions[0].name),
            "--out",
            str(tmp_path / "out"),
        ],
    )
    assert "would both write to" in str(result.exception)
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------ calib batch


def test_calib_batch_estimates_a_directory_of_sessions(
    sessions: list[Path], capture: Capture, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        "calib.pipeline.estimate.default_camera_basis", lambda *a, **k: capture.basis
    )
    parent = tmp_path / "sessions"
    shutil.copytree(sessions[1], parent / sessions[1].name)
    (parent / "notes.txt").write_text("not an input set")
    out = tmp_path / "out"
    arguments = ["batch", str(parent), "--out", str(out), "--jobs", "1", "-q"]
    result = CliRunner().invoke(build_app(), arguments)
    assert result.exit_code == 0, result.output
    # in this process (--jobs 1), with the report by default, and the summary beside them
    assert (out / sessions[1].name / "result.json").is_file()
    assert (out / sessions[1].name / "report.html").is_file()
    assert "input set" in result.stdout.splitlines()[0]
    assert f"| {sessions[1].name} | ok |" in (out / "summary.md").read_text()
    empty = tmp_path / "empty"
    empty.mkdir()
    result = CliRunner().invoke(build_app(), ["batch", str(empty)])
    assert result.exit_code != 0
    assert (
        "holds no input set: neither an inputs file (YAML with lamps:), a session directory "
        "(with log.jsonl), nor a directory of them" in str(result.exception)
    )
