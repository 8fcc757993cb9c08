"""Real signals to a real ``rig capture`` process: lamps end off and the log stays valid."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rig.records import InterruptionRecord, StepRecord
from rig.session import Session, find_sessions, read_session
from tests.rig.fakes import fake_config_data, wait_for, write_config
from tests.rig.handled_signals import send_one_at_a_time

ROOT = Path(__file__).resolve().parents[2]


def start_capture(
    tmp_path: Path, capture_delay_s: float
) -> tuple[subprocess.Popen[str], Path, Path]:
    data = fake_config_data(tmp_path / "sessions")
    for lamp in data["lamps"]:
        lamp["warmup"] = {"tolerance": 0.01, "interval_s": 0.05, "timeout_s": 10, "stable_pairs": 2}
    config = write_config(tmp_path / "rig.yaml", data)
    state, marker = tmp_path / "relays.state", tmp_path / "capturing"
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tests.rig.capture_process",
            str(config),
            str(state),
            str(marker),
            str(capture_delay_s),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_for(marker.exists, timeout_s=60, what="the first capture to begin")
    except AssertionError:
        process.kill()
        out, err = process.communicate(timeout=10)
        raise AssertionError(f"the capture never began:\n{out}\n{err}") from None
    assert state.read_text() == "10"  # LED-B3 is on while its bracket is captured
    return process, state, tmp_path / "sessions"


def finish(process: subprocess.Popen[str]) -> tuple[int, str, str]:
    try:
        out, err = process.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        process.kill()
        out, err = process.communicate(timeout=10)
        raise AssertionError(f"the capture did not stop:\n{out}\n{err}") from None
    return process.returncode, out, err


def the_session(parent: Path) -> Session:
    (path,) = find_sessions(parent)
    session = read_session(path)
    assert session.torn is None
    assert session.verify_files() == []
    assert session.stop is not None and session.stop.lamps_off
    assert session.records[-1] == session.stop
    return session


@pytest.mark.parametrize(("signum", "exit_code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_one_signal_finishes_the_step_and_switches_the_lamps_off(
    tmp_path: Path, signum: signal.Signals, exit_code: int
) -> None:
    process, state, sessions = start_capture(tmp_path, capture_delay_s=0.5)
    process.send_signal(signum)
    code, out, err = finish(process)
    assert code == exit_code, err
    assert state.read_text() == "00"
    assert "status: interrupted (interrupted)" in out
    session = the_session(sessions)
    assert session.status == "interrupted"
    last = [r for r in session.records if isinstance(r, StepRecord)][-1]
    assert (last.key, last.status) == ("lamp/LED-B3/scene/000", "done")
    (interruption,) = [r for r in session.records if isinstance(r, InterruptionRecord)]
    assert interruption.signal == signum.name


def test_a_second_ctrl_c_stops_at_once(tmp_path: Path) -> None:
    process, state, sessions = start_capture(tmp_path, capture_delay_s=30.0)
    send_one_at_a_time(process, [signal.SIGINT, signal.SIGINT], tmp_path / "capturing.signals")
    began = time.monotonic()
    code, _, err = finish(process)
    assert time.monotonic() - began < 10.0  # not the 30 s the capture would take
    assert code == 130, err
    assert state.read_text() == "00"
    session = the_session(sessions)
    assert session.stop is not None and session.stop.reason == "halted"
    assert [r.action for r in session.records if isinstance(r, InterruptionRecord)] == [
        "finish-step",
        "stop-now",
    ]


@pytest.mark.parametrize(
    ("signals", "exit_code", "ctrl_c_in_release"),
    [
        ([signal.SIGTERM], 143, False),
        ([signal.SIGINT], 130, True),
        ([signal.SIGINT, signal.SIGINT], 130, True),
    ],
    ids=["sigterm", "sigint-and-another-in-release", "sigint-twice-and-another-in-release"],
)
def test_a_signal_while_the_devices_open_switches_off_what_opened_and_records_nothing(
    tmp_path: Path, signals: list[signal.Signals], exit_code: int, ctrl_c_in_release: bool
) -> None:
    """With ``ctrl_c_in_release``, one more Ctrl-C comes while the opened board is switched off:
    only noted (it once cut the switching off: the lamps stayed on, and a traceback)."""
    config = write_config(tmp_path / "rig.yaml", fake_config_data(tmp_path / "sessions"))
    state, marker = tmp_path / "relays.state", tmp_path / "capturing"
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tests.rig.capture_process",
            *(str(config), str(state), str(marker), "0", "1.5"),
            *(["ctrl-c-in-release"] if ctrl_c_in_release else []),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    wait_for(Path(f"{marker}.opening").exists, timeout_s=60, what="the devices to be opening")
    assert state.read_text() == "10"  # a lamp a killed run left on; the board is open
    send_one_at_a_time(process, signals, Path(f"{marker}.signals"))
    code, _, err = finish(process)
    assert code == exit_code, err
    assert state.read_text() == "00"  # switched off, as far as the devices had opened
    assert err == (
        f"rig: error: {signals[0].name} while the devices were being opened: stopped before "
        "anything was recorded (every lamp switched off) [interrupted]\n"
    )
    assert not (tmp_path / "sessions").exists()  # nothing to resume, nothing half-made
    assert not marker.exists()  # no capture began


@pytest.fixture(scope="module")
def python_start_s() -> float:
    """How long this Python takes to start (interpreter and ``site``, before any code of rig runs):
    a Ctrl-C inside that is CPython's own (``Fatal Python error: init_import_site``)."""
    times = []
    for _ in range(3):
        began = time.monotonic()
        subprocess.run([sys.executable, "-c", "pass"], check=True)
        times.append(time.monotonic() - began)
    return max(times)


def landed_before_rig(command: Path, code: int, err: str) -> bool:
    """Whether a Ctrl-C landed in CPython's own start-up, before any code of rig ran: before the
    interpreter set its handler (the signal's default action ends the process, silently), while it
    imported ``site`` (``Fatal Python error: init_import_site``), or in its own frames after that
    (the console script's import line, the check of ``argv[0]``): a ``KeyboardInterrupt`` whose
    every frame is importlib's or the script's. A frame of rig, or of a library rig imported, is
    not CPython's start-up."""
    if code == -signal.SIGINT and not err:
        return True
    if err.startswith("Fatal Python error: init_import_site"):
        return True
    frames = re.findall(r'^ *File "([^"]*)"', err, flags=re.MULTILINE)
    return (
        bool(frames)
        and "\nKeyboardInterrupt\n" in err
        and all(frame.startswith("<frozen ") or frame == str(command) for frame in frames)
    )


@pytest.mark.parametrize("after_start_s", [0.02, 0.06, 0.1, 0.15, 0.25])
def test_ctrl_c_in_the_first_moments_is_one_line(
    tmp_path: Path, python_start_s: float, after_start_s: float
) -> None:
    """``rig`` is still importing its libraries: a Ctrl-C then ends it as one later would."""
    config = write_config(tmp_path / "rig.yaml", fake_config_data(tmp_path / "sessions"))
    command = Path(sys.executable).parent / "rig"
    delay_s = python_start_s + after_start_s
    for _ in range(5):
        process = subprocess.Popen(
            [str(command), "capture", "--config", str(config), "--quiet"],
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        time.sleep(delay_s)
        process.send_signal(signal.SIGINT)
        code, out, err = finish(process)
        # On a loaded machine this start can outlast the fixture's: the Ctrl-C then lands in
        # CPython's own start-up, before any code of rig runs — not what this test is about.
        if not landed_before_rig(command, code, err):
            break
        delay_s *= 2
    assert "Traceback" not in err
    assert code == 130, err
    # Interrupted while importing or opening: one line on stderr. Interrupted once the run had
    # begun (a loaded machine gets there within 0.25 s): the run's own report on stdout.
    assert err.count("\n") <= 2
    assert "rig: " in err or "status: interrupted" in out, (out, err)


@pytest.mark.parametrize(
    ("code", "err", "before_rig"),
    [
        (-signal.SIGINT, "", True),
        (1, "Fatal Python error: init_import_site: Failed to import the site module\n...", True),
        (
            -signal.SIGINT,
            'Traceback (most recent call last):\n  File "{rig}", line 3, in '
            "<module>\n    from rig.entry import main\nKeyboardInterrupt\n",
            True,
        ),
        (
            1,
            "Failed checking if argv[0] is an import path entry\nTraceback (most recent call "
            'last):\n  File "<frozen importlib._bootstrap_external>", line 1696, in '
            "path_hook_for_FileFinder\nKeyboardInterrupt\n",
            True,
        ),
        (
            -signal.SIGINT,
            'Traceback (most recent call last):\n  File "{rig}", line 3, in '
            '<module>\n    from rig.entry import main\n  File "{root}/rig/entry.py", line 12, in '
            "<module>\n    import signal\nKeyboardInterrupt\n",
            False,
        ),
        (
            1,
            "Exception ignored in: <function f>\nTraceback (most recent call last):\n  File "
            '"{root}/.venv/lib/site-packages/pydantic/main.py", line 9, in f\nKeyboardInterrupt\n',
            False,
        ),
        (-signal.SIGTERM, "", False),
        (1, "rig: error: something\n", False),
    ],
    ids=["killed", "site", "script", "argv0", "rig", "library", "sigterm", "rig-error"],
)
def test_only_a_ctrl_c_in_cpythons_own_start_up_is_retried(
    code: int, err: str, before_rig: bool
) -> None:
    """The retry above forgives only a Ctrl-C that landed before rig's first line."""
    command = Path(sys.executable).parent / "rig"
    err = err.format(rig=command, root=ROOT)
    assert landed_before_rig(command, code, err) is before_rig


#: A console script as pip writes it (between its import and ``main()`` it compiles a pattern),
#: with ``rig.cli`` stood in for by a module made in ``{cli}``.
CONSOLE_SCRIPT = """\
import os, re, signal, sys
from rig.entry import main
{cli}
sys.argv[0] = re.sub(r"(-script\\.pyw|\\.exe)?$", "", sys.argv[0])
sys.exit(main())
"""


@pytest.mark.parametrize(
    "cli",
    [
        # a Ctrl-C right after the import, and a rig.cli whose main() must not be reached
        "os.kill(os.getpid(), signal.SIGINT)\nsys.modules['rig.cli'] = type(sys)('rig.cli')",
        # a KeyboardInterrupt out of rig.cli.main: a Ctrl-C in the moment before its own ``try``
        "def main_of_cli(): raise KeyboardInterrupt\n"
        "cli = type(sys)('rig.cli'); cli.main = main_of_cli; sys.modules['rig.cli'] = cli",
    ],
    ids=["between-import-and-main", "out-of-cli-main"],
)
def test_a_ctrl_c_once_the_entry_is_imported_is_one_line(cli: str) -> None:
    """From the moment the console script has imported ``rig.entry``, a Ctrl-C is rig's: one line
    and 130, never the interpreter's traceback."""
    done = subprocess.run(
        [sys.executable, "-c", CONSOLE_SCRIPT.format(cli=cli)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert (done.returncode, done.stderr, done.stdout) == (130, "rig: interrupted\n", "")


class SchemaError(Exception):
    """pydantic-core's, as it reports a Ctrl-C that arrived while it built a validator."""


@pytest.mark.parametrize(
    "error",
    [
        SchemaError('Error building "model" validator:\n  SchemaError: ... KeyboardInterrupt: '),
        RuntimeError("a library's own error, raised while handling the interrupt"),
    ],
    ids=["pydantic-core", "chained"],
)
def test_a_ctrl_c_a_library_turned_into_its_own_error_still_ends_as_interrupted(
    error: Exception, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """pydantic-core turns a Ctrl-C while it builds a validator into a ``SchemaError``: still 130,
    as is any error raised while a ``KeyboardInterrupt`` was being handled; other errors are not."""
    from rig import cli

    def library(*_args: object, **_kwargs: object) -> int:
        if isinstance(error, SchemaError):
            raise error
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as interrupt:
            raise error from interrupt

    monkeypatch.setattr(cli, "run_app", library)
    with pytest.raises(SystemExit) as ended:
        cli.main([])
    assert ended.value.code == 130
    assert capsys.readouterr().err == "rig: interrupted\n"


def test_a_halt_that_escaped_its_cleanup_is_one_line_that_says_to_check_the_lamps(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from rig import cli
    from rig.interrupts import HaltRequested

    def run(*_args: object, **_kwargs: object) -> int:
        raise HaltRequested("SIGTERM")

    monkeypatch.setattr(cli, "run_app", run)
    with pytest.raises(SystemExit) as ended:
        cli.main([])
    assert ended.value.code == 143
    assert capsys.readouterr().err == (
        "rig: error: stopped at once by a second interrupt (SIGTERM), before the cleanup began: "
        "the lamps may still be on, check them by hand [halted]\n"
    )


def test_an_error_without_an_interrupt_is_still_an_internal_error(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from rig import cli

    def library(*_args: object, **_kwargs: object) -> int:
        raise SchemaError("Error building validator: a field has no type")

    monkeypatch.setattr(cli, "run_app", library)
    monkeypatch.delenv("RIG_DEBUG", raising=False)
    with pytest.raises(SystemExit) as ended:
        cli.main([])
    assert ended.value.code == 1
    assert "internal error: SchemaError" in capsys.readouterr().err
