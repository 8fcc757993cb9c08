"""Where the paper protocol's searched mappings err most, and how many of their stated σ that is.

For every searched mapping of :func:`calib.evaluation.synthetic.run_protocol`'s scenes (the
paper's variants, the same seeds as ``calib synthetic``: a subset of cameras or noise levels
renders the same scenes), one row: the largest error over the working grid (nm), the wavelength
and pixel where it is, whether that pixel lies within the reach of the lines that hold the
mapping (``QuadraticMapping.line_reach``, decision 0127) or past it, the mapping's stated
per-pixel σ there (``sigma_nm``, what every consumer reads), the error in units of it, the
largest |error|/σ over the grid, the share of grid pixels within ±2σ, the family, the warning
codes, the matched-line table (reference nm @ pixel, ``x`` when unused, residual nm) and the
search's profile evaluations, and the largest |error|/σ within each of three bands of the working
grid (:data:`BANDS`: its blue end, its middle, its red end; decision 0155). The summary counts
mappings more than 3 nm off and, of them, those neither warned nor covered (|error| > 3σ at the
worst pixel): a silent wrong answer is one the stated σ does not cover and no warning names; and,
over the unwarned mappings, each band's median |error|/σ and how many exceed 3σ there (where along
the profile the stated σ is too small).

Tuning choices may look at ``--split validation`` only; ``--split test`` is for the report.

    python bench/paper_mapping_sigma.py --data-dir $D --split validation --variant LED+Flu \\
        --run-noise 0.01,0.03 --seed 0 --csv out.csv
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.mapping import QuadraticMapping
from calib.core.result import MAPPING_FAILURE_NM, EstimateResult, mapping_warned
from calib.core.spectra import DEFAULT_GRID
from calib.evaluation.synthetic import SyntheticRow, SyntheticScene, run_protocol
from calib.evaluation.synthetic_splits import paper_split_cameras

#: An error within this many stated σ at its worst pixel is covered (a 3σ excursion over a few
#: hundred correlated pixels is what a right σ shows now and then; beyond it the σ is wrong).
COVERED_SIGMAS = 3.0

#: Bands of the working grid (true wavelength, nm) whose largest |error|/σ each row records: the
#: first and last 30 nm (where a broadband lamp's signal through the camera fades) and the middle.
BANDS = {"blue": (400.0, 430.0), "middle": (500.0, 600.0), "red": (670.0, 700.0)}

COLUMNS = (
    "camera,variant,noise,worst_nm,worst_at_nm,worst_px,where,sigma_nm,err_over_sigma,"
    "max_err_over_sigma,within_2sigma,family,codes,reach_nm,curvature,lines,evaluations,"
    + ",".join(f"{band}_err_over_sigma" for band in BANDS)
)


def band_ratios(truth: FloatArray, error: FloatArray, sigma: FloatArray) -> list[float]:
    """The largest |error|/σ within each of :data:`BANDS` (NaN where a band holds no pixel)."""
    ratios = []
    for low, high in BANDS.values():
        inside = (truth >= low) & (truth <= high)
        ratios.append(float(np.max(error[inside] / sigma[inside])) if inside.any() else np.nan)
    return ratios


def mapping_errors(
    scene: SyntheticScene, mapping: QuadraticMapping
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The pixels whose true wavelength lies on the working grid, that wavelength, the mapping's
    |error| (nm) there and its stated per-pixel σ (``sigma_nm``; its RMS where it states none)."""
    pixel = scene.broadband.observation.pixel
    truth = scene.mapping.wavelength_nm(pixel)
    inside = (truth >= DEFAULT_GRID.start_nm) & (truth <= DEFAULT_GRID.stop_nm)
    p = np.asarray(pixel, dtype=np.float64)[inside]
    error = np.abs(mapping.wavelength_nm(p) - truth[inside])
    sigma = mapping.sigma_nm(p)
    if sigma is None:
        sigma = np.full(p.shape, float(mapping.wavelength_rms_nm or np.nan))
    return p, truth[inside], error, np.asarray(sigma, dtype=np.float64)


def row_of(scene: SyntheticScene, row: SyntheticRow, result: EstimateResult) -> str | None:
    mapping = result.mapping
    if row.mapping_relative_error is None or not isinstance(mapping, QuadraticMapping):
        return None
    p, truth, error, sigma = mapping_errors(scene, mapping)
    k = int(np.argmax(error))
    details = getattr(mapping, "details", None) or {}
    reach = getattr(mapping, "line_reach", None)
    where, reach_text, curvature = "no reach", "", ""
    if reach is not None:
        low, high = sorted(reach.pixel_range)
        where = "inside" if low <= p[k] <= high else "past"
        reach_text = "-".join(f"{v:.1f}" for v in reach.wavelength_range_nm)
        curvature = f"{reach.curvature_nm_per_px2:.3g}"
    lines = " ".join(
        f"{float(m.get('wavelength_nm', np.nan)):.1f}@{float(m.get('pixel', np.nan)):.0f}"
        f"{'' if m.get('weight', 1.0) else 'x'}({float(m.get('residual_nm', np.nan)):+.2f})"
        for m in details.get("matched_lines", []) or []
    )
    codes = " ".join(details.get("warning_codes", ()))
    return (
        f'"{row.camera}",{row.variant},{row.noise:g},{error[k]:.3f},{truth[k]:.1f},'
        f"{p[k]:.1f},{where},{sigma[k]:.3f},{error[k] / sigma[k]:.2f},"
        f"{np.max(error / sigma):.2f},{np.mean(error <= 2 * sigma):.3f},"
        f'{details.get("family", "")},"{codes}",{reach_text},{curvature},"{lines}",'
        f"{details.get('evaluations', '')},"
        + ",".join(f"{r:.2f}" for r in band_ratios(truth, error, sigma))
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--split", choices=("validation", "test"), default="validation")
    parser.add_argument("--variant", action="append", default=None)
    parser.add_argument("--noise", default="0,0.003,0.01,0.03")
    parser.add_argument("--run-noise", default=None, help="the noise levels to run (of --noise)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--lamp", default="D65", help="the broadband lamp (a colour-science name)")
    parser.add_argument("--cameras", default=None, help="comma-separated camera-name substrings")
    parser.add_argument("--csv", default=None)
    args = parser.parse_args()
    cameras, basis = paper_split_cameras(args.split, args.data_dir)
    wanted = args.cameras.split(",") if args.cameras else []
    noise_levels = [float(v) for v in args.noise.split(",")]
    run = [float(v) for v in args.run_noise.split(",")] if args.run_noise else noise_levels
    rows: list[str] = []

    def keep(scene: SyntheticScene, row: SyntheticRow, result: EstimateResult) -> None:
        line = row_of(scene, row, result)
        if line is not None:
            rows.append(line)
            print(line, flush=True)

    # run_protocol's seeds run over the whole split and noise list; ``only`` renders the subset's
    # very scenes.
    run_protocol(
        cameras,
        basis,
        variants=args.variant or ["LED+Flu"],
        noise_levels=noise_levels,
        seed=args.seed,
        broadband_lamp=args.lamp,
        on_result=keep,
        only=lambda name, noise: noise in run and (not wanted or any(w in name for w in wanted)),
    )
    off = [r for r in rows if float(r.split('",')[1].split(",")[2]) > MAPPING_FAILURE_NM]
    fields = [r.split('",', 1)[1].split(",") for r in off]
    uncovered = [f for f in fields if float(f[7]) > COVERED_SIGMAS and not mapping_warned(f[11])]
    print(
        f"{args.split} split, seed {args.seed}: {len(rows)} mappings, > {MAPPING_FAILURE_NM:g} nm "
        f"{len(off)}, of them beyond {COVERED_SIGMAS:g}σ at the worst pixel {len(uncovered)}"
    )
    unwarned = [r.split('",', 1)[1].split(",") for r in rows]
    unwarned = [f for f in unwarned if not mapping_warned(f[11])]
    for index, band in enumerate(BANDS):
        values = np.array([float(f[len(f) - len(BANDS) + index]) for f in unwarned])
        values = values[np.isfinite(values)]
        if values.size:
            print(
                f"  {band} band of the grid, {values.size} unwarned: median |error|/σ "
                f"{np.median(values):.2f}, beyond {COVERED_SIGMAS:g}σ {int(np.sum(values > COVERED_SIGMAS))}"
            )
    if args.csv:
        Path(args.csv).write_text(COLUMNS + "\n" + "\n".join(rows) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
