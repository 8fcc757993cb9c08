"""The architecture's one-way dependencies, checked on the source (DESIGN.md, "Data flow")."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HARDWARE_MODULES = {"serial", "usb", "gphoto2"}
#: package -> project packages it must not import
FORBIDDEN = {
    "calib": {"rig", "drivers", "mocks"},
    "drivers": {"rig", "calib", "mocks"},
    "mocks": {"rig"},
}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_imports_point_one_way(package: str) -> None:
    offenders = {
        str(path.relative_to(ROOT)): sorted(_imports(path) & FORBIDDEN[package])
        for path in (ROOT / package).rglob("*.py")
    }
    assert {k: v for k, v in offenders.items() if v} == {}


def test_calib_imports_no_hardware_library() -> None:
    offenders = {
        str(path.relative_to(ROOT)): sorted(_imports(path) & HARDWARE_MODULES)
        for path in (ROOT / "calib").rglob("*.py")
    }
    assert {k: v for k, v in offenders.items() if v} == {}
