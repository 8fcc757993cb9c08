"""Offline estimation from files: RAW brackets or 1-D profiles plus lamp spectra → estimate + report.

The one pipeline behind ``calib estimate`` and ``rig estimate``:

* :func:`estimate_offline` — inputs (:class:`LampImages` or :class:`LampProfile` per lamp) to an
  :class:`OfflineEstimate` (see :mod:`calib.pipeline.estimate`);
* :func:`run_offline` — the same, then the output files (:mod:`calib.pipeline.outputs`, :mod:`calib.pipeline.report`).

Examples
--------
>>> from pathlib import Path                                                    # doctest: +SKIP
>>> lamp = LampImages("LED-B3", "led", Path("led.csv"), (Path("f1.dng"), Path("f2.dng")))  # doctest: +SKIP
>>> outcome = run_offline([lamp], Path("out"))                                  # doctest: +SKIP
>>> outcome.files["sensitivity"]                                                # doctest: +SKIP
PosixPath('out/sensitivity.csv')
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from calib.pipeline.inputs import LampImages, LampInput, LampProfile
from calib.pipeline.progress import NoProgress, OfflineProgress, RichFrameProgress
from calib.pipeline.provenance import InputFile, Provenance

if TYPE_CHECKING:
    from calib.pipeline.estimate import OfflineEstimate, OfflineSettings, estimate_offline
    from calib.pipeline.run import OfflineOutcome, run_offline

#: Imported on first use: the pipeline pulls in the estimators (scipy), which ``calib estimate``
#: imports while the first frames decode (:func:`calib.pipeline.estimate.import_estimation`).
_LAZY = {
    "OfflineEstimate": "calib.pipeline.estimate",
    "OfflineSettings": "calib.pipeline.estimate",
    "estimate_offline": "calib.pipeline.estimate",
    "OfflineOutcome": "calib.pipeline.run",
    "run_offline": "calib.pipeline.run",
}

__all__ = [
    "InputFile",
    "LampImages",
    "LampInput",
    "LampProfile",
    "NoProgress",
    "OfflineEstimate",
    "OfflineOutcome",
    "OfflineProgress",
    "OfflineSettings",
    "Provenance",
    "RichFrameProgress",
    "estimate_offline",
    "run_offline",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'calib.pipeline' has no attribute {name!r}")
