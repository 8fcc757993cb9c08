"""Which cameras the default basis holds when both Solomatov & Akkaynak and rawtoaces-data are present.

Measured on **validation cameras only** (decision 0023's validation split): leave-one-body-out over
the training collection, the 44 Solomatov/Akkaynak ground truths outside the paper's 5 test cameras.
Each camera is estimated with a basis that leaves its own body out, built from

- ``solomatov``: the other training bodies' curves (the paper's basis);
- ``solomatov + rawtoaces-data``: the same, plus rawtoaces-data's bodies that no Solomatov/Akkaynak
  curve has (43 of 52; one body, one weight: a body already measured is not added again, and the
  paper's test bodies, which both collections hold, never enter);
- ``rawtoaces-data``: the bundled cameras alone (the fallback a fresh install uses), its own body
  left out.

Scenes: the synthetic protocol's (:func:`calib.evaluation.synthetic.run_protocol`, seed 0), the same
scene for a camera under every basis; variants ``true mapping`` (the prior alone decides what the
two lamps leave open), ``LED+Flu`` (the mapping found with the prior's mean too) and ``multilamp: 5
lamps``. Printed: mean RE ×10⁻² per basis and variant, the paired difference against ``solomatov``
and how many cameras each basis wins.

    python bench/basis_choice.py --data-dir ../shared/data/camera_sensitivities [--noise 0.01]
        [--variant 'true mapping' …]

Without the data directory it says so and exits 0.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from calib.core.datasets import (
    RAWTOACES_DATA,
    SOLOMATOV,
    CameraRecord,
    exclude_cameras,
    load_collection,
    makabe2025_split,
    new_bodies,
)
from calib.core.spectra import DEFAULT_GRID
from calib.evaluation.synthetic import SyntheticRow, run_protocol
from calib.model.bases import CameraBasis, camera_basis

VARIANTS = ("true mapping", "LED+Flu", "multilamp: 5 lamps")


def _basis_without(records: Sequence[CameraRecord], camera: str, label: str) -> CameraBasis:
    kept, _ = exclude_cameras(records, [camera])
    return camera_basis(
        [record.sensitivity for record in kept],
        grid=DEFAULT_GRID,
        source=f"{label} without {camera}",
        camera_names=[record.name for record in kept],
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, required=True)
    parser.add_argument("--noise", type=float, default=0.01)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--variant", action="append", choices=VARIANTS, help="repeatable; default all three"
    )
    arguments = parser.parse_args(argv)
    variants = tuple(arguments.variant or VARIANTS)
    if not (arguments.data_dir / SOLOMATOV).is_dir():
        print(f"no {SOLOMATOV} in {arguments.data_dir}: nothing to measure")
        return 0
    training, _test = makabe2025_split(arguments.data_dir)
    every_solomatov = load_collection(SOLOMATOV, arguments.data_dir)
    bundled = load_collection(RAWTOACES_DATA)
    added = new_bodies(bundled, every_solomatov)
    bases: dict[str, Sequence[CameraRecord]] = {
        "solomatov": training,
        "solomatov + rawtoaces-data": [*training, *added],
        "rawtoaces-data": bundled,
    }
    print(
        f"validation cameras: {len(training)} Solomatov/Akkaynak training curves; rawtoaces-data "
        f"adds {len(added)} bodies of {len(bundled)}; noise {arguments.noise:g}, seed "
        f"{arguments.seed}",
        flush=True,
    )
    cameras = [(record.name, record.sensitivity) for record in training]
    rows: dict[str, list[SyntheticRow]] = {}
    for label, records in bases.items():
        started = time.process_time()

        def basis_for(
            name: str, records: Sequence[CameraRecord] = records, label: str = label
        ) -> CameraBasis:
            return _basis_without(records, name, label)

        choice: Callable[[str], CameraBasis] = basis_for
        rows[label] = run_protocol(
            cameras,
            choice,
            variants=variants,
            noise_levels=(arguments.noise,),
            seed=arguments.seed,
            budget=None,  # RE only: the σ budget's re-solves would cost without a use here
        )
        print(f"{label}: {time.process_time() - started:.0f} s CPU", file=sys.stderr, flush=True)
    print()
    print("| basis | " + " | ".join(variants) + " |")
    print("|---|" + "---|" * len(variants))
    reference = rows["solomatov"]
    for label, found in rows.items():
        cells = []
        for variant in variants:
            errors = np.array([r.relative_error for r in found if r.variant == variant])
            cell = f"{100 * np.nanmean(errors):.2f}"
            if label != "solomatov":
                base = np.array([r.relative_error for r in reference if r.variant == variant])
                difference = 100 * (errors - base)
                wins = int(np.sum(difference < 0))
                cell += (
                    f" (Δ {np.nanmean(difference):+.2f}, median {np.nanmedian(difference):+.2f}; "
                    f"better on {wins}/{len(errors)})"
                )
            cells.append(cell)
        print(f"| {label} | " + " | ".join(cells) + " |")
    print()
    print("mean RE ×10⁻² over the validation cameras (Δ: paired difference against solomatov)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
