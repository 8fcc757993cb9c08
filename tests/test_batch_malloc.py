"""A batch worker's allocator settings: roomy for an estimate, the worker's own put back after a
Dask task (what ``MALLOC_TRIM_THRESHOLD_`` says, or glibc's initial values), memory trimmed."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from calib.pipeline import batch_malloc
from calib.pipeline.batch_malloc import (
    GLIBC_MMAP_THRESHOLD_BYTES,
    ROOMY_MMAP_THRESHOLD_BYTES,
    ROOMY_TRIM_THRESHOLD_BYTES,
    allocator_for_task,
    roomy_allocator,
)


class RecordedLibc:
    def __init__(self) -> None:
        self.calls: list[tuple[str, int, int]] = []

    def mallopt(self, parameter: int, value: int) -> int:
        self.calls.append(("mallopt", parameter, value))
        return 1

    def malloc_trim(self, pad: int) -> int:
        self.calls.append(("malloc_trim", pad, 0))
        return 1


@pytest.fixture
def libc(monkeypatch: pytest.MonkeyPatch) -> RecordedLibc:
    recorded = RecordedLibc()
    monkeypatch.setattr(batch_malloc, "_glibc", lambda: recorded)
    return recorded


def test_a_task_runs_roomy_and_puts_the_workers_settings_back(
    libc: RecordedLibc, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")  # what a Dask nanny sets
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    with allocator_for_task():
        assert libc.calls == [
            ("mallopt", batch_malloc.M_TRIM_THRESHOLD, ROOMY_TRIM_THRESHOLD_BYTES),
            ("mallopt", batch_malloc.M_MMAP_THRESHOLD, ROOMY_MMAP_THRESHOLD_BYTES),
        ]
    assert libc.calls[2:] == [
        ("mallopt", batch_malloc.M_TRIM_THRESHOLD, 65536),
        ("mallopt", batch_malloc.M_MMAP_THRESHOLD, GLIBC_MMAP_THRESHOLD_BYTES),
        ("malloc_trim", 0, 0),
    ]


def test_a_failing_task_puts_the_settings_back_too(libc: RecordedLibc) -> None:
    with pytest.raises(ValueError, match="estimate failed"), allocator_for_task():
        raise ValueError("estimate failed")
    assert libc.calls[-1] == ("malloc_trim", 0, 0)


def test_without_glibc_nothing_is_changed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(batch_malloc, "_glibc", lambda: None)
    assert not roomy_allocator()
    with allocator_for_task():
        pass


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_the_real_allocator_takes_the_settings() -> None:
    if batch_malloc._glibc() is None:
        pytest.skip("not glibc")
    with allocator_for_task():
        assert roomy_allocator()
        block = np.ones(8 * 1024 * 1024)  # 64 MiB, above the roomy mmap threshold
        assert float(block.sum()) == block.size
