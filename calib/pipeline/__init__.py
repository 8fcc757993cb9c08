"""Stage 7, offline estimation from files: RAW brackets or 1-D profiles plus lamp spectra → estimate + report.

The one pipeline behind ``calib estimate`` and ``rig estimate`` (inputs, brackets, provenance, the
output writers, the report); ``calib.pipeline`` imports the stages before it (:mod:`calib.core` to
:mod:`calib.spd`), never :mod:`calib.evaluation` or the command line:

* :func:`estimate_offline` — inputs (:class:`LampImages` or :class:`LampProfile` per lamp) to an
  :class:`OfflineEstimate` (see :mod:`calib.pipeline.estimate`);
* :func:`run_offline` — the same, then the output files (:mod:`calib.pipeline.outputs`, :mod:`calib.pipeline.report`).

Examples
--------
Not run as a doctest: it needs lamp spectra and RAW files (``tests/test_offline.py`` runs the
pipeline on the twin's).

>>> from pathlib import Path                                                    # doctest: +SKIP
>>> lamp = LampImages("LED-B3", "led", Path("led.csv"), (Path("f1.dng"), Path("f2.dng")))  # doctest: +SKIP
>>> outcome = run_offline([lamp], Path("out"))                                  # doctest: +SKIP
>>> outcome.files["sensitivity"]                                                # doctest: +SKIP
PosixPath('out/sensitivity.csv')
"""

from __future__ import annotations

from calib.pipeline.estimate import OfflineEstimate, OfflineSettings, estimate_offline
from calib.pipeline.inputs import LampImages, LampInput, LampProfile
from calib.pipeline.progress import NoProgress, OfflineProgress, RichFrameProgress
from calib.pipeline.provenance import InputFile, Provenance
from calib.pipeline.run import OfflineOutcome, run_offline

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
