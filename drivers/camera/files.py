"""Files coming off the camera: which one is the RAW, where it goes, and writing it safely."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

__all__ = [
    "RAW_EXTENSIONS",
    "CameraPath",
    "files_per_capture",
    "local_path",
    "primary_file",
]

CameraPath = tuple[str, str]
"""(folder, name) of a file on the camera."""
RAW_EXTENSIONS = frozenset(
    {".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".dng", ".orf", ".raf"}
    | {".rw2", ".pef", ".srw", ".x3f", ".3fr", ".iiq", ".erf", ".kdc", ".mrw"}
)
"""Camera RAW file suffixes (lower case)."""


def files_per_capture(image_format: str | None) -> int:
    """Files one capture produces for an ``imageformat``/``imagequality`` value: 2 for RAW+JPEG
    (``RAW + Large Fine JPEG``, ``NEF+Fine``), else 1."""
    return 2 if image_format is not None and "+" in image_format else 1


def primary_file(files: Sequence[CameraPath]) -> CameraPath:
    """The file to keep from one capture: the first RAW one, else the first one."""
    if not files:
        raise ValueError("a capture produced no file")
    raws = [f for f in files if Path(f[1]).suffix.lower() in RAW_EXTENSIONS]
    return raws[0] if raws else files[0]


def local_path(destination: Path, camera_file: CameraPath) -> Path:
    """``destination``, with the camera file's lower-case suffix appended when it has none."""
    if destination.suffix:
        return destination
    return destination.with_suffix(Path(camera_file[1]).suffix.lower())
