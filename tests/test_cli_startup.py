"""``calib`` starts without the heavy libraries: each loads at its one seam when a command needs it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Libraries that each cost 0.3–1.1 s of CPU to import.
HEAVY = ("scipy", "matplotlib", "colour")


def test_the_calib_command_imports_no_heavy_library() -> None:
    code = (
        "import sys\n"
        "import calib.cli.app\n"
        "app = calib.cli.app.build_app()\n"
        f"print(sorted({{name.split('.')[0] for name in sys.modules}} & set({HEAVY!r})))\n"
    )
    shown = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    assert shown.stdout.strip() == "[]"


def test_every_command_is_registered() -> None:
    import typer
    from typer.core import TyperGroup

    from calib.cli.app import build_app

    command = typer.main.get_command(build_app())
    assert isinstance(command, TyperGroup)
    assert set(command.commands) == {
        "synthetic",
        "data",
        "estimate",
        "batch",
        "compare",
        "spd",
        "plan-lamps",
        "idt",
        "ccm",
        "raw-to-raw",
        "profile",
        "validate",
    }


def test_the_shared_options_do_not_load_the_calib_commands() -> None:
    # rig's command line imports calib.cli.options; it must not pay for every calib command.
    code = (
        "import sys\n"
        "import calib.cli.options\n"
        "print(sorted(name for name in sys.modules if name.startswith('calib.')))\n"
        "print('numpy' in sys.modules)\n"
    )
    shown = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    loaded, numpy_loaded = shown.stdout.splitlines()
    assert loaded == str(
        [
            "calib.cli",
            "calib.cli.command_line",
            "calib.cli.options",
            "calib.core",
            "calib.core.errors",
        ]
    )
    assert numpy_loaded == "False"
