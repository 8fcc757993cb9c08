"""The 2nd order on the 1st order's red end: the estimate with and without its mask (decision 0032).

The twin's optics (:class:`mocks.bench.optics.TwinOptics`: the shipped configuration's camera, the
Nikon 5100 by default, and its blazed grating, η₂ included) render each lamp's first-order pixel
integrals unblurred, with the 2nd order added where the grating equation puts it (1st-order
wavelength ``λ₁`` receives order 2 of ``λ₁/2``). The camera is then estimated through the known
grating (the twin's true η₁) with the true mapping, on a grid reaching 780 nm, so that nothing but
the 2nd order separates the estimate from the truth: once with the lamps' 2nd orders masked
(:func:`calib.model.forward.second_order_onset_nm`, the default) and once fitting every pixel as
1st-order light (the mask switched off). RE ×10⁻² against the true camera on the grid.

    python bench/second_order.py [--grating blazed|sinusoidal] [--lamps D65 FL2 gauss:400:20]
                                 [--noise 0.002] [--seed 0]
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from pathlib import Path
from unittest.mock import patch

import numpy as np

import calib.methods.responses as responses
from calib.core.grating_file import GratingEfficiency
from calib.core.lamp_specs import lamp_from_spec
from calib.core.metrics import relative_error
from calib.core.observations import LampObservation
from calib.core.spectra import WavelengthGrid
from calib.methods.known_grating import estimate_known_grating
from calib.model.bases import fallback_camera_basis
from calib.model.forward import second_order_onset_nm
from mocks.bench import TwinSpec
from mocks.bench.optics import TwinOptics
from rig.config import load_config

ROOT = Path(__file__).resolve().parents[1]
GRID = WavelengthGrid(380.0, 780.0, 5.0)
RED_END_NM = 700.0


def observations(
    optics: TwinOptics, lamps: list[str], noise: float, rng: np.random.Generator
) -> list[LampObservation]:
    """Each lamp's unblurred first order (+ 2nd order) at every sensor pixel of the band."""
    found = []
    start, stop = optics.band_range_px
    pixel = np.arange(math.ceil(start), math.floor(stop) + 1, dtype=np.float64)
    for spec in lamps:
        lamp = lamp_from_spec(spec)
        signal = optics.first_order(lamp, blur=False).signal
        edges = np.concatenate([pixel - 0.5, [pixel[-1] + 0.5]])
        cumulative = np.stack(
            [np.interp(edges, signal.position_px, signal.cumulative[:, c]) for c in range(3)],
            axis=1,
        )
        clean = np.diff(cumulative, axis=0)
        sigma = np.full_like(clean, noise * float(clean.max()))
        profile = clean + sigma * rng.standard_normal(clean.shape)
        found.append(LampObservation(spec, lamp, pixel, profile, profile_sigma=sigma, kind="other"))
    return found


def no_onset(lamp: object) -> float:
    return math.inf


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lamps", nargs="+", default=["D65", "FL2", "gauss:400:20"])
    parser.add_argument("--noise", type=float, default=0.002, help="σ, fraction of the peak")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--grating", default="blazed", help="the twin's grating: blazed (shipped) or sinusoidal"
    )
    args = parser.parse_args()
    data = load_config(ROOT / "config.yaml").model_dump(mode="json")
    data["devices"]["camera"]["grating"]["model"] = args.grating
    spec = TwinSpec.from_config_data(data)
    assert spec.camera is not None
    optics = TwinOptics.build(spec.camera)
    lamps = observations(optics, args.lamps, args.noise, np.random.default_rng(args.seed))
    for lamp in lamps:
        print(f"{lamp.name}: 2nd order from {second_order_onset_nm(lamp.spectrum):g} nm")
    without = observations(
        replace(optics, second_order_efficiency=optics.second_order_efficiency.scaled(0.0)),
        args.lamps,
        args.noise,
        np.random.default_rng(args.seed),
    )
    flat = GratingEfficiency(optics.efficiency.wavelength_nm, optics.efficiency.values)
    physical = replace(flat, model={"model": optics.grating["kind"], "parameters": optics.grating})
    basis = fallback_camera_basis(grid=GRID, exclude=[optics.camera_name])
    truth = optics.sensitivity.resample(GRID).values
    cases = [
        ("no 2nd order in the scene, no mask", without, flat, False),
        ("no 2nd order in the scene, masked", without, flat, True),
        ("2nd order fitted as 1st-order light", lamps, flat, False),
        ("2nd order masked (η₂ unknown)", lamps, flat, True),
        ("2nd order modelled (physical η₂)", lamps, physical, True),
    ]
    for label, scene, grating, onset in cases:
        # Without the onset, every pixel is fitted as 1st-order light (the estimator before).
        with patch.object(
            responses, "second_order_onset_nm", second_order_onset_nm if onset else no_onset
        ):
            began = time.process_time()
            result = estimate_known_grating(
                scene, grating=grating, basis=basis, grid=GRID, mapping=optics.mapping
            )
            spent = time.process_time() - began
        red = GRID.wavelength_nm >= RED_END_NM
        scale = float(truth.max())
        error = np.abs(result.sensitivity / result.sensitivity.max() - truth / scale)[red]
        print(
            f"{label}: RE {100 * relative_error(result.physical_sensitivity(), truth):.2f} ×10⁻², largest "
            f"error beyond {RED_END_NM:g} nm {100 * float(error.max()):.2f} % of the peak "
            f"(CPU {spent:.2f} s)"
        )


if __name__ == "__main__":
    main()
