"""The broadband-only mapping σ re-sized offline from ``bench/wavelength_validate.py --csv`` rows.

Each ``led`` row stores the stated σ's parts (the best basin's curvature, the basins, the camera
prior's pull, the spectrometer's scale) and the error and σ at 32 pixels. This script re-states σ
with other constants — :data:`~calib.wavelength.profile_search.LOCAL_SIGMA_SCALE`,
:data:`~calib.wavelength.profile_search.BASIN_TEMPER`, the prior's pull and the spectrometer-scale
term — keeping the σ's shape over the profile (the scale term a common offset, as
:func:`~calib.wavelength.profile_search.stated_covariance` states it) and the widening the
ambiguity rules gave (a floor), and prints the ±2σ coverage and the median actual/stated ratio.
For choosing on the validation split only.

    python bench/mapping_sigma_offline.py /tmp/val.csv --scale 0.29,0.06 --local-scale 1,2 --temper 3

``--coherence C`` states the prior's pull as :func:`~calib.wavelength.profile_search.prior_misfit_sigma_nm`
does since decision 0117 (C × the row's curvature σ × √(reduced χ² − 1)) instead of the stored term
re-scaled; ``--view V`` adds the coarser view's disagreement to it as decision 0128 does
(C² × (χ²ᵣ − 1) + V² × the coarse view's Δχ², under the square root; needs ``--coherence``);
``--by-group`` prints each camera group on its own line. Each line also says how well σ tells the
scenes apart: the spread (10–90 %, as a factor) of actual/stated error over the unwarned scenes,
against the spread a calibrated σ of the rows' own shape would leave (their stored
``calibrated_ratios``).

    python bench/mapping_sigma_offline.py /tmp/val.csv --scale 0.1039 --coherence 3 --view 2 --by-group
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from calib.wavelength.profile_search import BASIN_TEMPER, LOCAL_SIGMA_SCALE


def restated(
    row: dict[str, Any],
    scale_nm: float,
    local_scale: float,
    temper: float,
    misfit_factor: float,
    misfit_power: float = 0.5,
    coherence: float | None = None,
    view: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, float]:
    """The row's 32 errors, their σ under the new constants and the new RMS ratio."""
    errors = np.array(json.loads(row["errors_nm"]))
    sigmas = np.array(json.loads(row["sigmas_nm"]))
    local = float(row["local_rms_nm"])
    misfit = float(row["prior_misfit_sigma_nm"])
    # The prior's pull as a power of the deciding fit's reduced χ² (stored: its square root).
    fit_temper = max(float(row["temper"]), 1.0)
    pull = misfit * fit_temper ** (misfit_power - 0.5) if misfit > 0 else 0.0
    if coherence is not None:
        # Every ``led`` row is a broadband-only search (the LED alone).
        disagreement = float(row.get("coarse_delta_chi2") or "nan")
        disagreement = max(disagreement, 0.0) if math.isfinite(disagreement) else 0.0
        pull = local * math.sqrt(coherence**2 * max(fit_temper - 1.0, 0.0) + view**2 * disagreement)
    scale_old = float(row["spectrometer_scale_sigma_nm"])
    basins = json.loads(row["basins"])
    spread_old = float(row["basin_spread_nm"])

    def spread(t: float) -> float:
        if not basins:
            return 0.0
        weights = np.array([math.exp(-0.5 * b["delta_chi2"] / t) for b in basins])
        distances = np.array([b["distance_nm"] for b in basins])
        return float(np.sqrt(np.sum(weights * distances**2) / weights.sum()))

    old = math.sqrt((LOCAL_SIGMA_SCALE * local) ** 2 + spread_old**2 + scale_old**2 + misfit**2)
    new = math.sqrt(
        (local_scale * local) ** 2 + spread(temper) ** 2 + scale_nm**2 + (misfit_factor * pull) ** 2
    )
    stated_row = float(row["stated_nm"])
    # The ambiguity rules' widening (a floor the quadrature sum does not reach).
    floor = stated_row if stated_row > 1.05 * old else 0.0
    old_total = max(old, floor)
    new_total = max(new, floor)
    shape = np.clip(sigmas**2 - scale_old**2, 0.0, None) / max(old_total**2 - scale_old**2, 1e-12)
    new_sigmas = np.sqrt(shape * max(new_total**2 - scale_nm**2, 0.0) + scale_nm**2)
    factor = math.sqrt(float(np.mean(new_sigmas**2)) / max(float(np.mean(sigmas**2)), 1e-12))
    return errors, new_sigmas, float(row["ratio"]) / factor


def spread(ratios: list[float]) -> float:
    """The 10–90 % spread of actual/stated error ratios, as a factor (1: σ follows the error
    exactly scene by scene)."""
    low, high = np.percentile(np.log(ratios), [10.0, 90.0])
    return float(math.exp(high - low))


def calibrated_spread(rows: list[dict[str, Any]]) -> float:
    """The spread :func:`spread` a calibrated σ of the rows' own shape leaves: the median over the
    rows' stored draws (one draw per row at a time)."""
    draws = np.array([json.loads(row["calibrated_ratios"]) for row in rows])
    return float(np.median([spread(list(draws[:, k])) for k in range(draws.shape[1])]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("csv", nargs="+")
    parser.add_argument("--scale", default="0.2887", help="spectrometer-scale terms (nm), commas")
    parser.add_argument("--local-scale", default=str(LOCAL_SIGMA_SCALE))
    parser.add_argument("--temper", default=str(BASIN_TEMPER))
    parser.add_argument("--misfit-factor", default="1", help="× the stored prior-pull term")
    parser.add_argument("--misfit-power", default="0.5", help="the pull ∝ reduced χ² to this")
    parser.add_argument("--group", default=None, help="only rows of this group")
    parser.add_argument("--coherence", default=None, help="the pull as C × curvature × √(χ²ᵣ − 1)")
    parser.add_argument(
        "--view", default="0", help="with --coherence: + V² × the coarse view's Δχ² (commas)"
    )
    parser.add_argument("--by-group", action="store_true", help="one line per camera group")
    args = parser.parse_args()
    rows = []
    for name in args.csv:
        with Path(name).open(newline="") as handle:
            rows += [r for r in csv.DictReader(handle) if not r.get("failed")]
    if args.group:
        rows = [r for r in rows if r["group"] == args.group]
    print(f"{len(rows)} rows")
    coherences: list[float | None] = (
        [None] if args.coherence is None else [float(v) for v in args.coherence.split(",")]
    )
    grid = itertools.product(
        *(
            [float(v) for v in text.split(",")]
            for text in (
                args.scale,
                args.local_scale,
                args.temper,
                args.misfit_factor,
                args.misfit_power,
            )
        )
    )
    views = [float(v) for v in args.view.split(",")]
    if args.coherence is None and views != [0.0]:
        parser.error("--view needs --coherence")
    settings: list[tuple[tuple[float, ...], float | None, float]] = [
        (values, coherence, view) for values in grid for coherence in coherences for view in views
    ]
    groups = sorted({r["group"] for r in rows}) if args.by_group else [None]
    for (scale, local_scale, temper, misfit, power), coherence, view in settings:
        pull = (
            f"(χ²^{power:g})"
            if coherence is None
            else f"coherence {coherence:g}" + (f" view {view:g}" if view else "")
        )
        for group in groups:
            covered, ratios, unwarned, unwarned_rows = [], [], [], []
            for row in rows:
                if group is not None and row["group"] != group:
                    continue
                errors, sigmas, ratio = restated(
                    row, scale, local_scale, temper, misfit, power, coherence, view
                )
                covered.append(float(np.mean(np.abs(errors) <= 2.0 * sigmas)))
                ratios.append(ratio)
                if row["ambiguous"] not in ("True", "1") and ratio > 0:
                    unwarned.append(ratio)
                    unwarned_rows.append(row)
            told = (
                f", spread (unwarned, 10–90 %) {spread(unwarned):.2f}× "
                f"(calibrated {calibrated_spread(unwarned_rows):.2f}×)"
                if len(unwarned) >= 5
                else ""
            )
            print(
                f"scale {scale:.3f} local×{local_scale:g} temper {temper:g} misfit×{misfit:g} "
                f"{pull}{'' if group is None else f' [{group}, {len(ratios)}]'}: "
                f"±2σ {100 * np.mean(covered):.2f} %, ratio median {np.median(ratios):.2f}, "
                f"cameras ≥ 85 % covered {100 * np.mean(np.array(covered) >= 0.85):.1f} %{told}"
            )


if __name__ == "__main__":
    main()
