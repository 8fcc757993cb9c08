"""A Ctrl-C inside a typer command ends with one line on stderr (typer itself exits silently)."""

from __future__ import annotations

import pytest
import typer
from typer.testing import CliRunner

from calib.cli.exits import interrupted, say_interrupted


def _app_interrupted_inside_a_command() -> typer.Typer:
    app = typer.Typer()

    @app.command()
    def run() -> None:
        raise KeyboardInterrupt

    @app.command()
    def other() -> None:
        raise typer.Exit(130)

    return app


def test_typer_s_exit_for_a_ctrl_c_is_recognised(capsys: pytest.CaptureFixture[str]) -> None:
    app = _app_interrupted_inside_a_command()
    with pytest.raises(SystemExit) as exit_:
        app(["run"], standalone_mode=True)
    assert exit_.value.code == 130
    assert interrupted(exit_.value)
    say_interrupted(exit_.value, "rig")
    assert capsys.readouterr().err == "rig: interrupted\n"


def test_a_command_s_own_exit_130_is_not_a_ctrl_c(capsys: pytest.CaptureFixture[str]) -> None:
    app = _app_interrupted_inside_a_command()
    with pytest.raises(SystemExit) as exit_:
        app(["other"], standalone_mode=True)
    assert exit_.value.code == 130 and not interrupted(exit_.value)
    say_interrupted(exit_.value, "rig")
    assert capsys.readouterr().err == ""
    assert CliRunner().invoke(app, ["other"]).exit_code == 130
