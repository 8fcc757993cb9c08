"""The analysis core without the hardware libraries: what an analysis-only installation
(``pip install spectral-rig``, no ``[rig]`` nor ``[sim]``) runs, checked in a fresh interpreter in
which pyserial, pyusb, python-gphoto2 and python-seabreeze cannot be imported."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HARDWARE = ("serial", "usb", "gphoto2", "seabreeze")
BLOCKED = f"""
import importlib.abc, sys
class NotInstalled(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in {HARDWARE!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None
sys.meta_path.insert(0, NotInstalled())
"""


def _run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", BLOCKED + code],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_the_analysis_path_imports_no_hardware_library() -> None:
    done = _run(
        "import calib, calib.pipeline, calib.methods, calib.cli\n"
        "import rig.cli, rig.estimate, rig.compare, rig.session, rig.station, drivers\n"
        "from rig.cli import app\n"
        "loaded = sorted(m for m in sys.modules if m.split('.')[0] in "
        f"{HARDWARE!r})\n"
        "assert not loaded, loaded\n"
        "print('ok')\n"
    )
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_a_hardware_device_names_the_rig_extra() -> None:
    done = _run(
        "from drivers.libraries import HardwareLibraryMissing, pyserial, pyseabreeze\n"
        "for load in (pyserial, pyseabreeze):\n"
        "    try:\n"
        "        load()\n"
        "    except HardwareLibraryMissing as exc:\n"
        "        print(exc)\n"
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.strip().splitlines()
    assert len(lines) == 2
    assert all("pip install 'spectral-rig[rig]'" in line for line in lines)


def test_the_core_dependencies_hold_no_hardware_library() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = {
        requirement.split(">")[0].split(";")[0].strip() for requirement in project["dependencies"]
    }
    assert not names & {"pyserial", "pyusb", "gphoto2", "seabreeze"}
    extras = project["optional-dependencies"]
    assert {"pyserial>=3.5", "pyusb>=1.2.1", "seabreeze>=2.11"} <= set(extras["sim"])
    assert {"pyserial>=3.5", "pyusb>=1.2.1", "seabreeze>=2.11"} <= set(extras["rig"])
    assert any(requirement.startswith("gphoto2") for requirement in extras["rig"])
    (self_extra,) = [r for r in extras["dev"] if r.startswith("spectral-rig[")]
    assert {"rig", "sim"} <= set(self_extra.removeprefix("spectral-rig[").rstrip("]").split(","))


def test_the_twin_without_its_extra_says_which_to_install() -> None:
    done = _run(
        "from rig.errors import StationUnavailable\n"
        "from rig.twin import digital_twin\n"
        "try:\n"
        "    digital_twin()\n"
        "except StationUnavailable as exc:\n"
        "    print(exc)\n"
    )
    assert done.returncode == 0, done.stderr
    assert "pip install 'spectral-rig[sim]'" in done.stdout and "No module named" in done.stdout
