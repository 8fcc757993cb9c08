"""Han et al. (2012) under lights the method is not told about: sensitivity RE and daylight recovery.

For each camera (colour-science's three built-ins; with ``--data-dir`` also measured cameras, each
with a basis of the *other* cameras as the paper's footnote 2 allows) one chart of 16 seeded
fluorescent paints and a ColorChecker is photographed under CIE daylights of 4500–20000 K, a
fluorescent tube (FL2), a white LED (LED-B3) and tungsten (A), with Gaussian noise of 0.1 % of the
brightest patch. Prints RE (Makabe et al. Eq. 16, ×10⁻²) per light, and for daylights the CCT error
of the recovered daylight (K).

    python bench/han2012_unknown_light.py [--data-dir DIR] [--noise 0.001]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from calib.core.colour_data import cie_daylight, colorchecker
from calib.core.datasets import SOLOMATOV, colour_science_cameras, load_collection
from calib.core.lamp_specs import colour_lamp
from calib.core.metrics import relative_error
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, Spectrum
from calib.methods.baselines.han2012 import (
    FOURIER,
    Han2012Options,
    recover_han2012,
    render_fluorescent_chart,
    synthetic_fluorescent_paints,
)
from calib.model.bases import CameraBasis, default_camera_basis
from calib.spd.light_sources import correlated_colour_temperature

DAYLIGHTS_K = (4500.0, 5500.0, 6500.0, 8000.0, 12000.0, 20000.0)
OTHER_LIGHTS = ("FL2", "LED-B3", "A")


def run_camera(
    name: str,
    camera: MultiSpectrum,
    seed: int,
    noise: float,
    basis: CameraBasis | None,
) -> tuple[list[float], list[float]]:
    truth = camera.resample(DEFAULT_GRID, out_of_range="zero").values
    truth = truth / truth.max()
    lights: list[Spectrum] = [cie_daylight(k) for k in DAYLIGHTS_K]
    lights += [colour_lamp(n) for n in OTHER_LIGHTS]
    paints = synthetic_fluorescent_paints(np.random.default_rng(seed))  # one chart per camera
    errors, cct_errors, cells = [], [], []
    for index, light in enumerate(lights):
        rng = np.random.default_rng([seed, index])
        chart = render_fluorescent_chart(
            paints, colorchecker(), camera, light, rng=rng, noise_fraction=noise
        )
        smoothness = (0.03, 0.03, 0.01) if basis is not None else (0.01, 0.01, 0.004)
        try:
            result = recover_han2012(
                chart,
                basis=FOURIER if basis is None else basis,
                options=Han2012Options(smoothness=smoothness),
            )
        except Exception as exc:
            cells.append(f"failed ({exc.__class__.__name__})")
            continue
        error = relative_error(result.sensitivity, truth)
        errors.append(error)
        cell = f"{100 * error:5.1f}"
        if index < len(DAYLIGHTS_K) and result.illuminant is not None:
            delta = (
                correlated_colour_temperature(result.illuminant).cct_k["Ohno 2013"]
                - correlated_colour_temperature(light).cct_k["Ohno 2013"]
            )
            cct_errors.append(delta)
            cell += f" ({delta:+6.0f} K)"
        cells.append(cell)
    print(f"{name[:30]:30s} " + "  ".join(f"{c:>15s}" for c in cells), flush=True)
    return errors, cct_errors


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--noise", type=float, default=0.001)
    options = parser.parse_args()
    header = [f"D{k / 100:.0f}" for k in DAYLIGHTS_K] + list(OTHER_LIGHTS)
    print(f"noise {100 * options.noise:g} % of the brightest patch; RE ×10⁻² (daylight ΔCCT)")
    print(f"{'camera':30s} " + "  ".join(f"{h:>15s}" for h in header))
    print("— Fourier basis, 9 terms (the paper)")
    fourier: list[float] = []
    for index, record in enumerate(colour_science_cameras()):
        errors, _ = run_camera(record.name, record.sensitivity, 100 + index, options.noise, None)
        fourier += errors
    if options.data_dir is not None:
        records = load_collection(SOLOMATOV, options.data_dir)[::5]
        print("— measured cameras, Fourier basis")
        for index, record in enumerate(records):
            errors, _ = run_camera(
                record.name, record.sensitivity, 200 + index, options.noise, None
            )
            fourier += errors
        print("— measured cameras, basis of the other cameras (footnote 2)")
        camera_basis_errors: list[float] = []
        cct: list[float] = []
        for index, record in enumerate(records):
            basis = default_camera_basis(
                DEFAULT_GRID, data_dir=options.data_dir, exclude=[record.name]
            )
            errors, cct_errors = run_camera(
                record.name, record.sensitivity, 200 + index, options.noise, basis
            )
            camera_basis_errors += errors
            cct += cct_errors
        print(
            f"camera basis: RE mean {100 * np.mean(camera_basis_errors):.1f}, median "
            f"{100 * np.median(camera_basis_errors):.1f}, max {100 * np.max(camera_basis_errors):.1f} "
            f"(×10⁻²); daylight |ΔCCT| median {np.median(np.abs(cct)):.0f} K"
        )
    print(
        f"Fourier basis: RE mean {100 * np.mean(fourier):.1f}, median "
        f"{100 * np.median(fourier):.1f}, max {100 * np.max(fourier):.1f} (×10⁻²)"
    )


if __name__ == "__main__":
    main()
