"""``calib`` starts without the heavy libraries: each loads at its one seam when a command needs it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Libraries that each cost 0.3–1.1 s of CPU to import.
HEAVY = ("scipy", "matplotlib", "colour")


def _loaded_after(statements: str, skip: str = "calib.cli") -> tuple[str, str]:
    """In a fresh interpreter, after ``statements``: the ``calib.`` modules loaded (sorted, those
    starting with ``skip`` left out) and whether numpy is loaded, as printed."""
    code = (
        "import sys\n"
        f"{statements}\n"
        "print(sorted(name for name in sys.modules if name.startswith('calib.')\n"
        f"             and not name.startswith({skip!r})))\n"
        "print('numpy' in sys.modules)\n"
    )
    shown = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    loaded, numpy_loaded = shown.stdout.splitlines()
    return loaded, numpy_loaded


def _printed(code: str) -> str:
    """What ``code`` prints, run in a fresh interpreter (its imports its own)."""
    shown = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    return shown.stdout.strip()


def test_the_calib_command_imports_no_heavy_library() -> None:
    code = (
        "import sys\n"
        "import calib.cli.app\n"
        "app = calib.cli.app.build_app()\n"
        f"print(sorted({{name.split('.')[0] for name in sys.modules}} & set({HEAVY!r})))\n"
    )
    assert _printed(code) == "[]"


def test_building_calib_imports_no_stage() -> None:
    # The command modules import their stages inside the commands: --help, and the parsing of any
    # command, load typer and rich, not numpy or a pipeline stage (about 0.3 s of CPU).
    loaded, numpy_loaded = _loaded_after("import calib.cli.app\ncalib.cli.app.build_app()")
    # calib.core.optics_ranges: the stated optics' ranges (numbers, no imports), the options' own.
    assert loaded == str(["calib.core", "calib.core.errors", "calib.core.optics_ranges"])
    assert numpy_loaded == "False"


def test_the_defaults_and_choices_the_help_shows_are_the_stages_own() -> None:
    from typing import get_args

    from calib.cli import compare, plan_lamps, spd, synthetic, uses, validate
    from calib.core.colour_data import USE_ILLUMINANTS
    from calib.evaluation.compare import DEFAULT_NOISE_LEVELS, DEFAULT_TRANSMISSIVE_PATCHES
    from calib.evaluation.lamp_planning import DEFAULT_NOISE_FRACTION
    from calib.evaluation.synthetic import NOISE_LEVELS
    from calib.evaluation.validation.protocol import DEFAULT_VARIANTS, EXTRA_VARIANTS
    from calib.methods.makabe2025 import MAKABE2025_METHOD
    from calib.methods.multilamp import DEFAULT_EFFICIENCY_TERMS
    from calib.methods.prior_solve import PRIOR_METHOD
    from calib.spd.alvarez2014 import SourceMode, Weighting
    from calib.spd.light_sources import Metric

    assert synthetic.PAPER_METHODS == (PRIOR_METHOD, MAKABE2025_METHOD)
    assert ",".join(f"{n:g}" for n in NOISE_LEVELS) == synthetic.DEFAULT_NOISE
    assert ",".join(f"{n:g}" for n in DEFAULT_NOISE_LEVELS) == compare.DEFAULT_NOISE
    assert compare.DEFAULT_PATCHES == DEFAULT_TRANSMISSIVE_PATCHES
    assert plan_lamps.DEFAULT_NOISE_FRACTION == DEFAULT_NOISE_FRACTION
    assert plan_lamps.DEFAULT_EFFICIENCY_TERMS == DEFAULT_EFFICIENCY_TERMS
    assert get_args(spd.SourceMode) == get_args(SourceMode)
    assert get_args(spd.Weighting) == get_args(Weighting)
    assert get_args(spd.Metric) == get_args(Metric)
    assert tuple(uses.use_illuminants()) == tuple(USE_ILLUMINANTS)
    labels = validate.validation_variants()[0].split("; ")
    assert labels == [v.label for v in (*DEFAULT_VARIANTS, *EXTRA_VARIANTS)]


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
    loaded, numpy_loaded = _loaded_after("import calib.cli.options", skip="calib.none")
    assert loaded == str(
        [
            "calib.cli",
            "calib.cli.command_line",
            "calib.cli.options",
            "calib.core",
            "calib.core.errors",
            "calib.core.optics_ranges",
        ]
    )
    assert numpy_loaded == "False"


def test_building_rig_imports_no_numpy() -> None:
    # rig's errors (rig.errors → drivers.base) load with every command: `rig --help` and the
    # parsing of any command need typer and rich, not numpy (its import is most of rig's start).
    code = (
        "import contextlib, io, sys\n"
        "import typer\n"
        "import rig.cli\n"
        "typer.main.get_command(rig.cli.app)\n"
        "with contextlib.redirect_stdout(io.StringIO()) as shown:\n"
        "    try:\n"
        "        rig.cli.main(['--help'])\n"
        "    except SystemExit as exc:\n"
        "        assert exc.code == 0, exc.code\n"
        "assert 'capture' in shown.getvalue()\n"
        f"print(sorted({{name.split('.')[0] for name in sys.modules}} & {{'numpy', *{HEAVY!r}}}))\n"
    )
    assert _printed(code) == "[]"
