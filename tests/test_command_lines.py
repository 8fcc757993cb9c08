"""One style for every command of ``calib`` and ``rig``, enumerated from the apps themselves.

``-h`` and ``--help`` on every command and group, ``--version`` on every one, a mistake on the
command line as one line with exit 2, help that names every option in full at 80 columns and lists
the choices of ``--method`` and its like, and a Ctrl-C inside a command as one line with exit 130.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import re
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest
import typer

from calib.cli import app as calib_app
from calib.cli.command_line import (
    HELP_CHOICES,
    click_command,
    expand_list_options,
    new_app,
    run_app,
    subcommands,
)
from calib.core.software import current_software
from rig import cli as rig_cli

Main = Callable[[Sequence[str]], None]


def _paths(command: object, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    paths = [prefix]
    for name, child in sorted(subcommands(command).items()):  # type: ignore[arg-type]
        paths.extend(_paths(child, (*prefix, name)))
    return paths


CALIB_PATHS = _paths(click_command(calib_app.build_app()))
RIG_PATHS = _paths(click_command(rig_cli.app))
EVERY = [
    pytest.param(program, path, id=" ".join([program, *path]))
    for program, paths in (("calib", CALIB_PATHS), ("rig", RIG_PATHS))
    for path in paths
]
MAINS: dict[str, Main] = {"calib": calib_app.main, "rig": rig_cli.main}


def _run(program: str, argv: Sequence[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    code: object = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            MAINS[program](list(argv))
        except SystemExit as exit_:
            code = exit_.code
    return (code if isinstance(code, int) else 1), out.getvalue(), err.getvalue()


def test_the_apps_are_enumerated() -> None:
    assert ("estimate",) in CALIB_PATHS and ("data", "fetch") in CALIB_PATHS
    assert ("estimate",) in RIG_PATHS and ("data", "list") in RIG_PATHS
    assert len(EVERY) > 25


@pytest.mark.parametrize(("program", "path"), EVERY)
def test_every_command_has_h_help_and_version(program: str, path: tuple[str, ...]) -> None:
    for flag in ("-h", "--help"):
        code, stdout, stderr = _run(program, [*path, flag])
        assert code == 0, stderr
        assert "Usage:" in stdout and " ".join([program, *path]) in stdout
        unfilled = [name for name in HELP_CHOICES if "{" + name + "}" in stdout]
        assert unfilled == []  # choices are listed, not their placeholders
    code, stdout, stderr = _run(program, [*path, "--version"])
    assert (code, stdout, stderr) == (0, f"spectral-rig {current_software().version}\n", "")


@pytest.mark.parametrize(("program", "path"), EVERY)
def test_a_mistake_is_one_line_and_exit_2(program: str, path: tuple[str, ...]) -> None:
    code, stdout, stderr = _run(program, [*path, "--no-such-option"])
    assert code == 2
    assert stderr.startswith(f"{program}: error: ") and stderr.count("\n") == 1, stderr
    assert "--no-such-option" in stderr and "-h for help" in stderr
    assert stdout == ""


@pytest.mark.parametrize(("program", "path"), EVERY)
def test_the_help_names_every_option_in_full_at_80_columns(
    program: str, path: tuple[str, ...], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "80")
    command = click_command(calib_app.build_app() if program == "calib" else rig_cli.app)
    for name in path:
        command = subcommands(command)[name]
    _, stdout, _ = _run(program, [*path, "-h"])
    for parameter in command.params:
        for flag in [*parameter.opts, *parameter.secondary_opts]:
            if flag.startswith("--"):
                assert flag in stdout, f"{flag} is cut short in {program} {' '.join(path)} -h"


@pytest.mark.parametrize("program", ["calib", "rig"])
def test_a_group_lists_each_command_s_first_paragraph_unbroken(
    program: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The list of commands shows each one's first paragraph as one flowing text: a docstring's
    own line breaks would end a line mid-sentence there ("…, with a" / "summary table.")."""
    monkeypatch.setenv("COLUMNS", "100")
    command = click_command(calib_app.build_app() if program == "calib" else rig_cli.app)
    _, stdout, _ = _run(program, ["-h"])
    listed: dict[str, list[str]] = {}
    box = stdout.split("Commands", 1)[1].splitlines()[1:]
    for line in box:
        if not line.startswith("│"):
            break
        text = line.strip("│").rstrip()
        if not text.startswith("  "):  # a command's name starts the row; else a continuation
            name, _, text = text.strip().partition(" ")
            listed[name] = []
        listed[name].append(text.strip())
    width = max(len(row) for rows in listed.values() for row in rows)
    for name, child in subcommands(command).items():
        first = " ".join((child.help or "").split("\n\n", 1)[0].split())
        rows = listed[name]
        assert " ".join(rows) == first, name
        for row, following in itertools.pairwise(rows):
            # a row ends early only where the next word would not have fitted
            assert len(row) + 1 + len(following.split()[0]) > width, (name, row)


@pytest.mark.parametrize(
    ("program", "argv", "listed"),
    [
        ("calib", ["estimate", "-h"], ("known-grating", "multilamp", "typicality", "evidence")),
        ("rig", ["estimate", "-h"], ("known-grating", "multilamp", "typicality", "evidence")),
        ("rig", ["grating", "-h"], ("typicality", "evidence")),
        ("rig", ["compare", "-h"], ("toivonen2020", "jiang2013")),
        ("calib", ["compare", "-h"], ("toivonen2020", "jiang2013")),
        ("calib", ["synthetic", "-h"], ("typicality",)),
        ("calib", ["idt", "-h"], ("D65",)),
        ("calib", ["data", "fetch", "-h"], ("solomatov-akkaynak-2023",)),
    ],
)
def test_choices_are_listed_in_the_help(
    program: str, argv: list[str], listed: tuple[str, ...]
) -> None:
    code, stdout, _ = _run(program, argv)
    assert code == 0
    flat = " ".join(stdout.replace("│", " ").split())
    for choice in listed:
        assert choice in flat


def test_the_same_options_have_the_same_names_in_rig_and_calib() -> None:
    """An option both programs' commands take is spelt alike, with the same short form."""

    def flags(program_app: typer.Typer) -> dict[str, set[str]]:
        found: dict[str, set[str]] = {}
        for path in _paths(click_command(program_app)):
            command = click_command(program_app)
            for name in path:
                command = subcommands(command)[name]
            for parameter in command.params:
                if parameter.name:
                    found.setdefault(parameter.name, set()).update(parameter.opts)
        return found

    calib_flags, rig_flags = flags(calib_app.build_app()), flags(rig_cli.app)
    for name in ("data_dir", "exclude_camera", "method", "weight_rule", "quiet", "force", "grid"):
        assert name in calib_flags and name in rig_flags, name
        assert calib_flags[name] == rig_flags[name], name
    assert calib_flags["out"] >= {"--out", "-o"} and rig_flags["out"] >= {"--out", "-o"}
    assert "--dest" not in set().union(*calib_flags.values(), *rig_flags.values())


def test_a_ctrl_c_inside_a_command_is_one_line_and_exit_130(
    capsys: pytest.CaptureFixture[str],
) -> None:
    app = new_app("demo", "A demonstration.")

    @app.command()
    def run() -> None:
        raise KeyboardInterrupt

    @app.command()
    def other() -> None:
        raise typer.Exit(130)  # a command's own exit code 130 is not a Ctrl-C

    assert run_app(app, "demo", ["run"]) == 130
    assert capsys.readouterr().err == "demo: interrupted\n"
    assert run_app(app, "demo", ["other"]) == 130
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize(
    ("argv", "expanded"),
    [
        (["--images", "a", "b", "--out", "o"], ["--images", "a", "--images", "b", "--out", "o"]),
        (["--images=a", "b"], ["--images=a", "b"]),
        (["--out", "o", "x"], ["--out", "o", "x"]),
        (["--exposure", "-1", "2"], ["--exposure", "-1", "--exposure", "2"]),
        (["--images", "a", "--", "--images", "b"], ["--images", "a", "--", "--images", "b"]),
    ],
)
def test_list_options_take_the_values_up_to_the_next_option(
    argv: list[str], expanded: list[str]
) -> None:
    assert expand_list_options(argv, frozenset({"--images", "--exposure"})) == expanded


def test_the_help_lists_the_registry_s_own_choices() -> None:
    from calib.cli.options import METHOD_NAMES, WEIGHT_RULES
    from calib.methods import method_names
    from calib.methods.multilamp import PRIOR_WEIGHT_RULES

    assert method_names() == METHOD_NAMES
    assert WEIGHT_RULES == PRIOR_WEIGHT_RULES


#: A Python repr in a message: a list or tuple of quoted strings, a call, an object's default repr.
PYTHON_REPR = re.compile(r"\[['\"]|\(['\"]|<[\w.]+ object at|\w+\(\[|Traceback")


@pytest.mark.parametrize(
    ("program", "argv", "names"),
    [
        ("calib", ["estimate", "--out", "o"], "--lamp"),
        ("calib", ["estimate", "--out", "o", "--method", "magic"], "--method"),
        ("calib", ["estimate", "--out", "o", "--grid", "700:400:10"], "--grid"),
        ("calib", ["synthetic", "--method", "magic"], "--method"),
        ("calib", ["validate", "--split", "train"], "--split"),
        ("calib", ["validate", "--variant", "magic"], "--variant"),
        ("calib", ["validate", "--grating", "ruled,magic"], "--grating"),
        ("calib", ["data", "fetch", "--collection", "magic"], "--collection"),
        ("calib", ["spd", "--profile"], "--profile"),
        ("rig", ["estimate", "no-such-session", "--method", "magic"], "--method"),
        ("rig", ["compare", "--exclude-camera"], "--exclude-camera"),
    ],
)
def test_a_wrong_invocation_is_one_line_without_python_reprs(
    program: str, argv: list[str], names: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    code, stdout, stderr = _run(program, argv)
    assert code == 2, stderr
    assert stdout == "" and stderr.count("\n") == 1, stderr
    assert stderr.startswith(f"{program}: error: ") and names in stderr
    assert not PYTHON_REPR.search(stderr), stderr


def test_calib_estimate_help_loads_no_heavy_library() -> None:
    # The command modules are imported for real (issue 14: no string indirection hides the import
    # graph); what keeps the help fast is that scipy, matplotlib and colour-science load at their
    # seams only when a command runs.
    code = (
        "import sys\n"
        "from calib.cli.app import main\n"
        "try:\n"
        "    main(['estimate', '--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "print(sorted({'scipy', 'matplotlib', 'colour'} & set(sys.modules)), file=sys.stderr)\n"
    )
    shown = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert shown.stderr.strip() == "[]"


#: Every command that estimates a camera from a basis.
ESTIMATING = [
    ("calib", ("estimate",)),
    ("calib", ("synthetic",)),
    ("calib", ("compare",)),
    ("calib", ("validate",)),
    ("rig", ("estimate",)),
    ("rig", ("grating",)),
    ("rig", ("compare",)),
]


@pytest.mark.parametrize(("program", "path"), ESTIMATING)
def test_every_estimating_command_takes_exclude_camera_repeatedly(
    program: str, path: tuple[str, ...]
) -> None:
    command = click_command(calib_app.build_app() if program == "calib" else rig_cli.app)
    for name in path:
        command = subcommands(command)[name]
    (option,) = [p for p in command.params if p.name == "exclude_camera"]
    assert option.opts == ["--exclude-camera"] and option.multiple
    assert option.metavar == "PATTERN"
