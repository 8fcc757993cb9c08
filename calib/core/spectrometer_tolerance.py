"""What a spectroradiometer's data sheet promises, as the project assumes it everywhere.

One source for the σ budget (:mod:`calib.methods.uncertainty`), the validation protocol's
reference spectrometer (:class:`calib.evaluation.validation.rig_errors.SpectrometerError`) and the
twin's in-spec instrument (:mod:`mocks.bench.deviation`) share these tolerances. They do not draw
the same errors from them (decision 0055): the protocol draws a constant scale offset and states
the bandwidth exactly, the twin a straight-line scale error between independent ends (σ 0.225 nm
over 400–700 nm against the budget's 0.289 nm) and a ±25 % slit; the budget covers both. No
imports, so the twin's station loads it without the estimators.

Where an estimate's fluorescent lamp shows its Hg lines clearly enough, the scale is measured
instead of assumed (:mod:`calib.core.spectrometer_scale`, decision 0069): the spectra are corrected
and the check's σ replaces :data:`WAVELENGTH_SCALE_NM` × :data:`IN_SPEC_TOLERANCE_SIGMA`.
"""

#: Wavelength-scale tolerance (nm): the ±0.5 nm a PR-670 / calibrated compact spectrometer
#: specifies (PR-655 ±2 nm, CS-2000 ±0.3 nm).
WAVELENGTH_SCALE_NM = 0.5
#: Relative tolerance of a stated slit bandwidth (a slit's FWHM is specified to about ±25 %).
BANDWIDTH_TOLERANCE = 0.25
#: σ per unit of tolerance of an instrument within its specification: anywhere inside ±tolerance,
#: uniformly (σ = tolerance/√3), as the twin and the validation protocol draw it (decision 0038).
IN_SPEC_TOLERANCE_SIGMA = 3.0**-0.5
#: The broadest spectrometer bandwidth (FWHM of the slit function, nm) the project takes: twice the
#: broadest instrument it models (an i1Pro in its 10 nm bands, 25 nm; a PR-655 is 8 nm, a CS-2000
#: 5 nm). A broader "slit" blurs a lamp's spectrum over a camera channel's own width: a typo (a
#: range, a wavelength). The rig's configuration and an estimate's inputs both refuse one.
MAX_BANDWIDTH_NM = 50.0
