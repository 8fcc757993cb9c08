"""How noisy the direct spot is next to the first-order profile, as the rig's pipeline measures both.

The multi-lamp estimator's efficiency rests on each lamp's direct (0th-order) RGB; the synthetic
protocol (``calib synthetic``) gives the direct measurement the profile's noise fraction unless
``--direct-noise`` says otherwise. This prints what the digital twin's captures give instead: for each
lamp of a ``rig demo`` estimate, σ of the profile at its peak over the peak, and σ of each direct
channel over the brightest channel, and their ratio (the protocol's default assumes 1).

    python bench/direct_noise.py [RESULT_JSON]

Without an argument it runs ``rig demo`` (simulated capture + estimate) in a temporary directory.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np


def _demo_result(directory: Path) -> Path:
    rig = Path(sys.executable).with_name("rig")  # the console script beside this interpreter
    subprocess.run(
        [str(rig), "demo", "--out", str(directory), "--quiet"],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    (result,) = directory.glob("estimate/*/result.json")
    return result


def report(path: Path) -> list[float]:
    """Print one line per lamp; return the ratios (profile's relative σ / direct's)."""
    document = json.loads(path.read_text())
    ratios = []
    for lamp in document["lamps"]:
        if lamp["direct_rgb"] is None or lamp["direct_sigma"] is None:
            continue
        profile = np.asarray(lamp["profile"], dtype=float)
        profile_sigma = np.asarray(lamp["profile_sigma"], dtype=float)
        direct = np.asarray(lamp["direct_rgb"], dtype=float)
        direct_sigma = np.asarray(lamp["direct_sigma"], dtype=float)
        peak = np.unravel_index(int(np.nanargmax(profile)), profile.shape)
        profile_fraction = float(profile_sigma[peak] / profile[peak])
        direct_fraction = float(np.max(direct_sigma) / np.max(direct))
        ratios.append(profile_fraction / direct_fraction)
        print(
            f"{lamp['name']:>8}: profile σ at peak {100 * profile_fraction:.3f} % of the peak, "
            f"direct σ {100 * direct_fraction:.3f} % of the brightest channel, "
            f"ratio {ratios[-1]:.1f}"
        )
    return ratios


def main() -> None:
    if len(sys.argv) > 1:
        ratios = report(Path(sys.argv[1]))
    else:
        with tempfile.TemporaryDirectory() as temporary:
            ratios = report(_demo_result(Path(temporary)))
    if ratios:
        print(f"median ratio {float(np.median(ratios)):.1f} (the synthetic protocol's default: 1)")


if __name__ == "__main__":
    main()
