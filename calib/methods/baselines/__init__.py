"""The published methods the paper compares against, each in the module named after its paper.

Jiang et al. 2013 (a colour chart under a known light), Toivonen & Klami 2020 (transmissive
filters), Han et al. 2012 (a fluorescent chart under unknown light), Solomatov & Akkaynak 2023
(the camera's colour matrices and a colour chart), with their shared input checks
(:mod:`calib.methods.baselines.inputs`). Each is reached through :func:`calib.methods.estimate`;
a baseline receives its basis and must not call the registry itself. They import :mod:`calib.core`, :mod:`calib.model`,
:mod:`calib.wavelength` and :mod:`calib.methods`.
"""
