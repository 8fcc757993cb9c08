"""``rig init``: commented configurations for every mix of real and twin devices, the packaged twin
configuration (the repository's ``config.yaml``), and a new user's first commands from an empty
directory."""

from __future__ import annotations

import itertools
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from rig.config import ConfigError, parse_config
from rig.init_config import KINDS, TWIN, packaged_twin_config, render_config
from tests.rig.test_cli import run_cli

ROOT = Path(__file__).resolve().parents[2]


def test_the_repositorys_config_is_the_packaged_twin_configuration() -> None:
    assert (ROOT / "config.yaml").read_text(encoding="utf-8") == packaged_twin_config()


REAL = list(
    itertools.product(
        *(kinds[1:] for kinds in (KINDS["spectrometer"], KINDS["relays"], KINDS["camera"]))
    )
)


@pytest.mark.parametrize(("spectrometer", "relays", "camera"), REAL)
def test_every_real_rig_gets_a_valid_commented_configuration(
    spectrometer: str, relays: str, camera: str, tmp_path: Path
) -> None:
    text = render_config(spectrometer, relays, camera)
    config = parse_config(text, "config.yaml", tmp_path)
    assert config.devices.twin_roles() == ()
    assert config.devices.spectrometer.kind == spectrometer
    assert config.devices.relays.kind == relays and config.devices.camera.kind == camera
    for kind in (spectrometer, relays, camera):  # every device block says what it is
        (line,) = [line for line in text.splitlines() if line.strip().startswith(f"kind: {kind}")]
        assert "# " in line


@pytest.mark.parametrize(
    ("spectrometer", "camera"),
    [(kind, TWIN) for kind in KINDS["spectrometer"][1:]] + [(TWIN, "gphoto2")],
)
def test_real_devices_beside_the_twins_lamps(
    spectrometer: str, camera: str, tmp_path: Path
) -> None:
    config = parse_config(render_config(spectrometer, TWIN, camera), "config.yaml", tmp_path)
    assert "relays" in config.devices.twin_roles()


def test_rig_init_from_an_empty_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert run_cli(["init", "--twin"], monkeypatch) == 0
    assert (tmp_path / "config.yaml").read_text() == packaged_twin_config()
    assert "next: rig demo" in capsys.readouterr().out
    assert run_cli(["init", "--twin"], monkeypatch) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    arguments = ["init", "--spectrometer", "seabreeze", "--relays", "lcus", "-o", "rig.yaml"]
    assert run_cli(arguments, monkeypatch) == 0
    assert "spectrometer seabreeze, relays lcus, camera gphoto2" in capsys.readouterr().out
    text = (tmp_path / "rig.yaml").read_text()
    assert "rig calibrate-spectrometer --lamp A" in text and "port: /dev/ttyUSB0" in text
    assert (
        run_cli(["init", "--camera", "twin", "--relays", "lcus", "-o", "bad.yaml"], monkeypatch)
        == 2
    )
    assert "the relays must be 'twin' too" in capsys.readouterr().err
    assert not (tmp_path / "bad.yaml").exists()
    assert run_cli(["dry-run", "--summary"], monkeypatch) == 0


def test_a_missing_configuration_says_how_to_write_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert run_cli(["dry-run"], monkeypatch) == 2
    assert "`rig init --twin`" in capsys.readouterr().err
    with pytest.raises(ConfigError):
        parse_config("devices: {}\n", "x.yaml")


@pytest.mark.slow
def test_init_then_demo_in_a_fresh_directory_with_the_installed_command(tmp_path: Path) -> None:
    """What a new user types: ``cd /tmp && rig init --twin && rig demo`` (the console script)."""
    rig = shutil.which("rig", path=str(Path(sys.executable).parent))
    assert rig is not None, "the rig console script is not installed next to this Python"
    subprocess.run([rig, "init", "--twin"], cwd=tmp_path, check=True, capture_output=True)
    done = subprocess.run(
        [rig, "demo", "-q"], cwd=tmp_path, check=True, capture_output=True, text=True
    )
    assert "RE against the twin's camera" in done.stdout
