"""Does the camera population's channel balance hold a held-out camera's? (decision 0050)

Where a profile's channel gains are unknown (a converted image), the delivered balance is the basis
mean's with the population's spread as σ (:func:`calib.methods.uncertainty.population_channel_balance`).
This judges it on the VALIDATION split only, with no estimate: each validation camera's own ratio of
channel areas against its leave-one-body-out basis mean, the share within ±2σ and the RMS of the
normalised miss.

    python bench/channel_balance.py [--data-dir ../shared/data/camera_sensitivities]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from calib.evaluation.validation.protocol import DEFAULT_VARIANTS, ProtocolSettings, split_tasks
from calib.evaluation.validation.splits import load_splits
from calib.methods.uncertainty import population_channel_balance


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    splits, _ = load_splits(args.data_dir, seed=args.seed)
    settings = ProtocolSettings(seed=args.seed, variants=DEFAULT_VARIANTS[:1])
    misses: list[float] = []
    for task in split_tasks(splits.validation, settings):
        ratio, relative_sigma, reference = population_channel_balance(task.basis)
        truth = np.clip(
            task.camera.sensitivity.resample(task.basis.grid, "interpolate").values, 0, None
        )
        area = truth.sum(axis=0)
        relative_miss = ratio / (area / area[reference]) - 1.0
        misses += [relative_miss[c] / relative_sigma[c] for c in range(3) if c != reference]
    z = np.asarray(misses)
    print(
        f"validation split ({len(z) // 2} cameras, seed {args.seed}): channel-area ratios within "
        f"±2σ {100 * np.mean(np.abs(z) <= 2):.1f} %, RMS of miss/σ {np.sqrt(np.mean(z**2)):.2f}, "
        f"median |miss/σ| {np.median(np.abs(z)):.2f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
