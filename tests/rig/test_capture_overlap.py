"""A dark frame is stored while the camera takes the next one (decision 0052): every frame kept,
the log in step order, a failure of the storing or a kill during it ends in a usable session."""

from __future__ import annotations

import inspect
import json
import signal
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from calib.core import checksums
from rig.capture import run_capture
from rig.errors import SessionFormatError
from rig.interrupts import HaltRequested, InterruptController
from rig.records import FileRecord, StepRecord
from rig.resume import run_resume
from rig.runner import RetryPolicy, Runner
from rig.session import SessionWriter, read_session
from tests.rig.fakes import RAW_MAGIC, FakeRig, fake_config, make_fake_rig, wait_for
from tests.rig.test_fault_matrix import (
    NO_BACKOFF,
    Uninterrupted,
    assert_invariants,
    leftovers,
    matrix_config,
    uninterrupted,  # noqa: F401 - the fixture
    uninterrupted_runs,  # noqa: F401 - the fixture
)

FAST_RETRY = RetryPolicy(max_attempts=3, initial_s=0.0, max_s=0.0)

CommitFile = Callable[..., FileRecord]


def in_journal() -> bool:
    return threading.current_thread().name.startswith("rig-journal")


class NextCapture:
    """Whether the camera began the next capture while the journal stored a frame.

    The journal is held at the frame's acknowledgement until the fake camera has begun the capture
    after this frame's (the frame is stored while the next is taken) or the runner waits for the
    journal (it is not), whichever comes first: the order of events, not how soon the next
    capture comes, which a loaded machine delays (a 0.5 s poll for "the camera is busy now" could
    miss a 50 ms capture there)."""

    def __init__(self, rig: FakeRig, monkeypatch: pytest.MonkeyPatch) -> None:
        self.rig = rig
        self.settling = threading.Event()
        settle = Runner._settle

        def settle_noted(runner: Runner) -> None:
            self.settling.set()
            try:
                settle(runner)
            finally:
                self.settling.clear()

        monkeypatch.setattr(Runner, "_settle", settle_noted)

    def captures_begun(self) -> int:
        return self.rig.events.count(("begin", "camera", "capture"))

    def begun_while_stored(self, frame_file: Path) -> bool:
        """Called in the journal as it acknowledges ``frame_file`` (a fake RAW file)."""
        number = int(json.loads(frame_file.read_bytes().removeprefix(RAW_MAGIC))["number"])
        wait_for(
            lambda: self.captures_begun() > number or self.settling.is_set(),
            timeout_s=60,
            what=f"capture {number + 1} or the runner waiting for the journal",
        )
        return self.captures_begun() > number


def watch_commits(
    monkeypatch: pytest.MonkeyPatch,
    on_commit: Callable[[SessionWriter, str, Path], None],
) -> None:
    """Call ``on_commit(writer, key, temporary)`` before every file the session acknowledges."""
    real: CommitFile = SessionWriter.commit_file

    def commit_file(self: SessionWriter, temporary: Path, *args: Any, **kwargs: Any) -> FileRecord:
        on_commit(self, kwargs["key"], temporary)
        return real(self, temporary, *args, **kwargs)

    monkeypatch.setattr(SessionWriter, "commit_file", commit_file)


def test_frames_are_stored_while_the_camera_takes_the_next(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    rig = make_fake_rig()
    rig.camera.io.delay_s["capture"] = 0.05
    next_capture = NextCapture(rig, monkeypatch)
    overlapped: list[str] = []

    def note(writer: SessionWriter, key: str, temporary: Path) -> None:
        # The journal holds the store until the camera takes the next frame: it must not wait.
        frame = "/scene/" in key or "/dark/" in key
        if frame and in_journal() and next_capture.begun_while_stored(temporary):
            overlapped.append(key)

    watch_commits(monkeypatch, note)
    outcome = run_capture(fake_config(tmp_path / "sessions"), builder=rig.builder, retry=FAST_RETRY)
    assert outcome.exit_status == "success", outcome
    session = read_session(outcome.session)
    assert session.status == "complete" and session.verify_files() == []
    frames = [
        r
        for r in session.records
        if isinstance(r, StepRecord) and r.action in ("Capture", "DarkFrame")
    ]
    # Every frame but the run's last was stored while the camera took a later one.
    assert sorted(overlapped) == sorted(r.key for r in frames[:-1])
    # Each frame: its file, then its step record, nothing between; the steps in plan order.
    for record in frames:
        assert record.status == "done" and record.result is not None
        (file,) = [f for f in session.files() if f.key == record.key]
        assert file.path == record.result["file"]
        assert record.seq == file.seq + 1
    keys = [r.key for r in session.records if isinstance(r, StepRecord)]
    assert len(keys) == len(set(keys))
    assert rig.relays.state() == (False, False)


def test_a_dark_frame_that_cannot_be_stored_keeps_the_next_frame_and_lamps_go_off(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The storing of dark frame 0 fails in the journal while the camera takes dark frame 1:
    the run fails on dark frame 0's step, dark frame 1 is kept (a verified file), the lamps are
    off, and ``rig resume`` completes the session."""
    rig = make_fake_rig()
    rig.camera.io.delay_s["capture"] = 0.05
    failing = "lamp/LED-B3/dark/000"
    busy: list[bool] = []

    next_capture = NextCapture(rig, monkeypatch)

    def refuse(writer: SessionWriter, key: str, temporary: Path) -> None:
        if key == failing and in_journal():
            busy.append(next_capture.begun_while_stored(temporary))
            raise SessionFormatError(f"{writer.path}: frames/LED-B3/dark-000.dng refused")

    with monkeypatch.context() as patch:
        watch_commits(patch, refuse)
        outcome = run_capture(
            fake_config(tmp_path / "sessions"), builder=rig.builder, retry=FAST_RETRY
        )
    assert busy == [True]  # the camera was taking the next frame meanwhile
    assert (outcome.reason, outcome.failed_key) == ("session_format", failing)
    assert outcome.lamps_off and rig.relays.state() == (False, False)
    session = read_session(outcome.session)
    assert session.torn is None and session.verify_files() == []
    assert session.stop is not None and session.records[-1] == session.stop
    assert session.stop.failed_key == failing
    (failed,) = [r for r in session.records if isinstance(r, StepRecord) and r.status == "failed"]
    assert failed.key == failing
    # The next frame was downloaded while dark frame 0 was being stored: it is kept …
    (kept,) = [f for f in session.files() if f.key == "lamp/LED-B3/dark/001"]
    assert (outcome.session / kept.path).is_file()
    # … but not acknowledged as a done step (its predecessor failed).
    assert "lamp/LED-B3/dark/001" not in session.done_steps()
    resumed = run_resume(
        outcome.session,
        fake_config(tmp_path / "sessions"),
        builder=make_fake_rig().builder,
        retry=FAST_RETRY,
    )
    assert resumed.exit_status == "success", resumed
    done = read_session(outcome.session)
    assert done.status == "complete" and done.verify_files() == []
    assert leftovers(outcome.session) == []


def test_killed_while_a_dark_frame_is_stored_then_resumed(
    tmp_path: Path,
    uninterrupted: Uninterrupted,  # noqa: F811 - the fixture
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The process stops (as ``kill -9`` does: nothing more written, not even the stop record)
    while the journal stores a dark frame and the camera takes the next; ``rig resume`` then
    completes the session with the same estimator inputs as an uninterrupted capture."""
    killed: list[str] = []

    def kill(writer: SessionWriter, key: str, temporary: Path) -> None:
        if key == "lamp/LED-B3/dark/001" and in_journal() and not killed:
            killed.append(key)
            writer.kill()

    with monkeypatch.context() as patch:
        watch_commits(patch, kill)
        outcome = run_capture(matrix_config(tmp_path), retry=NO_BACKOFF)
    assert killed and outcome.exit_status == "fail"
    first = read_session(outcome.session)
    assert first.stop is None and first.torn is None
    assert "lamp/LED-B3/dark/000" in first.done_steps()
    assert "lamp/LED-B3/dark/001" not in first.done_steps()
    resumed = run_resume(outcome.session, matrix_config(tmp_path), retry=NO_BACKOFF)
    assert resumed.exit_status == "success", resumed
    assert_invariants(outcome.session, tmp_path, uninterrupted, estimate=False)
    assert leftovers(outcome.session) == []


@pytest.mark.skipif(
    threading.current_thread() is not threading.main_thread(),
    reason="signal handlers run in the main thread only",
)
def test_the_journal_storing_does_not_hold_back_a_second_signal() -> None:
    """A critical section in another thread (the journal's writes) cannot be cut by a signal, so
    it does not delay the second signal's stop of the main thread (a long exposure)."""
    controller = InterruptController()
    entered, leave = threading.Event(), threading.Event()

    def journal() -> None:
        with controller.critical():
            entered.set()
            leave.wait(5)

    thread = threading.Thread(target=journal)
    thread.start()
    try:
        assert entered.wait(5)
        controller._handle(signal.SIGINT, None)
        with pytest.raises(HaltRequested):
            controller._handle(signal.SIGINT, None)
    finally:
        leave.set()
        thread.join(5)


def test_a_frame_is_read_for_its_digest_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The stale-frame check's digest is the one the file record carries: storing the frame does
    not read it again (it only syncs it), and every stored file still verifies."""
    hashed: list[Path] = []

    class CountedDigest(checksums.FileDigest):
        def __init__(self, *args: Any) -> None:
            hashed.append(Path(inspect.stack()[1].frame.f_locals["path"]))
            super().__init__(*args)

    monkeypatch.setattr(checksums, "FileDigest", CountedDigest)
    rig = make_fake_rig()
    outcome = run_capture(fake_config(tmp_path / "sessions"), builder=rig.builder, retry=FAST_RETRY)
    assert outcome.exit_status == "success", outcome
    downloads = [path for path in hashed if path.parent.parent.name == "frames"]
    session = read_session(outcome.session)
    assert session.status == "complete" and session.verify_files() == []
    frames = [f for f in session.files() if f.role in ("frame", "dark")]
    assert len(frames) >= 4
    # Each download hashed once, under its temporary name, before it was renamed into place.
    assert all(path.suffix == ".part" for path in downloads)
    assert len(downloads) == len(set(downloads)) == len(frames)
