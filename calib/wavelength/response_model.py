"""A profile explained by the lamp times a smooth per-channel response — fast, batched, differentiable.

The model of one lamp's first-order profile::

    m_c(p) = Σ_t k_t ∫_{pixel p+h−t} e(λ) r_c(λ) dλ,

``e`` the lamp, ``r_c = η s_c`` a response linear between nodes, ``k`` the camera's line spread. For a
trial mapping the response is found by penalised least squares under a Gaussian camera prior
(variable projection), and the cost is what remains. Three things make it fast:

- **The lamp is integrated once** onto a fine axis (exact hat-function averages of its linear
  interpolant, in ``O(samples)``: :func:`hat_averages`), whatever its sampling; the cumulative
  integral of ``e·φ_j`` for every response node ``j`` is a table. A pixel's entry is a difference
  of that table at its edge wavelengths, and with the line spread the row is a short difference
  filter over the edges (:meth:`LampColumns.evaluate`), so a blurred pixel row costs ``L + 1``
  table look-ups per node it touches.
- **Rows are banded**: a pixel (or a binned pixel, or a blurred one) touches a few consecutive
  nodes, so the model matrix is stored as ``(n, w)`` values and a first column per row, and its
  normal matrix's diagonals come from one ``bincount`` — for a whole batch of trial mappings at
  once (:meth:`ResponseModel.costs`), whose dense systems are then written once.
- **Analytic derivatives**: ``∂A/∂x`` is the lamp density at the edges times ``∂λ_edge/∂x`` from the
  mapping family, and the exact variable-projection Jacobian (Golub & Pereyra 1973) of the
  residual follows from the same factorised normal matrices (:meth:`ResponseModel.residual`).

The per-channel systems are regularised by a tiny ridge (``RIDGE`` times their mean diagonal) so a
batch never falls back to a per-channel least-squares solve: nodes no light reaches are held at the
smoothest value their penalty allows.

References
----------
Golub, G., Pereyra, V. (1973). The differentiation of pseudo-inverses and nonlinear least squares
problems whose variables separate. SIAM J. Numer. Anal. 10(2), 413–432.
"""

from __future__ import annotations

import functools
import math
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.observations import LampObservation, profile_sigma
from calib.core.spectra import Spectrum, WavelengthGrid
from calib.model.bases import CameraPrior, whitening
from calib.model.forward import hat_matrix, pixel_edges

#: Relative ridge added to every per-channel normal matrix (times its mean diagonal).
RIDGE = 1e-10
#: Relative error of the profile model itself, added in quadrature to the noise (as the search's).
MODEL_ERROR = 0.002
#: Relative smoothness (second-difference penalty) of the response beyond the working range.
MARGIN_SMOOTHNESS = 1e-2
#: The grating efficiency the camera prior is widened by, around a flat one: relative σ and
#: correlation length (nm).
EFFICIENCY_SIGMA = 0.3
EFFICIENCY_CORRELATION_NM = 80.0
#: Correlation length (nm) of the response's smooth departure from the camera prior.
FLEX_CORRELATION_NM = 25.0
#: A blurred pixel's row reads more edges than this: each edge's cumulatives are computed once
#: for the pixels sharing it (:meth:`ResponseModel._edge_cumulatives`; the same numbers, 1.2–3×
#: faster from a 3-tap line spread on; for an unblurred profile the table costs more than it saves).
SHARED_EDGES_FROM = 3
#: Up to this many band values (``K·n·w``) the normal matrices' pair products are gathered along
#: the band's short last axis (one mapping: 3× faster); beyond, pixels last (a scan's batch: 10×).
SMALL_BAND = 16384
#: From this many rows (``K·n``) on, a scan's batch holds its band's last column apart
#: (:attr:`Band.outer`): the band is as wide as its widest rows (a pixel at a junction of the node
#: pieces meets four hats), and the last column is nonzero in few rows (decision 0157).
OUTER_FROM = 4096
#: Up to this many entries (``n·N``) of one mapping's dense matrix its normal matrices are the
#: dense product ``(WA)ᵀ(WA)`` (fewer calls); beyond, they come from the band (``n·w²`` work
#: instead of ``n·N²``: at the final stage's 941 pixels × 75 nodes half a residual's time).
DENSE_NORMAL = 10000

IntArray = NDArray[np.intp]

#: :class:`ResponseModel`'s cached properties that depend only on what :meth:`ResponseModel.reference`
#: keeps (the nodes, lamp table, edges, filter, penalty, weights and prior), not on the scale and
#: penalty weights it holds: a reference model reads its model's.
_REFERENCE_SHARED = (
    "_two_edges",
    "_edge_index",
    "_column_support",
    "_penalty_reach",
    "_unit_pulls",
    "_weighted_target",
    "_normal_weight_cache",
    "_mean_pair_cache",
    "_band_layouts",
)

_potrf = lapack.dpotrf
_potrs = lapack.dpotrs


# ------------------------------------------------------------------------------ the lamp, once


def response_prior(
    prior: CameraPrior, nodes_nm: FloatArray, flexibility: float
) -> tuple[FloatArray, FloatArray]:
    """Mean ``(N, 3)`` and precision factors ``(3, N, N)`` of the response ``r_c = η s_c`` at ``nodes``.

    The camera prior (interpolated from its grid to the nodes), widened by a smooth grating
    efficiency — ``η`` = 1 plus a relative variation of σ :data:`EFFICIENCY_SIGMA` correlated over
    :data:`EFFICIENCY_CORRELATION_NM` — and by a *flexibility* term: a Gaussian-process deviation
    (correlation :data:`FLEX_CORRELATION_NM`) of ``flexibility`` times the channel's peak, so that a
    camera unlike the training set (or measured with finer structure) stays representable while the
    response keeps a camera's shape.
    """
    interpolate = hat_matrix(prior.grid, nodes_nm, clamp=True)
    distance = (nodes_nm[:, None] - nodes_nm[None, :]) / EFFICIENCY_CORRELATION_NM
    efficiency_kernel = EFFICIENCY_SIGMA**2 * np.exp(-0.5 * distance**2)
    flex_distance = (nodes_nm[:, None] - nodes_nm[None, :]) / FLEX_CORRELATION_NM
    flex_kernel = np.exp(-0.5 * flex_distance**2)
    mean = interpolate @ prior.mean
    factors = []
    for c in range(3):
        channel_mean = mean[:, c]
        covariance = (
            interpolate @ prior.covariance[c] @ interpolate.T
            + np.outer(channel_mean, channel_mean) * efficiency_kernel
            + (flexibility * float(np.max(channel_mean))) ** 2 * flex_kernel
        )
        factors.append(whitening(covariance))
    return np.asarray(mean, dtype=np.float64), np.stack(factors)


#: :func:`shared_response_prior`'s results, per prior (held weakly: they go with it) and per
#: ``(nodes, flexibility)``.
_PRIOR_CACHE: weakref.WeakKeyDictionary[
    CameraPrior, dict[tuple[bytes, float], tuple[FloatArray, FloatArray]]
] = weakref.WeakKeyDictionary()
#: At most this many node sets and flexibilities are kept per prior (a search's stages use 3).
PRIOR_CACHE_SIZE = 8


def shared_response_prior(
    prior: CameraPrior, nodes_nm: FloatArray, flexibility: float
) -> tuple[FloatArray, FloatArray]:
    """:func:`response_prior`, computed once per prior, nodes and flexibility (read-only arrays).

    It does not depend on the lamp or the mapping: a search's stages build one model per lamp
    (two with a fluorescent shot) and several stages share their nodes and flexibility, and each
    build whitened the same three covariances again (three ``eigh``, a third to a half of a
    model's build). :class:`CameraPrior` is immutable (frozen) and compared by identity, so the
    prior object is the key; the same numbers as :func:`response_prior`'s.
    """
    per_prior = _PRIOR_CACHE.setdefault(prior, {})
    key = (np.asarray(nodes_nm, dtype=np.float64).tobytes(), float(flexibility))
    found = per_prior.get(key)
    if found is None:
        mean, factors = response_prior(prior, nodes_nm, flexibility)
        mean.flags.writeable = factors.flags.writeable = False
        if len(per_prior) >= PRIOR_CACHE_SIZE:
            per_prior.pop(next(iter(per_prior)))
        found = per_prior[key] = (mean, factors)
    return found


def hat_averages(spectrum: Spectrum, start_nm: float, step_nm: float, count: int) -> FloatArray:
    """Exact averages of a spectrum's linear interpolant under the hats of a uniform axis.

    Node ``m`` (at ``start + m·step``) receives ``∫ e(λ) ψ_m(λ) dλ / step`` with ``ψ_m`` the
    triangle of half-width ``step`` (the spectrum is zero outside its range). This is the
    projection of :meth:`calib.core.spectra.Spectrum.resample` with ``"integrate"`` (decision
    0001), computed from cumulative moments in ``O(samples + count)`` so a 0.1 nm spectrum costs
    no more than its length.

    Examples
    --------
    >>> flat = Spectrum([400.0, 500.0], [2.0, 2.0])
    >>> hat_averages(flat, 420.0, 1.0, 3)
    array([2., 2., 2.])
    """
    x = spectrum.wavelength_nm
    v = spectrum.values
    reference = 0.5 * (x[0] + x[-1])
    xs = x - reference
    width = np.diff(xs)
    slope = np.diff(v) / width
    # Cumulative ∫v and ∫(λ − ref)v up to each sample.
    segment0 = 0.5 * (v[1:] + v[:-1]) * width
    segment1 = (
        xs[:-1] * v[:-1] * width + (xs[:-1] * slope + v[:-1]) * width**2 / 2 + slope * width**3 / 3
    )
    moment0 = np.concatenate([[0.0], np.cumsum(segment0)])
    moment1 = np.concatenate([[0.0], np.cumsum(segment1)])

    def moments(at: FloatArray) -> tuple[FloatArray, FloatArray]:
        clipped = np.clip(at - reference, xs[0], xs[-1])
        k = np.clip(np.searchsorted(xs, clipped, side="right") - 1, 0, xs.size - 2)
        t = clipped - xs[k]
        base, s = v[k], slope[k]
        zero = moment0[k] + base * t + s * t**2 / 2
        one = moment1[k] + xs[k] * base * t + (xs[k] * s + base) * t**2 / 2 + s * t**3 / 3
        return zero, one

    nodes = start_nm + step_nm * np.arange(-1, count + 1, dtype=np.float64)
    zero, one = moments(nodes)
    centred = nodes - reference
    # ∫ e (λ − a_{m−1})/h over [a_{m−1}, a_m] and ∫ e (a_{m+1} − λ)/h over [a_m, a_{m+1}].
    rising = (np.diff(one) - centred[:-1] * np.diff(zero)) / step_nm
    falling = (centred[1:] * np.diff(zero) - np.diff(one)) / step_nm
    return np.asarray((rising[:-1] + falling[1:]) / step_nm, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class NodeLayout:
    """Response nodes: margin pieces and the working range, each piece's hats cut at its ends.

    Attributes
    ----------
    nodes_nm
        ``(N,)`` in piece order (a junction wavelength appears in both pieces).
    piece_bounds
        ``(N, 2)``: the ends of the piece each node belongs to.
    working
        Indices of the working range's nodes.
    difference
        Second differences within the margin pieces, ``(rows, N)``.
    step_nm
        Node spacing.
    """

    nodes_nm: FloatArray
    piece_bounds: FloatArray
    working: IntArray
    difference: FloatArray
    step_nm: float

    @classmethod
    def build(
        cls, grid: WavelengthGrid, range_nm: tuple[float, float], step_nm: float
    ) -> NodeLayout:
        """Nodes every ``step_nm`` over the grid and over margins reaching into ``range_nm``."""
        lo, hi = range_nm
        count = round((grid.stop_nm - grid.start_nm) / step_nm)
        working_nodes = grid.start_nm + step_nm * np.arange(count + 1.0)
        pieces: list[FloatArray] = []
        if grid.start_nm - lo >= step_nm:
            n_left = int((grid.start_nm - lo) // step_nm)
            pieces.append(grid.start_nm - step_nm * np.arange(n_left, -1, -1.0))
        first_working = sum(piece.size for piece in pieces)
        pieces.append(working_nodes)
        if hi - grid.stop_nm >= step_nm:
            n_right = int((hi - grid.stop_nm) // step_nm)
            pieces.append(grid.stop_nm + step_nm * np.arange(0, n_right + 1.0))
        nodes = np.concatenate(pieces)
        bounds = np.concatenate(
            [np.tile([piece[0], piece[-1]], (piece.size, 1)) for piece in pieces]
        )
        rows: list[FloatArray] = []
        offset = 0
        for piece in pieces:
            if piece is not working_nodes:
                for row in range(piece.size - 2):
                    line = np.zeros(nodes.size)
                    line[offset + row : offset + row + 3] = (1.0, -2.0, 1.0)
                    rows.append(line)
            offset += piece.size
        return cls(
            nodes_nm=nodes,
            piece_bounds=bounds,
            working=np.arange(first_working, first_working + working_nodes.size),
            difference=np.array(rows).reshape(len(rows), nodes.size),
            step_nm=step_nm,
        )

    @cached_property
    def support(self) -> tuple[FloatArray, FloatArray]:
        """Each node's hat support ``(lo, hi)``, cut at its piece's ends (both non-decreasing)."""
        lo = np.maximum(self.nodes_nm - self.step_nm, self.piece_bounds[:, 0])
        hi = np.minimum(self.nodes_nm + self.step_nm, self.piece_bounds[:, 1])
        return lo, hi


@dataclass(frozen=True, eq=False)
class LampColumns:
    """``∫ e φ_j`` up to every fine-axis node, for every response node ``j`` (a lookup table).

    The lamp ``e`` enters once, as hat averages on the fine axis (:func:`hat_averages`); each
    column's density ``e·φ_j`` is linear between fine nodes, so its cumulative integral is exact
    and continuously differentiable in the integration limit.
    """

    start_nm: float
    step_nm: float
    density: FloatArray
    cumulative: FloatArray

    @classmethod
    def build(cls, lamp: Spectrum, layout: NodeLayout, fine_step_nm: float) -> LampColumns:
        lo = float(layout.piece_bounds[:, 0].min())
        hi = float(layout.piece_bounds[:, 1].max())
        count = round((hi - lo) / fine_step_nm) + 1
        axis = lo + fine_step_nm * np.arange(count, dtype=np.float64)
        lamp_fine = hat_averages(lamp, lo, fine_step_nm, count)
        nodes = layout.nodes_nm
        size = nodes.size
        # Column j's density e·φ_j is zero outside its hat's support, so only the fine nodes
        # around it are computed (a block of ``span`` rows from ``start_j``; the dense table's
        # other entries are the zeros and the column's total they would sum to): the same
        # numbers as the dense (count, N) hats and cumulative sum, a fifth of the passes over
        # the table (decision 0131).
        span = min(int(np.ceil(2.0 * layout.step_nm / fine_step_nm)) + 3, count)
        start = np.clip(
            np.floor((nodes - layout.step_nm - lo) / fine_step_nm).astype(np.intp) - 1,
            0,
            count - span,
        )
        rows = start + np.arange(span)[:, None]  # (span, N), all on the axis
        at = axis[rows]
        hats = np.clip(1.0 - np.abs(at - nodes[None, :]) / layout.step_nm, 0.0, None)
        outside = (at < layout.piece_bounds[None, :, 0] - 1e-9) | (
            at > layout.piece_bounds[None, :, 1] + 1e-9
        )
        hats[outside] = 0.0
        # The block's first and last rows lie a fine step beyond the hat's support (unless the
        # block meets the axis's end), so the rows outside it hold no density.
        if np.any(hats[0][start > 0] != 0.0) or np.any(hats[-1][start + span < count] != 0.0):
            raise AssertionError("a response node's hat reaches past its block of fine nodes")
        block = lamp_fine[rows] * hats  # (span, N)
        partial = np.zeros_like(block)
        partial[1:] = np.cumsum(0.5 * (block[1:] + block[:-1]) * fine_step_nm, axis=0)
        columns = np.arange(size)
        density = np.zeros((count, size))
        density[rows, columns] = block
        cumulative = (np.arange(count)[:, None] >= start + span) * partial[-1]
        cumulative[rows, columns] = partial
        return cls(lo, fine_step_nm, density, cumulative)

    def evaluate(
        self, wavelength_nm: FloatArray, column: IntArray, *, derivative: bool = False
    ) -> tuple[FloatArray, FloatArray | None]:
        """``C_j(λ)`` (and ``∂C_j/∂λ = e φ_j (λ)``) for broadcast arrays of wavelengths and columns."""
        flat, t, low, high = self._interval(wavelength_nm, column)
        rise = high - low
        # (high − low)·(t/2): the half taken on the small factor (exact, the same numbers).
        value = self.cumulative.ravel().take(flat) + self.step_nm * t * (low + rise * (0.5 * t))
        if not derivative:
            return value, None
        # density_at's numbers from the same interval (no second search).
        return value, (low + rise * t) * self._inside(wavelength_nm)

    def _inside(self, wavelength_nm: FloatArray) -> NDArray[np.bool_]:
        """Strictly inside the axis (beyond it the cumulative is constant: no density)."""
        last = self.density.shape[0] - 1
        inside = (wavelength_nm > self.start_nm) & (
            wavelength_nm < self.start_nm + last * self.step_nm
        )
        return np.asarray(inside, dtype=np.bool_)

    def _interval(
        self, wavelength_nm: FloatArray, column: IntArray
    ) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:
        """Each wavelength's node on the fine axis (flat index with its column), its fraction
        through the interval, and the density at the interval's two ends."""
        count, size = self.density.shape
        last = count - 1
        # np.clip's values by hand (its Python wrapper costs more than the work here).
        position = np.minimum(
            np.maximum((wavelength_nm - self.start_nm) / self.step_nm, 0.0), float(last)
        )
        index = np.minimum(position.astype(np.intp), last - 1)
        flat = index * size + column
        density = self.density.ravel()
        return flat, position - index, density.take(flat), density[size:].take(flat)

    def density_at(self, wavelength_nm: FloatArray, column: IntArray) -> FloatArray:
        """``∂C_j/∂λ = e φ_j (λ)`` (zero beyond the axis, where the cumulative is constant)."""
        _, t, low, high = self._interval(wavelength_nm, column)
        return np.asarray((low + (high - low) * t) * self._inside(wavelength_nm), dtype=np.float64)


# -------------------------------------------------------------------------------- the model


def _difference_filter(kernel: FloatArray | None) -> FloatArray:
    """Weights of the edge cumulatives that make one blurred pixel: ``d_i = k_{L−i} − k_{L−1−i}``."""
    taps = np.array([1.0]) if kernel is None else np.asarray(kernel, dtype=np.float64)
    if taps.size % 2 != 1:
        raise InputError("the line spread kernel must have an odd length", source="kernel")
    padded = np.concatenate([[0.0], taps, [0.0]])  # padded[i + 1] = k_i
    length = taps.size
    return np.array([padded[length - i + 1] - padded[length - i] for i in range(length + 1)])


@dataclass(frozen=True)
class Band:
    """A banded model matrix for a batch: values ``(K, n, w)``, first columns ``(K, n)``.

    ``derivative`` ``(K, n, w, P)`` when asked for (``∂A/∂x``).
    """

    values: FloatArray
    first: IntArray
    derivative: FloatArray | None = None
    #: The lamp density ``e φ_j`` at each entry's edges, ``(w, L + 1, K, n)``, zero beyond the
    #: lamp axis (:meth:`LampColumns.density_at`), when :meth:`ResponseModel.band` was asked for
    #: it: read by :meth:`ResponseModel.band_derivative` instead of locating the edges again.
    slope: FloatArray | None = None
    #: The band's last column held apart (``values`` then the others, ``(K, n, w − 1)``): the
    #: rows (flat in ``K·n``) where it can be nonzero and its values there ``(R,)``; zero in every
    #: other row (:meth:`ResponseModel._outer_column`).
    outer: tuple[IntArray, FloatArray] | None = None

    @cached_property
    def columns(self) -> IntArray:
        width = self.values.shape[-1]
        return np.asarray(self.first[..., None] + np.arange(width), dtype=np.intp)


@dataclass(frozen=True, eq=False)
class ResponseModel:
    """One lamp's profile model for any mapping (see the module docstring).

    Build with :meth:`build`; evaluate batches of mappings with :meth:`costs` and single ones with
    :meth:`residual` (value and exact Jacobian in the mapping parameters).

    Attributes
    ----------
    observation
        The (possibly binned) observation.
    layout, columns
        Response nodes and the lamp's lookup table.
    edges_px
        Pixel edges ``(n + 1,)``.
    filter
        Difference filter over ``L + 1`` edges (``L`` the kernel's length).
    target
        ``W y`` ``(n, 3)`` with ``W = 1/σ``.
    weights
        ``W`` ``(n, 3)``.
    penalty
        ``ΔᵀΔ`` ``(N, N)`` of the margins' second differences.
    prior_factor, precision, prior_mean
        The working range's prior: whitening factors ``(3, n_w, N)`` (rows ``F (r − β μ)``),
        the precision ``FᵀF`` ``(3, N, N)`` and the mean ``(3, N)`` (for a camera of unit scale).
    smoothness
        The margins' relative penalty weight.
    scale, penalty_weight
        The prior's scale ``β̂`` and the penalty weights ``(3,)`` of a reference mapping (held
        fixed by :meth:`residual`, so its Jacobian is exact; :meth:`costs` may refresh them).
    """

    observation: LampObservation
    layout: NodeLayout
    columns: LampColumns
    edges_px: FloatArray
    filter: FloatArray
    target: FloatArray
    weights: FloatArray
    penalty: FloatArray
    prior_factor: FloatArray
    precision: FloatArray
    prior_mean: FloatArray
    smoothness: float
    scale: float = 1.0
    penalty_weight: FloatArray | None = None
    #: :meth:`reference`'s mapping: its edge wavelengths and band, which the
    #: fit's first :meth:`residual_lazy` (at that mapping) reads instead of recomputing.
    referenced: tuple[FloatArray, Band] | None = field(default=None, repr=False)
    #: The band reaches where a cut hat's cumulative still changes (:meth:`_column_support`).
    cut_ramps: bool = False

    @classmethod
    def build(
        cls,
        observation: LampObservation,
        grid: WavelengthGrid,
        *,
        node_step_nm: float,
        prior: CameraPrior,
        flexibility: float,
        kernel: FloatArray | None = None,
        margin_nm: float = 30.0,
        sigma_floor: float = 0.0,
        fine_step_nm: float = 1.0,
        smoothness: float = MARGIN_SMOOTHNESS,
        cut_ramps: bool = False,
    ) -> ResponseModel:
        """The model of ``observation`` with a camera-prior response on ``node_step_nm`` nodes.

        ``flexibility``: the response's smooth departure from the prior (a fraction of each
        channel's peak, :func:`response_prior`); ``sigma_floor``: σ is at
        least this fraction of the profile's peak (a coarse scan looks for a basin, which very
        precise data make too narrow to find); ``fine_step_nm``: the lamp's integration step;
        ``cut_ramps``: see :meth:`_column_support`.
        """
        lamp = observation.spectrum
        lo = max(grid.start_nm - margin_nm, lamp.range_nm[0])
        hi = min(grid.stop_nm + margin_nm, lamp.range_nm[1])
        if lo > grid.start_nm or hi < grid.stop_nm:
            raise InputError(
                f"lamp spectrum covers {lamp.range_nm[0]:g}–{lamp.range_nm[1]:g} nm but the grid "
                f"needs {grid.start_nm:g}–{grid.stop_nm:g} nm",
                source=lamp.name,
            )
        if prior.grid != grid:
            raise InputError(
                f"the camera prior is on grid {prior.grid}, not {grid}", source="prior"
            )
        layout = NodeLayout.build(grid, (lo, hi), node_step_nm)
        return cls._assembled(
            observation,
            layout,
            LampColumns.build(lamp, layout, fine_step_nm),
            pixel_edges(observation.pixel),
            _difference_filter(kernel),
            layout.difference.T @ layout.difference,
            prior=prior,
            flexibility=flexibility,
            sigma_floor=sigma_floor,
            smoothness=smoothness,
            cut_ramps=cut_ramps,
        )

    def with_prior(
        self, prior: CameraPrior, *, flexibility: float, sigma_floor: float
    ) -> ResponseModel:
        """The model :meth:`build` makes of the same observation, nodes, lamp table and line
        spread with another flexibility and σ floor: its node layout, lamp columns, pixel edges,
        filter and margin penalty are this model's (shared, not copied), the prior's terms and
        the weights are built anew; the scale and penalty weights are :meth:`build`'s defaults.

        A search's stages on the same bins and nodes differ only in these two (the refinement
        stage and the deciding stage's ranking): each built its own layout and lamp table, the
        same numbers (decision 0135)."""
        working = self.layout.nodes_nm[self.layout.working]
        if not (
            math.isclose(prior.grid.start_nm, working[0], abs_tol=1e-9)
            and math.isclose(prior.grid.stop_nm, working[-1], abs_tol=1e-9)
        ):
            raise InputError(
                f"the camera prior is on grid {prior.grid}, not on this model's "
                f"{working[0]:g}–{working[-1]:g} nm",
                source="prior",
            )
        return self._assembled(
            self.observation,
            self.layout,
            self.columns,
            self.edges_px,
            self.filter,
            self.penalty,
            prior=prior,
            flexibility=flexibility,
            sigma_floor=sigma_floor,
            smoothness=self.smoothness,
            cut_ramps=self.cut_ramps,
        )

    @classmethod
    def _assembled(
        cls,
        observation: LampObservation,
        layout: NodeLayout,
        columns: LampColumns,
        edges_px: FloatArray,
        filter_: FloatArray,
        penalty: FloatArray,
        *,
        prior: CameraPrior,
        flexibility: float,
        sigma_floor: float,
        smoothness: float,
        cut_ramps: bool,
    ) -> ResponseModel:
        """:meth:`build` from its layout, lamp table, edges, filter and penalty: the prior's
        terms (:func:`shared_response_prior`) and the weights."""
        working = layout.working
        mean, factors = shared_response_prior(prior, layout.nodes_nm[working], flexibility)
        size = layout.nodes_nm.size
        factor = np.zeros((3, working.size, size))
        factor[:, :, working] = factors
        embedded_mean = np.zeros((3, size))
        embedded_mean[:, working] = mean.T
        sigma = np.maximum(
            np.hypot(profile_sigma(observation), MODEL_ERROR * np.abs(observation.profile)),
            sigma_floor * float(np.max(observation.profile)),
        )
        weights = 1.0 / sigma
        return cls(
            observation=observation,
            layout=layout,
            columns=columns,
            edges_px=edges_px,
            filter=filter_,
            target=weights * observation.profile,
            weights=weights,
            penalty=penalty,
            prior_factor=factor,
            precision=factor.transpose(0, 2, 1) @ factor,
            prior_mean=embedded_mean,
            smoothness=smoothness,
            cut_ramps=cut_ramps,
        )

    @property
    def n_nodes(self) -> int:
        return int(self.layout.nodes_nm.size)

    # -------------------------------------------------------------------------- the band

    def band(
        self,
        edges_nm: FloatArray,
        edge_jacobian: FloatArray | None = None,
        *,
        slopes: bool = False,
    ) -> Band:
        """The banded model matrix for edge wavelengths ``(K, n + 1)`` (and ``∂/∂x`` from
        ``edge_jacobian`` ``(K, n + 1, P)``; with ``slopes``, the lamp density at the edges kept
        for a later :meth:`band_derivative`)."""
        band = self._band_values(edges_nm, slopes=slopes or edge_jacobian is not None)
        if edge_jacobian is None:
            return band
        return replace(band, derivative=self.band_derivative(edges_nm, edge_jacobian, band))

    @cached_property
    def _two_edges(self) -> bool:
        """The profile is not blurred: a pixel is the difference of its two edges' cumulatives
        (the filter is ``(−1, 1)``)."""
        return self.filter.size == 2 and self.filter[0] == -1.0 and self.filter[1] == 1.0

    @cached_property
    def _edge_index(self) -> IntArray:
        """The edges of the blurred pixels' windows, the ends repeated (``n + L``)."""
        half = (self.filter.size - 2) // 2
        n = self.edges_px.size - 1
        return np.asarray(np.clip(np.arange(n + 2 * half + 1) - half, 0, n), dtype=np.intp)

    @cached_property
    def _column_support(self) -> tuple[FloatArray, FloatArray]:
        """The columns a pixel's band holds: each node's hat support (:attr:`NodeLayout.support`)
        and, with :attr:`cut_ramps`, one lamp step past a piece's end where the hat is cut there.

        The lamp's density is linear between its fine nodes (:class:`LampColumns`), so a hat cut
        at a junction (the working range's ends) ramps to zero over the next fine step instead of
        at the junction itself; a band on the nominal support leaves that column out of a pixel
        that starts within the step, drops the ramp's light, and the cost jumps (by 0.12 in χ² on
        the speed bench's final fit, a pixel edge crossing 400 nm) — where a descent converging to
        its last digits meets it (decision 0124). With ``cut_ramps`` the cost is continuous.
        The search's scan and deciding stages keep the nominal support: their thresholds and
        their basins on the validation split were judged with it, and the broadband quadratic
        family's basins move with any change of their costs (decision 0115)."""
        return self._ramp_support if self.cut_ramps else self.layout.support

    @cached_property
    def _ramp_support(self) -> tuple[FloatArray, FloatArray]:
        """Each node's hat support and one lamp step past a piece's end where the hat is cut
        there (:meth:`_column_support`'s with :attr:`cut_ramps`): beyond it a column's cumulative
        is constant, so a pixel outside it has an exact zero in that column."""
        layout = self.layout
        fine = self.columns.step_nm
        return (
            np.maximum(layout.nodes_nm - layout.step_nm, layout.piece_bounds[:, 0] - fine),
            np.minimum(layout.nodes_nm + layout.step_nm, layout.piece_bounds[:, 1] + fine),
        )

    def _windows(self, edges_nm: FloatArray) -> tuple[FloatArray, IntArray]:
        """Each blurred pixel's ``L + 1`` edge wavelengths ``(K, n, L + 1)`` and the edge index."""
        count = self.filter.size  # L + 1 edges per blurred pixel
        index = self._edge_index
        # Unblurred (L = 1), the windows' edges are the edges themselves: no gathered copy.
        padded = edges_nm if count == 2 else edges_nm[:, index]
        return _sliding(np.ascontiguousarray(padded), count), index  # (K, n + L)

    def _band_values(
        self, edges_nm: FloatArray, *, slopes: bool = False, outer: bool = False
    ) -> Band:
        """The band of :meth:`band` (``outer``: its last column held apart, :attr:`Band.outer`,
        for a batch's normal sums; not with ``slopes`` or shared edges)."""
        windows, _ = self._windows(edges_nm)  # (K, n, L+1)
        low, high = _reduced(windows, np.minimum), _reduced(windows, np.maximum)
        support_lo, support_hi = self._column_support
        first = np.searchsorted(support_hi, low, side="right")
        last = np.searchsorted(support_lo, high, side="left") - 1
        size = self.n_nodes
        width = max(int((last - first).max()) + 1, 1)
        first = np.minimum(np.maximum(first, 0), max(size - width, 0))
        # With at least w nodes, first ≤ size − w: every column is a node, so the validity mask
        # is all ones and the clipped columns are the columns; a rising batch's signs are all
        # +1. Multiplying by one is exact, so those passes over the band are left out
        # (decision 0142).
        every_node = width <= size
        rising = _rising(edges_nm)
        if self.filter.size > SHARED_EDGES_FROM:
            values = self._edge_cumulatives(edges_nm, first, width)
            if not every_node:
                values = values * (first[..., None] + np.arange(width) < size)  # (K, n, w)
            return Band(values if rising else values * _signs(edges_nm), first)
        held_apart = outer and every_node and width > 1 and not slopes
        kept = width - 1 if held_apart else width
        # Laid out (w, L + 1, K, n), pixels last: every elementwise pass runs over whole rows of
        # pixels, not over the short (w, L + 1) axes (the same operations on the same numbers).
        column = first + np.arange(kept)[:, None, None]  # (w, K, n)
        edge_windows = _last_first(windows)  # (L + 1, K, n), a view
        value, slope = self.columns.evaluate(
            edge_windows[None],
            (column if every_node else np.minimum(column, size - 1))[:, None],
            derivative=slopes,
        )  # (w, L + 1, K, n)
        filtered = self._filtered([value[:, tap] for tap in range(self.filter.size)])
        if not every_node:
            filtered = filtered * (column < size)
        values = _first_last(filtered)  # (K, n, w), laid out (w, K, n) as the products were
        return Band(
            values if rising else values * _signs(edges_nm),
            first,
            slope=slope,
            outer=(
                self._outer_column(windows, low, high, first + kept, edges_nm)
                if held_apart
                else None
            ),
        )

    def _filtered(self, taps: list[FloatArray]) -> FloatArray:
        """``Σ_l f_l C_l`` of the cumulatives at a blurred pixel's ``L + 1`` edges, tap by tap."""
        if self._two_edges:
            # (−C_lo)·1 + C_hi·1 is C_hi − C_lo exactly: one pass instead of three.
            return np.asarray(taps[1] - taps[0], dtype=np.float64)
        filtered = taps[0] * self.filter[0]
        for tap in range(1, len(taps)):
            filtered = filtered + taps[tap] * self.filter[tap]
        return np.asarray(filtered, dtype=np.float64)

    def _outer_column(
        self,
        windows: FloatArray,
        low: FloatArray,
        high: FloatArray,
        column: IntArray,
        edges_nm: FloatArray,
    ) -> tuple[IntArray, FloatArray]:
        """:attr:`Band.outer`: the band's last column ``column`` ``(K, n)`` in the rows whose
        pixel (``low``–``high``) meets that node's hat or its ramp (:attr:`_ramp_support`; in
        every other row the column is an exact zero), the same operations as the band's."""
        reach_lo, reach_hi = self._ramp_support
        rows = np.flatnonzero((reach_lo[column] < high) & (reach_hi[column] > low))
        n = column.shape[1]
        mapping, pixel = np.divmod(rows, n)
        value, _ = self.columns.evaluate(
            _last_first(windows[mapping, pixel]), column.reshape(-1)[rows]
        )  # (L + 1, R)
        filtered = self._filtered(list(value))
        if not _rising(edges_nm):
            filtered = filtered * _signs(edges_nm)[mapping, 0, 0]
        return rows, np.asarray(filtered, dtype=np.float64)

    def _edge_cumulatives(self, edges_nm: FloatArray, first: IntArray, width: int) -> FloatArray:
        """``Σ_l f_l C_j`` over each blurred pixel's ``L + 1`` edges for its ``w`` columns
        ``(K, n, w)`` (columns past the last node read the last one's).

        Neighbouring pixels share their edges (a blurred pixel's window overlaps ``L`` others'),
        so each edge is evaluated once, for the columns of every pixel whose window holds it,
        and the pixels' entries are read from that table, one filter tap at a time (the
        ``(K, n, w, L + 1)`` entries are never held at once: 2–3× faster at 16 taps; the same
        sums up to rounding)."""
        count = self.filter.size
        batch, n = first.shape
        size = self.n_nodes
        half = (count - 2) // 2
        padded = edges_nm[:, np.clip(np.arange(n + 2 * half + 1) - half, 0, n)]  # (K, n + L)
        # The columns an edge serves: those of the pixels n − L … n whose window holds it.
        apart = np.full((batch, count - 1), size, dtype=np.intp)
        lowest = _reduced(
            np.lib.stride_tricks.sliding_window_view(
                np.concatenate([apart, first, apart], axis=1), count, axis=1
            ),
            np.minimum,
        )  # (K, n + L)
        highest = _reduced(
            np.lib.stride_tricks.sliding_window_view(
                np.concatenate([-apart, first, -apart], axis=1), count, axis=1
            ),
            np.maximum,
        )
        span = int(np.max(highest - lowest)) + width
        table, _ = self.columns.evaluate(
            padded[..., None], np.minimum(lowest[..., None] + np.arange(span), size - 1)
        )  # (K, n + L, span)
        # Row (k, e) of the table starts at (k (n + L) + e)·span and holds the columns from
        # lowest[k, e] on: pixel (k, i)'s column first + a at its edge i + l is the table's entry
        # starts[k, i + l] + first[k, i] + a.
        starts = (
            np.arange(batch)[:, None] * padded.shape[1] + np.arange(padded.shape[1])
        ) * span - lowest  # (K, n + L)
        column = first[:, :, None] + np.arange(width)  # (K, n, w)
        entries = table.reshape(-1)
        total = entries.take(starts[:, :n, None] + column) * self.filter[0]
        for tap in range(1, count):
            total += entries.take(starts[:, tap : tap + n, None] + column) * self.filter[tap]
        return np.asarray(total, dtype=np.float64)  # (K, n, w)

    def band_derivative(
        self, edges_nm: FloatArray, edge_jacobian: FloatArray, band: Band
    ) -> FloatArray:
        """``∂A/∂x`` ``(K, n, w, P)`` of :meth:`band`'s matrix, from ``∂λ_edge/∂x`` ``(K, n + 1, P)``:
        the lamp density at the edges (:meth:`LampColumns.density_at`) through the filter."""
        if band.slope is not None:
            pixels_last = self._pixels_last_derivative(edges_nm, edge_jacobian, band)
            return pixels_last.transpose(2, 3, 1, 0)  # (K, n, w, P), a view
        windows, index = self._windows(edges_nm)
        size = self.n_nodes
        column = band.columns
        valid = column < size
        count = self.filter.size
        jac_windows = _sliding(np.ascontiguousarray(edge_jacobian[:, index, :]), count)
        slope = self.columns.density_at(
            windows[..., None, :], np.minimum(column, size - 1)[..., None]
        )
        # One small product per pixel (a batched matmul: a three-operand einsum cost 4–5× more).
        return np.asarray(
            np.matmul(slope * self.filter, jac_windows.swapaxes(-1, -2))
            * (valid * _signs(edges_nm))[..., None],
            dtype=np.float64,
        )

    def _pixels_last_derivative(
        self, edges_nm: FloatArray, edge_jacobian: FloatArray, band: Band
    ) -> FloatArray:
        """:meth:`band_derivative` laid out ``(P, w, K, n)``, pixels last, from the densities the
        band kept (``band.slope``): tap by tap, each entry's coefficient — density, filter
        weight, validity and sign — times its edge's ``∂λ/∂x``, every pass over whole rows of
        pixels (the ``(K, n, w, P)`` layout's short inner axes cost 3× more; the sums in the
        taps' order, the batched matmul's up to rounding; decision 0106)."""
        slope = band.slope
        assert slope is not None
        index = self._edge_index  # the windows' edges (not their wavelengths: not needed here)
        n = band.first.shape[1]
        # Validity and sign (w, K, n); none when every column is a node and every mapping rises
        # (all ones: :meth:`_band_values`).
        mask = (
            None
            if slope.shape[0] <= self.n_nodes and _rising(edges_nm)
            else (band.first + np.arange(slope.shape[0])[:, None, None] < self.n_nodes)
            * _signs(edges_nm)[None, :, :, 0]
        )
        # ∂λ/∂x at each window's edges, (P, K, n + L).
        moving = np.ascontiguousarray(
            _last_first(edge_jacobian if self.filter.size == 2 else edge_jacobian[:, index, :])
        )
        total = None
        for tap in range(self.filter.size):
            weight = self.filter[tap] if mask is None else self.filter[tap] * mask
            coefficient = slope[:, tap] * weight  # (w, K, n)
            term = coefficient[None] * moving[:, None, :, tap : tap + n]
            total = term if total is None else total + term
        assert total is not None
        return np.asarray(total, dtype=np.float64)

    # ----------------------------------------------------------------------- normal matrices

    def _normal(self, band: Band) -> tuple[FloatArray, FloatArray]:
        """Per batch and channel: the diagonals of ``AᵀW²A`` ``(K, 3, N, w)`` and ``AᵀW²y``
        ``(K, 3, N)``.

        The normal matrix of a banded ``A`` (a row's ``w`` columns consecutive from its first) is
        banded too: its ``d``-th diagonal sums ``W² A_{n,f+a} A_{n,f+a+d}`` over the rows, so one
        ``bincount`` over the ``w(w+1)/2`` pairs ``a ≤ a + d`` of every (batch, channel, row)
        gives every diagonal: entry ``[k, c, i, d]`` is ``(AᵀW²A)[i, i + d]`` (zero past the
        matrix). :meth:`_systems` lays them out in the dense systems; a scan's batch never holds
        the dense normal matrices themselves.
        """
        diagonals, rhs = self._normal_sums(band, with_rhs=True)
        assert rhs is not None
        return diagonals, rhs

    def _normal_diagonals(self, band: Band) -> FloatArray:
        """:meth:`_normal`'s diagonals ``(K, 3, N, w)`` alone (one mapping's dense normal
        matrices need no right-hand side from the band)."""
        return self._normal_sums(band, with_rhs=False)[0]

    def _normal_sums(self, band: Band, *, with_rhs: bool) -> tuple[FloatArray, FloatArray | None]:
        """:meth:`_normal`'s diagonals and, ``with_rhs``, its right-hand sides: one ``bincount``
        per channel over the ``M = w(w+1)/2`` pair products and the ``w`` band values of every
        row, laid out ``(K, n, M + w)``, the pairs' bins first and the right-hand sides' after
        them. Every bin receives the same entries in the same order as in a ``bincount`` of its
        own (the pairs' and the values' bins are apart): the same sums to the bit, in three
        calls instead of six (decision 0131). A band whose last column is held apart
        (:attr:`Band.outer`, a scan's batch) gives its ``w − 1`` columns' pairs here and the last
        column's products in the few rows where it is nonzero through :meth:`_outer_sums`, added
        after: the same nonzero products, the rest exact zeros left out (up to rounding;
        decision 0157)."""
        values = band.values  # (K, n, w), or (K, n, w − 1) with the last column apart
        batch, n, width = values.shape
        size = self.n_nodes
        # The diagonals' count: the band's width with its last column when held apart.
        bins = width + (band.outer is not None)
        lows, offsets = _band_pairs(width)
        pairs = lows.size
        extra = width if with_rhs else 0
        # Channel-free: each pair's product (and each value) and its place; the channels differ
        # by the weights (W² for the pairs, W²y for the values).
        factors = np.empty((batch, n, pairs + extra))
        if values.size <= SMALL_BAND:
            np.multiply(values[..., lows], values[..., lows + offsets], out=factors[..., :pairs])
        else:
            # Formed pixels last (gathering the short last axis of a scan's batch cost 10× more),
            # then laid out (K, n, M): the same products, each bin summed in the same order.
            # (Written through a pixels-last view of the entries: no temporary and copy.)
            by_column = _last_first(values)  # (w, K, n)
            np.multiply(
                by_column[lows], by_column[lows + offsets], out=_last_first(factors[..., :pairs])
            )
        # The places, each an integer sum (exact in any order): a row's start (its batch's
        # offset and its first column) plus each entry's offset, written in place.
        per_batch = size * bins + (size if with_rhs else 0)
        batch_start = (np.arange(batch) * per_batch)[:, None]  # (K, 1)
        places = np.empty((batch, n, pairs + extra), dtype=np.intp)
        np.add(
            (band.first * bins + batch_start)[:, :, None],
            lows * bins + offsets,
            out=places[..., :pairs],
        )
        if with_rhs:
            factors[..., pairs:] = values
            np.add(
                (band.first + batch_start)[:, :, None],
                (size * bins) + np.arange(width),
                out=places[..., pairs:],
            )
        flat = places.reshape(-1)
        weights = self._normal_weights(width, with_rhs)  # (3, n, M [+ w])
        sums = np.asarray(
            np.stack(
                [
                    np.bincount(
                        flat,
                        weights=(factors * weights[c]).reshape(-1),
                        minlength=batch * per_batch,
                    ).reshape(batch, per_batch)
                    for c in range(3)
                ],
                axis=1,
            ),
            dtype=np.float64,
        )  # (K, 3, N·w [+ N])
        if band.outer is not None:
            sums += self._outer_sums(band, per_batch, with_rhs)
        diagonals = sums[..., : size * bins].reshape(batch, 3, size, bins)
        rhs = sums[..., size * bins :] if with_rhs else None
        return diagonals, rhs

    def _outer_sums(self, band: Band, per_batch: int, with_rhs: bool) -> FloatArray:
        """What :attr:`Band.outer`'s entries add to :meth:`_normal_sums`' bins ``(K, 3, per_batch)``:
        in each of its rows the last column's products with the row's columns (the pairs
        ``(a, w − 1 − a)``, the low column first, as the band's own pairs are formed) and, with
        ``rhs``, its value; the same products, summed apart and added (equal up to rounding)."""
        assert band.outer is not None
        rows, outer = band.outer
        batch, n, width = band.values.shape  # width: the columns kept, the last one apart
        size = self.n_nodes
        bins = width + 1
        mapping, pixel = np.divmod(rows, n)
        first = band.first[mapping, pixel]  # (R,)
        products = np.empty((rows.size, bins + (1 if with_rhs else 0)))
        np.multiply(band.values[mapping, pixel], outer[:, None], out=products[:, :width])
        products[:, width] = outer * outer
        reach = np.arange(bins)
        places = np.empty(products.shape, dtype=np.intp)
        np.add(
            (mapping * per_batch + first * bins)[:, None],
            reach * bins + (width - reach),
            out=places[:, :bins],
        )
        weights = np.repeat((self.weights**2).T[:, pixel, None], products.shape[1], axis=2)
        if with_rhs:
            products[:, bins] = outer
            places[:, bins] = mapping * per_batch + size * bins + first + width
            weights[:, :, bins] = self._weighted_target[:, pixel]
        flat = places.reshape(-1)
        return np.stack(
            [
                np.bincount(
                    flat, weights=(products * weights[c]).reshape(-1), minlength=batch * per_batch
                ).reshape(batch, per_batch)
                for c in range(3)
            ],
            axis=1,
        )

    def _normal_weights(self, width: int, with_rhs: bool) -> FloatArray:
        """The per-channel weights of :meth:`_normal_sums`' entries ``(3, n, M [+ w])``: ``W²``
        for the pair products, ``W²y`` (``W·target``) for the band values; once per width."""
        cache: dict[tuple[int, bool], FloatArray] = self._normal_weight_cache
        key = (width, with_rhs)
        if key not in cache:
            pairs = _band_pairs(width)[0].size
            squared = (self.weights**2).T  # (3, n)
            columns = [np.repeat(squared[:, :, None], pairs, axis=2)]
            if with_rhs:
                columns.append(np.repeat(self._weighted_target[:, :, None], width, axis=2))
            cache[key] = np.ascontiguousarray(np.concatenate(columns, axis=2))
        return cache[key]

    @cached_property
    def _normal_weight_cache(self) -> dict[tuple[int, bool], FloatArray]:
        return {}

    def _prior_scale(self, band: Band) -> FloatArray:
        """``β̂`` per batch: the mean camera's scale that best explains the profile ``(K,)``."""
        mean = self.prior_mean  # (3, N)
        gathered = mean[:, band.columns]  # (3, K, n, w)
        predicted = np.einsum("cknw,knw->knc", gathered, band.values) * self.weights
        numerator = np.einsum("knc,nc->k", predicted, self.target)
        denominator = np.einsum("knc,knc->k", predicted, predicted)
        scale = numerator / np.maximum(denominator, 1e-300)
        return np.asarray(np.where(np.isfinite(scale) & (scale > 0), scale, 1.0), dtype=np.float64)

    def _prior_scale_from_normal(self, diagonals: FloatArray, rhs: FloatArray) -> FloatArray:
        """:meth:`_prior_scale` from the normal equations a batch has already formed
        (:meth:`_normal`): the mean camera's fit ``μᵀAᵀW²y / μᵀAᵀW²Aμ`` as ``μ·rhs`` and the
        band's quadratic form in ``μ`` — ``(K, 3, N, w)`` products instead of gathering the mean at
        every ``(K, n, w)`` band entry (the same sums in another order: equal up to rounding;
        decision 0106)."""
        width = diagonals.shape[-1]
        batch = rhs.shape[0]
        numerator = rhs.reshape(batch, -1) @ self.prior_mean.ravel()
        denominator = diagonals.reshape(batch, -1) @ self._mean_pairs(width)
        scale = numerator / np.maximum(denominator, 1e-300)
        return np.asarray(np.where(np.isfinite(scale) & (scale > 0), scale, 1.0), dtype=np.float64)

    def _mean_pairs(self, width: int) -> FloatArray:
        """``μ_{c,i} μ_{c,i+d}`` (twice off the diagonal, zero past the matrix) ``(3·N·w,)``: the
        weights of :meth:`_normal`'s diagonals in the quadratic form ``μᵀAᵀW²Aμ``; once per width."""
        cache: dict[int, FloatArray] = self._mean_pair_cache
        if width not in cache:
            size = self.n_nodes
            mean = np.concatenate([self.prior_mean, np.zeros((3, width))], axis=1)
            offsets = np.arange(width)
            pairs = mean[:, :size, None] * mean[:, offsets + np.arange(size)[:, None]]
            cache[width] = np.ascontiguousarray((pairs * np.where(offsets > 0, 2.0, 1.0)).ravel())
        return cache[width]

    @cached_property
    def _mean_pair_cache(self) -> dict[int, FloatArray]:
        return {}

    @cached_property
    def _penalty_reach(self) -> int:
        """``1 +`` the farthest diagonal on which the margins' penalty ``ΔᵀΔ`` has an entry."""
        rows, columns = np.nonzero(self.penalty)
        return int(np.max(np.abs(rows - columns))) + 1 if rows.size else 0

    def _systems(
        self,
        diagonals: FloatArray,
        scale: FloatArray,
        penalty_weight: FloatArray,
        rhs: FloatArray | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Full per-channel systems ``H`` ``(K, 3, N, N)``, pulls ``g`` and ``γ`` (the β row),
        from the normal matrices' diagonals (:meth:`_normal`).

        ``H = (AᵀW²A + w_Δ ΔᵀΔ) + β̂⁻² FᵀF`` (plus the ridge) is written once: the dense prior
        term, then the banded sum added diagonal by diagonal through strided views, so a batch
        of a thousand trial mappings makes one ``(K, 3, N, N)`` array, not four.

        With ``rhs`` (``AᵀW²y`` ``(K, 3, N)``) the systems come bordered, ``(K, 3, N + 2, N + 2)``:
        ``H`` in the first ``N`` rows and columns (the same numbers), ``[rhs, g]`` in the last two
        columns and rows, and a diagonal there large enough that the whole stays positive
        definite (:func:`_bordered_forms`; decision 0116).
        """
        batch, _, size, width = diagonals.shape
        extra = 0 if rhs is None else 2
        row = size + extra
        inverse_square = 1.0 / scale**2  # (K,)
        if rhs is None:
            systems = inverse_square[:, None, None, None] * self.precision
            inner = systems
        else:
            # The prior's term over the whole bordered matrix from a zero-bordered precision:
            # one contiguous pass (the border's zeros are overwritten below), not a strided one.
            systems = inverse_square[:, None, None, None] * self._bordered_precision
            inner = systems[..., :size, :size]
        flat = systems.reshape(batch, 3, row * row)
        # Diagonal by diagonal through strided views (above and below the main one): each entry
        # of the band written once, the sum ``(AᵀW²A)_ij + w_Δ (ΔᵀΔ)_ij`` added to the prior's
        # as before. (Scattered through an index array, ``flat[..., positions] += …``, the same
        # writes cost 5–10× more: numpy's fancy-index path over a batch's leading axes; 0106.)
        stride = row + 1
        for offset in range(min(max(width, self._penalty_reach), size)):
            length = size - offset
            penalty = penalty_weight[..., None] * np.diagonal(self.penalty, offset)
            addend = diagonals[..., :length, offset] + penalty if offset < width else penalty
            flat[..., offset::stride][..., :length] += addend
            if offset:
                flat[..., offset * row :: stride][..., :length] += addend
        diagonal = np.einsum("kcii->kc", inner)
        ridge = RIDGE * np.maximum(diagonal / self.n_nodes, 1e-300)
        flat[..., ::stride][..., :size] += ridge[..., None]
        unit_pulls, unit_gamma = self._unit_pulls
        pulls = inverse_square[:, None, None] * unit_pulls
        gamma = inverse_square * unit_gamma
        if rhs is not None:
            # H ≥ ridge·I, so bᵀH⁻¹b ≤ |b|²/ridge: four times that (plus one, for b = 0) on
            # the border's diagonal keeps its Schur complement positive.
            systems[..., :size, size] = rhs
            systems[..., size, :size] = rhs
            systems[..., :size, size + 1] = pulls
            systems[..., size + 1, :size] = pulls
            systems[..., size, size + 1] = systems[..., size + 1, size] = 0.0
            systems[..., size, size] = 4.0 * np.sum(rhs * rhs, axis=-1) / ridge + 1.0
            systems[..., size + 1, size + 1] = 4.0 * np.sum(pulls * pulls, axis=-1) / ridge + 1.0
        return systems, pulls, gamma

    @cached_property
    def _bordered_precision(self) -> FloatArray:
        """The prior's precision ``FᵀF`` with two rows and columns of zeros ``(3, N + 2, N + 2)``."""
        size = self.n_nodes
        padded = np.zeros((3, size + 2, size + 2))
        padded[:, :size, :size] = self.precision
        return padded

    def _band_layout(self, width: int) -> tuple[IntArray, IntArray, FloatArray]:
        """Where :meth:`_banded_normal` writes one mapping's band of ``w`` diagonals (and the
        penalty's; :meth:`_systems` writes the same entries diagonal by diagonal): the flat
        positions in an ``N × N`` matrix of entries ``(i, i + d)`` and ``(i + d, i)``, the
        diagonals' flat index ``i·w + d`` (``N·w``, a zero, beyond the band) and the penalty's
        values there; once per width."""
        cache: dict[int, tuple[IntArray, IntArray, FloatArray]] = self._band_layouts
        if width not in cache:
            size = self.n_nodes
            positions, source, values = [], [], []
            for offset in range(min(max(width, self._penalty_reach), size)):
                length = size - offset
                along = np.arange(length) * (size + 1)
                read = np.arange(length) * width + offset if offset < width else None
                for start in (offset, offset * size) if offset else (0,):
                    positions.append(start + along)
                    source.append(np.full(length, size * width) if read is None else read)
                    values.append(np.diagonal(self.penalty, offset))
            cache[width] = (
                np.concatenate(positions).astype(np.intp),
                np.concatenate(source).astype(np.intp),
                np.concatenate(values).astype(np.float64),
            )
        return cache[width]

    @cached_property
    def _band_layouts(self) -> dict[int, tuple[IntArray, IntArray, FloatArray]]:
        return {}

    def _banded_normal(self, band: Band) -> FloatArray:
        """``AᵀW²A`` ``(3, N, N)`` of one mapping's band, laid out dense (:meth:`_normal`'s
        diagonals at :meth:`_band_layout`'s places, without the prior or penalty)."""
        diagonals = self._normal_diagonals(band)  # (1, 3, N, w)
        size, width = diagonals.shape[2:]
        positions, source, _ = self._band_layout(width)
        padded = np.concatenate([diagonals.reshape(3, size * width), np.zeros((3, 1))], axis=-1)
        normal = np.zeros((3, size * size))
        normal[:, positions] = padded[:, source]
        return normal.reshape(3, size, size)

    @cached_property
    def _held_systems(self) -> FloatArray:
        """``β̂⁻² FᵀF + w_Δ ΔᵀΔ`` ``(3, N, N)`` at the held scale and penalty weights."""
        assert self.penalty_weight is not None
        return np.asarray(
            self.precision / self.scale**2 + self.penalty_weight[:, None, None] * self.penalty,
            dtype=np.float64,
        )

    @cached_property
    def _held_root(self) -> FloatArray:
        """``√w_Δ`` ``(3,)``: the margin penalty rows' weights at the held penalty weights."""
        assert self.penalty_weight is not None
        return np.asarray(np.sqrt(self.penalty_weight), dtype=np.float64)

    @cached_property
    def _weighted_target(self) -> FloatArray:
        """``(W y)ᵀ W`` ``(3, n)``: each channel's data weighted twice (the right-hand sides'
        factor, the same for every mapping)."""
        return (self.target * self.weights).T

    @cached_property
    def _held_factor(self) -> FloatArray:
        """The prior's whitening factors ``F / β̂`` ``(3, n_w, N)`` at the held scale."""
        return np.asarray(self.prior_factor / self.scale, dtype=np.float64)

    @cached_property
    def _held_pulls(self) -> tuple[FloatArray, float]:
        """The pulls ``g`` ``(3, N)`` and ``γ`` at the held scale."""
        unit_pulls, unit_gamma = self._unit_pulls
        inverse_square = 1.0 / self.scale**2
        return inverse_square * unit_pulls, inverse_square * unit_gamma

    @cached_property
    def _unit_pulls(self) -> tuple[FloatArray, float]:
        """The prior's pulls ``FᵀF μ`` ``(3, N)`` and ``μᵀFᵀF μ`` for a camera of unit scale."""
        unit_pulls = np.einsum("cij,cj->ci", self.precision, self.prior_mean)
        return np.asarray(unit_pulls, dtype=np.float64), float(np.sum(unit_pulls * self.prior_mean))

    def _penalty_weight(self, diagonals: FloatArray) -> FloatArray:
        # The main diagonal is a strided view (every w-th value), as a dense matrix's is:
        # einsum sums it in the same order, to the last bit.
        trace = np.einsum("kci->kc", diagonals[..., 0]) / self.n_nodes
        return np.asarray(self.smoothness * np.maximum(trace, 1e-300), dtype=np.float64)

    def reference(self, edges_nm: FloatArray) -> ResponseModel:
        """This model with ``β̂`` and the penalty weights of the mapping with these edge
        wavelengths ``(n + 1,)`` held fixed (what :meth:`residual` differentiates)."""
        band = self.band(edges_nm[None, :], slopes=True)
        # The normal matrices' trace (what :meth:`_penalty_weight` reads) straight from the band:
        # Σ_n W² Σ_a A_na², without the matrices themselves.
        trace = (band.values[0] ** 2).sum(axis=1) @ self.weights**2 / self.n_nodes  # (3,)
        held = replace(
            self,
            scale=float(self._prior_scale(band)[0]),
            penalty_weight=np.asarray(
                self.smoothness * np.maximum(trace, 1e-300), dtype=np.float64
            ),
            referenced=(np.array(edges_nm, dtype=np.float64), band),
        )
        # What does not depend on the held scale and penalty weights is this model's: made
        # once, not again by each descent's model (decision 0142). The per-width tables are
        # the same dictionaries, so a width one descent laid out serves the next.
        for name in _REFERENCE_SHARED:
            held.__dict__[name] = getattr(self, name)
        return held

    # --------------------------------------------------------------------------- evaluate

    def costs(self, edges_nm: FloatArray, *, adaptive: bool = True) -> FloatArray:
        """``χ²`` of the best response for each mapping's edge wavelengths ``(K, n + 1)`` → ``(K,)``.

        ``adaptive`` recomputes ``β̂`` and the penalty weights per mapping (scans over a wide range
        of dispersions); otherwise the reference values are used.
        """
        edges_nm = np.atleast_2d(edges_nm)
        band = self._band_values(
            edges_nm, outer=edges_nm.shape[0] * (edges_nm.shape[1] - 1) >= OUTER_FROM
        )
        diagonals, rhs = self._normal(band)
        batch = diagonals.shape[0]
        if adaptive or self.penalty_weight is None:
            scale = self._prior_scale_from_normal(diagonals, rhs)
            weight = self._penalty_weight(diagonals)
        else:
            scale = np.full(batch, self.scale)
            weight = np.broadcast_to(self.penalty_weight, (batch, 3))
        bordered, _, gamma = self._systems(diagonals, scale, weight, rhs)
        forms = _bordered_forms(bordered)
        if forms is None:  # a system not positive definite in floating point (NaN, overflow)
            systems, pulls, gamma = self._systems(diagonals, scale, weight)
            solved = np.linalg.solve(systems, np.stack([rhs, pulls], axis=-1))
            free, along = solved[..., 0], solved[..., 1]
            forms = (
                np.einsum("kci,kci->k", rhs, free),
                np.einsum("kci,kci->k", pulls, free),
                np.einsum("kci,kci->k", pulls, along),
            )
        # χ² = yᵀy − rᵀx with x = H⁻¹r + β H⁻¹g, β = gᵀH⁻¹r / (γ − gᵀH⁻¹g) (summed over channels).
        explained_free, pull_free, pull_along = forms
        denominator = gamma - pull_along
        beta = pull_free / np.where(np.abs(denominator) > 1e-300, denominator, np.inf)
        explained = explained_free + beta * pull_free
        return np.asarray(float(np.sum(self.target**2)) - explained, dtype=np.float64)

    def residual(
        self, edges_nm: FloatArray, edge_jacobian: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray | None, dict[str, Any]]:
        """Residual rows (data, margin penalty, prior) for one mapping, and their exact Jacobian.

        Parameters
        ----------
        edges_nm
            ``(n + 1,)`` wavelengths at the pixel edges.
        edge_jacobian
            ``(n + 1, P)``: ``∂λ_edge/∂x``; ``None`` skips the Jacobian.

        Returns
        -------
        (residual, jacobian, parts)
            Residual ``(R,)`` (model − data, weighted), Jacobian ``(R, P)`` or ``None``, and the
            fitted response ``(3, N)``, the camera scale ``β`` and the model profile ``(n, 3)``.
        """
        residual, jacobian, parts = self.residual_lazy(edges_nm, edge_jacobian)
        return residual, None if jacobian is None else jacobian(), parts

    def residual_lazy(
        self, edges_nm: FloatArray, edge_jacobian: FloatArray | None = None
    ) -> tuple[FloatArray, Callable[[], FloatArray] | None, dict[str, Any]]:
        """:meth:`residual` with the Jacobian left to a call: a fit computes it only for the
        trial points it accepts (about half the work of an evaluation).

        One mapping's matrix is small (``n × N``, a few hundred by a few dozen): besides its band
        (which still gives the normal matrices) it is laid out dense for the products with ``A``
        and ``∂A/∂x``, and each channel's system is factorised once (Cholesky: ridged, SPD) for
        the fit and every Jacobian column — an inverse cost 2–4× more (0056)."""
        model = self if self.penalty_weight is not None else self.reference(edges_nm)
        assert model.penalty_weight is not None
        referenced = model.referenced
        # (np.array_equal's numbers: the same shape and every entry equal, NaN never; without its
        # per-call conversions.)
        if (
            referenced is not None
            and referenced[0].shape == edges_nm.shape
            and bool((referenced[0] == edges_nm).all())
        ):
            band = referenced[1]
        else:
            band = model.band(edges_nm[None, :], slopes=edge_jacobian is not None)
        size = model.n_nodes
        n = band.values.shape[1]
        flat = (np.arange(n)[:, None] * size + np.minimum(band.columns[0], size - 1)).ravel()
        matrix = _dense(flat, band.values[0], (n, size))  # A (n, N)
        weights = model.weights.T  # (3, n)
        if n * size <= DENSE_NORMAL:
            # One small mapping's normal matrices from the dense A (three small products): the
            # band's bincount and the diagonal-by-diagonal writes cost more than the work itself
            # at this size; the same sums up to rounding.
            # W A laid out dense from the band's weighted values, as A is (each entry one band
            # value, times its weight: the same products; W times the dense A passed over all
            # n·N entries, the zeros too; decision 0142).
            weighted = _dense(  # (3, n, N): W A
                (flat + (n * size) * np.arange(3)[:, None]).ravel(),
                weights[:, :, None] * band.values[0],
                (3, n, size),
            )
            systems = model._held_systems + np.matmul(weighted.transpose(0, 2, 1), weighted)
        else:
            # A large one's from its band (:meth:`_normal`): the dense product's n·N² work is
            # mostly zeros (the band is w ≪ N wide); the same sums up to rounding.
            systems = model._held_systems + model._banded_normal(band)
        diagonal = systems.reshape(3, size * size)[:, :: size + 1]
        diagonal += RIDGE * np.maximum(diagonal.sum(axis=1) / size, 1e-300)[:, None]
        rhs = model._weighted_target @ matrix  # (3, N): Aᵀ W y per channel
        pull, border = model._held_pulls
        factors = _cholesky(systems)
        right = np.empty((3, size, 2))  # [rhs, pull] side by side (np.stack's numbers, fewer calls)
        right[..., 0] = rhs
        right[..., 1] = pull
        free, along = _last_first(_cholesky_solve(factors, right))
        beta = _scale_of_one(pull, border, free, along)
        response = free + beta * along  # (3, N)
        fitted = response @ matrix.T  # (3, n)
        data_rows = weights * fitted - model.target.T  # (3, n)
        root = model._held_root
        penalty_rows = root[:, None] * (response @ model.layout.difference.T)  # (3, r)
        factor = model._held_factor
        prior_rows = np.einsum("cij,cj->ci", factor, response - beta * model.prior_mean)
        residual = np.concatenate([data_rows.ravel(), penalty_rows.ravel(), prior_rows.ravel()])
        parts = {"response": response, "beta": beta, "model_profile": fitted.T}
        if edge_jacobian is None:
            return residual, None, parts
        edge_derivative = edge_jacobian

        def jacobian() -> FloatArray:
            n_parameters = edge_derivative.shape[-1]
            if band.slope is not None:
                # Pixels last (P, w, n): laid out dense through the band's places read (w, n).
                derivative = model._pixels_last_derivative(
                    edges_nm[None, :], edge_derivative[None], band
                )[:, :, 0]
                places = flat.reshape(n, -1).T
            else:
                derivative = _last_first(
                    model.band_derivative(edges_nm[None, :], edge_derivative[None], band)[0]
                )  # (P, n, w)
                places = flat.reshape(n, -1)
            moved_matrix = _dense(  # ∂A/∂x (P, n, N)
                (places[None] + (n * size) * np.arange(n_parameters)[:, None, None]).ravel(),
                derivative,
                (n_parameters, n, size),
            )
            return model._residual_jacobian(
                moved_matrix, matrix, factors, pull, border, along, response, data_rows
            )

        return residual, jacobian, parts

    def _residual_jacobian(
        self,
        derivative: FloatArray,
        matrix: FloatArray,
        factors: list[FloatArray],
        pulls: FloatArray,
        gamma: float,
        along: FloatArray,
        response: FloatArray,
        data_rows: FloatArray,
    ) -> FloatArray:
        """The exact variable-projection Jacobian of :meth:`residual_lazy`'s rows (``derivative``:
        ``∂A/∂x`` ``(P, n, N)``, ``matrix`` ``A`` ``(n, N)``)."""
        model = self
        assert model.penalty_weight is not None
        n_parameters = derivative.shape[0]
        weights = model.weights.T  # (3, n)
        root = model._held_root
        factor = model._held_factor
        # v_k = W ∂A_k r̂ (data rows only); u_k = ∂A_kᵀ W ρ + Aᵀ W v_k.
        # (rT laid out C-ordered: with the transposed view numpy's stacked product took the slow
        # non-BLAS loop, 2.5× longer at 941 pixels.)
        moved = (
            np.matmul(derivative, np.ascontiguousarray(response.T)).transpose(2, 1, 0)
            * weights[..., None]
        )  # (3, n, P)
        gathered = np.matmul(derivative.transpose(0, 2, 1), (weights * data_rows).T).transpose(
            2, 1, 0
        ) + np.matmul(matrix.T, weights[..., None] * moved)  # (3, N, P)
        solved = _cholesky_solve(factors, gathered)  # (3, N, P)
        change_beta = _scale_of_columns(pulls, gamma, solved, along)
        change = solved + along[..., None] * change_beta  # (3, N, P)
        # The three blocks written straight into the Jacobian's rows (the same elementwise
        # operations on the same products; no reshaped copies and concatenation; decision 0153).
        n = matrix.shape[0]
        penalty_count = model.layout.difference.shape[0]
        out = np.empty((3 * (n + penalty_count) + factor.shape[1] * 3, n_parameters))
        data_end = 3 * n
        penalty_end = data_end + 3 * penalty_count
        np.subtract(
            moved,
            weights[..., None] * np.matmul(matrix, change),
            out=out[:data_end].reshape(3, n, n_parameters),
        )
        np.multiply(
            -root[:, None, None],
            np.matmul(model.layout.difference, change),
            out=out[data_end:penalty_end].reshape(3, penalty_count, n_parameters),
        )
        np.negative(
            np.matmul(factor, change - change_beta * model.prior_mean[..., None]),
            out=out[penalty_end:].reshape(3, factor.shape[1], n_parameters),
        )
        return out


def _sliding(padded: FloatArray, count: int) -> FloatArray:
    """``sliding_window_view(padded, count, axis=1)`` of a C-contiguous ``(K, m, …)`` array —
    ``(K, m − count + 1, …, count)``, read-only — as a plain strided view, without that function's
    per-call checks (they cost more than the view's use for one mapping).

    Examples
    --------
    >>> padded = np.arange(12.0).reshape(2, 3, 2)
    >>> view = _sliding(padded, 2)
    >>> view.shape, bool(np.array_equal(view, np.lib.stride_tricks.sliding_window_view(padded, 2, axis=1)))
    ((2, 2, 2, 2), True)
    """
    batch, length, *rest = padded.shape
    view = np.ndarray(
        (batch, length - count + 1, *rest, count),
        dtype=padded.dtype,
        buffer=padded,
        strides=(*padded.strides, padded.strides[1]),
    )
    view.flags.writeable = False
    return view


def _reduced(windows: NDArray[Any], ufunc: np.ufunc) -> NDArray[Any]:
    """``ufunc`` (``np.minimum`` or ``np.maximum``) folded over the last axis of a window view
    ``(…, L + 1)``, slice by slice: the same values as ``min``/``max(axis=-1)``, whose reduction
    over a short strided axis cost 20–30× more (0065).

    Examples
    --------
    >>> windows = _sliding(np.array([[3.0, 1.0, 2.0, 5.0]]), 2)
    >>> _reduced(windows, np.minimum), _reduced(windows, np.maximum)
    (array([[1., 1., 2.]]), array([[3., 2., 5.]]))
    """
    folded = windows[..., 0]
    for index in range(1, windows.shape[-1]):
        folded = ufunc(folded, windows[..., index])
    return folded


def _last_first(array: NDArray[Any]) -> NDArray[Any]:
    """``np.moveaxis(array, -1, 0)``: the same view, without that function's per-call axis
    handling (it cost more than the view's use at a descent's sizes; decision 0135).

    Examples
    --------
    >>> array = np.arange(24.0).reshape(2, 3, 4)
    >>> bool(np.array_equal(_last_first(array), np.moveaxis(array, -1, 0)))
    True
    """
    return array.transpose(array.ndim - 1, *range(array.ndim - 1))


def _first_last(array: NDArray[Any]) -> NDArray[Any]:
    """``np.moveaxis(array, 0, -1)``: the same view (see :func:`_last_first`).

    Examples
    --------
    >>> array = np.arange(24.0).reshape(2, 3, 4)
    >>> bool(np.array_equal(_first_last(array), np.moveaxis(array, 0, -1)))
    True
    """
    return array.transpose(*range(1, array.ndim), 0)


def _dense(flat: IntArray, values: FloatArray, shape: tuple[int, ...]) -> FloatArray:
    """A banded matrix (or a stack of them) laid out dense: ``values`` summed at ``flat``."""
    total = np.bincount(flat, weights=values.ravel(), minlength=math.prod(shape))
    return np.asarray(total.reshape(shape), dtype=np.float64)


def _bordered_forms(
    bordered: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """``(Σ_c rᵀH⁻¹r, Σ_c gᵀH⁻¹r, Σ_c gᵀH⁻¹g)`` ``(K,)`` each, from :meth:`ResponseModel._systems`'
    bordered systems ``M = [[H, B], [Bᵀ, D]]`` ``(K, 3, N + 2, N + 2)``, ``B = [r, g]``: the lower
    Cholesky factor of ``M`` holds ``Zᵀ = (L⁻¹B)ᵀ`` in its last two rows (``L`` the factor of
    ``H``; ``Z`` does not depend on ``D``), and ``bᵀH⁻¹c = (L⁻¹b)ᵀ(L⁻¹c)``. One LAPACK
    ``potrf`` per system, in place (the array is overwritten), instead of an LU solve with two
    right-hand sides: half the flops, and numpy's batched ``solve`` copied each matrix in and the
    solution out (decision 0116; the costs agree with the solve's to ~1e-11 relative). ``None``
    where a system is not positive definite in floating point."""
    size = bordered.shape[-1] - 2
    potrf = _potrf
    # M is symmetric: its transposed view is M, Fortran-ordered, so LAPACK factors it in place;
    # the factor's last rows land in M's last columns. (The views transposed all at once, and
    # the wrapper's arguments by position — lower, clean, overwrite_a —: by keyword it parsed
    # them at twice the cost, a tenth of a scan's factorisations at 41 × 41; decision 0142.)
    for transposed in bordered.reshape(-1, size + 2, size + 2).transpose(0, 2, 1):
        if potrf(transposed, 1, 0, 1)[1] != 0:
            return None
    free = bordered[..., :size, size]  # L⁻¹r (K, 3, N)
    along = bordered[..., :size, size + 1]  # L⁻¹g
    return (
        np.einsum("kci,kci->k", free, free),
        np.einsum("kci,kci->k", along, free),
        np.einsum("kci,kci->k", along, along),
    )


def _cholesky(systems: FloatArray) -> list[FloatArray]:
    """Lower Cholesky factors of the per-channel systems ``(3, N, N)`` (ridged, SPD), each
    factored in place (``systems`` is overwritten): a symmetric C-ordered matrix is its own
    Fortran-ordered transpose, so LAPACK reads the same numbers without a copy in, and the
    factor it returns is that view, read by :func:`_cholesky_solve` without a copy either."""
    factors = []
    for channel in systems:
        # lower, clean, overwrite_a (by position: :func:`_bordered_forms`)
        lower, info = _potrf(channel.T, 1, 1, 1)
        if info != 0:
            raise np.linalg.LinAlgError("a channel's response system is not positive definite")
        factors.append(lower)
    return factors


def _cholesky_solve(factors: list[FloatArray], right: FloatArray) -> FloatArray:
    """``H_c⁻¹ r_c`` per channel from the Cholesky factors (:meth:`ResponseModel._factorised`):
    right-hand sides ``(3, N, m)`` → ``(3, N, m)``."""
    out = np.empty_like(right)
    for channel, lower in enumerate(factors):
        out[channel], info = _potrs(lower, right[channel], 1)  # lower
        if info != 0:
            raise np.linalg.LinAlgError("the response system's triangular solve failed")
    return out


def _scale_of(
    pulls: FloatArray, gamma: float, free: FloatArray, along: FloatArray, right_beta: Any
) -> Any:
    """The camera scale ``β`` of the bordered system ``H_c x_c − g_c β = r_c``,
    ``−Σ g_cᵀ x_c + γ β = r_β`` (then ``x_c = a_c + β e_c``) from ``a_c = H_c⁻¹ r_c``
    ``(3, N[, m])`` and ``e_c = H_c⁻¹ g_c`` ``(3, N[, 1])``: a number, or ``(m,)``."""
    denominator = gamma - _over_channels_and_nodes(pulls, along)
    denominator = np.where(np.abs(denominator) > 1e-300, denominator, np.inf)
    return (right_beta + _over_channels_and_nodes(pulls, free)) / denominator


def _scale_of_one(pulls: FloatArray, gamma: float, free: FloatArray, along: FloatArray) -> float:
    """:func:`_scale_of` for one mapping (``free``, ``along`` ``(3, N)``, no right-hand side for
    ``β``) on Python floats: the same products and the same IEEE operations in the same order, so
    the same number, without the 0-d arrays' and ``np.where``'s per-call cost (decision 0142).

    Examples
    --------
    >>> pulls, free, along = np.arange(6.0).reshape(3, 2), np.ones((3, 2)), np.full((3, 2), 0.5)
    >>> _scale_of_one(pulls, 20.0, free, along) == float(_scale_of(pulls, 20.0, free, along, 0.0))
    True
    """
    denominator = gamma - float(_over_channels_and_nodes(pulls, along))
    if not abs(denominator) > 1e-300:  # (NaN included, as np.where's test)
        denominator = math.inf
    return (0.0 + float(_over_channels_and_nodes(pulls, free))) / denominator


def _scale_of_columns(
    pulls: FloatArray, gamma: float, free: FloatArray, along: FloatArray
) -> FloatArray:
    """:func:`_scale_of` for ``m`` right-hand sides ``free`` ``(3, N, m)`` with ``along``
    ``(3, N)`` and a zero ``r_β``: its denominator on Python floats (the same product, the same
    IEEE operations) and the same division, without ``np.where`` and the zeros' array (decision
    0153).

    Examples
    --------
    >>> pulls, along = np.arange(6.0).reshape(3, 2), np.full((3, 2), 0.5)
    >>> free = np.arange(12.0).reshape(3, 2, 2)
    >>> bool(np.array_equal(_scale_of_columns(pulls, 20.0, free, along),
    ...                     _scale_of(pulls, 20.0, free, along[..., None], np.zeros(2))))
    True
    """
    denominator = gamma - float(_over_channels_and_nodes(pulls, along[..., None])[0])
    if not abs(denominator) > 1e-300:  # (NaN included, as np.where's test)
        denominator = math.inf
    return np.asarray((0.0 + _over_channels_and_nodes(pulls, free)) / denominator)


def _over_channels_and_nodes(pulls: FloatArray, right: FloatArray) -> FloatArray:
    """``Σ_c,i pulls[c, i] right[c, i, …]``: ``np.tensordot(pulls, right, axes=([0, 1], [0, 1]))``
    as the one product it makes (the same ``dot``), without its per-call shape handling.

    Examples
    --------
    >>> pulls, right = np.arange(6.0).reshape(3, 2), np.arange(24.0).reshape(3, 2, 4)
    >>> bool(np.array_equal(_over_channels_and_nodes(pulls, right),
    ...                     np.tensordot(pulls, right, axes=([0, 1], [0, 1]))))
    True
    """
    flat = right.reshape(pulls.size, -1)
    return np.asarray(np.dot(pulls.reshape(1, -1), flat).reshape(right.shape[2:]))


def _rising(edges_nm: FloatArray) -> bool:
    """Every mapping of the batch ``(K, n + 1)`` rises: its :func:`_signs` are all +1.

    Examples
    --------
    >>> _rising(np.array([[400.0, 410.0]])), _rising(np.array([[400.0, 410.0], [9.0, 1.0]]))
    (True, False)
    """
    if edges_nm.shape[0] == 1:  # (one mapping: two numbers, not a pass)
        return bool(edges_nm[0, -1] >= edges_nm[0, 0])
    return bool(np.all(edges_nm[:, -1] >= edges_nm[:, 0]))


def _signs(edges_nm: FloatArray) -> FloatArray:
    """A falling mapping integrates from the higher edge: the pixel's light is ``|ΔC|``
    (``(K, 1, 1)``)."""
    return np.where(edges_nm[:, -1] >= edges_nm[:, 0], 1.0, -1.0)[:, None, None]


@functools.lru_cache(maxsize=16)
def _band_pairs(width: int) -> tuple[IntArray, IntArray]:
    """The pairs ``(a, d)`` with ``a + d < width`` (a band's entry and its ``d``-th neighbour).

    Examples
    --------
    >>> _band_pairs(2)
    (array([0, 1, 0]), array([0, 0, 1]))
    """
    pairs = [(low, offset) for offset in range(width) for low in range(width - offset)]
    lows, offsets = np.array(pairs, dtype=np.intp).reshape(-1, 2).T.copy()
    lows.flags.writeable = offsets.flags.writeable = False  # shared by every call (cached)
    return lows, offsets


def fine_step_for(nm_per_sample: float) -> float:
    """The lamp's integration step: half a profile sample, between 0.1 and 1 nm (a divisor of 1)."""
    for step in (1.0, 0.5, 0.25, 0.2, 0.1):
        if step <= 0.5 * nm_per_sample or math.isclose(step, 0.1):
            return step
    return 0.1
