"""Mapping families: the parameters a pixel→wavelength search moves, with analytic derivatives.

A family turns a parameter vector ``x`` into a mapping and gives ``∂λ(p)/∂x`` in closed form, for
one vector or a batch of them (a scan evaluates a whole grid in one vectorised call):

:class:`QuadraticFamily`
    ``λ = a p² + b p + c`` (Makabe et al. 2025, Eq. 13), parameterised by the wavelengths at both
    ends and the middle of the profile (well conditioned, in nm; linear, so the Jacobian is a
    constant matrix). For profiles whose pixel origin is arbitrary and nothing is known of the rig.
:class:`GratingFamily`
    The grating equation through a lens (:class:`calib.core.mapping.TiltedGrating`):
    ``λ(p) = d [sin(θ + atan((u + u₀)/F) − atan(u₀/F)) − sin θ]``, ``u = s (p − p₀)``, with
    parameters ``(p₀, ln d, ln F, θ)``; any of them can be held at a known value (``p₀ = 0`` for
    profiles measured from the direct spot, ``d`` from the grating's line density). A Gaussian
    prior on the parameters (:class:`GratingPrior`) carries what the rig says (line density, the
    lens' focal length over the pixel pitch, an incidence near 0) into the fit as extra residual
    rows, so a search starts — and stays — in the physically possible basin.

Both produce mappings with the same ``wavelength_nm(pixel)`` interface as
:class:`calib.core.mapping.QuadraticMapping`, which the response fits use.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.mapping import QuadraticMapping, TiltedGrating

#: The grating family's parameters, in the order of a full parameter vector.
GRATING_PARAMETERS: tuple[str, ...] = (
    "zero_order_px",
    "log_spacing",
    "log_focal",
    "incidence_deg",
    "axis_offset_px",
)
#: Parameters held at the family's own value unless the prior names them.
_HELD_UNLESS_NAMED = ("axis_offset_px",)
_DEG = math.pi / 180.0
#: Pixel arrays whose :meth:`QuadraticFamily.jacobian` a family keeps.
_KEPT_JACOBIANS = 8
#: Sample indices of the 9 pixels :meth:`GratingFamily.valid` checks.
_PROBE_STEPS = np.arange(9.0)


def _exp(value: float) -> float:
    try:
        return math.exp(value)
    except OverflowError:
        return math.inf


def _anchors(pixel_range: tuple[float, float]) -> FloatArray:
    return np.array([pixel_range[0], 0.5 * (pixel_range[0] + pixel_range[1]), pixel_range[1]])


@dataclass(frozen=True)
class QuadraticFamily:
    """Quadratic mappings parameterised by ``λ`` at the ends and middle of ``pixel_range`` (nm).

    Examples
    --------
    >>> family = QuadraticFamily((0.0, 100.0))
    >>> family.mapping(np.array([400.0, 450.0, 500.0])).wavelength_nm(np.array([50.0]))
    array([450.])
    """

    pixel_range: tuple[float, float]
    names: tuple[str, ...] = ("left_nm", "middle_nm", "right_nm")

    @cached_property
    def _to_coefficients(self) -> FloatArray:
        anchors = _anchors(self.pixel_range)
        return np.asarray(
            np.linalg.inv(np.stack([anchors**2, anchors, np.ones(3)], axis=1)), dtype=np.float64
        )

    def parameters(self, mapping: QuadraticMapping | TiltedGrating) -> FloatArray:
        """The parameter vector of (the quadratic through) ``mapping``."""
        return np.asarray(mapping.wavelength_nm(_anchors(self.pixel_range)), dtype=np.float64)

    def mapping(self, x: ArrayLike) -> QuadraticMapping:
        a, b, c = self._to_coefficients @ np.asarray(x, dtype=np.float64)
        return QuadraticMapping(float(a), float(b), float(c), pixel_range=self.pixel_range)

    def wavelengths(self, pixel: FloatArray, x: FloatArray) -> FloatArray:
        """``λ`` at ``pixel`` ``(n,)`` for parameters ``(P,)`` → ``(n,)`` or ``(K, P)`` → ``(K, n)``."""
        return np.asarray(np.asarray(x, dtype=np.float64) @ self.jacobian(pixel).T)

    def jacobian(self, pixel: FloatArray, x: FloatArray | None = None) -> FloatArray:
        """``∂λ(p)/∂x``, shape ``(n, 3)`` (the same for every ``x``: the family is linear), kept
        for the last few pixel arrays (a fit asks for it at every trial point); read-only."""
        p = np.asarray(pixel, dtype=np.float64)
        key = p.tobytes()
        known = self._jacobians.get(key)
        if known is not None:
            return known
        design = np.stack([p**2, p, np.ones_like(p)], axis=1)
        jacobian = np.asarray(design @ self._to_coefficients, dtype=np.float64)
        jacobian.setflags(write=False)
        if len(self._jacobians) >= _KEPT_JACOBIANS:
            self._jacobians.clear()
        self._jacobians[key] = jacobian
        return jacobian

    @cached_property
    def _jacobians(self) -> dict[bytes, FloatArray]:
        return {}

    @cached_property
    def _probe(self) -> FloatArray:
        """The 9 pixels :meth:`valid` checks, made once (a descent checks every trial point;
        ``np.linspace`` cost more than the check)."""
        probe = np.linspace(*self.pixel_range, 9)
        probe.setflags(write=False)
        return probe

    def batch_jacobian(self, pixel: FloatArray, x: FloatArray) -> FloatArray:
        """``∂λ/∂x`` for a batch ``(K, P)``: shape ``(K, n, P)``."""
        single = self.jacobian(pixel)
        return np.broadcast_to(single, (np.asarray(x).shape[0], *single.shape))

    @cached_property
    def _probe_map(self) -> FloatArray:
        """``∂λ/∂x`` at :attr:`_probe`, transposed ``(3, 9)``: what :meth:`wavelengths` multiplies
        by there (the same view of the same numbers), made once."""
        return self.jacobian(self._probe).T

    def valid(self, x: FloatArray) -> FloatArray:
        """Whether each mapping ``(K, P)`` (or one ``(P,)``) keeps one direction over the range."""
        if np.ndim(x) == 1:
            # One point (a descent's trial): the same product, its eight slopes and the tests on
            # Python floats (the same IEEE subtractions and comparisons), without five array
            # reductions on nine numbers (decision 0153).
            point = np.asarray(x, dtype=np.float64)[None]
            probed: list[float] = (point @ self._probe_map)[0].tolist()
            rises = [high - low for low, high in itertools.pairwise(probed)]
            one_way = all(rise > 0 for rise in rises) or all(rise < 0 for rise in rises)
            return np.array([one_way and all(map(math.isfinite, probed))])
        wavelengths = self.wavelengths(self._probe, np.atleast_2d(x))
        slopes = wavelengths[..., 1:] - wavelengths[..., :-1]  # np.diff's own subtraction
        ok = (np.all(slopes > 0, axis=-1) | np.all(slopes < 0, axis=-1)) & np.all(
            np.isfinite(wavelengths), axis=-1
        )
        return np.asarray(ok)


@dataclass(frozen=True)
class GratingPrior:
    """A Gaussian prior on the grating family's parameters: ``(mean, σ)`` per parameter name.

    A σ of ``0`` holds the parameter at its mean (it leaves the parameter vector); a missing
    parameter is free with no prior. Rows ``(x − mean)/σ`` join the fit's residual.

    Attributes
    ----------
    values
        ``{name: (mean, sigma)}`` for names of :data:`GRATING_PARAMETERS`.
    source
        What the numbers came from (EXIF, a grating file, defaults), for the result's details.
    axis_offset_px
        The 0th order's distance from the lens axis along the order (known from the spot's sensor
        position; not fitted), ``u₀`` of :class:`calib.core.mapping.TiltedGrating`.
    """

    values: dict[str, tuple[float, float]] = field(default_factory=dict)
    source: str = "defaults"
    axis_offset_px: float = 0.0

    def __post_init__(self) -> None:
        for name, (mean, sigma) in self.values.items():
            if name not in GRATING_PARAMETERS:
                raise InputError(
                    f"unknown grating parameter {name!r}; expected one of {GRATING_PARAMETERS}",
                    source="grating prior",
                )
            if not (math.isfinite(mean) and math.isfinite(sigma) and sigma >= 0):
                raise InputError(
                    f"{name}: mean and σ must be finite, σ ≥ 0, got ({mean}, {sigma})",
                    source="grating prior",
                )

    def fixed(self) -> dict[str, float]:
        return {name: mean for name, (mean, sigma) in self.values.items() if sigma == 0}

    def soft(self) -> dict[str, tuple[float, float]]:
        return {name: value for name, value in self.values.items() if value[1] > 0}


@dataclass(frozen=True)
class GratingFamily:
    """:class:`calib.core.mapping.TiltedGrating` mappings over the free parameters of a prior.

    Parameters
    ----------
    prior
        Which parameters are held (σ = 0), which are pulled towards a value, which are free.
    orientation
        ``+1`` (wavelength rises with the pixel) or ``−1``.
    axis_offset_px
        The 0th order's distance from the lens axis along the order, ``u₀``: held at this value
        unless the prior names ``axis_offset_px`` (then fitted from it).
    """

    prior: GratingPrior
    orientation: int = 1
    axis_offset_px: float = 0.0

    def _held(self) -> dict[str, float]:
        held = self.prior.fixed()
        for name in _HELD_UNLESS_NAMED:
            if name not in self.prior.values:
                held[name] = self.axis_offset_px
        return held

    @property
    def offset_guess(self) -> float:
        """``u₀`` to start from: the prior's mean when it is fitted, else the held value."""
        value = self.prior.values.get("axis_offset_px")
        return self.axis_offset_px if value is None else value[0]

    @cached_property
    def names(self) -> tuple[str, ...]:
        held = self._held()
        return tuple(name for name in GRATING_PARAMETERS if name not in held)

    def full(self, x: FloatArray) -> FloatArray:
        """Parameters ``(..., P)`` → the full vectors ``(..., 5)`` with the held values filled in."""
        x = np.asarray(x, dtype=np.float64)
        held = self._held()
        columns = []
        free = iter(range(x.shape[-1]))
        for name in GRATING_PARAMETERS:
            if name in held:
                columns.append(np.full(x.shape[:-1], held[name]))
            else:
                columns.append(x[..., next(free)])
        return np.stack(columns, axis=-1)

    def parameters(self, grating: TiltedGrating) -> FloatArray:
        """The free parameter vector of ``grating``."""
        values = {
            "zero_order_px": grating.zero_order_px,
            "log_spacing": math.log(grating.groove_spacing_nm),
            "log_focal": math.log(grating.focal_length_px),
            "incidence_deg": grating.incidence_deg,
            "axis_offset_px": grating.axis_offset_px,
        }
        return np.array([values[name] for name in self.names])

    def mapping(self, x: ArrayLike) -> TiltedGrating:
        p0, log_spacing, log_focal, incidence, offset = self.full(np.asarray(x, dtype=np.float64))
        focal = math.exp(log_focal)
        return TiltedGrating(
            math.exp(log_spacing) / focal,
            focal,
            float(incidence),
            float(p0),
            self.orientation,
            float(offset),
        )

    def _terms(
        self, pixel: FloatArray, x: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        full = self.full(x)
        p0, spacing, focal, theta, offset = (
            full[..., 0:1],
            np.exp(full[..., 1:2]),
            np.exp(full[..., 2:3]),
            full[..., 3:4] * _DEG,
            full[..., 4:5],
        )
        distance = self.orientation * (np.asarray(pixel, dtype=np.float64) - p0)
        along = distance + offset
        angle = np.arctan(along / focal) - np.arctan(offset / focal)
        return spacing, focal, theta, along, angle, offset

    def wavelengths(self, pixel: FloatArray, x: FloatArray) -> FloatArray:
        """``λ`` at ``pixel`` ``(n,)`` for ``x`` ``(P,)`` → ``(n,)`` or ``(K, P)`` → ``(K, n)``."""
        spacing, _, theta, _, angle, _ = self._terms(pixel, x)
        return np.asarray(spacing * (np.sin(theta + angle) - np.sin(theta)), dtype=np.float64)

    def batch_jacobian(self, pixel: FloatArray, x: FloatArray) -> FloatArray:
        """``∂λ(p)/∂x`` for ``x`` ``(K, P)``: shape ``(K, n, P)`` (closed form)."""
        spacing, focal, theta, along, angle, offset = self._terms(pixel, x)
        cosine = np.cos(theta + angle)
        columns = {
            # ∂/∂p₀: through u = s (p − p₀).
            "zero_order_px": -self.orientation * spacing * cosine * focal / (focal**2 + along**2),
            "log_spacing": spacing * (np.sin(theta + angle) - np.sin(theta)),
            # ∂angle/∂ln F = F·∂/∂F [atan((u+u₀)/F) − atan(u₀/F)].
            "log_focal": spacing
            * cosine
            * (-along * focal / (focal**2 + along**2) + offset * focal / (focal**2 + offset**2)),
            "incidence_deg": spacing * (cosine - np.cos(theta)) * _DEG,
            # ∂angle/∂u₀ = F/(F² + (u+u₀)²) − F/(F² + u₀²).
            "axis_offset_px": spacing
            * cosine
            * (focal / (focal**2 + along**2) - focal / (focal**2 + offset**2)),
        }
        return np.stack(
            [np.broadcast_to(columns[name], angle.shape) for name in self.names], axis=-1
        )

    def jacobian(self, pixel: FloatArray, x: FloatArray) -> FloatArray:
        """``∂λ(p)/∂x`` for one ``x``: shape ``(n, P)``."""
        return np.asarray(self.batch_jacobian(pixel, np.asarray(x)[None, :])[0])

    @cached_property
    def _layout(self) -> tuple[FloatArray, FloatArray, NDArray[np.intp]]:
        """The full vector's held values (NaN where free), and each free parameter's place in it."""
        held = self._held()
        template = np.array([held.get(name, math.nan) for name in GRATING_PARAMETERS])
        places = np.array([GRATING_PARAMETERS.index(name) for name in self.names], dtype=np.intp)
        soft = self.prior.soft()
        rows = [(column, soft[name]) for column, name in enumerate(self.names) if name in soft]
        prior = np.array([(column, mean, sigma) for column, (mean, sigma) in rows]).reshape(-1, 3)
        return template, prior, places

    def evaluate(
        self,
        pixel: FloatArray,
        x: FloatArray,
        pixel_range: tuple[float, float] | None = None,
        *,
        with_jacobian: bool = True,
    ) -> tuple[FloatArray, FloatArray | None] | None:
        """``λ`` at ``pixel`` ``(n,)`` and ``∂λ/∂x`` ``(n, P)`` for one ``x`` in one pass — what
        :meth:`wavelengths`, :meth:`jacobian` and :meth:`valid` give, for a fit's inner loop —
        or ``None`` when ``x`` is not :meth:`valid` over ``pixel_range`` (when given)."""
        template, _, places = self._layout
        full = template.copy()
        full[places] = x
        if not np.isfinite(full).all():
            return None
        p0, log_spacing, log_focal, incidence, offset = full.tolist()
        spacing, focal = _exp(log_spacing), _exp(log_focal)
        theta = incidence * _DEG
        pixel = np.asarray(pixel, dtype=np.float64)
        probe = 0
        if pixel_range is not None:
            # The 9 pixels :meth:`valid` checks (np.linspace's own arithmetic), ahead of the
            # asked ones.
            probe = _PROBE_STEPS.size
            lo, hi = pixel_range
            ends = _PROBE_STEPS * ((hi - lo) / (probe - 1)) + lo
            ends[-1] = hi
            pixel = np.concatenate([ends, pixel])
        along = self.orientation * (pixel - p0) + offset
        angle = np.arctan(along / focal) - math.atan(offset / focal)
        turned = theta + angle
        sine = np.sin(turned)
        wavelength = spacing * (sine - math.sin(theta))
        if probe and not (
            (np.abs(turned[:probe]) < 0.5 * math.pi).all() and (wavelength[:probe] > 0).all()
        ):
            return None
        wavelength = wavelength[probe:]
        if not with_jacobian:
            return wavelength, None
        along, turned = along[probe:], turned[probe:]
        cosine = spacing * np.cos(turned)
        radial = focal / (focal**2 + along**2)
        at_axis = focal / (focal**2 + offset**2)
        columns = {
            "zero_order_px": -self.orientation * cosine * radial,
            "log_spacing": wavelength,
            "log_focal": cosine * (offset * at_axis - along * radial),
            "incidence_deg": (cosine - spacing * math.cos(theta)) * _DEG,
            "axis_offset_px": cosine * (radial - at_axis),
        }
        return wavelength, np.stack([columns[name] for name in self.names], axis=-1)

    def prior_cost(self, x: FloatArray) -> FloatArray:
        """``Σ ((x − mean)/σ)²`` of the soft prior for a batch ``(K, P)`` → ``(K,)``."""
        soft = self.prior.soft()
        x = np.atleast_2d(x)
        total = np.zeros(x.shape[0])
        for column, name in enumerate(self.names):
            if name in soft:
                mean, sigma = soft[name]
                total += ((x[:, column] - mean) / sigma) ** 2
        return total

    def prior_rows(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Residual rows ``(x − mean)/σ`` of the soft prior and their Jacobian ``(r, P)`` (the
        same read-only array every call: the rows are linear)."""
        columns, mean, sigma, jacobian = self._prior_layout
        values = (np.asarray(x, dtype=np.float64)[columns] - mean) / sigma
        return values, jacobian

    @cached_property
    def _prior_layout(self) -> tuple[NDArray[np.intp], FloatArray, FloatArray, FloatArray]:
        """The soft prior's columns, means, σ and (constant, read-only) Jacobian."""
        _, prior, places = self._layout
        columns = prior[:, 0].astype(np.intp)
        jacobian = np.zeros((columns.size, places.size))
        jacobian[np.arange(columns.size), columns] = 1.0 / prior[:, 2]
        jacobian.setflags(write=False)
        return columns, prior[:, 1].copy(), prior[:, 2].copy(), jacobian

    def valid(self, x: FloatArray, pixel_range: tuple[float, float]) -> FloatArray:
        """Whether each mapping ``(K, P)`` (or one ``(P,)``) puts the whole range on the first
        order's side of the 0th order, in one direction (``|θ + angle| < 90°`` keeps ``dλ/dp`` of
        one sign; ``λ > 0`` the right side)."""
        pixels = np.linspace(*pixel_range, 9)
        x = np.atleast_2d(x)
        spacing, _, theta, _, angle, _ = self._terms(pixels, x)
        wavelength = spacing * (np.sin(theta + angle) - np.sin(theta))
        ok = (
            np.all(np.abs(theta + angle) < 0.5 * math.pi, axis=-1)
            & np.all(wavelength > 0, axis=-1)
            & np.all(np.isfinite(x), axis=-1)
        )
        return np.asarray(ok)


def grating_prior(
    *,
    grooves_per_mm: float | None = None,
    grooves_sigma: float = 0.02,
    focal_length_px: float | None = None,
    focal_sigma: float = 0.1,
    incidence_deg: float = 0.0,
    incidence_sigma_deg: float = 5.0,
    zero_order_px: float | None = 0.0,
    zero_order_sigma_px: float = 0.0,
    axis_offset_px: float = 0.0,
    source: str = "defaults",
) -> GratingPrior:
    """A :class:`GratingPrior` from what a rig tells: line density, focal length in pixels, incidence.

    ``grooves_sigma`` and ``focal_sigma`` are relative (σ of the logarithm); ``zero_order_px=None``
    leaves the 0th order's position free (profiles whose origin is arbitrary).
    """
    values: dict[str, tuple[float, float]] = {}
    if zero_order_px is not None:
        values["zero_order_px"] = (zero_order_px, zero_order_sigma_px)
    if grooves_per_mm is not None:
        if not grooves_per_mm > 0:
            raise InputError(f"must be > 0, got {grooves_per_mm}", source="grooves_per_mm")
        values["log_spacing"] = (math.log(1e6 / grooves_per_mm), grooves_sigma)
    if focal_length_px is not None:
        if not focal_length_px > 0:
            raise InputError(f"must be > 0, got {focal_length_px}", source="focal_length_px")
        values["log_focal"] = (math.log(focal_length_px), focal_sigma)
    values["incidence_deg"] = (incidence_deg, incidence_sigma_deg)
    return GratingPrior(values, source, axis_offset_px)
