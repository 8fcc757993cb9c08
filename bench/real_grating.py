"""The real grating captures as a user brings them: RMS and ±2σ coverage against monochromator truth.

Reads ``../shared/data/real-grating/`` at run time (never committed; exits 0 with a note when it is
absent) and estimates through the registry's ``auto`` choice with the σ budget
(:mod:`calib.methods.uncertainty`), as ``calib estimate`` would:

- *Nikon D7000* (Butcher, rawproc ``.dat`` exports): the halogen profile with the Dedolight's
  5 nm spectrum, and the CFL profile whose spectrum nobody measured (the built-in tri-phosphor line
  list, marked ``spectrum_known=False``: ``auto`` uses it for the mapping only). No direct measurement
  and no grating file: the known-grating solve through an assumed flat grating (the default), and
  beside it through η₁ marginalised over the physical families and the flat candidate, weighed by
  the camera prior (``assumed_grating="physical"``, decisions 0074 and 0088). Truth:
  rawtoaces' monochromator curve of the D7000 (not in the basis). The validation protocol's
  variants "A + FL unmeasured, no direct" (and "…, physical η") are this set-up.
- *Canon EOS 10D* (rrogge, FITS planes): sunlight (AM0 × the atmosphere's transmission) through
  the LHires III 150 l/mm, whose maker's efficiency curve is the grating file. Both 10D ground
  truths left out of the basis.

Scores as the data's README states them: estimate and truth each normalised to a maximum of 1, the
estimate scaled by one least-squares factor, RMS over 400–700 nm / 10 nm; ±2σ coverage is the share
of those samples within twice the (equally scaled) stated σ. The 10D is also scored with each
channel normalised on its own (its planes come from a demosaicked conversion).

    python bench/real_grating.py [--data-dir ../shared/data]

``bench/real_decompose.py`` takes these RMS apart (decision 0100).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.datasets import find_camera, load_collection
from calib.core.grating_file import GratingEfficiency
from calib.core.lamp_specs import lamp_from_spec
from calib.core.observations import CHANNEL_GAINS_KEY, LampObservation
from calib.core.result import EstimateResult
from calib.core.spectra import DEFAULT_GRID, Spectrum, read_spectrum_csv, read_table
from calib.image.profile_files import read_fits_profile, read_rawproc_dat
from calib.methods import estimate
from calib.methods.known_grating import KnownGratingOptions
from calib.model.bases import CameraBasis, camera_basis, default_camera_basis

GRID = DEFAULT_GRID


def scaled_difference(
    result: EstimateResult, truth: FloatArray, *, per_channel: bool = False
) -> tuple[FloatArray, FloatArray, float]:
    """The estimate less ``truth`` ``(f, 3)`` as the data's README scores it (module docstring),
    the equally scaled stated σ, and the least-squares factor."""
    estimate_curves = result.physical_sensitivity()
    sigma = result.sensitivity_sigma
    sigma = (
        np.zeros_like(estimate_curves)
        if sigma is None
        else sigma / float(np.clip(result.sensitivity, 0.0, None).max())
    )
    target = truth / truth.max()
    if per_channel:
        target = truth / truth.max(axis=0)
        peak = estimate_curves.max(axis=0)
        estimate_curves, sigma = estimate_curves / peak, sigma / peak
    factor = float(np.sum(estimate_curves * target) / np.sum(estimate_curves**2))
    return factor * estimate_curves - target, factor * sigma, factor


def rms_and_coverage(
    result: EstimateResult, truth: FloatArray, *, per_channel: bool = False
) -> tuple[float, float]:
    """RMS and ±2σ coverage of the estimate against ``truth`` (module docstring); the solar
    analog (``bench/solar_validate.py --sensitivity``) scores the 10D's set-up with it."""
    difference, sigma, _ = scaled_difference(result, truth, per_channel=per_channel)
    rms = math.sqrt(float(np.mean(difference**2)))
    return rms, float(np.mean(np.abs(difference) <= 2 * sigma))


def scores(result: EstimateResult, truth: FloatArray, *, per_channel: bool = False) -> str:
    """RMS and ±2σ coverage of the estimate against ``truth`` ``(f, 3)`` (module docstring)."""
    difference, sigma, factor = scaled_difference(result, truth, per_channel=per_channel)
    sigma = sigma / factor
    rms, coverage = rms_and_coverage(result, truth, per_channel=per_channel)
    budget = result.quality.uncertainty
    share = budget.get("share_of_variance", {})
    biggest = max(share, key=share.get) if share else "—"
    # The named components alone (without the validation-fitted factor): what the band would be
    # if the method's factor were 1 — the real data say whether the factor or a component is short.
    scale = float(budget.get("coverage_scale", 1.0) or 1.0)
    named = float(np.mean(np.abs(difference) <= 2 * factor * sigma / scale))
    error_rms = rms if rms > 0 else math.nan
    sigma_ratio = math.sqrt(float(np.mean((factor * sigma) ** 2))) / error_rms
    chi2 = budget.get("reduced_chi2")
    components = ", ".join(
        f"{name} {factor * value / error_rms:.2f}" for name, value in budget.get("rms", {}).items()
    )
    return (
        f"RMS {rms:.4f}, ±2σ coverage {100 * coverage:.0f} % (named components alone "
        f"{100 * named:.0f} %, factor {scale:.2f}), σ/err {sigma_ratio:.2f}, reduced χ² "
        f"{'—' if chi2 is None else f'{chi2:.3g}'}, verdict {result.quality.verdict}, largest σ "
        f"share: {biggest}\n    σ component RMS / error RMS: {components}"
    )


#: The spectrum standing in for the D7000's CFL, which nobody measured: the built-in tri-phosphor
#: line list (Hg, Tb, Eu at their physical wavelengths; the spec the mapping stage names for a lamp
#: nobody measured, and the one ``tests/test_wavelength_real.py`` maps it with). Before decision
#: 0055 this bench used colour-science's FL11, a 5 nm table whose lines sit on its nodes (Hg 546.1
#: at 545, 435.8 at 435): the line fit refused it and the mapping rested on the whole-profile fit,
#: 1.8 nm off at 546 nm (a real-data handling bug of this bench, not a tuning).
D7000_CFL_SPEC = "builtin:cfl-triphosphor"


def d7000_lamps(folder: Path) -> list[LampObservation]:
    """The D7000 pair as a user brings it: the CFL (spectrum unknown: :data:`D7000_CFL_SPEC`,
    ``spectrum_known=False`` so ``auto`` uses it for the mapping only) and the halogen with the
    Dedolight's 5 nm spectrum."""
    cfl = read_rawproc_dat(folder / "D7000_calibration.dat")
    halogen = read_rawproc_dat(folder / "D7000_spectrum.dat")
    dedolight = read_spectrum_csv(folder / "Dedolight_5nm.csv", name="Dedolight")
    return [
        replace(
            cfl.to_observation("CFL", lamp_from_spec(D7000_CFL_SPEC), kind="fluorescent"),
            metadata={"spectrum_known": False},
        ),
        halogen.to_observation("halogen", dedolight, kind="halogen"),
    ]


def d7000_truth(data_dir: Path) -> FloatArray:
    """rawtoaces' monochromator curve of the D7000 on :data:`GRID` ``(f, 3)``."""
    truth = find_camera(load_collection("rawtoaces", data_dir), "nikon d7000")
    return truth.sensitivity.resample(GRID, "interpolate").values


def d7000(folder: Path, data_dir: Path) -> None:
    lamps = d7000_lamps(folder)
    basis = default_camera_basis(GRID, data_dir=data_dir)
    result = estimate(lamps, basis=basis, assume_flat_grating=True)
    physical = estimate(
        lamps,
        basis=basis,
        assume_flat_grating=True,
        options=KnownGratingOptions(assumed_grating="physical"),
    )
    curves = d7000_truth(data_dir)
    choice = result.diagnostics["method_choice"]
    print(f"Nikon D7000: {choice['method']} ({choice['reason']})")
    print(f"  vs rawtoaces: {scores(result, curves)}")
    print(f"  the option assumed_grating='physical', vs rawtoaces: {scores(physical, curves)}")
    assumed = physical.diagnostics.get("grating")
    if isinstance(assumed, dict) and "most_likely" in assumed:
        weights = ", ".join(f"{k} {v:.2f}" for k, v in assumed["family_weights"].items())
        print(
            f"  assumed η: most likely {assumed['most_likely']}, family weights {weights}, "
            f"{assumed['effective_candidates']:.1f} effective candidates"
        )
    for flag in result.quality.flags:
        print(f"  flag: {flag.line()}")


def solar_spectrum(folder: Path) -> Spectrum:
    """The 10D's source: Wehrli's AM0 table (1 nm) × the atmosphere's transmission (airmass 2.13),
    350–800 nm."""
    irradiance = read_table(folder / "Wehrli85.csv").rows
    transmission = read_table(folder / "Atmosphere Transmission.csv").rows
    wavelength = irradiance[:, 0]
    values = irradiance[:, 1] * np.interp(wavelength, transmission[:, 0], transmission[:, 1])
    keep = (wavelength >= 350) & (wavelength <= 800)
    return Spectrum(wavelength[keep], values[keep], name="sun (AM0 × atmosphere)")


class Canon10DInputs(NamedTuple):
    """The 10D as this bench estimates it: the sunlight's observation, the maker's curve as the
    grating file, the basis without the 10D and both 10D ground truths on :data:`GRID`."""

    sun: LampObservation
    grating: GratingEfficiency
    basis: CameraBasis
    truths: dict[str, FloatArray]


def canon_10d_inputs(folder: Path, data_dir: Path, solar: Spectrum | None = None) -> Canon10DInputs:
    """:class:`Canon10DInputs` (``solar``: the source spectrum, :func:`solar_spectrum` by default)."""
    profile = read_fits_profile([folder / f"Solar Spectrum Canon EOS 10D {c}.fit" for c in "RGB"])
    catalogue = read_table(folder / "LHires III Grating Efficiency 150.csv").rows
    grating = GratingEfficiency(
        catalogue[:, 0], catalogue[:, 1] / catalogue[:, 1].max(), source="LHires III 150 l/mm"
    )
    records = list(load_collection("solomatov-akkaynak-2023", data_dir))
    kept = [r for r in records if "10d" not in r.name.lower()]
    basis = camera_basis(
        [r.sensitivity for r in kept],
        grid=GRID,
        source=f"solomatov-akkaynak-2023 without the 10D ({len(kept)})",
        camera_names=[r.name for r in kept],
    )
    # The planes come from a demosaicked conversion (PixInsight's DSLR_RAW through dcraw): their
    # channel gains are not the raw data's, so the balance is the population's (decision 0050).
    sun = replace(
        profile.to_observation("sun", solar or solar_spectrum(folder), kind="other"),
        metadata={CHANNEL_GAINS_KEY: "unknown"},
    )
    truths = {
        r.name: r.sensitivity.resample(GRID, "interpolate").values
        for r in records
        if "10d" in r.name.lower()
    }
    return Canon10DInputs(sun, grating, basis, truths)


def canon_10d(folder: Path, data_dir: Path) -> None:
    inputs = canon_10d_inputs(folder, data_dir)
    result = estimate([inputs.sun], basis=inputs.basis, grating=inputs.grating)
    choice = result.diagnostics["method_choice"]
    print(f"Canon EOS 10D: {choice['method']} ({choice['reason']})")
    for name, curves in inputs.truths.items():
        print(f"  vs {name}: {scores(result, curves)}")
        print(f"  vs {name}, per channel: {scores(result, curves, per_channel=True)}")
    for flag in result.quality.flags:
        print(f"  flag: {flag.line()}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    here = Path(__file__).resolve().parents[1]
    parser.add_argument("--data-dir", type=Path, default=here.parent / "shared" / "data")
    args = parser.parse_args(argv)
    real = args.data_dir / "real-grating"
    cameras = args.data_dir / "camera_sensitivities"
    if not real.is_dir() or not cameras.is_dir():
        print(f"real grating data not found under {args.data_dir}: nothing to do")
        return 0
    d7000(real / "butcher-nikon-d7000-2020-08", cameras)
    canon_10d(real / "rrogge-canon-eos-10d", cameras)
    return 0


if __name__ == "__main__":
    sys.exit(main())
