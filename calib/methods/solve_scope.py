"""What one estimate's σ budget re-solves share with the estimate itself (decision 0031).

The σ budget (:mod:`calib.methods.uncertainty`) re-runs the method with its mapping fixed, once per
perturbation (the spectrometer's wavelength scale and bandwidth, the η model's terms). Each re-run
used to repeat the whole solve, and the solve's grating-model choice (a Fourier solve under the
camera prior plus two physical fits, each a 120-point scan refined three times) is most of it. Two
things are shared, inside one :func:`solve_scope` (opened by :func:`calib.methods.estimate` around
the method and its budget):

*Identical sub-solves* (:func:`reuse`). A deterministic sub-solve whose inputs are the same, to the
bit, as one already made in the scope returns that result: e.g. the η-terms perturbation changes
only the prior solve's Fourier basis, so the grating-model choice from the same lamps is the one
already made. The key is a digest of the inputs' content (:func:`fingerprint`), never an object's
identity, so a changed input can never hit a stale result.

*Warm starts* (:func:`remember_start`, :func:`warm_start`). Inside :func:`perturbation` (the
budget's re-runs), a sub-solve may start from the main solve's solution of the same problem (same
lamps, same model) instead of from scratch: a physical grating's parameter is refined in a window
around the main fit's instead of scanned over its whole range. A start is only a start: where the
perturbed optimum is not inside the window, the sub-solve falls back to the full search
(:func:`calib.methods.multilamp.solve_efficiency`).

Outside a scope (a method called directly) nothing is shared and every solve runs in full.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, TypeVar, cast

import numpy as np

T = TypeVar("T")


@dataclass(eq=False)
class SolveScope:
    """The shared state of one estimate and its budget's re-solves.

    Attributes
    ----------
    results
        Sub-solve results by the digest of their inputs (:func:`reuse`).
    starts
        The main solve's solutions by what they solve (:func:`remember_start`).
    perturbed
        Inside a perturbation re-solve (:func:`perturbation`): warm starts are offered.
    reused, warm_started
        How many sub-solves were answered from :attr:`results`, and how many starts were handed
        out (a record for tests and profiles).
    """

    results: dict[bytes, Any] = field(default_factory=dict)
    starts: dict[str, Any] = field(default_factory=dict)
    perturbed: bool = False
    reused: int = 0
    warm_started: int = 0


_SCOPE: ContextVar[SolveScope | None] = ContextVar("calib_solve_scope", default=None)


@contextmanager
def solve_scope(shared: bool = True) -> Iterator[SolveScope | None]:
    """Share sub-solves until the block ends (a scope already open is joined, not replaced);
    ``shared=False``: nothing is shared inside the block, not even an enclosing scope's."""
    current = _SCOPE.get()
    if not shared:
        token = _SCOPE.set(None)
        try:
            yield None
        finally:
            _SCOPE.reset(token)
        return
    if current is not None:
        yield current
        return
    scope = SolveScope()
    token = _SCOPE.set(scope)
    try:
        yield scope
    finally:
        _SCOPE.reset(token)


@contextmanager
def perturbation() -> Iterator[None]:
    """Mark the solves in the block as re-solves of a perturbed problem (warm starts allowed);
    without an open scope, nothing."""
    scope = _SCOPE.get()
    if scope is None:
        yield
        return
    previous = scope.perturbed
    scope.perturbed = True
    try:
        yield
    finally:
        scope.perturbed = previous


def _feed(digest: Any, value: object) -> None:
    """Add ``value``'s content to ``digest`` (arrays by dtype, shape and bytes; dataclasses by
    their fields; sequences and mappings element by element; scalars by ``repr``)."""
    if isinstance(value, np.ndarray):
        digest.update(f"a{value.dtype.str}{value.shape}".encode())
        digest.update(np.ascontiguousarray(value).tobytes())
    elif is_dataclass(value) and not isinstance(value, type):
        digest.update(f"d{type(value).__qualname__}".encode())
        for item in fields(value):
            digest.update(item.name.encode())
            _feed(digest, getattr(value, item.name))
    elif isinstance(value, list | tuple):
        digest.update(f"s{len(value)}".encode())
        for item in value:
            _feed(digest, item)
    elif isinstance(value, dict):
        digest.update(f"m{len(value)}".encode())
        for key in sorted(value, key=repr):
            _feed(digest, key)
            _feed(digest, value[key])
    elif value is None or isinstance(value, bool | int | float | str | np.number):
        digest.update(f"v{type(value).__name__}{value!r}".encode())
    else:
        raise TypeError(f"no content digest for {type(value).__name__}")


def fingerprint(*parts: object) -> bytes:
    """A digest of the parts' content (BLAKE2b, 16 bytes): equal only for equal content."""
    digest = hashlib.blake2b(digest_size=16)
    for part in parts:
        _feed(digest, part)
    return digest.digest()


def recall(label: str, parts: tuple[object, ...]) -> Any:
    """The result of ``label`` already computed in the open scope from inputs ``parts``, else
    ``None``."""
    scope = _SCOPE.get()
    if scope is None:
        return None
    value = scope.results.get(fingerprint(label, *parts))
    if value is not None:
        scope.reused += 1
    return value


def reuse(
    label: str, parts: tuple[object, ...], compute: Callable[[], T], *, strict: bool = True
) -> T:
    """``compute()``, or the result already computed in the open scope from the same ``label`` and
    inputs ``parts`` (everything ``compute`` reads must be in them); outside a scope: ``compute()``.

    A part with no content digest (:func:`fingerprint`) raises :class:`TypeError`; with
    ``strict=False`` the result is computed and not shared (inputs that carry whatever a reader
    put in them, e.g. an observation's ``metadata``)."""
    scope = _SCOPE.get()
    if scope is None:
        return compute()
    try:
        key = fingerprint(label, *parts)
    except TypeError:
        if strict:
            raise
        return compute()
    if key in scope.results:
        scope.reused += 1
        return cast(T, scope.results[key])
    value = compute()
    scope.results[key] = value
    return value


def remember_start(label: str, value: object) -> None:
    """Record the main solve's solution of ``label`` (the first one; re-solves record nothing)."""
    scope = _SCOPE.get()
    if scope is not None and not scope.perturbed:
        scope.starts.setdefault(label, value)


def warm_start(label: str) -> Any:
    """The main solve's solution of ``label`` inside a perturbation re-solve, else ``None``."""
    scope = _SCOPE.get()
    if scope is None or not scope.perturbed or label not in scope.starts:
        return None
    scope.warm_started += 1
    return scope.starts[label]
