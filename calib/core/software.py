"""What software produced a record: the one description of spectral-rig's version for every output.

A session's start record (:mod:`rig.runner`), an estimate's provenance (:mod:`calib.pipeline.provenance`,
``result.json``, the report, the grating file) and ``calib spd``'s ``spd.json`` all record
:func:`current_software`; ``rig version`` prints its version.
"""

from __future__ import annotations

import platform
import sys
from dataclasses import asdict, dataclass
from functools import lru_cache

#: The distribution whose version is recorded.
DISTRIBUTION = "spectral-rig"


@dataclass(frozen=True)
class SoftwareInfo:
    """The installed spectral-rig, and the Python and platform it runs on.

    ``version`` is ``"unknown"`` when running from a source tree that was never installed.
    """

    name: str
    version: str
    python: str
    platform: str

    def to_dict(self) -> dict[str, str]:
        """``{"name", "version", "python", "platform"}`` (the form every output records)."""
        return asdict(self)


@lru_cache(maxsize=1)
def current_software() -> SoftwareInfo:
    """This process's :class:`SoftwareInfo` (read once: the installed version cannot change under it)."""
    # Deferred: importlib.metadata (email, zipfile, csv …) costs ~15 ms that `rig --help` need not pay.
    from importlib.metadata import PackageNotFoundError, version

    try:
        installed = version(DISTRIBUTION)
    except PackageNotFoundError:  # running from a source tree without installing
        installed = "unknown"
    return SoftwareInfo(
        name=DISTRIBUTION,
        version=installed,
        python=sys.version.split()[0],
        platform=platform.platform(),
    )
