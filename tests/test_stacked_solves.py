"""Decision 0146: the solve's per-channel pseudo-inverses and whitenings made in stacked calls, and
the solve scope's digests reading a dataclass type's fields once — the same numbers and digests."""

from __future__ import annotations

from dataclasses import dataclass, fields, is_dataclass
from types import SimpleNamespace
from typing import Any, cast

import numpy as np

from calib.core.blas import pinv_symmetric, pinv_symmetric_stack
from calib.methods.multilamp import prior_rows
from calib.methods.solve_scope import _dataclass_shape, fingerprint, solve_scope
from calib.model.bases import whitening


def _spd(rng: np.random.Generator, size: int) -> np.ndarray:
    factor = rng.standard_normal((size, size))
    return np.asarray(factor @ factor.T + 1e-3 * np.eye(size), dtype=np.float64)


def test_the_stacked_pseudo_inverse_is_each_matrixs_to_the_bit_for_the_response_fits_size():
    """The response fit's three 31 × 31 normal matrices (decision 0146), also singular ones."""
    rng = np.random.default_rng(5)
    low_rank = rng.standard_normal((31, 6))
    stack = np.stack([_spd(rng, 31), low_rank @ low_rank.T, 1e8 * _spd(rng, 31)])
    stacked = pinv_symmetric_stack(stack)
    assert stacked.flags.c_contiguous
    for matrix, inverse in zip(stack, stacked, strict=True):
        assert np.array_equal(inverse, pinv_symmetric(matrix))


def test_the_fourier_models_prior_rows_whiten_each_channel_as_whitening_does():
    """:func:`prior_rows` whitens its three channels' spreads in one stacked call: every row the
    one :func:`whitening` of the channel's spread alone gives, to the bit."""
    rng = np.random.default_rng(7)
    size, terms = 31, 7
    prior = SimpleNamespace(
        covariance=np.stack([_spd(rng, size) for _ in range(3)]),
        mean=rng.uniform(0.1, 1.0, (size, 3)),
    )
    reference = SimpleNamespace(
        covariance=np.stack([1e-3 * _spd(rng, size) for _ in range(3)]),
        response=rng.uniform(0.1, 1.0, (size, 3)),
    )
    basis = rng.standard_normal((size, terms))
    inverse = rng.uniform(0.5, 2.0, size)
    rows = prior_rows(cast(Any, reference), cast(Any, prior), basis, inverse, 1.7)
    for c in range(3):
        spread = 1.7**2 * prior.covariance[c] + (
            inverse[:, None] * reference.covariance[c] * inverse[None, :]
        )
        factor = whitening(spread)
        block = rows[c * size : (c + 1) * size]
        assert np.array_equal(
            block[:, :terms], factor @ (reference.response[:, c][:, None] * basis)
        )
        assert np.array_equal(block[:, -1], -(factor @ prior.mean[:, c]))


@dataclass(frozen=True)
class _Frozen:
    values: np.ndarray
    label: str


@dataclass
class _Open:
    values: np.ndarray


def test_a_dataclass_types_shape_is_what_dataclasses_says():
    for kind, frozen in ((_Frozen, True), (_Open, False)):
        shape = _dataclass_shape(kind)
        assert shape is not None and is_dataclass(kind)
        assert [name for name, _ in shape.fields] == [item.name for item in fields(kind)]
        assert shape.frozen == frozen
        assert shape.prefix == f"d{kind.__qualname__}".encode()
    # A class object (its type is ``type``), an array and a scalar are not dataclass instances.
    for other in (type, np.ndarray, float, tuple):
        assert _dataclass_shape(other) is None


def test_a_digest_reads_the_same_fields_in_and_out_of_a_scope():
    values = np.arange(4.0)
    values.flags.writeable = False
    frozen, changed = _Frozen(values, "a"), _Frozen(values, "b")
    outside = fingerprint(frozen, _Open(values.copy()))
    with solve_scope():
        assert fingerprint(frozen, _Open(values.copy())) == outside
        assert fingerprint(frozen, _Open(values.copy())) == outside  # read from the scope
        assert fingerprint(changed, _Open(values.copy())) != outside


def test_a_scalar_is_fed_by_its_type_name_and_repr_whichever_path_reads_it():
    """Plain scalars are read first (a search's details hold hundreds); a subclass (numpy's
    ``float64`` is a ``float``) takes the general path: both feed ``v``, the type's name and
    the ``repr``."""
    import hashlib

    def expected(*encoded: str) -> bytes:
        digest = hashlib.blake2b(digest_size=16)
        for text in encoded:
            digest.update(text.encode())
        return digest.digest()

    assert fingerprint(1.5, 2, True, "x", None) == expected(
        "vfloat1.5", "vint2", "vboolTrue", "vstr'x'", "vNoneTypeNone"
    )
    value = np.float64(1.5)
    assert fingerprint(value) == expected(f"vfloat64{value!r}")
