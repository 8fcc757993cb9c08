"""Stage 3, from RAW files to profiles: the measurements the estimators take.

LibRaw decoding to linear colour planes (regions of interest for large frames) and RAW metadata,
the HDR merge of a bracket with its noise model, block-averaged images, and the detection of the
direct spot and the first orders with 1-D profile extraction and σ (:mod:`calib.image.profiles`).
``calib.image`` imports only :mod:`calib.core`.
"""
