"""Estimation of camera spectral sensitivity: pure numpy/scipy, no hardware imports.

See :mod:`calib.spectra` for spectra and grids and :mod:`calib.observations` for the estimators' input.
"""
