"""Stage 2, the image formation model: what the camera records of a lamp through the grating.

The forward model of Makabe et al. (2025, Eq. 2–3) on the working grid (hat functions, lamp
spectra integrated onto it), camera bases and priors, linear models and their solvers, colour charts
(patch RGBs), the optical resolution. ``calib.model`` imports only :mod:`calib.core`.
"""
