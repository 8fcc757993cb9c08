"""Estimation of camera spectral sensitivity: pure numpy/scipy, no hardware imports.

The packages follow the data: :mod:`calib.core` (the shared types: spectra, observations, results,
errors, metrics, datasets, grating files, mapping types) → :mod:`calib.model` (the image formation
model, bases, linear models) → :mod:`calib.image` (RAW → HDR → profiles) → :mod:`calib.wavelength`
(the pixel→wavelength mapping) → :mod:`calib.methods` (the estimators and the front function
:func:`calib.methods.estimate`) → :mod:`calib.spd` (the rig as a spectrometer) → :mod:`calib.use`
(what the curves are for: IDT, colour correction, raw-to-raw, dcamprof) →
:mod:`calib.pipeline` (files in → estimate → files out) → :mod:`calib.evaluation` (synthetic
protocol, comparison, lamp planning) → :mod:`calib.cli`. Each imports only the ones before it.
"""
