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
    digests
        The digest of an object that cannot change, by its ``id`` (the object kept with it, so
        the ``id`` is not reused while the scope is open): a read-only array whose memory no
        writeable array owns, fed once by content; an array or frozen dataclass a
        :func:`reuse` computed, by where it came from (:func:`_register`).
    content_fed
        The objects (arrays, dataclasses) whose content was fed to a digest and not kept in
        :attr:`digests` (by ``id``, kept alive): never registered afterwards, so that each
        object's digest stays the same for the whole scope.
    """

    results: dict[bytes, Any] = field(default_factory=dict)
    starts: dict[str, Any] = field(default_factory=dict)
    perturbed: bool = False
    reused: int = 0
    warm_started: int = 0
    digests: dict[int, tuple[object, bytes]] = field(default_factory=dict)
    content_fed: dict[int, object] = field(default_factory=dict)


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


def _unchangeable(array: np.ndarray) -> bool:
    """Whether no writeable array reaches ``array``'s memory: it and every array it views are
    read-only (the project's frozen arrays: ``flags.writeable = False`` on an array that owns its
    copy), down to an owner that is an array or ``bytes``."""
    value: object = array
    while isinstance(value, np.ndarray):
        if value.flags.writeable:
            return False
        if value.base is None:
            return True
        value = value.base
    return isinstance(value, bytes)


def _array_digest(value: np.ndarray) -> bytes:
    """An array's own digest: dtype, shape and bytes."""
    if value.dtype.hasobject:
        raise TypeError("no content digest for an array of Python objects")
    digest = hashlib.blake2b(digest_size=16)
    digest.update(f"a{value.dtype.str}{value.shape}".encode())
    digest.update(np.ascontiguousarray(value).tobytes())
    return digest.digest()


#: The scalar types :func:`_feed` reads first (by exact type; a subclass takes the general path,
#: which feeds the same bytes).
_PLAIN_SCALARS = frozenset({bool, int, float, str})


def _feed(digest: Any, value: object, scope: SolveScope | None = None) -> bool:
    """Add ``value``'s content to ``digest`` (arrays by dtype, shape and bytes; dataclasses by
    their fields; sequences and mappings element by element; scalars by ``repr``; an array's and
    a dataclass's content through a digest of its own). Returns whether the content cannot
    change: a scalar, a read-only array no writeable array reaches (:func:`_unchangeable`), a
    tuple or frozen dataclass of such.

    In an open ``scope`` an object already in :attr:`SolveScope.digests` is fed by its recorded
    digest, and an array or frozen dataclass whose content cannot change is recorded there the
    first time it is fed: its bytes are read once per scope."""
    if value is None or type(value) in _PLAIN_SCALARS:
        # (A scalar first, by its exact type: a search's details hold hundreds of them.)
        digest.update(f"v{type(value).__name__}{value!r}".encode())
        return True
    is_array = isinstance(value, np.ndarray)
    shape = None if is_array else _dataclass_shape(type(value))
    if scope is not None and (is_array or shape is not None):
        known = scope.digests.get(id(value))
        if known is not None and known[0] is value:
            digest.update(b"k")
            digest.update(known[1])
            return True
    if isinstance(value, np.ndarray):
        own = _array_digest(value)
        fixed = _unchangeable(value)
    elif shape is not None:
        inner = hashlib.blake2b(digest_size=16)
        inner.update(shape.prefix)
        fixed = shape.frozen
        for name, encoded in shape.fields:
            inner.update(encoded)
            fixed = _feed(inner, getattr(value, name), scope) and fixed
        own = inner.digest()
    elif isinstance(value, list | tuple):
        digest.update(f"s{len(value)}".encode())
        fixed = isinstance(value, tuple)
        for item in value:
            fixed = _feed(digest, item, scope) and fixed
        return fixed
    elif isinstance(value, dict):
        digest.update(f"m{len(value)}".encode())
        for key in sorted(value, key=repr):
            _feed(digest, key, scope)
            _feed(digest, value[key], scope)
        return False
    elif value is None or isinstance(value, bool | int | float | str | np.number):
        digest.update(f"v{type(value).__name__}{value!r}".encode())
        return True
    else:
        raise TypeError(f"no content digest for {type(value).__name__}")
    if scope is not None:
        if fixed:
            scope.digests[id(value)] = (value, own)
        else:
            scope.content_fed[id(value)] = value
    digest.update(b"k")
    digest.update(own)
    return fixed


@dataclass(frozen=True)
class _DataclassShape:
    """What :func:`_feed` and :func:`_register` read of a dataclass type: the digest's prefix
    (``d`` and the qualified name, encoded), whether it is frozen, and its fields' names (each
    with its encoding)."""

    prefix: bytes
    frozen: bool
    fields: tuple[tuple[str, bytes], ...]


#: :class:`_DataclassShape` by type, ``None`` for a type that is not a dataclass: the same
#: answers as ``dataclasses.is_dataclass``, ``fields`` and ``__dataclass_params__`` on each call,
#: looked up once per type (the digests of one estimate walk ~1000 objects: decision 0146).
_SHAPES: dict[type, _DataclassShape | None] = {}


def _dataclass_shape(kind: type) -> _DataclassShape | None:
    """:class:`_DataclassShape` of ``kind`` (the type of an object), ``None`` unless it is a
    dataclass (a class object's type is ``type`` or a metaclass: not a dataclass instance)."""
    try:
        return _SHAPES[kind]
    except KeyError:
        pass
    shape = None
    if is_dataclass(kind):
        parameters = getattr(kind, "__dataclass_params__", None)
        shape = _DataclassShape(
            f"d{kind.__qualname__}".encode(),
            parameters is not None and bool(parameters.frozen),
            tuple((item.name, item.name.encode()) for item in fields(kind)),
        )
    _SHAPES[kind] = shape
    return shape


def _kept(value: object) -> bool:
    """Whether ``value`` is an object :attr:`SolveScope.digests` may hold: an array or a
    dataclass instance."""
    return isinstance(value, np.ndarray) or _dataclass_shape(type(value)) is not None


def _register(scope: SolveScope, origin: bytes, value: object) -> bool:
    """Record, in ``scope``, the digest of each array and frozen dataclass in ``value`` (what a
    :func:`reuse` computed from inputs of digest ``origin``) as its place in the result: the
    result is determined by its inputs (what :func:`reuse` rests on), and a result handed to
    more than one caller is never modified (each would see the other's change), so the place is
    as good a digest as the content, without reading it again for each lookup. Tuples, lists and
    frozen dataclasses are walked; dictionaries and other objects are not (their content is fed
    as before). An object already fed by content in the scope (an input passed through, say)
    keeps its content digest. Returns whether all of ``value`` is recorded."""

    def walk(item: object, place: str) -> bool:
        if _kept(item):
            known = scope.digests.get(id(item))
            if known is not None and known[0] is item:
                return True
            if id(item) in scope.content_fed:
                return False
        if isinstance(item, np.ndarray):
            if item.dtype.hasobject:
                return False
            token = hashlib.blake2b(origin + place.encode(), digest_size=16).digest()
            scope.digests[id(item)] = (item, token)
            return True
        if isinstance(item, list | tuple):
            done = True
            for index, part in enumerate(item):  # every part, also after one not recorded
                done = walk(part, f"{place}/{index}") and done
            return done
        shape = _dataclass_shape(type(item))
        if shape is not None:
            inner = True
            for name, _ in shape.fields:
                inner = walk(getattr(item, name), f"{place}.{name}") and inner
            if not (inner and shape.frozen):
                return False
            token = hashlib.blake2b(origin + place.encode(), digest_size=16).digest()
            scope.digests[id(item)] = (item, token)
            return True
        return item is None or isinstance(item, bool | int | float | str | np.number)

    return walk(value, "r")


def fingerprint(*parts: object) -> bytes:
    """A digest of the parts' content (BLAKE2b, 16 bytes): equal only for equal content.

    Inside an open scope, objects that cannot change are read once (:attr:`SolveScope.digests`)."""
    return _fingerprint(_SCOPE.get(), parts)


def _fingerprint(scope: SolveScope | None, parts: tuple[object, ...]) -> bytes:
    digest = hashlib.blake2b(digest_size=16)
    for part in parts:
        _feed(digest, part, scope)
    return digest.digest()


def recall(label: str, parts: tuple[object, ...]) -> Any:
    """The result of ``label`` already computed in the open scope from inputs ``parts``, else
    ``None``."""
    scope = _SCOPE.get()
    if scope is None:
        return None
    value = scope.results.get(_fingerprint(scope, (label, *parts)))
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
        key = _fingerprint(scope, (label, *parts))
    except TypeError:
        if strict:
            raise
        return compute()
    if key in scope.results:
        scope.reused += 1
        return cast(T, scope.results[key])
    value = compute()
    scope.results[key] = value
    _register(scope, key, value)
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
