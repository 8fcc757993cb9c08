"""The rig's own layering: plans never import drivers, and no rig module imports mocks."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

RIG = Path(__file__).resolve().parents[2] / "rig"
#: Modules that describe or record, and must not touch (or import) any device code.
DEVICE_FREE = ("plan", "steps", "dryrun", "config", "records", "analysis", "errors")


def imported_packages(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


@pytest.mark.parametrize("module", sorted(p.stem for p in RIG.glob("*.py")))
def test_no_rig_module_imports_mocks(module: str) -> None:
    imported = imported_packages(RIG / f"{module}.py")
    assert not [name for name in imported if name.split(".")[0] == "mocks"]


@pytest.mark.parametrize("module", DEVICE_FREE)
def test_plans_and_records_never_import_drivers(module: str) -> None:
    imported = imported_packages(RIG / f"{module}.py")
    offenders = [
        name
        for name in imported
        if name.split(".")[0] in {"drivers", "serial", "usb", "gphoto2"}
        and not (module == "errors" and name == "drivers.base")
    ]
    assert offenders == []
