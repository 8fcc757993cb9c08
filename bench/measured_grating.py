"""The grating measured by the rig's spectrometer, on the small test twin (decision 0032).

Captures the twin twice with the same seed — without and with ``measure_grating`` (LED-B3, 18
first-order aims, 2 repeats) — writes the twin's truth beside each session and estimates them
with ``rig estimate``'s defaults. Prints the RE ×10⁻² of each against the twin's camera, the
measured grating's fit against the twin's η₁, and, on the session without the measurement, the
known-grating path through the *true* η (its floor on this twin) and ``multilamp``.

    python bench/measured_grating.py [--out DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from calib.core.grating_file import GratingEfficiency, read_grating_file
from rig.capture import run_capture
from rig.config import RigConfig
from rig.estimate import estimate_session
from rig.twin import read_twin_truth, write_twin_truth

# The small twin lives with the tests; make the checkout importable when run as a script.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.rig.twin_setup import twin_config_data


def capture(directory: Path, measure: bool) -> Path:
    data = twin_config_data(directory / "sessions")
    if measure:
        data["measure_grating"] = {"lamp": "LED-B3", "grooves_per_mm": 500, "repeats": 2}
    config = RigConfig.model_validate(data)
    outcome = run_capture(config)
    if outcome.exit_status != "success":
        raise SystemExit(f"the capture failed: {outcome.message}")
    write_twin_truth(config, outcome.session)
    return outcome.session


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="measured-grating-"))
    plain, measured = capture(out / "plain", False), capture(out / "measured", True)
    for label, session, options in (
        ("η estimated (rig estimate's choice)", plain, {}),
        ("η measured in the beams (known grating)", measured, {}),
        ("multilamp", plain, {"method": "multilamp"}),
    ):
        began = time.process_time()
        outcome = estimate_session(session, force=True, report=False, **options)  # type: ignore[arg-type]
        spent = time.process_time() - began
        error = outcome.truth_relative_error or float("nan")
        method = outcome.estimate.result.method
        print(f"{label}: {method}, RE {100 * error:.2f} ×10⁻² (CPU {spent:.1f} s)")
    truth = read_twin_truth(plain / "twin-truth.json")
    true_eta = truth.grating_efficiency
    given = GratingEfficiency(true_eta.wavelength_nm, true_eta.values, obtained="maker's curve")
    outcome = estimate_session(plain, force=True, report=False, settings={"grating": given})
    print(f"the true η (known grating): RE {100 * (outcome.truth_relative_error or 0):.2f} ×10⁻²")
    grating = read_grating_file(measured / "estimate" / "grating.json")
    assert grating.model is not None and grating.efficiency_sigma is not None
    eta = true_eta.at(grating.wavelength_nm)
    eta = eta / eta.max()
    inside = np.abs(grating.efficiency - eta) <= 2 * grating.efficiency_sigma
    name = next(k for k in grating.model["parameters"] if k != "scale")
    print(
        f"measured: {grating.model['model']} {name} {grating.model['parameters'][name]:.2f} ± "
        f"{grating.model['parameter_sigma'][name]:.2f}, scale "
        f"{grating.model['parameters']['scale']:.4f}; η₁ (relative) within "
        f"{float(np.max(np.abs(grating.efficiency - eta))):.4f} of the truth, inside ±2σ at "
        f"{100 * float(np.mean(inside)):.0f} % of {eta.size} nodes; reduced χ² "
        f"{grating.model['reduced_chi2']:.2f}"
    )


if __name__ == "__main__":
    main()
