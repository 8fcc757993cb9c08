"""Repository-wide pytest set-up: the doctests in ``calib/`` and the tests in ``tests/`` share it."""

from __future__ import annotations

import signal
from collections.abc import Iterator

import numpy as np
import pytest

# A shell starts a background job (`make test &`) with SIGINT ignored, and every process it starts
# inherits that (POSIX). The signal tests send Ctrl-C to `rig` children and expect what a user at a
# terminal gets, so the test processes take Python's own handler back; their children then start
# with the default disposition.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(autouse=True, scope="session")
def _children_keep_their_temporary_files_in_this_run(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[None]:
    """Child processes make their temporary files under this run's own directory.

    The crash tests kill ``rig`` children with SIGKILL, which leaves the twin camera's scratch
    directory behind (a killed process removes nothing). Under the run's directory, pytest prunes
    it with the run's other files instead of it staying in the system's temporary directory.
    """
    scratch = tmp_path_factory.mktemp("children-tmp", numbered=False)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("TMPDIR", str(scratch))
        yield


@pytest.fixture(autouse=True)
def _numpy_prints_as_documented() -> Iterator[None]:
    """NumPy's current print style for every test and docstring example.

    Importing colour-science directly (some tests do) switches NumPy's global print options to the
    1.13 legacy style; the examples in the docstrings show today's style.
    """
    with np.printoptions(legacy=False):
        yield
