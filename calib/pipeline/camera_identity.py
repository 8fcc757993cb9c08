"""The camera's make and model as raw converters name it, for the files that must match a RAW file.

rawtoaces (and dcamprof's users: RawTherapee, darktable) look a camera file up by the make and
model LibRaw gives a RAW file, not by its EXIF tags: ``Nikon`` / ``D5100``, not ``NIKON
CORPORATION`` / ``NIKON D5100``. :func:`libraw_names` asks LibRaw itself — the ``libraw_r`` shared
library that rawpy ships — through its C API (``libraw_init``, ``libraw_open_file``,
``libraw_get_iparams``): the identification only, no decoding. LibRaw's *normalised* names are used
when it has them (a maker it knows), else its cleaned ``make``/``model``. Without a RAW file or a
loadable LibRaw the EXIF names are cleaned the same way rawtoaces' ``aliases.json`` does (and the
file says so). rawtoaces-data's aliases are applied last (:func:`calib.core.formats.ampas.rawtoaces_names`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from calib.core.formats.ampas import rawtoaces_names

#: LibRaw ≥ 0.20 has normalised names in ``libraw_iparams_t`` (0.20.0 = 0x1400).
_MIN_VERSION = 0x001400


class _IParams(ctypes.Structure):
    """The head of LibRaw's ``libraw_iparams_t`` (0.20 and later): only the names are read."""

    _fields_ = [
        ("guard", ctypes.c_char * 4),
        ("make", ctypes.c_char * 64),
        ("model", ctypes.c_char * 64),
        ("software", ctypes.c_char * 64),
        ("normalized_make", ctypes.c_char * 64),
        ("normalized_model", ctypes.c_char * 64),
    ]


@dataclass(frozen=True)
class LibRawNames:
    """What LibRaw calls a RAW file's camera."""

    make: str
    model: str
    normalized_make: str
    normalized_model: str
    libraw_version: str


@dataclass(frozen=True)
class CameraIdentity:
    """The names written into camera files, and where they come from.

    Attributes
    ----------
    make, model
        As rawtoaces will look them up (LibRaw's names after rawtoaces-data's aliases).
    source
        ``"LibRaw 0.22.2 (normalised)"``, ``"EXIF"``, or ``"unknown"``.
    note
        Why the names differ from the camera's own, when they do (an alias), else ``None``.
    """

    make: str
    model: str
    source: str
    note: str | None = None

    @property
    def name(self) -> str:
        return f"{self.make} {self.model}".strip()


def _candidates() -> list[Path | str]:
    paths: list[Path | str] = []
    try:
        import rawpy
    except ImportError:  # pragma: no cover - rawpy is a dependency
        return paths
    here = Path(rawpy.__file__).parent
    for folder in (here, here.parent / "rawpy.libs"):
        for pattern in ("libraw_r*.so*", "libraw_r*.dylib", "libraw*.dll", "libraw*.so*"):
            paths.extend(sorted(folder.glob(pattern)))
    for name in ("raw_r", "raw"):
        found = ctypes.util.find_library(name)
        if found:
            paths.append(found)
    return paths


@cache
def _libraw() -> ctypes.CDLL | None:
    """LibRaw's C library with the four functions declared, or ``None`` when none loads."""
    for candidate in _candidates():
        try:
            library = ctypes.CDLL(str(candidate))
            library.libraw_versionNumber.restype = ctypes.c_int
            if library.libraw_versionNumber() < _MIN_VERSION:
                continue
            library.libraw_version.restype = ctypes.c_char_p
            library.libraw_init.restype = ctypes.c_void_p
            library.libraw_init.argtypes = [ctypes.c_uint]
            library.libraw_open_file.restype = ctypes.c_int
            library.libraw_open_file.argtypes = [ctypes.c_void_p, ctypes.c_char_p]
            library.libraw_get_iparams.restype = ctypes.POINTER(_IParams)
            library.libraw_get_iparams.argtypes = [ctypes.c_void_p]
            library.libraw_close.argtypes = [ctypes.c_void_p]
        except (OSError, AttributeError):
            continue
        return library
    return None


def _text(raw: bytes) -> str:
    return raw.decode("utf-8", errors="replace").strip()


def libraw_names(path: Path) -> LibRawNames | None:
    """LibRaw's identification of ``path``; ``None`` when LibRaw cannot be loaded or open it."""
    library = _libraw()
    if library is None:
        return None
    handle = library.libraw_init(0)
    if not handle:
        return None
    try:
        if library.libraw_open_file(handle, str(path).encode()) != 0:
            return None
        params = library.libraw_get_iparams(handle).contents
        return LibRawNames(
            make=_text(params.make),
            model=_text(params.model),
            normalized_make=_text(params.normalized_make),
            normalized_model=_text(params.normalized_model),
            libraw_version=_text(library.libraw_version()),
        )
    finally:
        library.libraw_close(handle)


def camera_identity(
    raw_file: Path | None, exif_make: str | None = None, exif_model: str | None = None
) -> CameraIdentity:
    """The make and model to write into camera files (see the module).

    Parameters
    ----------
    raw_file
        One of the RAW files the estimate used, when there is one.
    exif_make, exif_model
        The EXIF names, used when LibRaw cannot name the camera.
    """
    names = libraw_names(raw_file) if raw_file is not None else None
    if names is not None and (names.make or names.normalized_make):
        make = names.normalized_make or names.make
        model = names.normalized_model or names.model
        source = f"LibRaw {names.libraw_version} (normalised)"
    elif exif_make or exif_model:
        exif = (exif_make or "").strip()
        make = rawtoaces_names(exif, "")[0] if exif else ""
        model = (exif_model or "").strip()
        for prefix in {make, exif, exif.split(" ")[0]} - {""}:
            if model.lower().startswith(prefix.lower() + " "):
                model = model[len(prefix) :].strip()
        source = "EXIF (LibRaw could not name the camera)"
    else:
        return CameraIdentity("unknown", "camera", "unknown")
    mapped_make, mapped_model, why = rawtoaces_names(make, model)
    note = None
    if (mapped_make.lower(), mapped_model.lower()) != (make.lower(), model.lower()):
        note = (
            f"{make} {model} is named {mapped_make} {mapped_model} as rawtoaces-data's "
            f"aliases.json maps it ({why})"
        )
    return CameraIdentity(mapped_make, mapped_model, source, note)
