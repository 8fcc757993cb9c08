"""rig.session: the session directory format, written and read back, including hostile input."""

from __future__ import annotations

import errno
import hashlib
import json
import os
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from calib.core.spectra import Spectrum, read_spectrum_csv
from drivers.base import TranscriptEntry
from rig.errors import SessionFormatError, SessionWriteError
from rig.records import (
    FileRecord,
    PlanInfo,
    SoftwareInfo,
    StartRecord,
    StepRecord,
    StopRecord,
    check_session_path,
)
from rig.session import (
    SessionWriter,
    decode_transcript_line,
    encode_transcript_entry,
    find_sessions,
    read_session,
    summarise,
)

SOFTWARE = SoftwareInfo(name="spectral-rig", version="0", python="3.11", platform="test")


def start(writer: SessionWriter) -> StartRecord:
    return writer.write(
        StartRecord,
        session_id=writer.session_id,
        wall_time=datetime(2025, 11, 21, 12, 0, tzinfo=UTC),
        software=SOFTWARE,
        plan=PlanInfo(name="standard_capture", args={"dark_frames": 1}),
        config={"seed": 1},
        devices={},
        clock="SimulatedClock",
    )


def stop(writer: SessionWriter, status: str = "success") -> StopRecord:
    return writer.write(
        StopRecord,
        exit_status=status,
        reason="completed" if status == "success" else "interrupted",
        message="done",
        wall_time=datetime(2025, 11, 21, 12, 5, tzinfo=UTC),
        t_s=300.0,
        lamps_off=True,
    )


def frame(writer: SessionWriter, content: bytes, key: str = "lamp/A/scene/000") -> FileRecord:
    temporary = writer.incoming_path()
    temporary.write_bytes(content)
    return writer.commit_file(temporary, "frames/A/scene-000.dng", key=key, role="frame")


def append_line(session: Path, record: dict[str, object]) -> None:
    with (session / "log.jsonl").open("a", encoding="utf-8") as log:
        log.write(json.dumps(record) + "\n")


def file_record_data(seq: int, path: str) -> dict[str, object]:
    return {
        "seq": seq,
        "run": 1,
        "type": "file",
        "key": "lamp/A/scene/000",
        "role": "frame",
        "path": path,
        "size": 4,
        "sha256": "0" * 64,
    }


@pytest.fixture
def writer(tmp_path: Path) -> SessionWriter:
    return SessionWriter.create(tmp_path / "sessions")


class TestRoundTrip:
    def test_everything_written_reads_back_identically(self, writer: SessionWriter) -> None:
        written: list[object] = [start(writer)]
        raw = bytes(range(256)) * 100
        written.append(frame(writer, raw))
        spectrum = Spectrum([400.0, 500.0, 600.0], [0.5, 1.0, 0.25], name="s")
        written.append(
            writer.write_spectrum(
                "spectra/A/reference-000.csv", spectrum, key="lamp/A/reference/000", units="W/nm"
            )
        )
        sink = writer.transcript_sink("camera")
        sink.record(TranscriptEntry("cam", "call", b'{"capture": 1}', 1.5))
        written.append(
            writer.write(
                StepRecord,
                key="lamp/A/scene/000",
                action="Capture",
                params={"lamp": "A", "index": 0, "exposure_s": 0.01},
                status="done",
                attempts=1,
                started_s=1.0,
                duration_s=0.5,
                result={"file": "frames/A/scene-000.dng"},
            )
        )
        writer.close_transcripts()
        written.append(stop(writer))
        writer.close()

        session = read_session(writer.path)
        assert session.torn is None
        assert session.records[:4] == written[:4]
        assert session.records[-1] == written[-1]
        transcript = session.records[4]
        assert isinstance(transcript, FileRecord) and transcript.role == "transcript"
        assert [r.seq for r in session.records] == list(range(len(session.records)))
        assert session.status == "complete"
        assert session.verify_files() == []
        assert session.file_path("frames/A/scene-000.dng").read_bytes() == raw
        stored = read_spectrum_csv(session.file_path("spectra/A/reference-000.csv"))
        np.testing.assert_array_equal(stored.values, spectrum.values)
        assert {f.role for f in session.files()} == {"frame", "spectrum", "transcript"}
        assert set(session.done_steps()) == {"lamp/A/scene/000"}
        # no temporary file is left behind
        assert not list(writer.path.rglob(".incoming*"))

    def test_file_records_hash_what_is_on_disk(self, writer: SessionWriter) -> None:
        start(writer)
        record = frame(writer, b"raw bytes")
        assert record.size == 9
        assert record.sha256 == hashlib.sha256(b"raw bytes").hexdigest()

    def test_an_acknowledged_file_is_never_replaced(self, writer: SessionWriter) -> None:
        start(writer)
        first = frame(writer, b"first")
        second = frame(writer, b"second")
        assert (first.path, second.path) == ("frames/A/scene-000.dng", "frames/A/scene-000.2.dng")
        assert (writer.path / first.path).read_bytes() == b"first"

    def test_transcript_entries_round_trip(self, writer: SessionWriter) -> None:
        entries = [
            TranscriptEntry("PR-655", "tx", b"M5\r", 1.0),
            TranscriptEntry("PR-655", "rx", b"\x00\xff00000,1\r\n", 1.25),
            TranscriptEntry("cam", "return", '{"file": "IMG_0001.NEF", "µ": 1}'.encode(), 2.0),
            TranscriptEntry("cam", "event", b"\xff\xfe not utf-8", 3.0),
        ]
        lines = [json.dumps(encode_transcript_entry(e)) for e in entries]
        assert [json.loads(line)["enc"] for line in lines] == ["hex", "hex", "utf-8", "base64"]
        assert [decode_transcript_line(line) for line in lines] == entries
        sink = writer.transcript_sink("spectrometer")
        for entry in entries:
            sink.record(entry)
        size, sha256 = sink.close()
        on_disk = (writer.path / "transcripts" / "spectrometer.jsonl").read_bytes()
        assert (size, sha256) == (len(on_disk), hashlib.sha256(on_disk).hexdigest())


class TestStatus:
    @pytest.mark.parametrize(
        ("exit_status", "expected"),
        [
            ("success", "complete"),
            ("fail", "failed"),
            ("abort", "interrupted"),
            (None, "interrupted"),
        ],
    )
    def test_status_from_the_stop_record(
        self, writer: SessionWriter, exit_status: str | None, expected: str
    ) -> None:
        start(writer)
        if exit_status is not None:
            stop(writer, exit_status)
        writer.close()
        assert read_session(writer.path).status == expected

    def test_listing(self, tmp_path: Path) -> None:
        parent = tmp_path / "sessions"
        parent.mkdir()
        complete = SessionWriter(parent / "a-complete")
        start(complete)
        frame(complete, b"x")
        stop(complete)
        crashed = SessionWriter(parent / "b-crashed")
        start(crashed)
        (parent / "c-garbage").mkdir()
        (parent / "c-garbage" / "log.jsonl").write_text("not json\n")
        (parent / "d-not-a-session").mkdir()
        summaries = [summarise(path) for path in find_sessions(parent)]
        assert [(s.path.name, s.status) for s in summaries] == [
            ("a-complete", "complete"),
            ("b-crashed", "interrupted"),
            ("c-garbage", "invalid"),
        ]
        assert summaries[0].frames == 1 and summaries[0].plan == "standard_capture"
        assert [s.resumable for s in summaries] == [False, True, False]
        assert summaries[1].reason == "no stop record (crashed or killed)"
        assert "line 1" in summaries[2].reason


class TestDamagedLogs:
    def test_a_torn_last_line_is_reported_not_fatal(self, writer: SessionWriter) -> None:
        start(writer)
        frame(writer, b"frame")
        writer.close()
        with (writer.path / "log.jsonl").open("ab") as log:
            log.write(b'{"seq": 3, "run": 1, "type": "st')
        session = read_session(writer.path)
        assert session.torn is not None
        assert (session.torn.line, session.torn.size) == (3, 32)
        assert len(session.records) == 2
        assert session.status == "interrupted"
        assert "torn last line 3" in summarise(writer.path).reason

    def test_a_complete_record_without_its_newline_counts_as_torn(
        self, writer: SessionWriter
    ) -> None:
        start(writer)
        writer.close()
        line = json.dumps(file_record_data(1, "frames/A/x.dng")).encode()
        with (writer.path / "log.jsonl").open("ab") as log:
            log.write(line)
        session = read_session(writer.path)
        assert session.torn is not None and len(session.records) == 1

    def test_a_bad_line_in_the_middle_is_an_error_with_its_number(
        self, writer: SessionWriter
    ) -> None:
        start(writer)
        writer.close()
        with (writer.path / "log.jsonl").open("ab") as log:
            log.write(b"garbage\n")
        append_line(writer.path, file_record_data(2, "frames/A/x.dng"))
        with pytest.raises(SessionFormatError, match="line 2"):
            read_session(writer.path)

    def test_lost_or_reordered_records_are_detected(self, writer: SessionWriter) -> None:
        start(writer)
        writer.close()
        append_line(writer.path, file_record_data(2, "frames/A/x.dng"))
        with pytest.raises(SessionFormatError, match="line 2 has seq 2, expected 1"):
            read_session(writer.path)

    def test_the_first_record_must_be_a_start(self, tmp_path: Path) -> None:
        (tmp_path / "log.jsonl").write_text(
            json.dumps(file_record_data(0, "frames/A/x.dng")) + "\n"
        )
        with pytest.raises(SessionFormatError, match="not a start record"):
            read_session(tmp_path)

    def test_inconsistent_records_are_rejected(self, writer: SessionWriter) -> None:
        start(writer)
        writer.close()
        append_line(
            writer.path,
            {
                "seq": 1,
                "run": 1,
                "type": "step",
                "key": "lamp/A/scene/000",
                "action": "Capture",
                "params": {},
                "status": "done",
                "attempts": 1,
                "started_s": 0.0,
                "duration_s": 0.0,
            },
        )
        with pytest.raises(SessionFormatError, match="a done step must have a result"):
            read_session(writer.path)

    def test_not_a_session(self, tmp_path: Path) -> None:
        with pytest.raises(SessionFormatError, match="not a session"):
            read_session(tmp_path)
        (tmp_path / "elsewhere.jsonl").write_text("")
        (tmp_path / "log.jsonl").symlink_to(tmp_path / "elsewhere.jsonl")
        with pytest.raises(SessionFormatError, match="not a regular file"):
            read_session(tmp_path)

    @settings(
        max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
    )
    @given(tail=st.binary(max_size=300))
    def test_arbitrary_appended_bytes_never_crash_the_reader(
        self, tmp_path: Path, tail: bytes
    ) -> None:
        directory = tmp_path / f"s{hashlib.sha1(tail).hexdigest()}"
        writer = SessionWriter(directory)
        start(writer)
        writer.close()
        with (directory / "log.jsonl").open("ab") as log:
            log.write(tail)
        try:
            session = read_session(directory)
        except SessionFormatError:
            return
        assert session.records[0].seq == 0


class TestHostilePaths:
    @pytest.mark.parametrize(
        "path",
        [
            "../../etc/passwd",
            "/etc/passwd",
            "frames/../../x",
            "frames/./x.dng",
            "frames//x.dng",
            "frames\\..\\x",
            "frames/.hidden",
            "frames/a b.dng",
            "log.jsonl",
            "other/x.dng",
            "frames",
            "frames/x\x00.dng",
            "C:/x/y",
        ],
    )
    def test_unsafe_paths_in_the_log_are_rejected(self, writer: SessionWriter, path: str) -> None:
        start(writer)
        writer.close()
        append_line(writer.path, file_record_data(1, path))
        with pytest.raises(SessionFormatError, match="line 2"):
            read_session(writer.path)
        with pytest.raises(ValueError):
            check_session_path(path)

    def test_a_symlinked_file_is_not_followed(self, writer: SessionWriter, tmp_path: Path) -> None:
        start(writer)
        record = frame(writer, b"data")
        writer.close()
        outside = tmp_path / "outside.dng"
        outside.write_bytes(b"data")
        target = writer.path / record.path
        target.unlink()
        target.symlink_to(outside)
        session = read_session(writer.path)
        with pytest.raises(SessionFormatError, match="symlink"):
            session.file_path(record.path)
        (problem,) = session.verify_files()
        assert "symlink" in problem.problem

    def test_a_symlinked_directory_is_not_followed(
        self, writer: SessionWriter, tmp_path: Path
    ) -> None:
        start(writer)
        record = frame(writer, b"data")
        writer.close()
        outside = tmp_path / "elsewhere"
        (writer.path / "frames" / "A").rename(outside)
        (writer.path / "frames" / "A").symlink_to(outside)
        with pytest.raises(SessionFormatError, match=r"symlink \(A\)"):
            read_session(writer.path).file_path(record.path)

    def test_changed_or_missing_files_are_reported(self, writer: SessionWriter) -> None:
        start(writer)
        record = frame(writer, b"abcd")
        spectrum = Spectrum([400.0, 700.0], [1.0, 2.0])
        csv = writer.write_spectrum("spectra/A/warmup-000.csv", spectrum, key="k/s", units="W")
        writer.close()
        (writer.path / record.path).write_bytes(b"abce")
        (writer.path / csv.path).unlink()
        problems = {p.path: p.problem for p in read_session(writer.path).verify_files()}
        assert problems == {
            record.path: "sha256 differs from the log",
            csv.path: "does not exist",
        }

    def test_each_unreadable_file_is_said_once_by_path_and_by_problem(
        self, writer: SessionWriter, tmp_path: Path
    ) -> None:
        """verify_files names the path apart from the problem, file_path names it in the error:
        the same words for a missing file, a symlink, a directory in a file's place and an
        unsafe name."""
        start(writer)
        missing, linked, directory = (frame(writer, b"x", f"lamp/A/scene/00{k}") for k in range(3))
        assert len({missing.path, linked.path, directory.path}) == 3
        writer.close()
        (writer.path / missing.path).unlink()
        (writer.path / linked.path).unlink()
        (writer.path / linked.path).symlink_to(tmp_path / "elsewhere.dng")
        (writer.path / directory.path).unlink()
        (writer.path / directory.path).mkdir()
        session = read_session(writer.path)
        said = {
            missing.path: "does not exist",
            linked.path: f"goes through a symlink ({Path(linked.path).name}); refused",
            directory.path: "is not a regular file",
        }
        assert {p.path: p.problem for p in session.verify_files()} == said
        for path, problem in said.items():
            with pytest.raises(SessionFormatError) as raised:
                session.file_path(path)
            assert str(raised.value) == f"{writer.path}: {path} {problem}"
        with pytest.raises(SessionFormatError) as raised:
            session.file_path("frames/../log.jsonl")
        assert str(raised.value).startswith(f"{writer.path}: path 'frames/../log.jsonl' has an ")


class TestWriteFailures:
    def test_a_failed_write_is_cut_back_and_stops_all_later_writes_but_the_last(
        self, writer: SessionWriter, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        start(writer)

        def disk_full(fd: int, data: bytes) -> None:
            os.write(fd, data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")

        monkeypatch.setattr("rig.session.write_all", disk_full)
        with pytest.raises(SessionWriteError, match="No space left on device"):
            stop(writer)
        monkeypatch.undo()
        with pytest.raises(SessionWriteError, match="an earlier write failed"):
            stop(writer)
        assert read_session(writer.path).torn is None  # the half-written line was cut back off
        assert writer.finish()  # the run's last records may still be written
        stop(writer)
        writer.close()
        session = read_session(writer.path)
        assert session.torn is None and [type(r).__name__ for r in session.records] == [
            "StartRecord",
            "StopRecord",
        ]

    def test_a_write_that_cannot_be_cut_back_ends_all_writing(
        self, writer: SessionWriter, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        start(writer)

        def disk_full(fd: int, data: bytes) -> None:
            os.write(fd, data[: len(data) // 2])
            raise OSError(errno.EIO, "Input/output error")

        def truncate_fails(fd: int, size: int) -> None:
            raise OSError(errno.EIO, "Input/output error")

        monkeypatch.setattr("rig.session.write_all", disk_full)
        monkeypatch.setattr("rig.session.os.ftruncate", truncate_fails)
        with pytest.raises(SessionWriteError, match="Input/output error"):
            stop(writer)
        monkeypatch.undo()
        assert not writer.finish()
        with pytest.raises(SessionWriteError, match="an earlier write failed"):
            stop(writer)
        writer.close()
        session = read_session(writer.path)
        assert session.torn is not None  # the half-written line stays the last line
        assert len(session.records) == 1

    def test_a_failed_sync_is_a_write_error(
        self, writer: SessionWriter, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        def sync_fails(fd: int) -> None:
            raise OSError(errno.EIO, "Input/output error")

        monkeypatch.setattr("rig.session._sync", sync_fails)
        with pytest.raises(SessionWriteError, match="Input/output error"):
            start(writer)
        assert writer.broken is not None

    def test_an_existing_session_directory_is_never_reused(self, writer: SessionWriter) -> None:
        with pytest.raises(SessionWriteError, match="already exists"):
            SessionWriter(writer.path)
