"""Command-line options that more than one command declares (``calib compare``, ``rig compare``).

Kept free of heavy imports: ``rig``'s command line imports it at start-up.
"""

from __future__ import annotations

from typing import Annotated

import typer

#: Toivonen et al.'s ensemble size for comparisons.
EnsembleOption = Annotated[
    int | None, typer.Option(min=1, help="Toivonen ensemble size (default 16).")
]
#: Toivonen et al.'s Adam epochs for comparisons.
EpochsOption = Annotated[
    int | None, typer.Option(min=1, help="Toivonen Adam epochs (default 5000).")
]
