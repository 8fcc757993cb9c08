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
import os
import shutil
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from hypothesis import strategies as st

from drivers.base import Disconnected
from rig.capture import run_capture
from rig.errors import NotResumable, ResumeConfigRefused, RigError, SessionFormatError
from rig.records import (
    FileRecord,
    PlanInfo,
    SoftwareInfo,
    StartRecord,
    StepRecord,
    StopRecord,
)
from rig.replay import load_recording
from rig.resume import prepare_resume, run_resume
from rig.runner import RetryPolicy
from rig.session import Session, parse_transcript, read_session, summarise
from tests.fuzzing import fuzz
from tests.rig.fakes import fake_config, make_fake_rig

NO_RETRY = RetryPolicy(max_attempts=1, initial_s=0.0, max_s=0.0)

FRAME = b"not really a raw frame"
WHEN = datetime(2026, 1, 1, tzinfo=UTC)
HOSTILE_PATHS = [
    "../../etc/passwd",
    "/etc/passwd",
    "frames/../../x",
    "frames/link.dng",
    "frames/L/x.dng",
    "frames/dir.dng",
    "frames/missing.dng",
    "transcripts/../log.jsonl",
    "frames/x\x00.dng",
    "frames/A/scene-000.dng\n",
    "frames/A\n/scene-000.dng",
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
    (directory / "frames" / "A" / "scene-000.dng\n").write_bytes(FRAME)  # a name with a newline
    (outside.parent / "x.dng").write_bytes(b"secret")
    (directory / "frames" / "L").symlink_to(outside.parent)  # a lamp directory linked outside
    (directory / "transcripts").mkdir()
    (directory / "transcripts" / "relays.jsonl").write_bytes(b"")
    return directory


def _assert_inside(session_dir: Path, relative: str) -> None:
    """``file_path`` refuses ``relative``, or gives a path that really is inside the session: no
    link on the way (resolved, not compared by name) and no component outside."""
    session = Session(session_dir)
    try:
        path = session.file_path(relative)
    except SessionFormatError:
        return
    assert Path(os.path.realpath(path)).is_relative_to(os.path.realpath(session_dir))
    on_the_way = [path, *path.parents]
    assert not any(p.is_symlink() for p in on_the_way if p.is_relative_to(session_dir))
    assert path.is_file()


@pytest.mark.parametrize("relative", HOSTILE_PATHS)
def test_every_hostile_path_is_refused(session_dir: Path, relative: str) -> None:
    with pytest.raises(SessionFormatError):
        Session(session_dir).file_path(relative)


def test_a_real_file_is_given(session_dir: Path) -> None:
    _assert_inside(session_dir, "frames/A/scene-000.dng")
    assert Session(session_dir).file_path("frames/A/scene-000.dng").read_bytes() == FRAME


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
        _assert_inside(session_dir, record.path)
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


# ----------------------------------------------------------- rig resume on malformed, valid logs


@pytest.fixture(scope="module")
def resumable(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]]]:
    """A fake-rig session whose camera went away mid-bracket, and its log's records as JSON."""
    rig = make_fake_rig()
    rig.camera.io.faults["capture"] = [None, Disconnected("FakeCam", "unplugged")]
    directory = tmp_path_factory.mktemp("resumable")
    outcome = run_capture(fake_config(directory / "sessions"), builder=rig.builder, retry=NO_RETRY)
    assert outcome.reason == "disconnected"
    log = (outcome.session / "log.jsonl").read_text()
    return outcome.session, [json.loads(line) for line in log.splitlines()]


_EXTREME = st.sampled_from([10**400, -(10**400), 1e308, -1e308, 5e-324, 0, -1, "", "x", [], {}])
_VALUES = st.one_of(_EXTREME, _json_values)


@st.composite
def malformed_logs(draw: st.DrawFn, records: list[dict[str, Any]]) -> tuple[bytes, bool]:
    """The session's log with schema-valid records made malformed: keys of a step's ``params`` or
    ``result``, or of the configuration snapshot and the plan's arguments, dropped or replaced by
    odd JSON (huge and tiny numbers, strings, lists). And whether to run the resume to the end."""
    edited = json.loads(json.dumps(records))
    steps = [record for record in edited if record["type"] == "step" and record["result"]]
    for _ in range(draw(st.integers(1, 3))):
        where = draw(st.sampled_from(["result", "params", "config", "plan"]))
        if where in ("result", "params"):
            target: Any = draw(st.sampled_from(steps))[where]
        elif where == "config":
            target = edited[0]["config"]
            while isinstance(target, dict) and target and draw(st.booleans()):
                target = target[draw(st.sampled_from(sorted(target)))]
        else:
            target = edited[0]["plan"]["args"]
        if not isinstance(target, dict) or not target:
            continue
        key = draw(st.sampled_from(sorted(target)))
        if draw(st.booleans()):
            del target[key]
        else:
            target[key] = draw(_VALUES)
    log = "".join(json.dumps(record) + "\n" for record in edited).encode()
    return log, draw(st.integers(0, 9)) == 0


def _resume_refuses_in_one_line(
    resumable: tuple[Path, list[dict[str, Any]]], fuzz_dir: Path, data: st.DataObject
) -> None:
    session, records = resumable
    log, run_it = data.draw(malformed_logs(records))
    copy = fuzz_dir / "fuzzed" / session.name
    if copy.parent.exists():
        shutil.rmtree(copy.parent)
    shutil.copytree(session, copy, symlinks=True)
    (copy / "log.jsonl").write_bytes(log)
    config = fake_config(session.parent)
    try:
        prepare_resume(copy, config)
    except (SessionFormatError, NotResumable, ResumeConfigRefused) as refused:
        assert "\n" not in str(refused)  # one line
        return
    if run_it:  # every record the run reuses was rebuilt above: the run cannot trip on one
        outcome = run_resume(copy, config, builder=make_fake_rig().builder, retry=NO_RETRY)
        assert outcome.reason != "internal", outcome


@pytest.fixture
def fuzz_dir(tmp_path: Path) -> Path:
    """In memory where the machine allows (tests/rig/conftest.py): the resume syncs every record."""
    return tmp_path


test_resume_refuses_malformed_logs, test_resume_refuses_malformed_logs_slow = fuzz(
    5_000, data=st.data()
)(_resume_refuses_in_one_line)
