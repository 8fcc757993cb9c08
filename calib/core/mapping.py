"""Pixel→wavelength mapping types: the quadratic model and grating physics.

:class:`QuadraticMapping` ``g(p) = a p² + b p + c`` (Makabe et al. 2025, Eq. 13) with its inverse, how
it was found and an estimate of its error; :class:`GratingGeometry`, the physical first order at normal
incidence (``sin θ = λ/d``, pixel offset ``f_px·tan θ``) with its quadratic approximation;
:class:`TiltedGrating`. They serialise with ``to_dict``/``from_dict``. How a mapping is *found* lives
in :mod:`calib.wavelength`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import EstimationError, InputError

# ---------------------------------------------------------------------------------------- types


@dataclass(frozen=True)
class QuadraticMapping:
    """``λ = g(p) = a p² + b p + c`` (nm), Makabe et al. (2025) Eq. 13.

    Attributes
    ----------
    a, b, c
        Coefficients (nm/px², nm/px, nm).
    method
        How it was found (``"given"``, ``"fluorescent-peaks"``, ``"led-search"``, ``"geometry"`` …).
    pixel_range
        ``(p_min, p_max)`` over which it was fitted / is valid.
    covariance
        3×3 covariance of ``(a, b, c)`` from the fit, or ``None``.
    wavelength_rms_nm
        Estimated RMS wavelength error over ``pixel_range`` (from the covariance), or ``None``.
    details
        Diagnostics of the estimation (JSON-safe).
    model
        The physical mapping this quadratic reports, when it was fitted as one
        (:class:`TiltedGrating`): it is what :meth:`wavelength_nm`, :meth:`dispersion_nm_per_px`
        and :meth:`pixel_at` evaluate — the quadratic is then the report format, ``(a, b, c)``
        its least-squares summary over ``pixel_range``.
    line_reach
        Where the lamp's lines hold the mapping and how its σ grows past them
        (:class:`LineReach`), or ``None``. With it, :meth:`sigma_nm` and ``wavelength_rms_nm``
        state the covariance's σ and the extrapolation past the lines together (decision 0127).
    """

    a: float
    b: float
    c: float
    method: str = "given"
    pixel_range: tuple[float, float] | None = None
    covariance: tuple[tuple[float, float, float], ...] | None = None
    wavelength_rms_nm: float | None = None
    details: Mapping[str, Any] = field(default_factory=dict)
    model: TiltedGrating | None = field(default=None, compare=False)
    line_reach: LineReach | None = None

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.a, self.b, self.c)):
            raise InputError(
                f"mapping coefficients must be finite, got {self.coefficients}", source="mapping"
            )

    @property
    def coefficients(self) -> tuple[float, float, float]:
        return (self.a, self.b, self.c)

    def wavelength_nm(self, pixel: ArrayLike) -> FloatArray:
        """``g(p)`` in nm (the physical :attr:`model`'s when there is one)."""
        if self.model is not None:
            return self.model.wavelength_nm(pixel)
        p = np.asarray(pixel, dtype=np.float64)
        return np.asarray((self.a * p + self.b) * p + self.c, dtype=np.float64)

    def dispersion_nm_per_px(self, pixel: ArrayLike) -> FloatArray:
        """``g'(p)``."""
        if self.model is not None:
            return self.model.dispersion_at(pixel)
        return np.asarray(
            2 * self.a * np.asarray(pixel, dtype=np.float64) + self.b, dtype=np.float64
        )

    def pixel_at(self, wavelength_nm: ArrayLike) -> FloatArray:
        """Inverse ``g⁻¹(λ)``: the root on the branch where ``g`` is monotonic over ``pixel_range``."""
        if self.model is not None:
            return self.model.pixel_at(wavelength_nm)
        wavelength = np.asarray(wavelength_nm, dtype=np.float64)
        if abs(self.a) < 1e-15 * max(abs(self.b), 1e-300):
            return np.asarray((wavelength - self.c) / self.b, dtype=np.float64)
        reference = 0.0 if self.pixel_range is None else 0.5 * sum(self.pixel_range)
        slope_sign = np.sign(2 * self.a * reference + self.b) or 1.0
        discriminant = self.b**2 - 4 * self.a * (self.c - wavelength)
        root = np.sqrt(np.clip(discriminant, 0.0, None))
        # Stable form of (−b ± √D) / 2a choosing the branch with g' of the right sign.
        return np.asarray((-self.b + slope_sign * root) / (2 * self.a), dtype=np.float64)

    def sigma_nm(self, pixel: ArrayLike) -> FloatArray | None:
        """The stated σ (nm) of ``g(p)`` at each pixel: the coefficients' covariance and, past the
        lines' reach, the extrapolation term (:class:`LineReach`) in quadrature; ``None`` without
        a covariance. Every consumer of the mapping's σ reads this (decision 0127)."""
        if self.covariance is None:
            return None
        return _sigma_nm(self.covariance, pixel, self.line_reach)

    def sigma_at_wavelength_nm(self, wavelength_nm: ArrayLike) -> FloatArray | None:
        """:meth:`sigma_nm` at the pixel the mapping puts each wavelength (``wavelength_rms_nm``
        where it states no covariance or does not reach the wavelength); ``None`` when it states
        no σ at all."""
        rms = self.wavelength_rms_nm
        if rms is None or not math.isfinite(rms):
            return None
        wavelength = np.asarray(wavelength_nm, dtype=np.float64)
        constant = np.full(wavelength.shape, float(rms))
        if self.covariance is None:
            return constant
        try:
            pixel = np.asarray(self.pixel_at(wavelength), dtype=np.float64)
        except InputError:
            return constant
        sigma = _sigma_nm(self.covariance, pixel, self.line_reach)
        return np.asarray(np.where(np.isfinite(sigma), sigma, constant), dtype=np.float64)

    def with_line_reach(self, reach: LineReach | None) -> QuadraticMapping:
        """A copy stating ``reach``: its ``wavelength_rms_nm`` the RMS of :meth:`sigma_nm` over
        ``pixel_range`` (unchanged without a covariance or a pixel range)."""
        changes: dict[str, Any] = {"line_reach": None if reach is None else reach.to_dict()}
        if self.covariance is not None and self.pixel_range is not None:
            changes["wavelength_rms_nm"] = wavelength_rms_from_covariance(
                self.covariance, self.pixel_range, reach
            )
        return self.with_details(**changes)

    def with_details(self, **changes: Any) -> QuadraticMapping:
        """A copy with fields replaced (``method``, ``covariance`` …). A mapping with a
        :attr:`line_reach` whose covariance is replaced states its RMS with the reach: the
        ``wavelength_rms_nm`` is recomputed (a caller passes the covariance's own)."""
        values = {**self.to_dict(), **changes}
        reach = values.get("line_reach")
        if (
            "covariance" in changes
            and reach is not None
            and values.get("covariance") is not None
            and values.get("pixel_range") is not None
        ):
            values["wavelength_rms_nm"] = wavelength_rms_from_covariance(
                values["covariance"],
                tuple(values["pixel_range"]),
                reach if isinstance(reach, LineReach) else LineReach.from_dict(reach),
            )
        return QuadraticMapping.from_dict(values)

    def to_dict(self) -> dict[str, Any]:
        return {
            "type": "quadratic",
            "a": self.a,
            "b": self.b,
            "c": self.c,
            "method": self.method,
            "pixel_range": list(self.pixel_range) if self.pixel_range else None,
            "covariance": [list(row) for row in self.covariance] if self.covariance else None,
            "wavelength_rms_nm": self.wavelength_rms_nm,
            **({} if self.line_reach is None else {"line_reach": self.line_reach.to_dict()}),
            "details": dict(self.details),
            **({} if self.model is None else {"model": self.model.to_dict()}),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> QuadraticMapping:
        try:
            covariance = data.get("covariance")
            pixel_range = data.get("pixel_range")
            model = data.get("model")
            reach = data.get("line_reach")
            return cls(
                a=float(data["a"]),
                b=float(data["b"]),
                c=float(data["c"]),
                method=str(data.get("method", "given")),
                pixel_range=(float(pixel_range[0]), float(pixel_range[1])) if pixel_range else None,
                covariance=tuple((float(r[0]), float(r[1]), float(r[2])) for r in covariance)
                if covariance
                else None,
                wavelength_rms_nm=None
                if data.get("wavelength_rms_nm") is None
                else float(data["wavelength_rms_nm"]),
                details=dict(data.get("details") or {}),
                model=None if model is None else TiltedGrating.from_dict(model),
                line_reach=None
                if reach is None
                else reach
                if isinstance(reach, LineReach)
                else LineReach.from_dict(reach),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InputError(f"not a quadratic mapping record ({exc})", source="mapping") from None

    @classmethod
    def fit(
        cls,
        pixel: ArrayLike,
        wavelength_nm: ArrayLike,
        *,
        weights: ArrayLike | None = None,
        method: str = "fit",
        degree: int = 2,
        with_covariance: bool = True,
    ) -> QuadraticMapping:
        """Weighted least-squares quadratic (or line, ``degree=1``) through ``(pixel, wavelength)`` pairs.

        Needs ``degree + 1`` points; the covariance of ``(a, b, c)`` is attached when there are more
        (and ``with_covariance``: a search's trial fits use only the curve).
        """
        p = np.asarray(pixel, dtype=np.float64)
        lam = np.asarray(wavelength_nm, dtype=np.float64)
        if degree not in (1, 2) or p.size < degree + 1 or p.shape != lam.shape:
            raise EstimationError(
                f"a degree-{degree} mapping needs ≥ {degree + 1} matched points, got {p.size}"
            )
        w = np.ones_like(p) if weights is None else np.asarray(weights, dtype=np.float64)
        design = np.stack([p**2, p, np.ones_like(p)], axis=1)
        used = design[:, 2 - degree :]
        partial, *_ = np.linalg.lstsq(used * w[:, None], lam * w, rcond=None)
        coef = np.concatenate([np.zeros(2 - degree), partial])
        span = (float(p.min()), float(p.max()))
        mapping = cls(
            float(coef[0]), float(coef[1]), float(coef[2]), method=method, pixel_range=span
        )
        dof = p.size - (degree + 1)
        if dof <= 0 or not with_covariance:
            return mapping
        residual = lam - design @ coef
        variance = float(np.sum((w * residual) ** 2) / dof)
        normal = used.T @ (used * (w**2)[:, None])
        covariance = np.zeros((3, 3))
        covariance[2 - degree :, 2 - degree :] = np.linalg.pinv(normal) * variance
        return mapping.with_details(
            covariance=[list(row) for row in covariance],
            wavelength_rms_nm=wavelength_rms_from_covariance(covariance, span),
        )


@dataclass(frozen=True)
class LineReach:
    """How far a mapping's lamp lines reach, and the σ of its extrapolation past them (decision 0127).

    Between its outermost lines (``pixel_range``, at ``wavelength_range_nm``) a line lamp's
    sharp features hold the mapping; past them only broadband shapes do, through the camera
    prior's ends. In the quadratic family (profiles of arbitrary origin) nothing else holds the
    curvature there: the mapping's departure from its straight continuation (value and slope) at
    the outermost line, ``|a| (p − p_line)²``, is stated as its σ past the line — the curvature
    taken as unknown to 100 %, no constant fitted (decision 0122 measured it: the validation
    split's fits 1–3 nm off at the red end with a curvature σ of 0.1–0.5 nm). Inside the reach the
    term is zero. In the physical family (the 0th order pins the grating equation) the curvature
    is the geometry's, carried by the covariance: ``curvature_nm_per_px2`` is 0 and only the reach
    is recorded.

    Attributes
    ----------
    pixel_range
        ``(low, high)`` pixels of the outermost lines.
    wavelength_range_nm
        Their wavelengths (bluest, reddest).
    curvature_nm_per_px2
        ``|a|`` of the term (≥ 0).
    """

    pixel_range: tuple[float, float]
    wavelength_range_nm: tuple[float, float]
    curvature_nm_per_px2: float = 0.0

    def __post_init__(self) -> None:
        values = (*self.pixel_range, *self.wavelength_range_nm, self.curvature_nm_per_px2)
        if not all(math.isfinite(v) for v in values) or self.curvature_nm_per_px2 < 0:
            raise InputError(f"not a line reach: {values}", source="mapping")

    def sigma_nm(self, pixel: ArrayLike) -> FloatArray:
        """The extrapolation term at each pixel: 0 within the reach, ``|a| d²`` at ``d`` px past it."""
        p = np.asarray(pixel, dtype=np.float64)
        low, high = sorted(self.pixel_range)
        past = np.maximum(low - p, 0.0) + np.maximum(p - high, 0.0)
        return np.asarray(self.curvature_nm_per_px2 * past**2, dtype=np.float64)

    def to_dict(self) -> dict[str, Any]:
        return {
            "pixel_range": [float(v) for v in self.pixel_range],
            "wavelength_range_nm": [float(v) for v in self.wavelength_range_nm],
            "curvature_nm_per_px2": self.curvature_nm_per_px2,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LineReach:
        try:
            pixels, wavelengths = data["pixel_range"], data["wavelength_range_nm"]
            return cls(
                (float(pixels[0]), float(pixels[1])),
                (float(wavelengths[0]), float(wavelengths[1])),
                float(data.get("curvature_nm_per_px2", 0.0)),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InputError(f"not a line-reach record ({exc})", source="mapping") from None


def _sigma_nm(
    covariance: ArrayLike, pixel: ArrayLike, reach: LineReach | None = None
) -> FloatArray:
    """σ of ``g(p)`` at each pixel from the covariance of (a, b, c) and the extrapolation past
    ``reach`` in quadrature."""
    p = np.asarray(pixel, dtype=np.float64)
    design = np.stack([p**2, p, np.ones_like(p)], axis=-1)
    variance = np.clip(
        np.einsum("...j,jk,...k->...", design, np.asarray(covariance, dtype=np.float64), design),
        0.0,
        None,
    )
    if reach is not None:
        variance = variance + reach.sigma_nm(p) ** 2
    return np.asarray(np.sqrt(variance), dtype=np.float64)


def wavelength_rms_from_covariance(
    covariance: ArrayLike, pixel_range: tuple[float, float], reach: LineReach | None = None
) -> float:
    """RMS over ``pixel_range`` of the standard deviation of ``g(p)`` given the covariance of
    (a, b, c) — and the extrapolation past ``reach``'s lines when given (:class:`LineReach`)."""
    p = np.linspace(pixel_range[0], pixel_range[1], 64)
    return float(np.sqrt(np.mean(_sigma_nm(covariance, p, reach) ** 2)))


@dataclass(frozen=True)
class GratingGeometry:
    """A transmission grating in front of the camera lens, first order, normal incidence.

    ``sin θ = λ/d`` with ``d = 1/grooves_per_mm``; the image of direction θ lands at
    ``p = direct_spot_px + f_px tan θ`` with ``f_px = focal_length_mm / pixel_pitch_mm`` (camera focused
    on the slit, far away). The slit's image is ``slit_width_mm · focal_length_mm / slit_distance_mm``
    wide on the sensor.

    Attributes
    ----------
    grooves_per_mm
        Grating line density (e.g. 500 or 1000).
    focal_length_mm
        Lens focal length.
    pixel_pitch_um
        Sensor pixel pitch (for a profile in CFA-plane pixels use twice the photosite pitch).
    direct_spot_px
        Pixel coordinate of the direct (0th-order) spot along the dispersion direction.
    slit_distance_mm, slit_width_mm
        Distance slit→grating and slit width, for the slit image width (optional).
    """

    grooves_per_mm: float
    focal_length_mm: float
    pixel_pitch_um: float
    direct_spot_px: float = 0.0
    slit_distance_mm: float | None = None
    slit_width_mm: float | None = None

    def __post_init__(self) -> None:
        for name in ("grooves_per_mm", "focal_length_mm", "pixel_pitch_um"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(
                    f"must be a positive number, got {value}", source=f"grating.{name}"
                )

    @property
    def focal_length_px(self) -> float:
        return self.focal_length_mm / (self.pixel_pitch_um * 1e-3)

    @property
    def slit_image_width_px(self) -> float | None:
        if self.slit_distance_mm is None or self.slit_width_mm is None:
            return None
        return (
            self.slit_width_mm
            * self.focal_length_mm
            / self.slit_distance_mm
            / (self.pixel_pitch_um * 1e-3)
        )

    def pixel_at(self, wavelength_nm: ArrayLike) -> FloatArray:
        """Exact pixel of each wavelength (first order)."""
        sine = np.asarray(wavelength_nm, dtype=np.float64) * 1e-6 * self.grooves_per_mm
        if np.any(np.abs(sine) >= 1):
            raise InputError(
                "a wavelength has no first order at this groove density (λ ≥ d)", source="grating"
            )
        return np.asarray(
            self.direct_spot_px + self.focal_length_px * np.tan(np.arcsin(sine)), dtype=np.float64
        )

    def wavelength_nm(self, pixel: ArrayLike) -> FloatArray:
        """Exact wavelength at each pixel (the inverse of :meth:`pixel_at`)."""
        offset = (np.asarray(pixel, dtype=np.float64) - self.direct_spot_px) / self.focal_length_px
        return np.asarray(
            np.sin(np.arctan(offset)) / (self.grooves_per_mm * 1e-6), dtype=np.float64
        )

    def quadratic(
        self, wavelength_range_nm: tuple[float, float] = (380.0, 720.0)
    ) -> QuadraticMapping:
        """Least-squares quadratic approximation over the pixels of ``wavelength_range_nm``."""
        lo, hi = self.pixel_at(np.array(wavelength_range_nm))
        pixels = np.linspace(min(lo, hi), max(lo, hi), 256)
        fitted = QuadraticMapping.fit(pixels, self.wavelength_nm(pixels), method="geometry")
        return QuadraticMapping(
            fitted.a,
            fitted.b,
            fitted.c,
            method="geometry",
            pixel_range=fitted.pixel_range,
            details={"geometry": self.to_dict()},
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "type": "grating",
            "grooves_per_mm": self.grooves_per_mm,
            "focal_length_mm": self.focal_length_mm,
            "pixel_pitch_um": self.pixel_pitch_um,
            "direct_spot_px": self.direct_spot_px,
            "slit_distance_mm": self.slit_distance_mm,
            "slit_width_mm": self.slit_width_mm,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> GratingGeometry:
        try:
            optional = {k: data.get(k) for k in ("slit_distance_mm", "slit_width_mm")}
            return cls(
                grooves_per_mm=float(data["grooves_per_mm"]),
                focal_length_mm=float(data["focal_length_mm"]),
                pixel_pitch_um=float(data["pixel_pitch_um"]),
                direct_spot_px=float(data.get("direct_spot_px", 0.0)),
                **{k: None if v is None else float(v) for k, v in optional.items()},
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"not a grating geometry record ({exc})", source="grating") from None


#: Two first orders' directions on the sensor count as opposite (the two sides of one grating, or
#: a camera turned round) within this many degrees of 180°: detection pairs a band with the other
#: first order by it, and a grating file's order is told from a capture's by it.
OPPOSITE_ORDER_TOLERANCE_DEG = 20.0


@dataclass(frozen=True)
class TiltedGrating:
    """The first order of a transmission grating in front of a lens: the grating equation seen
    through a pinhole camera, with the 0th order as the origin.

    ``λ(p) = d [sin(θ + atan((u + u₀)/F) − atan(u₀/F)) − sin θ]`` with ``u = s·(p − p₀)`` the
    distance from the 0th order along the order, ``d`` the groove spacing, ``F`` the focal length
    in pixels, ``θ`` the angle of incidence on the grating (the 0th order continues at ``θ``, the
    first order leaves at ``θ'`` with ``sin θ' − sin θ = λ/d``) and ``u₀`` the 0th order's distance
    from the principal point along the order (the camera's angle of a pixel is ``atan(x/F)``
    from its axis). ``λ(p₀) = 0`` exactly: the 0th order is where the undiffracted light lands —
    the constraint an arbitrary quadratic lacks. Profiles measured from the direct spot
    (:mod:`calib.image.profiles`) have ``p₀ = 0`` and ``s = +1``; a profile whose wavelength falls
    with the pixel (a mirrored export) has ``s = −1``. The other first order (``−1``, measured away
    from the spot on the other side) is the same grating with ``θ → −θ`` and ``u₀ → −u₀``
    (:meth:`other_order`). :class:`GratingGeometry` is the special case ``θ = 0``, ``u₀ = 0``
    with ``d`` and ``F`` from the rig's parts.

    Attributes
    ----------
    dispersion_nm_per_px
        ``d / F``: wavelength per pixel near the 0th order at normal incidence.
    focal_length_px
        ``F``.
    incidence_deg
        ``θ``.
    zero_order_px
        ``p₀``: the profile coordinate of the 0th order (0 for profiles measured from the spot).
    orientation
        ``s``: ``+1`` when the wavelength rises with the profile coordinate, ``−1`` when it falls.
    axis_offset_px
        ``u₀`` (0 when the 0th order is on the lens axis or its position is unknown).
    """

    dispersion_nm_per_px: float
    focal_length_px: float
    incidence_deg: float = 0.0
    zero_order_px: float = 0.0
    orientation: int = 1
    axis_offset_px: float = 0.0

    def __post_init__(self) -> None:
        if not (self.dispersion_nm_per_px > 0 and self.focal_length_px > 0):
            raise InputError(
                f"dispersion and focal length must be > 0, got {self.dispersion_nm_per_px}, "
                f"{self.focal_length_px}",
                source="mapping",
            )
        if self.orientation not in (1, -1):
            raise InputError(
                f"orientation must be +1 or -1, got {self.orientation}", source="mapping"
            )
        values = (self.incidence_deg, self.zero_order_px, self.axis_offset_px)
        if not all(math.isfinite(v) for v in values):
            raise InputError(f"grating parameters must be finite, got {values}", source="mapping")

    @property
    def groove_spacing_nm(self) -> float:
        """``d`` in nm (``10⁶ / grooves per mm``)."""
        return self.dispersion_nm_per_px * self.focal_length_px

    def _angle(self, pixel: ArrayLike) -> FloatArray:
        """``atan((u + u₀)/F) − atan(u₀/F)``: the first order's deviation from the 0th order."""
        distance = self.orientation * (np.asarray(pixel, dtype=np.float64) - self.zero_order_px)
        focal = self.focal_length_px
        return np.asarray(
            np.arctan((distance + self.axis_offset_px) / focal)
            - math.atan(self.axis_offset_px / focal),
            dtype=np.float64,
        )

    def wavelength_nm(self, pixel: ArrayLike) -> FloatArray:
        """``λ(p)`` in nm."""
        theta = math.radians(self.incidence_deg)
        angle = self._angle(pixel)
        return np.asarray(
            self.groove_spacing_nm * (np.sin(theta + angle) - math.sin(theta)), dtype=np.float64
        )

    def dispersion_at(self, pixel: ArrayLike) -> FloatArray:
        """``dλ/dp`` in nm per pixel (negative where the wavelength falls with the pixel)."""
        theta = math.radians(self.incidence_deg)
        distance = self.orientation * (np.asarray(pixel, dtype=np.float64) - self.zero_order_px)
        focal = self.focal_length_px
        along = distance + self.axis_offset_px
        return np.asarray(
            self.orientation
            * self.groove_spacing_nm
            * np.cos(theta + self._angle(pixel))
            * focal
            / (focal**2 + along**2),
            dtype=np.float64,
        )

    def pixel_at(self, wavelength_nm: ArrayLike) -> FloatArray:
        """Inverse of :meth:`wavelength_nm` (the first order's branch)."""
        theta = math.radians(self.incidence_deg)
        sine = np.asarray(wavelength_nm, dtype=np.float64) / self.groove_spacing_nm + math.sin(
            theta
        )
        if np.any(np.abs(sine) >= 1):
            raise InputError(
                "a wavelength has no first order at this groove spacing and incidence",
                source="grating",
            )
        focal = self.focal_length_px
        angle = np.arcsin(sine) - theta + math.atan(self.axis_offset_px / focal)
        distance = focal * np.tan(angle) - self.axis_offset_px
        return np.asarray(self.zero_order_px + self.orientation * distance, dtype=np.float64)

    def other_order(self) -> TiltedGrating:
        """The ``−1`` order measured away from the 0th order on the other side (``θ, u₀ → −θ, −u₀``)."""
        return replace(self, incidence_deg=-self.incidence_deg, axis_offset_px=-self.axis_offset_px)

    def quadratic(self, pixel_range: tuple[float, float]) -> QuadraticMapping:
        """The least-squares quadratic over ``pixel_range`` (the report format), with its largest
        departure from the grating in ``details["quadratic_max_error_nm"]``."""
        pixels = np.linspace(pixel_range[0], pixel_range[1], 256)
        exact = self.wavelength_nm(pixels)
        fitted = QuadraticMapping.fit(pixels, exact, method="grating")
        return QuadraticMapping(
            fitted.a,
            fitted.b,
            fitted.c,
            method="grating",
            pixel_range=(float(pixel_range[0]), float(pixel_range[1])),
            details={
                "grating": self.to_dict(),
                "quadratic_max_error_nm": float(
                    np.max(np.abs(fitted.wavelength_nm(pixels) - exact))
                ),
            },
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "type": "tilted_grating",
            "dispersion_nm_per_px": self.dispersion_nm_per_px,
            "focal_length_px": self.focal_length_px,
            "incidence_deg": self.incidence_deg,
            "zero_order_px": self.zero_order_px,
            "orientation": self.orientation,
            "axis_offset_px": self.axis_offset_px,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TiltedGrating:
        try:
            return cls(
                float(data["dispersion_nm_per_px"]),
                float(data["focal_length_px"]),
                float(data.get("incidence_deg", 0.0)),
                float(data.get("zero_order_px", 0.0)),
                int(data.get("orientation", 1)),
                float(data.get("axis_offset_px", 0.0)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"not a tilted-grating record ({exc})", source="mapping") from None


def mapping_from_dict(data: Mapping[str, Any]) -> QuadraticMapping | GratingGeometry:
    """Read either mapping type from its ``to_dict`` form."""
    kind = data.get("type")
    if kind == "quadratic":
        return QuadraticMapping.from_dict(data)
    if kind == "grating":
        return GratingGeometry.from_dict(data)
    raise InputError(
        f"unknown mapping type {kind!r}; expected 'quadratic' or 'grating'", source="mapping"
    )
