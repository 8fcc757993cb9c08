"""A benchmark script under ``bench/`` loaded as a module, for the tests that call its functions."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BENCH_DIR = Path(__file__).resolve().parents[1] / "bench"


def load_bench(filename: str) -> ModuleType:
    """``bench/<filename>`` as a module named ``<stem>_bench`` (registered in ``sys.modules`` so
    that its dataclasses resolve their annotations through it), loaded once per process."""
    name = f"{Path(filename).stem}_bench"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, BENCH_DIR / filename)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
