"""The optics a user may state, and the ranges the project takes them in.

One source for ``calib estimate``'s ``--grooves-per-mm``, ``--focal-length-mm`` and
``--pixel-pitch-um`` (:mod:`calib.cli.options`) and an inputs file's ``estimate:`` block
(:mod:`calib.pipeline.inputs_file`), so a value means the same in either place. No imports, so the
command line's help loads it without the estimators.
"""

#: ``--grooves-per-mm``: a grating sheet's nominal line density (lines/mm).
GROOVES_PER_MM = (1.0, 10000.0)
#: ``--focal-length-mm``: the lens' focal length (mm).
FOCAL_LENGTH_MM = (0.1, 5000.0)
#: ``--pixel-pitch-um``: the sensor's pixel pitch (µm).
PIXEL_PITCH_UM = (0.1, 100.0)
