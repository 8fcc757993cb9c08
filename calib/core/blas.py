"""The estimators' linear algebra runs on one BLAS thread.

The solves here are small (tens to a few hundred unknowns) and many: the mapping search alone makes
hundreds of batched solves per camera. A multi-threaded BLAS gains nothing on such sizes, and when the
machine is busy its spinning threads lose badly: measured on 2 cores with a load average of 6, one
``makabe2025`` estimate took 12.3 s with OpenBLAS' default two threads and 0.9 s with one. So every
public entry point that solves runs under :func:`one_blas_thread` (threadpoolctl; about 0.4 ms to
enter), whatever the caller's process-wide setting; element-wise numpy work (RAW decoding, the HDR
merge) does not use BLAS and is unaffected. Entry points call one another (an estimate's σ budget
re-runs the method, which finds a mapping …): only the outermost entry in a thread sets the limit,
the nested ones run inside it. Listing the loaded libraries is most of an entry's cost (about
0.8 ms, 2 % of a solve: 0056, 0083), so the listing is kept and made anew only when a module was
imported since (a library a new extension module brought would otherwise run unlimited).
"""

from __future__ import annotations

import functools
import sys
import threading
from collections.abc import Callable
from typing import ParamSpec, TypeVar

import numpy as np
from threadpoolctl import ThreadpoolController

from calib.core.arrays import FloatArray

P = ParamSpec("P")
R = TypeVar("R")

_inside = threading.local()
#: The loaded libraries' controller and the number of imported modules when it was made.
_controller: tuple[int, ThreadpoolController] | None = None


def blas_controller() -> ThreadpoolController:
    """The controller of the loaded BLAS libraries, listed anew when a module was imported since
    the last listing (``sys.modules`` grew: an extension module may have brought a library)."""
    global _controller
    modules = len(sys.modules)
    if _controller is None or _controller[0] != modules:
        _controller = (modules, ThreadpoolController())
    return _controller[1]


def one_blas_thread(function: Callable[P, R]) -> Callable[P, R]:
    """Run ``function`` with every loaded BLAS library limited to one thread (restored after)."""

    @functools.wraps(function)
    def limited(*args: P.args, **kwargs: P.kwargs) -> R:
        if getattr(_inside, "limited", False):
            return function(*args, **kwargs)
        with blas_controller().limit(limits=1, user_api="blas"):
            _inside.limited = True
            try:
                return function(*args, **kwargs)
            finally:
                _inside.limited = False

    return limited


def pinv_symmetric(matrix: FloatArray) -> FloatArray:
    """``numpy.linalg.pinv(matrix, hermitian=True)`` for a real symmetric matrix, to the bit, at
    half its cost: the same eigendecomposition, ordering, cutoff (``1e-15`` of the largest
    magnitude) and product, without the general routine's per-call checks and stacked-array
    indexing (the solves take hundreds of pseudo-inverses of matrices of 8–31 rows per estimate,
    where that overhead is most of the time; decision 0083). The eigenvectors are reordered into a
    C-ordered array, as numpy's ``take_along_axis`` leaves them: the final product's BLAS call then
    sees the same memory layout and gives the same bits."""
    values, vectors = np.linalg.eigh(matrix)
    signs = np.copysign(1.0, values)
    values = np.abs(values)
    order = np.argsort(values)[::-1]
    signs = signs[order]
    values = values[order]
    vectors = np.ascontiguousarray(vectors[:, order])
    right = np.transpose(vectors * signs[None, :]).conjugate()
    large = values > 1e-15 * values.max()
    inverse = np.divide(1, values, where=large, out=values)
    inverse[~large] = 0
    return np.asarray(
        np.matmul(np.transpose(right), np.multiply(inverse[:, None], np.transpose(vectors))),
        dtype=np.float64,
    )


def pinv_symmetric_stack(matrices: FloatArray) -> FloatArray:
    """:func:`calib.core.blas.pinv_symmetric` of each matrix of a stack ``(k, n, n)``, to the bit,
    in one pass: the same ``eigh``, the same ordering, cutoff and final product per matrix. The
    reordering by plain indexing (copies of the same numbers into a new C-ordered array, as
    ``take_along_axis`` made them at three times the call's cost: decision 0146). One call's
    overhead for a stack instead of one per matrix (decisions 0107, 0132, 0146)."""
    values, vectors = np.linalg.eigh(matrices)
    signs = np.copysign(1.0, values)
    values = np.abs(values)
    order = np.argsort(values, axis=-1)[..., ::-1]
    lead = np.arange(order.shape[0])[:, None]
    signs = signs[lead, order]
    values = values[lead, order]
    vectors = vectors[lead[:, :, None], np.arange(order.shape[1])[None, :, None], order[:, None, :]]
    right = np.swapaxes(vectors * signs[..., None, :], -1, -2)
    large = values > 1e-15 * values.max(axis=-1, keepdims=True)
    inverse = np.divide(1, values, where=large, out=values)
    inverse[~large] = 0
    return np.asarray(
        np.matmul(np.swapaxes(right, -1, -2), inverse[..., :, None] * np.swapaxes(vectors, -1, -2)),
        dtype=np.float64,
    )
