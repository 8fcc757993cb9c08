"""Physical grating efficiency models: the efficiency ``η_m(λ)`` of the orders m = 0, 1, 2.

A transmission grating sends a fraction ``η_m(λ)`` of the light of wavelength ``λ`` into order
``m``: the 0th order (the direct, undiffracted beam the rig measures as the "direct" signal), the
first order (the rainbow the profile is read from) and the second (which lands on top of the first
order's red end, at twice the wavelength). Three models, one interface (:class:`GratingModel`):

:class:`SinusoidalPhaseGrating` — a thin sinusoidal phase grating (holographic and embossed replica
    sheets, the cheap "rainbow" film). Its transmission ``t(x) = exp(i φ sin(2πx/d))`` expands by the
    Jacobi–Anger identity into plane waves ``Σ_m J_m(φ) exp(2πi m x/d)``, so

        η_m(λ) = J_m²(φ(λ)),    φ(λ) = φ₀ · λ₀ / λ,

    with ``φ`` the peak phase (half the peak-to-peak phase excursion ``2π Δn h / λ`` of a relief
    of depth ``h`` and index step ``Δn``; the index's own dispersion is neglected). ``η₀ = J₀²``
    and ``η₂ = J₂²`` follow from the same two parameters. ``η₁`` peaks at 33.8 % for
    ``φ = 1.84 rad`` — the ceiling of any thin sinusoidal phase grating.
:class:`BlazedGrating` — a thin blazed (sawtooth) phase grating in scalar theory: the groove depth
    gives a phase ramp of ``2π α(λ)`` per period with ``α = λ_B / λ`` (``λ_B`` the blaze
    wavelength, where the whole ramp is one wave), and

        η_m(λ) = sinc²(α(λ) − m),    sinc(x) = sin(πx)/(πx),

    so order 1 is 100 % efficient at ``λ_B``, the 0th order is ``sinc²(α)`` and the 2nd
    ``sinc²(α − 2)``.
:class:`CatalogueGrating` — a maker's tabulated first-order efficiency (e.g. the Shelyak LHires
    III 150 l/mm curve), read from a file at run time. A catalogue gives order 1 only; the 0th and
    2nd orders are those of the blazed model fitted to the curve (its blaze wavelength and one
    scale), which is what scalar theory predicts for the same groove profile.

Scalar theory holds while the groove period is several wavelengths: for ``d/λ ≳ 5`` its
efficiencies are within ~10 % of rigorous (vector) results (Pommet et al. 1994); at 1000 l/mm
(``d/λ`` ≈ 1.4–2.5 in the visible) it is an approximation — polarisation and resonance (Wood)
anomalies are not modelled. All efficiencies here are *relative to the incident light at the
grating*: a common loss (Fresnel reflections of the substrate, absorption) scales every order
alike and cancels from the ratios the estimators use.

The parameters of each model are a small frozen dataclass with ``efficiency(order,
wavelength_nm)``, :meth:`GratingModel.efficiency_spectrum` for a :class:`~calib.core.spectra.Spectrum`,
``to_dict`` for records, and ``draw(rng)`` for a random grating of physically plausible
parameters (the ranges are documented at each class). The estimator's η model family and the
twin use the same classes.

References
----------
Goodman, J. W. (2005). *Introduction to Fourier Optics*, 3rd ed., §4.4 (thin sinusoidal phase
grating, efficiencies ``J_q²``).
Magnusson, R., Gaylord, T. K. (1978). Diffraction efficiencies of thin phase gratings with arbitrary
grating shape. *J. Opt. Soc. Am.* 68(6), 806–809.
Swanson, G. J. (1989). Binary optics technology: the theory and design of multi-level diffractive
optical elements. MIT Lincoln Laboratory Technical Report 854 (blazed efficiency
``sinc²(m − α)``).
Loewen, E. G., Popov, E. (1997). *Diffraction Gratings and Applications*. Marcel Dekker, ch. 4.
Palmer, C., Loewen, E. (2005). *Diffraction Grating Handbook*, 6th ed. Newport Corporation, ch. 9
(efficiency and blaze).
Pommet, D. A., Moharam, M. G., Grann, E. B. (1994). Limits of scalar diffraction theory for
diffractive phase elements. *J. Opt. Soc. Am. A* 11(6), 1827–1834.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.spectra import Spectrum, read_table

GratingKind = Literal["sinusoidal", "blazed", "catalogue"]
GRATING_KINDS: tuple[GratingKind, ...] = ("sinusoidal", "blazed", "catalogue")
#: The orders a rig sees: the direct beam, the first order, and the second on the red end.
GRATING_ORDERS: tuple[int, ...] = (0, 1, 2)
#: Peak phase at 550 nm of a cheap embossed replica sheet (the twin's default grating): a sinusoidal
#: relief ``h ≈ 0.36 µm`` deep in a polymer of index ``n ≈ 1.58`` (PET/PVC) gives
#: ``φ₀ = π (n − 1) h / λ ≈ 1.2 rad``: η₁ = J₁² 0.33 / 0.25 / 0.18 and η₀ = J₀² 0.18 / 0.45 / 0.62
#: at 400 / 550 / 700 nm — a bright direct spot, as such sheets show. Mid-range of
#: :attr:`SinusoidalPhaseGrating.PHASE_RANGE_RAD` (decision 0040).
REPLICA_SHEET_PEAK_PHASE_RAD = 1.2
#: Wavelengths at which :meth:`GratingModel.efficiency_spectrum` tabulates a model by default.
DEFAULT_TABLE_NM: tuple[float, float, float] = (300.0, 1100.0, 1.0)


def _wavelengths(wavelength_nm: ArrayLike, source: str) -> FloatArray:
    wavelength = np.asarray(wavelength_nm, dtype=np.float64)
    # min/max (NaN propagates into both): two reductions, not four passes with temporaries.
    if wavelength.size and not (wavelength.min() > 0 and wavelength.max() < math.inf):
        raise InputError("wavelengths must be finite and > 0 nm", source=source)
    return wavelength


def _order(order: int, source: str) -> int:
    if isinstance(order, bool) or not isinstance(order, int | np.integer):
        raise InputError(f"a diffraction order is an integer, got {order!r}", source=source)
    return int(order)


class GratingModel(Protocol):
    """What every grating model offers (the estimator's η family and the twin use this)."""

    kind: ClassVar[GratingKind]

    @property
    def name(self) -> str:
        """A short description with the parameters, for tables and plots."""
        ...

    def efficiency(self, order: int, wavelength_nm: ArrayLike) -> FloatArray:
        """``η_order(λ)`` at each wavelength, a fraction of the incident light."""
        ...

    def efficiency_spectrum(self, order: int, wavelength_nm: ArrayLike | None = None) -> Spectrum:
        """``η_order`` as a :class:`Spectrum` (default: 300–1100 nm at 1 nm)."""
        ...

    def to_dict(self) -> dict[str, Any]:
        """The parameters as plain data (``{"kind": …, …}``)."""
        ...


class _SpectrumMixin:
    """``efficiency_spectrum`` from ``efficiency`` (shared by the three models)."""

    @property
    def name(self) -> str:
        raise NotImplementedError

    def efficiency(self, order: int, wavelength_nm: ArrayLike) -> FloatArray:
        raise NotImplementedError

    def efficiency_spectrum(self, order: int, wavelength_nm: ArrayLike | None = None) -> Spectrum:
        axis = (
            np.arange(DEFAULT_TABLE_NM[0], DEFAULT_TABLE_NM[1] + 0.5, DEFAULT_TABLE_NM[2])
            if wavelength_nm is None
            else np.asarray(wavelength_nm, dtype=np.float64)
        )
        return Spectrum(axis, self.efficiency(order, axis), name=f"{self.name}, order {order}")


def _sinusoidal_efficiency(order: int, phase_rad: FloatArray) -> FloatArray:
    """``J_m²(φ)`` for ``m ≥ 0`` (:meth:`SinusoidalPhaseGrating.efficiency`)."""
    from scipy.special import j0, j1, jv  # deferred: scipy.special is slow to import

    # J₀ and J₁ by their own routines (Cephes, ~30× faster than the general order's and equal
    # to it within 1e-15): the physical grating fit evaluates them hundreds of times.
    bessel = j0(phase_rad) if order == 0 else j1(phase_rad) if order == 1 else jv(order, phase_rad)
    return np.asarray(bessel**2, dtype=np.float64)


def _blazed_efficiency(order: int, blaze_ratio: FloatArray) -> FloatArray:
    """``sinc²(λ_B/λ − m)`` given ``λ_B/λ`` (:meth:`BlazedGrating.efficiency`)."""
    return np.asarray(np.sinc(blaze_ratio - order) ** 2, dtype=np.float64)


@dataclass(frozen=True)
class SinusoidalPhaseGrating(_SpectrumMixin):
    """A thin sinusoidal phase grating: ``η_m(λ) = J_m²(φ₀ λ₀ / λ)`` (module docstring).

    Attributes
    ----------
    peak_phase_rad
        ``φ₀``, the peak phase modulation at ``reference_nm`` (radians, > 0).
    reference_nm
        ``λ₀`` (default 550 nm, the middle of the visible).

    Examples
    --------
    >>> grating = SinusoidalPhaseGrating(1.0)
    >>> [round(float(grating.efficiency(m, 550.0)), 4) for m in (0, 1, 2)]
    [0.5855, 0.1936, 0.0132]
    """

    peak_phase_rad: float
    reference_nm: float = 550.0
    kind: ClassVar[GratingKind] = "sinusoidal"
    #: Range of ``φ₀`` at 550 nm that :meth:`draw` samples (uniformly). Replica sheets sold for
    #: spectroscopy put a sizeable share into ±1 but keep a bright 0th order: at the upper end
    #: (1.8 rad, next to the 1.84 rad optimum) ``η₁ = 33.8 %`` and ``η₀ = 11.6 %``; at the lower end
    #: (0.5 rad, a shallow replica) ``η₁ = 5.9 %`` and ``η₀ = 88 %``, the 0th order 15× brighter
    #: than the first. The range stays below the optimum, so ``η₁`` falls monotonically towards
    #: the red as ``φ ∝ 1/λ`` does — the single broad hump a real sheet's first order shows.
    PHASE_RANGE_RAD: ClassVar[tuple[float, float]] = (0.5, 1.8)

    def __post_init__(self) -> None:
        for label, value in (
            ("peak_phase_rad", self.peak_phase_rad),
            ("reference_nm", self.reference_nm),
        ):
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"must be a positive number, got {value}", source=label)

    @property
    def name(self) -> str:
        return f"sinusoidal phase grating φ₀ = {self.peak_phase_rad:.3g} rad at {self.reference_nm:g} nm"

    def phase_rad(self, wavelength_nm: ArrayLike) -> FloatArray:
        """``φ(λ) = φ₀ λ₀ / λ`` (radians)."""
        wavelength = _wavelengths(wavelength_nm, "wavelength_nm")
        return np.asarray(self.peak_phase_rad * self.reference_nm / wavelength, dtype=np.float64)

    def efficiency(self, order: int, wavelength_nm: ArrayLike) -> FloatArray:
        """``J_m²(φ(λ))``; orders ``±m`` are equal."""
        return _sinusoidal_efficiency(abs(_order(order, "order")), self.phase_rad(wavelength_nm))

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "peak_phase_rad": self.peak_phase_rad,
            "reference_nm": self.reference_nm,
        }

    @classmethod
    def draw(cls, rng: np.random.Generator) -> SinusoidalPhaseGrating:
        """A random sheet: ``φ₀`` uniform in :attr:`PHASE_RANGE_RAD` at 550 nm."""
        return cls(float(rng.uniform(*cls.PHASE_RANGE_RAD)))


@dataclass(frozen=True)
class BlazedGrating(_SpectrumMixin):
    """A thin blazed phase grating in scalar theory: ``η_m(λ) = sinc²(λ_B/λ − m)`` (module docstring).

    Attributes
    ----------
    blaze_nm
        ``λ_B``: where the first order takes all the light.

    Examples
    --------
    >>> grating = BlazedGrating(500.0)
    >>> [round(float(grating.efficiency(m, 500.0)), 4) for m in (0, 1, 2)]
    [0.0, 1.0, 0.0]
    >>> round(float(grating.efficiency(1, 700.0)), 3)
    0.759
    """

    blaze_nm: float
    kind: ClassVar[GratingKind] = "blazed"
    #: Range of ``λ_B`` that :meth:`draw` samples (uniformly). Blazed transmission gratings sold for
    #: the visible are blazed inside it (500 nm is the common choice); a grating blazed in the near
    #: infrared (750 nm and up) would still be usable but is not what one buys for this work.
    BLAZE_RANGE_NM: ClassVar[tuple[float, float]] = (400.0, 650.0)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.blaze_nm) and self.blaze_nm > 0):
            raise InputError(f"must be a positive number, got {self.blaze_nm}", source="blaze_nm")

    @property
    def name(self) -> str:
        return f"blazed grating λ_B = {self.blaze_nm:.4g} nm"

    def efficiency(self, order: int, wavelength_nm: ArrayLike) -> FloatArray:
        """``sinc²(λ_B/λ − m)``."""
        wavelength = _wavelengths(wavelength_nm, "wavelength_nm")
        return _blazed_efficiency(_order(order, "order"), self.blaze_nm / wavelength)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "blaze_nm": self.blaze_nm}

    @classmethod
    def draw(cls, rng: np.random.Generator) -> BlazedGrating:
        """A random blazed grating: ``λ_B`` uniform in :attr:`BLAZE_RANGE_NM`."""
        return cls(float(rng.uniform(*cls.BLAZE_RANGE_NM)))


def fit_blaze(curve: Spectrum) -> tuple[BlazedGrating, float]:
    """The blazed grating (and scale) closest to a first-order curve in least squares.

    ``η₁(λ) ≈ scale · sinc²(λ_B/λ − 1)`` over the curve's samples; ``λ_B`` is scanned from 200 to
    1500 nm and refined by a bounded scalar minimisation, the scale is linear.
    """
    from scipy.optimize import minimize_scalar  # deferred: scipy.optimize is slow to import

    wavelength, values = curve.wavelength_nm, curve.values

    def misfit(blaze_nm: float) -> tuple[float, float]:
        model = np.sinc(blaze_nm / wavelength - 1.0) ** 2
        scale = float(model @ values / max(float(model @ model), 1e-300))
        return float(np.sum((values - scale * model) ** 2)), scale

    candidates = np.linspace(200.0, 1500.0, 261)
    start = float(candidates[int(np.argmin([misfit(b)[0] for b in candidates]))])
    best = minimize_scalar(
        lambda b: misfit(float(b))[0],
        bounds=(max(150.0, start - 10.0), start + 10.0),
        method="bounded",
        options={"xatol": 1e-3},
    )
    blaze_nm = float(best.x)
    return BlazedGrating(blaze_nm), misfit(blaze_nm)[1]


@dataclass(frozen=True, eq=False)
class CatalogueGrating(_SpectrumMixin):
    """A maker's tabulated first-order efficiency, with the 0th and 2nd orders of its blazed fit.

    Attributes
    ----------
    first_order
        The catalogue curve ``η₁(λ)`` as a fraction (not per cent).
    blaze
        The blazed model fitted to it (:func:`fit_blaze`); orders other than 1 are
        ``blaze_scale · sinc²(λ_B/λ − m)``.
    blaze_scale
        The fitted scale (the catalogue's absolute level relative to the lossless model).
    source
        Where the curve was read.

    A catalogue curve has no free parameter: :meth:`draw` returns the grating itself. Wavelengths
    outside the tabulated range raise :class:`InputError` (never a silent zero).
    """

    first_order: Spectrum
    blaze: BlazedGrating
    blaze_scale: float
    source: str = ""
    kind: ClassVar[GratingKind] = "catalogue"
    _range_nm: tuple[float, float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_range_nm", self.first_order.range_nm)

    @classmethod
    def from_curve(cls, first_order: Spectrum, *, source: str = "") -> CatalogueGrating:
        """Build from a first-order curve (fractions), fitting its blazed model."""
        if float(np.max(first_order.values)) <= 0:
            raise InputError("the efficiency curve is zero everywhere", source=source or "curve")
        blaze, scale = fit_blaze(first_order)
        return cls(first_order, blaze, scale, source)

    @classmethod
    def from_file(cls, path: str | Path, *, percent: bool | None = None) -> CatalogueGrating:
        """Read a two-column ``wavelength_nm, efficiency`` table (any header, CSV or whitespace).

        Parameters
        ----------
        path
            The maker's curve, e.g. ``LHires III Grating Efficiency 150.csv``.
        percent
            Whether the values are per cent; ``None`` decides from the data (a maximum above 1.5
            can only be per cent).
        """
        table = read_table(path)
        if table.rows.shape[1] != 2:
            raise InputError(
                f"expected two columns (wavelength_nm, efficiency), found {table.columns}",
                source=str(path),
            )
        values = table.rows[:, 1]
        if percent is None:
            percent = float(np.max(values)) > 1.5
        if percent:
            values = values / 100.0
        if float(np.max(values)) > 1.0 + 1e-9:
            raise InputError(
                f"efficiency reaches {float(np.max(values)):.3g} > 1; is the column in per cent "
                "(pass percent=True)?",
                source=str(path),
            )
        curve = Spectrum(table.rows[:, 0], values, name=Path(path).stem)
        return cls.from_curve(curve, source=str(path))

    @property
    def name(self) -> str:
        return f"catalogue {self.first_order.name} (0th/2nd orders: {self.blaze.name})"

    def efficiency(self, order: int, wavelength_nm: ArrayLike) -> FloatArray:
        """The catalogue curve for order 1, the scaled blazed fit for any other order."""
        m = _order(order, "order")
        wavelength = _wavelengths(wavelength_nm, "wavelength_nm")
        if m != 1:
            return np.asarray(
                self.blaze_scale * self.blaze.efficiency(m, wavelength), dtype=np.float64
            )
        low, high = self._range_nm
        if wavelength.size and (float(wavelength.min()) < low or float(wavelength.max()) > high):
            raise InputError(
                f"the catalogue curve covers {low:g}–{high:g} nm; asked for "
                f"{float(wavelength.min()):g}–{float(wavelength.max()):g} nm",
                source=self.source or self.first_order.name,
            )
        return self.first_order.at(wavelength)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "source": self.source,
            "fitted_blaze_nm": self.blaze.blaze_nm,
            "fitted_blaze_scale": self.blaze_scale,
        }

    def draw(self, rng: np.random.Generator) -> CatalogueGrating:
        """The catalogue grating itself (no free parameter; ``rng`` is not used)."""
        del rng
        return self


#: The physical families the estimator fits (:mod:`calib.methods.grating_models`): each is one
#: shape parameter (the sinusoidal sheet's peak phase at 550 nm, the blazed grating's blaze
#: wavelength), with the orders' efficiencies all following from it.
PhysicalKind = Literal["sinusoidal", "blazed"]
PHYSICAL_KINDS: tuple[PhysicalKind, ...] = ("sinusoidal", "blazed")
#: Where the estimator searches each family's parameter. Wider than what any sheet sold for this
#: work has (and than :meth:`SinusoidalPhaseGrating.draw`/:meth:`BlazedGrating.draw` sample), but
#: inside the range where the first order has no zero between 380 and 780 nm: ``J₁`` vanishes at
#: ``φ = 3.83`` (``φ₀ = 3.83 · 380 / 550 = 2.65`` rad), ``sinc²(λ_B/λ − 1)`` at ``λ_B = 2λ``
#: (760 nm). The blaze's foot is half the band's shortest wavelength (190 nm): below it the
#: whole band lies on the far flank of the main lobe (``λ_B/λ − 1 < −0.5``), a grating blazed for
#: the vacuum UV that no sheet sold for this work is; a fit there is the family bent to absorb the
#: rig's errors (decision 0063). Units: radians at 550 nm, nm.
PHYSICAL_PARAMETER_RANGES: dict[PhysicalKind, tuple[float, float]] = {
    "sinusoidal": (0.05, 2.6),
    "blazed": (190.0, 755.0),
}
#: The parameter's name in records (``to_dict``'s key).
PHYSICAL_PARAMETER_NAMES: dict[PhysicalKind, str] = {
    "sinusoidal": "peak_phase_rad",
    "blazed": "blaze_nm",
}


def physical_grating(
    kind: PhysicalKind, parameter: float
) -> SinusoidalPhaseGrating | BlazedGrating:
    """The grating of a physical family with its one shape parameter (:data:`PHYSICAL_KINDS`).

    Examples
    --------
    >>> physical_grating("blazed", 500.0).name
    'blazed grating λ_B = 500 nm'
    """
    if kind == "sinusoidal":
        return SinusoidalPhaseGrating(parameter)
    if kind == "blazed":
        return BlazedGrating(parameter)
    raise InputError(
        f"unknown physical grating {kind!r}; choose from {PHYSICAL_KINDS}", source="grating_model"
    )


def physical_efficiencies(
    kind: PhysicalKind, parameters: ArrayLike, order: int, wavelength_nm: ArrayLike
) -> FloatArray:
    """``η_order(λ)`` of ``kind`` for many parameter values at once, ``(k, n)``: row ``i`` is
    ``physical_grating(kind, parameters[i]).efficiency(order, wavelength_nm)``, the same numbers
    (the physical grating fit's scans evaluate whole grids of the parameter).

    Examples
    --------
    >>> rows = physical_efficiencies("blazed", [500.0, 600.0], 1, [500.0, 700.0])
    >>> bool(np.array_equal(rows[1], BlazedGrating(600.0).efficiency(1, [500.0, 700.0])))
    True
    """
    values = np.asarray(parameters, dtype=np.float64).reshape(-1, 1)
    if not (np.all(np.isfinite(values)) and np.all(values > 0)):
        raise InputError("grating parameters must be positive numbers", source=kind)
    wavelength = _wavelengths(wavelength_nm, "wavelength_nm")
    if kind == "sinusoidal":
        phase = values * SinusoidalPhaseGrating.reference_nm / wavelength
        return _sinusoidal_efficiency(abs(_order(order, "order")), phase)
    if kind == "blazed":
        return _blazed_efficiency(_order(order, "order"), values / wavelength)
    raise InputError(
        f"unknown physical grating {kind!r}; choose from {PHYSICAL_KINDS}", source="grating_model"
    )


def draw_grating(
    kind: GratingKind, rng: np.random.Generator, *, catalogue: CatalogueGrating | None = None
) -> SinusoidalPhaseGrating | BlazedGrating | CatalogueGrating:
    """A random grating of ``kind`` (``"catalogue"`` needs the catalogue curve).

    Raises
    ------
    InputError
        An unknown kind, or ``"catalogue"`` without a curve.
    """
    if kind == "sinusoidal":
        return SinusoidalPhaseGrating.draw(rng)
    if kind == "blazed":
        return BlazedGrating.draw(rng)
    if kind == "catalogue":
        if catalogue is None:
            raise InputError(
                "a catalogue grating needs the maker's efficiency curve (a wavelength_nm,"
                "efficiency file)",
                source="grating",
            )
        return catalogue.draw(rng)
    raise InputError(
        f"unknown grating kind {kind!r}; choose from {GRATING_KINDS}", source="grating"
    )
