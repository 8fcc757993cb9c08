"""``rig compare``: twin sessions captured here → the grating methods' RE table, and refusals."""

from __future__ import annotations

import csv
import json
import math
import re
import shutil
from pathlib import Path
from typing import NoReturn

import pytest

from mocks.bench import TRUTH_FILE_NAME
from rig.capture import run_capture
from rig.session import read_session
from rig.twin import write_twin_truth
from tests.rig.test_cli import run_cli
from tests.rig.twin_setup import twin_config

GRATING_COLUMNS = (
    "prior (all lamps)",
    "prior (true mapping)",
    "makabe2025 (true mapping)",
    "toivonen2020 (1 patch)",
)
#: Toivonen options small enough for a plumbing test (not for accuracy).
TINY_TOIVONEN = ["--ensemble", "2", "--epochs", "200"]


@pytest.fixture(scope="module")
def twin_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A complete session of the small twin (LED-B3 + FL2) with the twin's truth, as `rig demo`."""
    parent = tmp_path_factory.mktemp("sessions")
    config = twin_config(parent)
    outcome = run_capture(config, out_dir=parent)
    assert outcome.exit_status == "success"
    write_twin_truth(config, outcome.session)
    return outcome.session


def _copy(session: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(session, tmp_path / session.name))


def _compare(
    sessions: list[Path], out: Path, monkeypatch: pytest.MonkeyPatch, *options: str
) -> tuple[dict[str, dict[str, str]], str]:
    """Run `rig compare`; the CSV's rows by column and the Markdown report."""
    arguments = ["compare", *map(str, sessions), "--out", str(out), "-q", *TINY_TOIVONEN]
    assert run_cli([*arguments, *options], monkeypatch) == 0
    with (out / "compare.csv").open(encoding="utf-8") as handle:
        rows = {row["column"]: row for row in csv.DictReader(handle)}
    assert (out / "compare_sessions.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return rows, (out / "compare.md").read_text(encoding="utf-8")


def _assert_sane(rows: dict[str, dict[str, str]], columns: tuple[str, ...], session: Path) -> None:
    for column in columns:
        error = float(rows[column]["relative_error"])
        # A sanity bound: a broken hand-over (wrong lamp, axis, truth) gives errors of order 1.
        assert math.isfinite(error) and 0.0 < error < 0.5, (column, rows[column])
        assert rows[column]["camera"] == f"Nikon 5100 (NPL) · {session.name}"


def test_compare_writes_grating_rows_and_lists_the_chart_methods_as_skipped(
    twin_session: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    methods = ["toivonen2020", "jiang2013", "solomatov2023", "han2012"]
    rows, report = _compare(
        [twin_session],
        tmp_path / "cmp",
        monkeypatch,
        *(option for method in methods for option in ("--method", method)),
    )
    _assert_sane(rows, ("toivonen2020 (1 patch)",), twin_session)
    assert set(rows) == {"toivonen2020 (1 patch)"}
    for method in ("jiang2013", "solomatov2023", "han2012", "toivonen2020 (16 patches)"):
        assert re.search(rf"^- \*\*{re.escape(method)}\*\*: needs ", report, re.MULTILINE), method
    # the basis leaves the twin's camera out, and says so
    assert re.search(r"(without|excluding) [^\n]*Nikon D?5100", report)


@pytest.mark.slow
def test_compare_runs_every_grating_column_and_matches_rig_estimate(
    twin_session: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    rows, report = _compare([twin_session], tmp_path / "cmp", monkeypatch)
    _assert_sane(rows, GRATING_COLUMNS, twin_session)
    # With two lamps `rig estimate` (auto) runs the prior solve: the all-lamps column is its own
    # computation on the same observations.
    all_lamps = float(rows["prior (all lamps)"]["relative_error"]) * 100
    assert f"`rig estimate`'s own result RE {all_lamps:.2f} ×10⁻²" in report


def test_compare_scores_the_curve_rig_demo_scores(
    twin_session: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`rig compare`'s all-lamps column and `rig demo`'s RE are one number for one session.

    (This small twin's estimate has no negative values, so the clipping itself is tested in
    tests/test_methods.py; here a divergence of basis, inputs or scoring would show.)
    """
    from rig.compare import twin_basis
    from rig.demo import sensitivity_error
    from rig.estimate import estimate_session

    rows, _ = _compare([twin_session], tmp_path / "cmp", monkeypatch, "--method", "prior")
    basis = twin_basis("Nikon 5100 (NPL)")
    estimate_session(twin_session, tmp_path / "est", settings={"basis": basis}, report=False)
    demo = sensitivity_error(tmp_path / "est" / "sensitivity.csv", twin_session / TRUTH_FILE_NAME)
    assert float(rows["prior (all lamps)"]["relative_error"]) == pytest.approx(demo, rel=1e-5)


def test_a_session_without_the_twins_truth_is_refused(
    twin_session: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    session = _copy(twin_session, tmp_path)
    (session / TRUTH_FILE_NAME).unlink()
    out = tmp_path / "cmp"
    assert run_cli(["compare", str(session), "--out", str(out), "-q"], monkeypatch) == 2
    error = capsys.readouterr().err
    assert error.startswith(f"rig: error: {session / TRUTH_FILE_NAME}: not found: RE needs")
    assert len(error.splitlines()) == 1 and not out.exists()


def _no_estimate(*args: object, **kwargs: object) -> NoReturn:
    raise AssertionError("a session was estimated before every session was checked")


def test_a_tampered_frame_or_a_foreign_truth_is_refused(
    twin_session: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    session = _copy(twin_session, tmp_path)
    frame = next(record.path for record in read_session(session).files() if record.role == "frame")
    data = bytearray((session / frame).read_bytes())
    data[-1] ^= 0xFF
    (session / frame).write_bytes(bytes(data))
    out = tmp_path / "cmp"
    # The good session first: every session is checked before anything is estimated.
    monkeypatch.setattr("rig.compare.estimate_offline", _no_estimate)
    arguments = ["compare", str(twin_session), str(session), "--out", str(out), "-q"]
    assert run_cli(arguments, monkeypatch) == 2
    error = capsys.readouterr().err
    assert f"{frame}: sha256 differs from the log" in error and len(error.splitlines()) == 1
    assert not out.exists()

    (session / frame).write_bytes(bytes(data[:-1]) + bytes([data[-1] ^ 0xFF]))
    truth = json.loads((session / TRUTH_FILE_NAME).read_text(encoding="utf-8"))
    truth["seed"] += 1
    (session / TRUTH_FILE_NAME).write_text(json.dumps(truth), encoding="utf-8")
    assert run_cli(["compare", str(session), "--out", str(out), "-q"], monkeypatch) == 2
    error = capsys.readouterr().err
    assert f"{session / TRUTH_FILE_NAME}: the truth of camera 'Nikon 5100 (NPL)'" in error
    assert "the session was captured with camera 'Nikon 5100 (NPL)', seed 7" in error
