"""Which camera *body* a measured curve belongs to: names normalised across collections, and aliases.

The same body appears under different names in different collections: ``Canon 5D-Mk-II``
(Solomatov & Akkaynak), ``Canon 5DMarkII`` (camspec), ``canon eos 5d mark ii`` (rawtoaces),
``Canon EOS 5D Mark II`` (rawtoaces-data); the Canon 400D is also sold as the Digital Rebel XTi
(``canon xti``). A validation split must know that they are one camera, or a test camera leaks
into the basis. :func:`body_key` reduces a name to a key (lower case, letters and digits only,
``mark`` → ``mk``, Canon's ``EOS`` dropped, the measurement source in parentheses dropped);
:class:`BodyIndex` joins keys that name one body (built-in Canon market names, plus the
rawtoaces-data ``aliases.json`` read at run time) and, separately, bodies that share a sensor.
:func:`names_camera` tells whether a pattern (``--exclude-camera``) names a camera: the same body,
or a shell wildcard over the normalised name.

Examples
--------
>>> index = BodyIndex()
>>> index.body("Canon 5D-Mk-II (Jiang-et-al-2013)") == index.body("canon eos 5d mark ii")
True
>>> index.body("canon xti") == index.body("Canon 400D (Lebourgeois-2008)")
True
"""

from __future__ import annotations

import fnmatch
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

from calib.core.errors import InputError
from calib.core.formats.ampas import ALIASES_FILE
from calib.core.formats.json_file import read_json

#: Market names of one Canon body (Americas "Rebel", Japan "Kiss", elsewhere "NNND"): the names
#: under which bodies of the measured collections appear.
CANON_MARKET_NAMES: tuple[tuple[str, ...], ...] = (
    ("Canon 300D", "Canon Digital Rebel", "Canon Kiss Digital"),
    ("Canon 400D", "Canon Digital Rebel XTi", "Canon XTi", "Canon Kiss Digital X"),
    ("Canon 500D", "Canon Rebel T1i", "Canon Kiss X3"),
    ("Canon 600D", "Canon Rebel T3i", "Canon Kiss X5"),
    ("Canon 100D", "Canon Rebel SL1", "Canon Kiss X7"),
    ("Canon 200D", "Canon Rebel SL2", "Canon Kiss X9"),
)

_SOURCE = re.compile(r"\([^)]*\)")


def body_key(name: str) -> str:
    """A make-and-model name reduced to letters and digits (see the module docstring).

    Examples
    --------
    >>> body_key("Canon EOS-1Ds Mark II")
    'canon1dsmkii'
    >>> body_key("SONY NEX-5N"), body_key("Sony NEX5N (Jiang-et-al-2013)")
    ('sonynex5n', 'sonynex5n')
    >>> body_key("Nikon 5100 (NPL)")
    'nikond5100'
    """
    text = _SOURCE.sub(" ", name.lower()).replace("nikon corporation", "nikon")
    tokens = [token for token in re.findall(r"[a-z0-9]+", text) if token != "eos"]
    key = "".join(tokens).replace("mark", "mk")
    # colour-science names the NPL D5100 "Nikon 5100": Nikon's DSLRs are D-numbers.
    return re.sub(r"^nikon(\d{3,4})", r"nikond\1", key)


@dataclass(frozen=True)
class BodyAlias:
    """One line of an alias table: ``alias`` names the body ``canonical`` (or shares its sensor)."""

    alias: str
    canonical: str
    same_model: bool
    comment: str = ""


def read_rawtoaces_aliases(path: str | Path | None = None) -> list[BodyAlias]:
    """The camera aliases of rawtoaces-data's ``data/aliases.json`` (default: the bundled copy,
    :data:`calib.core.formats.ampas.ALIASES_FILE`).

    ``"same model, alternative name"`` and ``"updated model, same sensor"`` entries name one body;
    ``"different model, same sensor"`` entries are sensor siblings (``same_model=False``).

    Raises
    ------
    InputError
        The file is missing, not JSON, or lacks ``data.camera.model``.
    """
    path = ALIASES_FILE if path is None else Path(path)
    document = read_json(path)
    try:
        models = document["data"]["camera"]["model"]
        aliases = []
        for make, entries in models.items():
            for alias, target in entries.items():
                comment = str(target.get("comments", ""))
                aliases.append(
                    BodyAlias(
                        f"{make} {alias}",
                        f"{target['make']} {target['model']}",
                        same_model="different model" not in comment,
                        comment=comment,
                    )
                )
    except (KeyError, TypeError, AttributeError) as exc:
        raise InputError(
            f"not a rawtoaces-data alias file (data.camera.model expected): {exc}",
            source=str(path),
        ) from None
    return aliases


def _builtin_aliases() -> list[BodyAlias]:
    return [
        BodyAlias(alias, names[0], same_model=True, comment="Canon market name")
        for names in CANON_MARKET_NAMES
        for alias in names[1:]
    ]


@dataclass
class BodyIndex:
    """Canonical body and sensor keys of camera names, through alias tables (union–find).

    Parameters
    ----------
    aliases
        Extra alias lines (e.g. :func:`read_rawtoaces_aliases`); the built-in Canon market names
        are always included.
    """

    aliases: Iterable[BodyAlias] = ()
    _body: dict[str, str] = field(default_factory=dict, init=False, repr=False)
    _sensor: dict[str, str] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        for alias in [*_builtin_aliases(), *self.aliases]:
            first, second = body_key(alias.alias), body_key(alias.canonical)
            if alias.same_model:
                self._join(self._body, first, second)
            self._join(self._sensor, first, second)

    @staticmethod
    def _find(parents: dict[str, str], key: str) -> str:
        root = key
        while parents.get(root, root) != root:
            root = parents[root]
        while parents.get(key, key) != root:
            parents[key], key = root, parents[key]
        return root

    def _join(self, parents: dict[str, str], first: str, second: str) -> None:
        a, b = self._find(parents, first), self._find(parents, second)
        if a != b:
            # The alphabetically first key names the group: the same answer in any order.
            low, high = sorted((a, b))
            parents[high] = low

    def body(self, name: str) -> str:
        """The body key of a camera name (aliases of one model share it)."""
        return self._find(self._body, body_key(name))

    def sensor(self, name: str) -> str:
        """The sensor key: bodies that share a sensor (by the alias tables) share it."""
        return self._find(self._sensor, self.body(name))


@cache
def default_body_index() -> BodyIndex:
    """A :class:`BodyIndex` with the bundled rawtoaces-data aliases (read once)."""
    return BodyIndex(read_rawtoaces_aliases())


#: Characters that make a pattern a shell wildcard (:func:`names_camera`).
WILDCARDS = frozenset("*?[")


def _wildcard_key(pattern: str) -> str:
    """A wildcard pattern normalised as :func:`body_key` normalises names, wildcards kept."""
    text = _SOURCE.sub(" ", pattern.lower())
    tokens = [token for token in re.findall(r"[a-z0-9*?\[\]]+", text) if token != "eos"]
    return "".join(tokens).replace("mark", "mk")


def names_camera(pattern: str, name: str, index: BodyIndex | None = None) -> bool:
    """Whether ``pattern`` names the camera ``name``.

    A plain pattern names a body: ``"Canon 600D"`` names ``Canon EOS 600D``, ``Canon 600D
    (Jiang-et-al-2013)`` and ``Canon Rebel T3i`` (:meth:`BodyIndex.body`; case, spaces,
    punctuation, ``EOS``, ``Mark``/``Mk`` and a source in brackets do not matter), and not the
    ``Canon 60D``. A pattern with shell wildcards (``*``, ``?``, ``[``) is matched against the
    normalised name: ``"Canon*"`` names every Canon, ``"*5D*"`` every 5D.

    Examples
    --------
    >>> names_camera("Canon 600D", "Canon EOS 600D (rawtoaces-data)")
    True
    >>> names_camera("Nikon D70", "Nikon D700 (Jiang-et-al-2013)")
    False
    >>> names_camera("nikon d7*", "Nikon D700 (Jiang-et-al-2013)")
    True
    """
    if WILDCARDS & set(pattern):
        return fnmatch.fnmatchcase(body_key(name), _wildcard_key(pattern))
    index = index or default_body_index()
    return index.body(pattern) == index.body(name)
