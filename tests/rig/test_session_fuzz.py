"""The session-log reader and replay's transcript reader raise only typed errors, whatever they read.

Logs are built from a valid session's lines, then damaged: lines replaced by garbage or by records
with hostile paths, bytes flipped, lines dropped or repeated, a torn tail. The reader may refuse
(:class:`rig.errors.SessionFormatError`) but nothing else may escape, and whatever it accepts must
be safe to use: every file it names is opened through the symlink-refusing checks. Replay's
transcript parser is fuzzed the same way (:class:`rig.replay.ReplayRefused` only).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
from datetime import UTC, datetime
from pathlib import Path

import pytest
from hypothesis import strategies as st

from rig.errors import RigError, SessionFormatError
from rig.records import (
    FileRecord,
    PlanInfo,
    SoftwareInfo,
    StartRecord,
    StepRecord,
    StopRecord,
)
from rig.replay import load_recording
from rig.session import parse_transcript, read_session, summarise
from tests.fuzzing import fuzz

FRAME = b"not really a raw frame"
WHEN = datetime(2026, 1, 1, tzinfo=UTC)
HOSTILE_PATHS = [
    "../../etc/passwd",
    "/etc/passwd",
    "frames/../../x",
    "frames/link.dng",
    "frames/dir.dng",
    "frames/missing.dng",
    "transcripts/../log.jsonl",
    "frames/x\x00.dng",
    "frames\\..\\x",
    "C:/x",
    "",
]


def _template() -> list[bytes]:
    """The lines of a small valid session: start, a step, its frame, the transcripts, stop."""
    records = [
        StartRecord(
            seq=0,
            run=1,
            session_id="0" * 32,
            wall_time=WHEN,
            software=SoftwareInfo(name="spectral-rig", version="0", python="3", platform="x"),
            plan=PlanInfo(name="standard_capture", args={}),
            config={},
            devices={},
            clock="SimulatedClock",
        ),
        FileRecord(
            seq=1,
            run=1,
            key="lamp/A/scene/000",
            role="frame",
            path="frames/A/scene-000.dng",
            size=len(FRAME),
            sha256=hashlib.sha256(FRAME).hexdigest(),
        ),
        StepRecord(
            seq=2,
            run=1,
            key="lamp/A/scene/000",
            action="Capture",
            params={"exposure_s": 0.01},
            status="done",
            attempts=1,
            started_s=0.0,
            duration_s=0.1,
            result={"file": "frames/A/scene-000.dng"},
        ),
        FileRecord(
            seq=3,
            run=1,
            key="transcripts/relays",
            role="transcript",
            path="transcripts/relays.jsonl",
            size=0,
            sha256=hashlib.sha256(b"").hexdigest(),
        ),
        StopRecord(
            seq=4,
            run=1,
            exit_status="success",
            reason="completed",
            message="done",
            wall_time=WHEN,
            t_s=1.0,
            lamps_off=True,
        ),
    ]
    return [record.model_dump_json().encode() for record in records]


TEMPLATE = _template()


def _with_path(line: bytes, path: str) -> bytes:
    record = json.loads(FileRecord.model_validate_json(TEMPLATE[1]).model_dump_json())
    return json.dumps(record | {"path": path}).encode()


@st.composite
def damaged_logs(draw: st.DrawFn) -> bytes:
    lines = list(TEMPLATE)
    for _ in range(draw(st.integers(0, 4))):
        index = draw(st.integers(0, len(lines) - 1))
        kind = draw(st.sampled_from(["garbage", "hostile", "flip", "drop", "repeat", "json"]))
        if kind == "garbage":
            lines[index] = draw(st.binary(max_size=80))
        elif kind == "hostile":
            path = draw(st.one_of(st.sampled_from(HOSTILE_PATHS), st.text(max_size=30)))
            lines[index] = _with_path(lines[index], path)
        elif kind == "flip" and lines[index]:
            line = bytearray(lines[index])
            position = draw(st.integers(0, len(line) - 1))
            line[position] = draw(st.integers(0, 255))
            lines[index] = bytes(line)
        elif kind == "drop" and len(lines) > 1:
            del lines[index]
        elif kind == "repeat":
            lines.insert(index, lines[index])
        elif kind == "json":
            lines[index] = json.dumps(draw(_json_values)).encode()
    log = b"".join(line.replace(b"\n", b" ") + b"\n" for line in lines)
    return log + draw(st.one_of(st.just(b""), st.binary(max_size=40).map(lambda t: t.strip(b"\n"))))


_json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=10),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3)
    ),
    max_leaves=10,
)


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A session directory with a real frame, a symlink out of it, and a directory named like a file."""
    directory = tmp_path_factory.mktemp("fuzzed")
    (directory / "frames" / "A").mkdir(parents=True)
    (directory / "frames" / "A" / "scene-000.dng").write_bytes(FRAME)
    (directory / "frames" / "dir.dng").mkdir()
    outside = tmp_path_factory.mktemp("outside") / "secret"
    outside.write_bytes(b"secret")
    (directory / "frames" / "link.dng").symlink_to(outside)
    (directory / "transcripts").mkdir()
    (directory / "transcripts" / "relays.jsonl").write_bytes(b"")
    return directory


def _session_reader(session_dir: Path, log: bytes) -> None:
    (session_dir / "log.jsonl").write_bytes(log)
    summarise(session_dir)  # reports "invalid" rather than raising
    try:
        session = read_session(session_dir)
    except SessionFormatError:
        return
    for problem in session.verify_files():
        assert problem.path
    for record in session.files():
        with contextlib.suppress(SessionFormatError):
            assert session.file_path(record.path).is_relative_to(session_dir)
    assert session.status in ("complete", "interrupted", "failed")
    session.done_steps()
    with contextlib.suppress(RigError):
        load_recording(session_dir)


test_session_reader, test_session_reader_slow = fuzz(15_000, log=damaged_logs())(_session_reader)


@st.composite
def transcripts(draw: st.DrawFn) -> bytes:
    entry = {
        "t_s": 1.5,
        "device": "PR-655 on /dev/ttyACM0",
        "dir": "tx",
        "enc": "hex",
        "data": "00",
    }
    lines = []
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(["valid", "field", "garbage", "json"]))
        if kind == "valid":
            lines.append(json.dumps(entry).encode())
        elif kind == "field":
            key = draw(st.sampled_from(sorted(entry)))
            lines.append(json.dumps(entry | {key: draw(_json_values)}).encode())
        elif kind == "garbage":
            lines.append(draw(st.binary(max_size=60)))
        else:
            lines.append(json.dumps(draw(_json_values)).encode())
    return b"\n".join(lines)


def _transcript_reader(data: bytes) -> None:
    with contextlib.suppress(RigError):
        for entry in parse_transcript(data, "transcripts/fuzzed.jsonl"):
            assert isinstance(entry.payload, bytes)


test_transcript_reader, test_transcript_reader_slow = fuzz(5_000, data=transcripts())(
    _transcript_reader
)
