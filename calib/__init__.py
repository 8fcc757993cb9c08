"""Estimation of camera spectral sensitivity: pure numpy/scipy, no hardware imports.

See :mod:`calib.spectra` for spectra and grids, :mod:`calib.observations` for the estimator's input
and :func:`calib.estimate` (the front function over every registered method) for the estimate.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from calib.methods import estimate, register_method

__all__ = ["estimate", "register_method"]


def __getattr__(name: str) -> Any:
    # The estimators pull in scipy (≈ 1 s): imported on first use, not with every ``calib.*`` module.
    if name in __all__:
        import calib.methods

        return getattr(calib.methods, name)
    raise AttributeError(f"module 'calib' has no attribute {name!r}")
