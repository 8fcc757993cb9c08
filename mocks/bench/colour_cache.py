"""The colour-science tables the twin opens with, kept on disk: its lamps' illuminant spectra and
its camera's sensitivity.

Importing colour-science costs about a second of CPU (colour 0.4.7 imports its plotting, and
matplotlib with it), and the twin needs it only for tables that never change for a given colour
version. The first twin opened reads them from colour and stores them under the user cache
(:func:`calib.model.bases.default_cache_dir`, in a directory named after this format and colour's
version); every later one reads the stored arrays and never imports colour. A file that cannot be
read is computed again and replaced (written to a temporary name, then renamed, so concurrent
twins never see half a file).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import zipfile
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

from calib.core.arrays import FloatArray
from calib.model.bases import default_cache_dir

__all__ = ["CACHE_FORMAT", "cache_directory", "cached_table"]

#: Bumped whenever what is stored changes meaning.
CACHE_FORMAT = "twin-colour-v1"


@functools.cache
def colour_version() -> str:
    """The installed colour-science's version (``"unknown"`` without it), looked up once: reading
    a distribution's metadata parses its ``METADATA`` file, 3 ms of CPU each time, and a twin
    opens with three tables."""
    try:
        return version("colour-science")
    except PackageNotFoundError:
        return "unknown"


def cache_directory() -> Path:
    """Where the tables of this colour version go."""
    return default_cache_dir() / f"{CACHE_FORMAT}-colour-{colour_version()}"


def cached_table(
    key: str, compute: Callable[[], tuple[FloatArray, FloatArray]]
) -> tuple[FloatArray, FloatArray]:
    """``(wavelength_nm, values)`` of the table ``key`` (``"illuminant FL2"``), from the cache or
    ``compute()`` (then stored).

    ``values`` has shape ``(n,)`` or ``(n, channels)``.
    """
    path = cache_directory() / f"{hashlib.sha256(key.encode()).hexdigest()[:24]}.npz"
    unreadable = (OSError, ValueError, KeyError, zipfile.BadZipFile)
    with contextlib.suppress(*unreadable), np.load(path, allow_pickle=False) as stored:
        if str(stored["key"]) == key:
            return (
                np.asarray(stored["wavelength_nm"], dtype=np.float64),
                np.asarray(stored["values"], dtype=np.float64),
            )
    wavelength_nm, values = compute()
    with contextlib.suppress(OSError):
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_name(f".{path.stem}.{os.getpid()}.npz")
        np.savez(temporary, key=np.array(key), wavelength_nm=wavelength_nm, values=values)
        temporary.replace(path)
    return wavelength_nm, values
