"""The validation protocol: camera splits that cannot be tuned to, physical scenes, the rig's errors.

:mod:`~calib.evaluation.validation.splits` (training / validation / test cameras),
:mod:`~calib.evaluation.validation.rig_errors` (what a real rig gets wrong),
:mod:`~calib.evaluation.validation.scenes` (physical gratings and geometry, rendered in 1-D),
:mod:`~calib.evaluation.validation.protocol` (estimates through the registry, scored), and
:mod:`~calib.evaluation.validation.report` (tables per split, method and channel). The paper's own
protocol stays in :mod:`calib.evaluation.synthetic` ("paper reproduction"). Design: decision 0023.
"""
