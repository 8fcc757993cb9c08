"""Stage 4, the pixel→wavelength mapping: every way to find it, and nowhere else.

Emission and absorption lines and peaks (:mod:`calib.wavelength.peaks`), and the fit of a whole
profile against the lamp's measured spectrum through the grating equation
(:mod:`calib.wavelength.search`), with honest ambiguity. ``calib.wavelength`` imports only
:mod:`calib.core` and :mod:`calib.model`.
"""
