"""Least squares under linear inequality constraints (Lawson & Hanson's LSI → LDP → NNLS).

``min ‖E x − f‖₂  subject to  G x ≥ h`` — used where a sensitivity ``s = B x`` written in a basis
must stay non-negative at every wavelength (``G = B``, ``h = 0``), which no bound on ``x`` expresses.

Method (Lawson & Hanson, *Solving Least Squares Problems*, 1974, ch. 23): with ``E = Q R`` the problem
becomes a least-distance problem ``min ‖z‖ s.t. (G R⁻¹) z ≥ h − G R⁻¹ Qᵀf`` in ``z = R x − Qᵀ f``,
whose solution follows from one non-negative least-squares problem (``scipy.optimize.nnls``). The
result is exact (an active-set solution, not an iterate), deterministic and fast for the small
systems here.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import EstimationError, InputError


def lstsq_inequality(
    design: ArrayLike, target: ArrayLike, constraints: ArrayLike, bounds: ArrayLike
) -> FloatArray:
    """Solve ``min ‖E x − f‖₂ s.t. G x ≥ h``.

    Parameters
    ----------
    design
        ``E``, shape ``(m, k)`` with full column rank ``k``.
    target
        ``f``, shape ``(m,)``.
    constraints
        ``G``, shape ``(p, k)``.
    bounds
        ``h``, shape ``(p,)``.

    Returns
    -------
    numpy.ndarray
        ``x``, shape ``(k,)``.

    Raises
    ------
    InputError
        Shapes that do not fit, or ``E`` without full column rank.
    EstimationError
        The constraints cannot all be met.

    Examples
    --------
    >>> x = lstsq_inequality([[1.0, 0.0], [0.0, 1.0]], [1.0, -1.0], [[0.0, 1.0]], [0.0])
    >>> bool(np.allclose(x, [1.0, 0.0]))  # the second unknown held at its bound 0
    True
    """
    from scipy.optimize import nnls

    E = np.asarray(design, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64)
    G = np.asarray(constraints, dtype=np.float64)
    h = np.asarray(bounds, dtype=np.float64)
    if E.ndim != 2 or f.shape != (E.shape[0],):
        raise InputError(f"design {E.shape} and target {f.shape} do not fit", source="lstsq")
    if G.ndim != 2 or G.shape[1] != E.shape[1] or h.shape != (G.shape[0],):
        raise InputError(
            f"constraints {G.shape} and bounds {h.shape} do not fit {E.shape[1]} unknowns",
            source="lstsq",
        )
    q, r = np.linalg.qr(E)
    diagonal = np.abs(np.diag(r))
    if diagonal.size < E.shape[1] or np.min(diagonal) <= 1e-12 * max(float(diagonal.max()), 1e-300):
        raise InputError(
            "the least-squares design has dependent columns (too few or too similar data)",
            source="lstsq",
        )
    projected = q.T @ f
    r_inverse = np.linalg.inv(r)
    ldp_matrix = G @ r_inverse
    ldp_bounds = h - ldp_matrix @ projected
    if G.shape[0] == 0 or np.all(ldp_bounds <= 0):
        z = np.zeros(E.shape[1])  # the unconstrained solution already satisfies G x ≥ h
    else:
        n = ldp_matrix.shape[1]
        stacked = np.vstack([ldp_matrix.T, ldp_bounds[None, :]])
        unit = np.zeros(n + 1)
        unit[n] = 1.0
        weights, _ = nnls(stacked, unit, maxiter=50 * stacked.shape[1])
        residual = stacked @ weights - unit
        if np.linalg.norm(residual) <= 1e-12 or abs(residual[n]) <= 1e-14:
            raise EstimationError("the inequality constraints cannot all be satisfied")
        z = -residual[:n] / residual[n]
    return np.asarray(r_inverse @ (z + projected), dtype=np.float64)
