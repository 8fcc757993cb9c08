"""Stage 1, the shared types: what every later stage reads, writes and raises.

Spectra on wavelength grids (resampling by integration, CSV by column name), observations and
results, typed errors, metrics, lamps named on a command line, camera datasets, grating files, the
pixel→wavelength mapping *types*, file checksums and the software record; and the seams to the
heavy libraries, each imported on first use: :mod:`calib.core.colour_data` (colour-science) and
:mod:`calib.core.figures` (matplotlib). ``calib.core`` imports no other package of ``calib``.
"""
