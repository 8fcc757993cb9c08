"""The estimators' linear algebra runs on one BLAS thread.

The solves here are small (tens to a few hundred unknowns) and many: the mapping search alone makes
hundreds of batched solves per camera. A multi-threaded BLAS gains nothing on such sizes, and when the
machine is busy its spinning threads lose badly: measured on 2 cores with a load average of 6, one
``makabe2025`` estimate took 12.3 s with OpenBLAS' default two threads and 0.9 s with one. So every
public entry point that solves runs under :func:`one_blas_thread` (threadpoolctl; about 0.4 ms to
enter), whatever the caller's process-wide setting; element-wise numpy work (RAW decoding, the HDR
merge) does not use BLAS and is unaffected. Entry points call one another (an estimate's σ budget
re-runs the method, which finds a mapping …): only the outermost entry in a thread sets the limit,
the nested ones run inside it (each entry lists the loaded libraries anew: 3 % of a solve, 0056).
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from typing import ParamSpec, TypeVar

from threadpoolctl import threadpool_limits

P = ParamSpec("P")
R = TypeVar("R")

_inside = threading.local()


def one_blas_thread(function: Callable[P, R]) -> Callable[P, R]:
    """Run ``function`` with every loaded BLAS library limited to one thread (restored after)."""

    @functools.wraps(function)
    def limited(*args: P.args, **kwargs: P.kwargs) -> R:
        if getattr(_inside, "limited", False):
            return function(*args, **kwargs)
        with threadpool_limits(limits=1, user_api="blas"):
            _inside.limited = True
            try:
                return function(*args, **kwargs)
            finally:
                _inside.limited = False

    return limited
