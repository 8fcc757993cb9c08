"""Stage 6, the rig as a spectrometer: a lamp's SPD with a calibrated camera.

SPD recovery (Alvarez et al. 2014, :mod:`calib.spd.alvarez2014`), light-source recognition, CCT
and white balance (:mod:`calib.spd.light_sources`), and the whole measurement from RAW brackets to
files (:mod:`calib.spd.pipeline`, behind ``calib spd``). ``calib.spd`` imports
:mod:`calib.core`, :mod:`calib.model`, :mod:`calib.image` and :mod:`calib.wavelength`.
"""
