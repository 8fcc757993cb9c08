"""The twin spectrometer as real ones are: a wavelength scale and a slit within specification.

A spectroradiometer's reading is off by its wavelength-scale error (the pixel it calls ``λ`` sees
``λ + δ(λ)``) and blurred by a slit whose true width differs from the stated one. The makers
specify (from their data sheets; [?] confirm against the sheet of the unit in use):

=====================  =====================================  ===============================
instrument             wavelength accuracy                    bandwidth (FWHM)
=====================  =====================================  ===============================
PR-655                 ±2 nm                                  8 nm
PR-670                 ±0.5 nm                                5 nm (standard aperture)
CS-2000                ±0.3 nm (Hg-Cd lines)                  5 nm or less
Ocean USB2000+ / STS   no figure; factory fit to Hg-Ar lines  1.5 / 3 nm (25 µm slit)
i1Pro (spotread)       no figure                              10 nm optical (3.3 nm sampling)
=====================  =====================================  ===============================

The twin draws one realisation per station from its seed alone (stream
:data:`SPECTROMETER_DEVIATION_STREAM`), the same whichever instrument ``emulate:`` picks, so twins
that differ only in the emulated instrument see the same scale error and the same relative slit
deviation (the spectrometer-equivalence bench compares like with like). Its sizes are those the σ
budget assumes (:mod:`calib.core.spectrometer_tolerance`, shared with
:mod:`calib.methods.uncertainty` and the validation protocol's
:class:`calib.evaluation.validation.rig_errors.SpectrometerError`), so the band and the twin agree
by construction:

- the scale error at 380 nm and at 780 nm, each uniform within ±:data:`WAVELENGTH_SCALE_NM`
  (0.5 nm: inside the PR-655's and PR-670's specification, a calibrated compact spectrometer's
  typical residual; a CS-2000 does better), straight between them — an offset and a small linear
  term, within ±0.5 nm everywhere;
- the slit's FWHM the stated one times ``1 + u``, ``u`` uniform within
  ±:data:`BANDWIDTH_TOLERANCE` (25 %).

The rig is told the stated scale and bandwidth only (the drivers' data-sheet values); the truth
file records the draw (``twin-truth.json``'s ``spectrometer``). ``devices.spectrometer.in_spec_error:
false`` makes the instrument exactly as stated (the twin before this draw).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calib.core.spectrometer_tolerance import BANDWIDTH_TOLERANCE, WAVELENGTH_SCALE_NM
from mocks.bench.spec import TwinSpec
from mocks.emulators.radiometer import InstrumentDeviation

#: Random stream of the spectrometer's in-spec errors, mixed with the seed.
SPECTROMETER_DEVIATION_STREAM = 3
#: The wavelength range the scale error is drawn over (its ends; the error is linear between).
SCALE_RANGE_NM = (380.0, 780.0)


def draw_deviation(seed: int) -> InstrumentDeviation:
    """The twin spectrometer's scale error and slit deviation for station ``seed`` (module doc).

    Examples
    --------
    >>> deviation = draw_deviation(20251121)
    >>> bool(abs(deviation.true_wavelength_nm(np.array([380.0, 780.0])) - [380, 780]).max() <= 0.5)
    True
    >>> draw_deviation(20251121) == deviation
    True
    """
    rng = np.random.default_rng([seed, SPECTROMETER_DEVIATION_STREAM])
    low_nm, high_nm = SCALE_RANGE_NM
    at_low, at_high = rng.uniform(-WAVELENGTH_SCALE_NM, WAVELENGTH_SCALE_NM, size=2)
    factor = 1.0 + rng.uniform(-BANDWIDTH_TOLERANCE, BANDWIDTH_TOLERANCE)
    return InstrumentDeviation(
        offset_nm=float(at_low + at_high) / 2.0,
        slope=float(at_high - at_low) / (high_nm - low_nm),
        bandwidth_factor=float(factor),
        reference_nm=(low_nm + high_nm) / 2.0,
    )


def spectrometer_deviation(spec: TwinSpec) -> InstrumentDeviation | None:
    """The emulated spectrometer's in-spec errors (``None``: the spectrometer is real, or
    ``in_spec_error`` is off); from the seed alone, whichever instrument is emulated."""
    if spec.spectrometer_model is None or not spec.spectrometer_in_spec_error:
        return None
    return draw_deviation(spec.seed)


def spectrometer_truth(spec: TwinSpec) -> dict[str, Any] | None:
    """What ``twin-truth.json`` records of the spectrometer (``None``: it is real)."""
    if spec.spectrometer_model is None:
        return None
    return {"emulate": spec.spectrometer_model, **deviation_record(spectrometer_deviation(spec))}


def deviation_record(deviation: InstrumentDeviation | None) -> dict[str, Any]:
    """The draw as ``twin-truth.json`` records it (``in_spec_error`` false: none)."""
    if deviation is None:
        return {"in_spec_error": False}
    low_nm, high_nm = SCALE_RANGE_NM
    ends = deviation.true_wavelength_nm(np.array([low_nm, high_nm])) - [low_nm, high_nm]
    return {
        "in_spec_error": True,
        "wavelength_offset_nm": deviation.offset_nm,
        "wavelength_slope_nm_per_nm": deviation.slope,
        "reference_nm": deviation.reference_nm,
        "wavelength_error_at_380_nm": float(ends[0]),
        "wavelength_error_at_780_nm": float(ends[1]),
        "bandwidth_factor": deviation.bandwidth_factor,
        "meaning": "the reading reported at λ is the light of λ + offset + slope·(λ − reference), "
        "through a slit bandwidth_factor times as wide as the instrument states",
    }


def deviation_from_record(record: Any) -> InstrumentDeviation | None:
    """The inverse of :func:`deviation_record` (``None`` when off or absent)."""
    if not isinstance(record, dict) or not record.get("in_spec_error"):
        return None
    return InstrumentDeviation(
        offset_nm=float(record["wavelength_offset_nm"]),
        slope=float(record["wavelength_slope_nm_per_nm"]),
        bandwidth_factor=float(record["bandwidth_factor"]),
        reference_nm=float(record["reference_nm"]),
    )
