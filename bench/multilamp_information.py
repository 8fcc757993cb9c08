"""How well the measurements alone pin the grating efficiency: the Cramér–Rao bound of issue 7.

For every lamp and channel the direct signal is the profile integrated against ``η⁻¹``; those
``3L`` equations are all the data say about ``η`` (the profiles fix ``η·s`` and nothing else). This
script computes, for the synthetic protocol's scenes, the Fisher information of the 7 Fourier terms
of ``η`` from the whitened direct equations at the *true* ``η`` and the true mapping, and turns the
bound into the RE it implies: ``ŝ = s ⊙ η / η̂`` with ``η̂`` drawn from ``N(η, F⁻¹)`` (400 draws,
normalised and scored like every estimate). No unbiased estimator does better from these
measurements; a camera prior can, but only for cameras like its training set — for the Foveon and
the filtered camera it is no help, so their bound is the floor.

It also prints the floor the profiles leave with ``η`` known exactly (``s = Q / η``).

    python bench/multilamp_information.py [--data-dir DIR] [--draws 2] [--direct 0.01 0.004 0.001]

The measured cameras come from ``--data-dir``, ``$SPECTRAL_RIG_DATA`` or the user cache
(``rig data fetch``); without them the script says so and exits 0.
"""

from __future__ import annotations

import argparse
import os
from dataclasses import replace

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from calib.core.datasets import makabe2025_split
from calib.core.errors import InputError
from calib.core.metrics import relative_error
from calib.core.result import physical_curves
from calib.core.spectra import DEFAULT_GRID
from calib.evaluation.synthetic import (
    LAMP_SETS,
    out_of_basis_cameras,
    random_efficiency,
    random_mapping,
    render_lamps,
)
from calib.methods.multilamp import pool_responses, prepare_lamps
from calib.methods.responses import direct_rows
from calib.model.bases import camera_basis, fourier_basis

MONTE_CARLO = 400


def bound_re(
    truth: np.ndarray,
    eta: np.ndarray,
    fisher: np.ndarray,
    basis: np.ndarray,
    rng: np.random.Generator,
) -> float:
    """Mean RE of ``s ⊙ η / η̂`` over draws ``η̂ = B (c + δ)``, ``δ ~ N(0, F⁻¹)``."""
    coefficients = np.linalg.lstsq(basis, eta, rcond=None)[0]
    covariance = np.linalg.pinv(fisher, hermitian=True)
    draws = rng.multivariate_normal(coefficients, covariance, size=MONTE_CARLO, method="eigh")
    scores = [
        relative_error(physical_curves(truth * (eta / (basis @ draw))[:, None]), truth)
        for draw in draws
    ]
    return float(np.mean(scores))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--draws", type=int, default=2)
    parser.add_argument("--direct", type=float, nargs="+", default=[0.01, 0.004, 0.001])
    args = parser.parse_args()
    grid = DEFAULT_GRID
    try:
        train, test = makabe2025_split(args.data_dir)
    except InputError as exc:
        print(f"skipped: {exc}")
        return
    basis = camera_basis([r.sensitivity for r in train], source="Makabe 2025 train (44)")
    cameras = [(r.camera, r.sensitivity, "test") for r in test]
    cameras += [
        (name, curves, "out of basis")
        for name, curves in out_of_basis_cameras(test[0].camera, test[0].sensitivity)
    ]
    efficiency_basis = fourier_basis(grid, 7)
    print(
        "mean RE ×10⁻² implied by the Cramér–Rao bound of the direct equations (1 % profile noise)"
    )
    print(
        f"{'lamps':22s} {'cameras':13s} "
        + " ".join(f"direct {d:.1%}" for d in args.direct)
        + "   η known"
    )
    for set_name, lamps in LAMP_SETS.items():
        for group in ("test", "out of basis"):
            bounds: dict[float, list[float]] = {d: [] for d in args.direct}
            known: list[float] = []
            for index, (_, curves, kind) in enumerate(cameras):
                if kind != group:
                    continue
                truth = curves.resample(grid, "interpolate", out_of_range="zero").values
                truth = truth / truth.max()
                for draw in range(args.draws):
                    # One rendering per scene: the bound depends on the direct noise only
                    # through the direct σ, which scales with the noise fraction.
                    rng = np.random.default_rng([0, index, draw])
                    mapping = random_mapping(rng, grid)
                    efficiency = random_efficiency(rng, grid)
                    first = args.direct[0]
                    observations = render_lamps(
                        lamps, curves, mapping, efficiency, rng, 0.01, first
                    )
                    prepared = prepare_lamps(observations, basis=basis, grid=grid, mapping=mapping)
                    eta = efficiency(grid.wavelength_nm)
                    for direct in args.direct:
                        scaled = [
                            replace(lamp, direct_sigma=lamp.direct_sigma * direct / first)
                            for lamp in prepared.lamps
                        ]
                        rows, _ = direct_rows(scaled, 1.0 / eta)
                        jacobian = rows @ (-(eta**-2)[:, None] * efficiency_basis)
                        bounds[direct].append(
                            bound_re(truth, eta, jacobian.T @ jacobian, efficiency_basis, rng)
                        )
                    pooled = pool_responses([lamp.response for lamp in prepared.lamps])[0]
                    known.append(
                        relative_error(physical_curves(pooled.response / eta[:, None]), truth)
                    )
            cells = " ".join(f"{100 * np.mean(bounds[d]):12.2f}" for d in args.direct)
            print(f"{set_name:22s} {group:13s} {cells}   {100 * np.mean(known):6.2f}", flush=True)


if __name__ == "__main__":
    main()
