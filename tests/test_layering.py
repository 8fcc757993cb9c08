"""The architecture's one-way dependencies, checked on the source (DESIGN.md, "Data flow")."""

from __future__ import annotations

import ast
import functools
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


@functools.cache
def _nodes(path: Path) -> tuple[ast.AST, ...]:
    """Every node of ``path``'s syntax tree (parsed once per process: the tests here share them)."""
    return tuple(ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))))


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in _nodes(path):
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


#: calib's stage packages, lowest first: a module may import its own stage and the ones below it.
CALIB_STAGES = (
    "core",
    "model",
    "image",
    "wavelength",
    "methods",
    "spd",
    "use",
    "pipeline",
    "evaluation",
    "cli",
)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _calib_imports(path: Path) -> set[str]:
    """Every ``calib.*`` module ``path`` imports, at module level or inside a function."""
    names: set[str] = set()
    for node in _nodes(path):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names if alias.name.startswith("calib."))
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module == "calib":
                names.update(f"calib.{alias.name}" for alias in node.names)
            elif node.module.startswith("calib."):
                names.add(node.module)
    return names


def _stage(module: str) -> int:
    parts = module.split(".")
    if len(parts) < 2 or parts[1] not in CALIB_STAGES:
        return -1
    return CALIB_STAGES.index(parts[1])


def test_every_calib_module_sits_in_a_stage_package() -> None:
    loose = [
        _module_name(path)
        for path in (ROOT / "calib").rglob("*.py")
        if _module_name(path) != "calib" and _stage(_module_name(path)) < 0
    ]
    assert loose == []


def test_calib_stages_import_only_downward() -> None:
    upward = {}
    for path in (ROOT / "calib").rglob("*.py"):
        module = _module_name(path)
        above = sorted(m for m in _calib_imports(path) if _stage(m) > _stage(module))
        if above:
            upward[module] = above
    assert upward == {}


def test_calib_modules_import_one_another_without_a_cycle() -> None:
    graph = {_module_name(path): _calib_imports(path) for path in (ROOT / "calib").rglob("*.py")}
    known = set(graph)
    # A package's __init__ re-exporting its modules is not a cycle of the data flow.
    edges = {
        module: {
            target
            for target in targets
            if target in known and not module.startswith(f"{target}.") and target != module
        }
        for module, targets in graph.items()
    }
    state: dict[str, int] = {}
    cycle: list[str] = []

    def visit(node: str, trail: list[str]) -> bool:
        state[node] = 1
        for target in sorted(edges[node]):
            if state.get(target) == 1:
                cycle.extend([*trail, node, target])
                return True
            if state.get(target) is None and visit(target, [*trail, node]):
                return True
        state[node] = 2
        return False

    for module in sorted(edges):
        if state.get(module) is None and visit(module, []):
            break
    assert cycle == []
