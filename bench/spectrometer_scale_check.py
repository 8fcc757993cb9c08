"""How well does the Hg-line check find the validation protocol's spectrometer offset? (decision 0069)

For every camera's scene of a split (seed 0, one scene each, as ``calib validate`` draws it), the
fluorescent lamp's reference spectrum as the scene's spectrometer reports it is checked
(:func:`calib.core.spectrometer_scale.check_spectrometer_scale`); the fitted mean offset over the grid
is compared with the offset the protocol drew. Prints per scene: slit, sampling, drawn offset,
fitted offset ± σ, error / σ, or why the check declined; then the share of scenes checked, the
error's RMS, the median σ and the share within ±2σ, by slit; the slit factor the isolated lines
measured (true FWHM / stated; the protocol's instrument has the slit it states, so its truth is 1,
decision 0099) the same way; and the checks' CPU time (the check
alone, the scenes' rendering left out: decision 0090).

    python bench/spectrometer_scale_check.py --split validation --data-dir DIR
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from calib.core.spectrometer_scale import check_spectrometer_scale
from calib.evaluation.validation.protocol import ProtocolSettings, render_task_scene, split_tasks
from calib.evaluation.validation.splits import load_splits


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("validation", "test"), default="validation")
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--lamp", default="FL2")
    args = parser.parse_args()
    settings = ProtocolSettings()
    loaded, _ = load_splits(args.data_dir)
    split = loaded.validation if args.split == "validation" else loaded.test
    rows = []
    cpu_s = 0.0
    for task in split_tasks(split, settings):
        scene = render_task_scene(task)
        reading = scene.plan.spectrometer
        lamp = scene.observations.get(args.lamp)
        if reading is None or lamp is None or lamp.spectrum_bandwidth_nm is None:
            continue
        grid = settings.grid
        started = time.process_time()
        outcome = check_spectrometer_scale(
            lamp.spectrum,
            lamp.spectrum_bandwidth_nm,
            lamp=args.lamp,
            range_nm=(grid.start_nm, grid.stop_nm),
        )
        cpu_s += time.process_time() - started
        if isinstance(outcome, str):
            print(
                f"{task.camera.name:40s} slit {reading.bandwidth_nm:4.1f} nm step "
                f"{reading.step_nm:g}  drawn {reading.offset_nm:+.3f}  declined: {outcome}"
            )
            rows.append((reading.bandwidth_nm, reading.offset_nm, np.nan, np.nan, np.nan, np.nan))
            continue
        fitted, sigma = outcome.mean_offset_nm, outcome.sigma_nm
        # The protocol's spectrometer has the slit it states: the measured factor's truth is 1.
        slit = outcome.slit_factor
        factor, factor_sigma = (np.nan, np.nan) if slit is None else slit
        print(
            f"{task.camera.name:40s} slit {reading.bandwidth_nm:4.1f} nm step {reading.step_nm:g}"
            f"  drawn {reading.offset_nm:+.3f}  fitted {fitted:+.3f} ± {sigma:.3f}  "
            f"z {(fitted - reading.offset_nm) / sigma:+.2f}  ({len(outcome.lines)} features)  "
            f"slit factor {factor:.3f} ± {factor_sigma:.3f}"
        )
        rows.append((reading.bandwidth_nm, reading.offset_nm, fitted, sigma, factor, factor_sigma))
    table = np.array(rows)
    print(
        f"\ncheck CPU: {cpu_s:.2f} s for {len(rows)} spectra, {1e3 * cpu_s / len(rows):.0f} ms each"
    )
    print("\n| slit (nm) | scenes | checked | error RMS (nm) | median σ (nm) | within ±2σ |")
    print("|---|---|---|---|---|---|")
    for low, high in ((2, 4), (4, 6), (6, 8), (8, 10.01), (0, 100)):
        chosen = table[(table[:, 0] >= low) & (table[:, 0] < high)]
        done = chosen[np.isfinite(chosen[:, 2])]
        label = "all" if high == 100 else f"{low}–{high:g}"
        if done.size == 0:
            print(f"| {label} | {len(chosen)} | 0 | — | — | — |")
            continue
        error = done[:, 2] - done[:, 1]
        print(
            f"| {label} | {len(chosen)} | {len(done)} | {np.sqrt(np.mean(error**2)):.3f} | "
            f"{np.median(done[:, 3]):.3f} | {100 * np.mean(np.abs(error) <= 2 * done[:, 3]):.0f} % |"
        )
    print("\n| slit (nm) | slit measured | factor − 1 RMS | median σ | within ±1σ | within ±2σ |")
    print("|---|---|---|---|---|---|")
    for low, high in ((2, 4), (4, 6), (6, 8), (8, 10.01), (0, 100)):
        chosen = table[(table[:, 0] >= low) & (table[:, 0] < high)]
        done = chosen[np.isfinite(chosen[:, 4])]
        label = "all" if high == 100 else f"{low}–{high:g}"
        if done.size == 0:
            print(f"| {label} | 0 of {len(chosen)} | — | — | — | — |")
            continue
        error = done[:, 4] - 1.0
        print(
            f"| {label} | {len(done)} of {len(chosen)} | {np.sqrt(np.mean(error**2)):.3f} | "
            f"{np.median(done[:, 5]):.3f} | {100 * np.mean(np.abs(error) <= done[:, 5]):.0f} % | "
            f"{100 * np.mean(np.abs(error) <= 2 * done[:, 5]):.0f} % |"
        )


if __name__ == "__main__":
    main()
