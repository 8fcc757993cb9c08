"""Symmetric pseudo-inverses and whitenings of a stack of matrices, each to the bit the one-matrix
routine's (decisions 0107, 0132, 0146).

numpy's stacked ``eigh`` runs LAPACK on each matrix in turn and its stacked ``matmul`` makes each
slice's product with the call a single matrix gets, so a stack costs one call's overhead instead of
one per matrix: the prior solve (the three channels' whitenings and step-3 pseudo-inverses), the
response fit (its three channels' pseudo-inverses), the Fourier η model's prior rows and its
prior-weight scores. Kept here, below :mod:`calib.methods.multilamp`, :mod:`calib.methods.responses`
and :mod:`calib.methods.prior_solve`, which all use them (an import between those would be a cycle).
"""

from __future__ import annotations

import numpy as np

from calib.core.arrays import FloatArray

#: :func:`calib.model.bases.whitening`'s default relative eigenvalue floor, which
#: :func:`whitening_stack` applies to each matrix.
WHITENING_FLOOR = 1e-10


def pinv_symmetric_stack(matrices: FloatArray) -> FloatArray:
    """:func:`calib.core.blas.pinv_symmetric` of each matrix of a stack ``(k, n, n)``, to the bit,
    in one pass: the same ``eigh``, the same ordering, cutoff and final product per matrix. The
    reordering by plain indexing (copies of the same numbers into a new C-ordered array, as
    ``take_along_axis`` made them at three times the call's cost: decision 0146)."""
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


def whitening_stack(covariances: FloatArray) -> FloatArray:
    """:func:`calib.model.bases.whitening` (its default floor) of each matrix of a stack
    ``(k, n, n)``, to the bit, in one pass: the same symmetrisation, ``eigh``, floor (of each
    matrix's own largest eigenvalue) and product per matrix."""
    values, vectors = np.linalg.eigh(0.5 * (covariances + np.swapaxes(covariances, -1, -2)))
    floor = WHITENING_FLOOR * np.maximum(values.max(axis=-1, keepdims=True), 1e-300)
    scaled = vectors / np.sqrt(np.maximum(values, floor))[..., None, :]
    return np.asarray(scaled @ np.swapaxes(vectors, -1, -2), dtype=np.float64)
