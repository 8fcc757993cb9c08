"""A synthetic sunlight spectrum for judging absorption-line (Fraunhofer) mappings.

No real capture of sunlight has a known mapping, so the absorption path is judged on this analog,
rendered through the validation protocol's scenes (``bench/solar_validate.py``). What matters for a
mapping is the *shape* of each feature at a camera's resolution, so the features are built from
their physics, never from any camera's data:

- **Continuum**: a 5772 K black body (the Sun's effective temperature, IAU 2015 B3) through a
  Rayleigh-scattering atmosphere (optical depth ``0.0088 λ[µm]^−4.05`` at the zenith, Bodhaine
  et al. 1999) at airmass 1.5.
- **Strong atomic lines** (air wavelengths, NIST ASD; equivalent widths after the Rowland table
  of Moore, Minnaert & Houtgast 1966, rounded, ±30 %): each a pseudo-Voigt depth profile with
  its listed central depth, its width set by its equivalent width. The Balmer lines are almost
  all Lorentzian (their Stark wings reach nanometres); Na D, Mg b and the strong Fe/Ca lines half.
- **The G band** (Fraunhofer's G, 429–432 nm): the CH A²Δ–X²Π (0,0) band — P, Q and R branches from
  the band constants (B″ = 14.19, B′ = 14.58 cm⁻¹, Huber & Herzberg 1979), its Q-branch head
  placed at 431.40 nm, populated at the photosphere's ~5000 K, each line split in two by its
  spin/Λ doubling and the whole scaled to a total equivalent width of 0.35 nm — under the Fe I
  430.79 + Ca I 430.77 blend, Ca I 430.25, Fe I 429.92 and Ti II 430.06. B′ > B″: the band is
  shaded to the violet, so at a camera's resolution its dip is broad and lopsided.
- **Telluric O₂** (b¹Σg⁺–X³Σg⁻, only odd N″ for ¹⁶O₂): the B (1,0), γ (2,0) and A (0,0) bands from
  their origins and rotational constants (B″ = 1.4377 cm⁻¹; Babcock & Herzberg 1948), P and R
  branches, each line a PQ/PP or RR/RQ pair 2B″ apart, populated at 250 K. B′ < B″: the R branch
  turns back into a head (B: 686.7 nm) and the P branch tails to the red (to ~695 nm). The
  strongest B-band lines are saturated (central optical depth ~17 at airmass 1, Lorentzian
  pressure-broadened: a band equivalent width of ~0.5–1 nm).
- **Water vapour** near 718 nm (the 4ν polyad): weak lines at fixed random places, 713–735 nm.
- **Line blanketing**: weak Fraunhofer lines at fixed random places, their summed equivalent
  width ~20 % of the continuum per nm at 400 nm falling to ~5 % at 600 nm (the Sun's blanketing).

:class:`SpectrographMapping` and :func:`draw_spectrograph` give the analog a second geometry
(decision 0086): a slit spectrograph whose camera lens distorts and whose sensor may be tilted, the
0th order off the frame — what the Canon 10D's LHires III is, and the mapping family is not.

Everything is rendered on a 0.001 nm grid as a transmission (the product of every feature's) and
box-averaged to :data:`STEP_NM` — the spectrum's own sampling, fine enough for a camera at 0.1 nm
per pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.spectra import Spectrum

#: Range and sampling of the rendered spectrum (nm).
RANGE_NM = (370.0, 800.0)
STEP_NM = 0.02
_FINE_NM = 0.001
#: The photosphere's temperature for the CH band's populations, the atmosphere's for O₂ (K).
CH_TEMPERATURE_K = 5000.0
O2_TEMPERATURE_K = 250.0
#: hc/k (cm K).
_C2 = 1.4388

#: (air nm, equivalent width nm, central depth, Lorentzian fraction, label).
STRONG_LINES: tuple[tuple[float, float, float, float, str], ...] = (
    (393.366, 2.00, 0.92, 1.0, "Ca II K"),
    (396.847, 1.50, 0.92, 1.0, "Ca II H"),
    (404.581, 0.087, 0.80, 0.5, "Fe I"),
    (410.175, 0.31, 0.80, 0.9, "H delta"),
    (422.673, 0.148, 0.85, 0.5, "Ca I"),
    (427.176, 0.076, 0.80, 0.5, "Fe I"),
    (429.921, 0.024, 0.55, 0.3, "Fe I"),
    (430.060, 0.020, 0.50, 0.3, "Ti II"),
    (430.253, 0.050, 0.70, 0.4, "Ca I"),
    (430.774, 0.020, 0.50, 0.3, "Ca I"),
    (430.791, 0.085, 0.75, 0.5, "Fe I"),
    (432.576, 0.079, 0.80, 0.5, "Fe I"),
    (434.047, 0.286, 0.80, 0.9, "H gamma"),
    (438.355, 0.101, 0.85, 0.5, "Fe I"),
    (440.475, 0.090, 0.80, 0.5, "Fe I"),
    (466.814, 0.027, 0.60, 0.3, "Fe I (d)"),
    (486.134, 0.368, 0.85, 0.9, "H beta"),
    (495.761, 0.030, 0.65, 0.3, "Fe I (c)"),
    (516.733, 0.065, 0.80, 0.5, "Mg I b4"),
    (516.749, 0.020, 0.50, 0.3, "Fe I b4"),
    (516.891, 0.030, 0.60, 0.3, "Fe I b3"),
    (517.270, 0.104, 0.85, 0.5, "Mg I b2"),
    (518.362, 0.126, 0.87, 0.5, "Mg I b1"),
    (526.954, 0.048, 0.70, 0.4, "Fe I E1"),
    (527.039, 0.040, 0.65, 0.4, "Fe I E2"),
    (532.804, 0.038, 0.65, 0.4, "Fe I"),
    (588.995, 0.075, 0.95, 0.5, "Na I D2"),
    (589.592, 0.056, 0.93, 0.5, "Na I D1"),
    (610.272, 0.014, 0.40, 0.3, "Ca I"),
    (612.222, 0.022, 0.50, 0.3, "Ca I"),
    (616.217, 0.022, 0.50, 0.3, "Ca I"),
    (643.907, 0.016, 0.45, 0.3, "Ca I"),
    (649.965, 0.010, 0.35, 0.3, "Ca I"),
    (656.281, 0.402, 0.83, 0.9, "H alpha"),
)
#: CH A²Δ–X²Π (0,0): Q head (air nm), B′, B″ (cm⁻¹), total equivalent width (nm).
CH_BAND = (431.40, 14.58, 14.19, 0.35)
#: O₂ b–X bands: origin (cm⁻¹, vacuum), B′ (cm⁻¹), strongest line's central optical depth.
#: Peak optical depth at airmass 1: the strongest B line's strength S ≈ 6e-25 cm/molecule (HITRAN)
#: times the O₂ column 4.5e24 cm⁻², over π times its pressure half-width 0.05 cm⁻¹; the A band
#: ~15× stronger, the γ band ~15× weaker.
O2_BANDS: tuple[tuple[float, float, float, str], ...] = (
    (14525.7, 1.3730, 17.0, "B (1,0)"),
    (15902.4, 1.3548, 1.2, "gamma (2,0)"),
    (13120.9, 1.3912, 250.0, "A (0,0)"),
)
#: FWHM of a telluric line at the ground: twice the air-broadened half-width 0.05 cm⁻¹ (nm at 690).
O2_WIDTH_NM = 0.0047
O2_B_LOWER = 1.4377


def _air(vacuum_nm: FloatArray) -> FloatArray:
    """Vacuum → air wavelength (nm), the refractive index of standard air (Edlén 1966)."""
    sigma2 = (1e3 / vacuum_nm) ** 2
    n = 1.0 + 1e-8 * (8342.13 + 2406030.0 / (130.0 - sigma2) + 15997.0 / (38.9 - sigma2))
    return np.asarray(vacuum_nm / n, dtype=np.float64)


def _add_depth(
    tau: FloatArray, axis: FloatArray, centre: float, profile: str, width: float, peak: float
) -> None:
    """Add one line's optical depth (``peak`` at its centre, FWHM ``width``) in a local window."""
    reach = width * (60.0 if profile == "lorentz" else 4.0)
    lo, hi = np.searchsorted(axis, [centre - reach, centre + reach])
    x = (axis[lo:hi] - centre) / width
    if profile == "lorentz":
        tau[lo:hi] += peak / (1.0 + 4.0 * x**2)
    else:
        tau[lo:hi] += peak * np.exp(-4.0 * math.log(2.0) * x**2)


def _strong_lines(tau: FloatArray, axis: FloatArray) -> None:
    for centre, ew, depth, lorentz, _ in STRONG_LINES:
        # Pseudo-Voigt depth d0·(η L + (1−η) G) of FWHM w: EW = d0 w (η π/2 + (1−η) 1.0645).
        width = ew / (depth * (lorentz * math.pi / 2.0 + (1.0 - lorentz) * 1.0645))
        # As optical depths: −ln(1 − d) of each part at its centre keeps the depth there.
        peak = -math.log(1.0 - depth)
        if lorentz > 0:
            _add_depth(tau, axis, centre, "lorentz", width, lorentz * peak)
        if lorentz < 1:
            _add_depth(tau, axis, centre, "gauss", width, (1.0 - lorentz) * peak)


def _ch_band(tau: FloatArray, axis: FloatArray) -> None:
    head_nm, upper, lower, total_ew = CH_BAND
    origin = 1e7 / head_nm
    lines: list[tuple[float, float]] = []
    for j in range(1, 40):
        population = (2 * j + 1) * math.exp(-lower * j * (j + 1) * _C2 / CH_TEMPERATURE_K)
        # Q (ΔJ = 0, strongest in a ΔΛ = 1 band), R (ΔJ = +1) and P (ΔJ = −1).
        for wavenumber, share in (
            (origin + (upper - lower) * j * (j + 1), 1.0),
            (origin + upper * (j + 1) * (j + 2) - lower * j * (j + 1), 0.5),
            (origin + upper * (j - 1) * j - lower * j * (j + 1), 0.5),
        ):
            for split in (-1.5, 1.5):  # spin / Λ doubling, ~3 cm⁻¹
                lines.append((1e7 / (wavenumber + split), population * share))
    weights = np.array([w for _, w in lines])
    # Weak lines (optically thin): a Gaussian of 0.012 nm FWHM (thermal + microturbulent) each.
    width = 0.012
    for (centre, _), weight in zip(lines, weights / weights.sum() * total_ew, strict=True):
        _add_depth(tau, axis, centre, "gauss", width, weight / (width * 1.0645))


def _o2_bands(tau: FloatArray, axis: FloatArray) -> None:
    for origin, upper, strongest, _ in O2_BANDS:
        lines: list[tuple[float, float]] = []
        for n in range(1, 60, 2):  # odd N″ only
            population = (2 * n + 1) * math.exp(-O2_B_LOWER * n * (n + 1) * _C2 / O2_TEMPERATURE_K)
            r_branch = origin + upper * (n + 1) * (n + 2) - O2_B_LOWER * n * (n + 1)
            p_branch = origin + upper * (n - 1) * n - O2_B_LOWER * n * (n + 1)
            for wavenumber in (r_branch, p_branch):
                for split in (0.0, 2.0 * O2_B_LOWER):  # the RR/RQ and PP/PQ pairs
                    lines.append((wavenumber + split, population))
        top = max(w for _, w in lines)
        centres = _air(1e7 / np.array([c for c, _ in lines]))
        for centre, (_, weight) in zip(centres, lines, strict=True):
            # Pressure-broadened (Lorentzian): saturated lines grow by their wings.
            _add_depth(tau, axis, float(centre), "lorentz", O2_WIDTH_NM, strongest * weight / top)


def _scattered_lines(tau: FloatArray, axis: FloatArray) -> None:
    """Weak Fraunhofer lines (blanketing) and the 718 nm water lines, at fixed random places."""
    rng = np.random.default_rng(1985)
    # Equivalent width per nm: 0.2 at 400 nm, e-folding every 130 nm (~5 % at 580 nm).
    ew_mean = (0.01 - 0.0005) / math.log(0.01 / 0.0005)
    span = np.arange(RANGE_NM[0], 720.0, 1.0)
    counts = rng.poisson(0.2 * np.exp(-(span - 400.0) / 130.0) / ew_mean)
    centres = np.concatenate(
        [lo + rng.uniform(0, 1, k) for lo, k in zip(span, counts, strict=True)]
    )
    widths = np.full(centres.size, 0.012)
    ews = np.exp(rng.uniform(math.log(0.0005), math.log(0.01), centres.size))
    water = rng.uniform(713.0, 735.0, 220)
    centres = np.concatenate([centres, water])
    widths = np.concatenate([widths, np.full(water.size, 0.006)])
    ews = np.concatenate([ews, np.exp(rng.uniform(math.log(0.0003), math.log(0.004), water.size))])
    for centre, width, ew in zip(centres, widths, ews, strict=True):
        _add_depth(tau, axis, float(centre), "gauss", float(width), float(ew / (width * 1.0645)))


def synthetic_sunlight(airmass: float = 1.5) -> Spectrum:
    """The analog's sunlight at the ground (module docstring), every :data:`STEP_NM`, through
    ``airmass`` atmospheres (Rayleigh and O₂ alike)."""
    fine = np.arange(RANGE_NM[0], RANGE_NM[1], _FINE_NM)
    tau = np.zeros_like(fine)
    _strong_lines(tau, fine)
    _ch_band(tau, fine)
    _scattered_lines(tau, fine)
    micron = fine * 1e-3
    planck = micron**-5 / np.expm1(_C2 * 1e4 / (micron * 5772.0))
    return _at_the_ground(fine, planck * np.exp(-tau), airmass, "synthetic sunlight")


def sunlight_from_atlas(atlas: Spectrum, airmass: float = 1.5) -> Spectrum:
    """A measured solar spectrum above the atmosphere (air wavelengths, finer than the features:
    a high-resolution atlas such as Chance & Kurucz's SAO2010, 0.04 nm FWHM) through the analog's
    atmosphere at ``airmass`` (Rayleigh and O₂, as :func:`synthetic_sunlight`), every
    :data:`STEP_NM`: the analog with the real Sun's features (decision 0110; an atlas is read at
    run time, never stored)."""
    fine = np.arange(RANGE_NM[0], RANGE_NM[1], _FINE_NM)
    return _at_the_ground(fine, atlas.at(fine), airmass, f"{atlas.name} at airmass {airmass:g}")


def _at_the_ground(fine: FloatArray, above: FloatArray, airmass: float, name: str) -> Spectrum:
    """``above`` (on the :data:`_FINE_NM` axis ``fine``) through ``airmass`` atmospheres, box-averaged
    to :data:`STEP_NM` and normalised to its maximum."""
    telluric = np.zeros_like(fine)
    _o2_bands(telluric, fine)
    micron = fine * 1e-3
    rayleigh = np.exp(-airmass * 0.0088 * micron**-4.05)
    # The O₂ optical depths are at airmass 1 (:data:`O2_BANDS`): the path scales them. (They were
    # divided by 1.5 before decision 0095, so the default airmass 1.5 rendered airmass 1's bands.)
    values = above * rayleigh * np.exp(-telluric * airmass)
    per = round(STEP_NM / _FINE_NM)
    n = values.size // per
    binned = values[: n * per].reshape(n, per).mean(axis=1)
    axis = fine[: n * per].reshape(n, per).mean(axis=1)
    return Spectrum(axis, binned / float(binned.max()), name=name)


def air_wavelength_nm(vacuum_nm: ArrayLike) -> FloatArray:
    """Vacuum → air wavelength (nm): :func:`_air` for a caller's table (an atlas in vacuum)."""
    return _air(np.asarray(vacuum_nm, dtype=np.float64))


@dataclass(frozen=True)
class SpectrographMapping:
    """The first order of a slit spectrograph as a camera sees it: slit → collimator → grating →
    camera lens → sensor, the 0th order off the frame and the profile's columns arbitrary (a crop
    exported as FITS or CSV, like the Canon 10D's LHires III set).

    The grating equation ``λ = d (sin α + sin β)`` (reflection, both angles from the normal on the
    same side; Littrow is ``α = β``); the camera's axis leaves the grating at ``β_c`` and meets the
    sensor at column ``p_c``. A ray at ``φ = β − β_c`` from the axis lands ``F sin φ / cos(φ + τ)``
    from it on a sensor tilted by ``τ`` about the slit's direction, then moves radially by the
    lens' distortion ``x_d = x (1 + k₁ x²)`` (the row's offset from the axis only rescales ``x``);
    column ``p = p_c + s x_d``.

    Attributes
    ----------
    spacing_nm
        ``d``.
    focal_length_px
        ``F``: the camera lens' image distance in pixels.
    incidence_deg, camera_deg
        ``α`` and ``β_c``.
    axis_px
        ``p_c``.
    orientation
        ``s``: ``+1`` when the wavelength rises with the column.
    k1_per_px2
        ``k₁`` (px⁻²): > 0 pincushion, < 0 barrel.
    tilt_deg
        ``τ``.
    """

    spacing_nm: float
    focal_length_px: float
    incidence_deg: float
    camera_deg: float
    axis_px: float
    orientation: int = 1
    k1_per_px2: float = 0.0
    tilt_deg: float = 0.0

    def wavelength_nm(self, pixel: ArrayLike) -> FloatArray:
        """``λ`` at each column (nm)."""
        distorted = self.orientation * (np.asarray(pixel, dtype=np.float64) - self.axis_px)
        # x_d = x (1 + k₁ x²) for x by Newton's method from x = x_d (|k₁ x²| ≪ 1).
        x = distorted.copy()
        for _ in range(8):
            x -= (x * (1.0 + self.k1_per_px2 * x**2) - distorted) / (
                1.0 + 3.0 * self.k1_per_px2 * x**2
            )
        tau = math.radians(self.tilt_deg)
        # x = F sin φ / cos(φ + τ)  ⇔  tan φ = x cos τ / (F + x sin τ).
        phi = np.arctan2(x * math.cos(tau), self.focal_length_px + x * math.sin(tau))
        beta = math.radians(self.camera_deg) + phi
        return np.asarray(
            self.spacing_nm * (math.sin(math.radians(self.incidence_deg)) + np.sin(beta)),
            dtype=np.float64,
        )

    def pixel_at(self, wavelength_nm: ArrayLike) -> FloatArray:
        """The column of each wavelength (nm)."""
        nm = np.asarray(wavelength_nm, dtype=np.float64)
        beta = np.arcsin(nm / self.spacing_nm - math.sin(math.radians(self.incidence_deg)))
        phi = beta - math.radians(self.camera_deg)
        x = self.focal_length_px * np.sin(phi) / np.cos(phi + math.radians(self.tilt_deg))
        return np.asarray(
            self.axis_px + self.orientation * x * (1.0 + self.k1_per_px2 * x**2), dtype=np.float64
        )

    def to_dict(self) -> dict[str, float]:
        return {
            "spacing_nm": self.spacing_nm,
            "focal_length_px": self.focal_length_px,
            "incidence_deg": self.incidence_deg,
            "camera_deg": self.camera_deg,
            "axis_px": self.axis_px,
            "orientation": float(self.orientation),
            "k1_per_px2": self.k1_per_px2,
            "tilt_deg": self.tilt_deg,
        }


@dataclass(frozen=True)
class SpectrographRanges:
    """What a spectrograph scene draws (:func:`draw_spectrograph`), each range from the physics of
    the instruments amateurs and labs point at the Sun.

    - ``grooves_per_mm_range``: reflection gratings of whole-visible spectrographs — the LHires
      III's 150 and 300 l/mm, DADOS' 200, DIY builds' 300–600 (above 600 l/mm the visible does
      not fit on one APS-C frame at these focal lengths).
    - ``deviation_deg_range``: the angle between the collimator's and the camera's arms,
      ``α − β_c``: 0 is Littrow (LHires III, a few degrees off it), Czerny–Turner and DIY builds
      up to ~30°.
    - ``centre_nm_range``: the wavelength on the camera's axis (where the user centres the
      grating): anywhere in the middle of the visible.
    - ``band_length_px_range``: 400–700 nm over 750–1600 columns (0.19–0.4 nm per column: the 10D
      is 0.24).
    - ``corner_distortion_range``: the camera lens' radial distortion at the sensor's corner,
      ``k₁ r_c²``: −3 % (barrel, standard and short lenses) to +2 % (pincushion, telephotos) —
      DSLR lenses' measured range (a dedicated spectrograph objective near 0).
    - ``fill_range``: the profile's share of the sensor's width (a 3:2 sensor; its corner at
      0.601 of the width from the centre), where ``k₁`` is set from the corner's distortion.
    - ``tilt_deg_range``: the sensor's tilt about the slit direction: an adapter's flange tolerance
      (~0.1°) up to the tilt that follows a simple camera lens' colour focus (~2°).
    - ``axis_range``: where the camera's axis meets the profile, as a share of its length.
    """

    grooves_per_mm_range: tuple[float, float] = (150.0, 600.0)
    deviation_deg_range: tuple[float, float] = (0.0, 30.0)
    centre_nm_range: tuple[float, float] = (480.0, 620.0)
    band_length_px_range: tuple[float, float] = (750.0, 1600.0)
    corner_distortion_range: tuple[float, float] = (-0.03, 0.02)
    fill_range: tuple[float, float] = (0.5, 1.0)
    tilt_deg_range: tuple[float, float] = (-2.0, 2.0)
    margin_below_nm_range: tuple[float, float] = (5.0, 30.0)
    margin_above_nm_range: tuple[float, float] = (5.0, 40.0)


def draw_spectrograph(
    rng: np.random.Generator,
    ranges: SpectrographRanges | None = None,
    grid: tuple[float, float] = (380.0, 780.0),
) -> tuple[SpectrographMapping, int]:
    """A random spectrograph (:class:`SpectrographRanges`) and the number of columns of a profile
    that covers ``grid`` (nm) with margins, its first column 0."""
    ranges = ranges or SpectrographRanges()
    spacing = 1e6 / float(math.exp(rng.uniform(*np.log(ranges.grooves_per_mm_range))))
    deviation = math.radians(float(rng.uniform(*ranges.deviation_deg_range)))
    centre = float(rng.uniform(*ranges.centre_nm_range))
    band_px = float(rng.uniform(*ranges.band_length_px_range))
    corner = float(rng.uniform(*ranges.corner_distortion_range))
    fill = float(rng.uniform(*ranges.fill_range))
    tilt = float(rng.uniform(*ranges.tilt_deg_range))
    orientation = 1 if rng.uniform() < 0.5 else -1
    below = float(rng.uniform(*ranges.margin_below_nm_range))
    above = float(rng.uniform(*ranges.margin_above_nm_range))
    # sin α + sin β_c = λ_c/d with α − β_c = δ: 2 sin((α+β_c)/2) cos(δ/2) = λ_c/d.
    half_sum = math.asin(centre / (2.0 * spacing * math.cos(0.5 * deviation)))
    alpha, beta_c = (
        math.degrees(half_sum + 0.5 * deviation),
        math.degrees(half_sum - 0.5 * deviation),
    )
    unit = SpectrographMapping(spacing, 1.0, alpha, beta_c, 0.0).pixel_at(np.array([400.0, 700.0]))
    focal = band_px / float(unit[1] - unit[0])
    span = np.array([grid[0] - below, grid[1] + above])
    # k₁ from the corner's distortion, the sensor's width from the undistorted profile's length.
    plain = SpectrographMapping(spacing, focal, alpha, beta_c, 0.0, tilt_deg=tilt).pixel_at(span)
    k1 = corner / (0.601 * float(plain[1] - plain[0]) / fill) ** 2
    low, high = SpectrographMapping(spacing, focal, alpha, beta_c, 0.0, 1, k1, tilt).pixel_at(span)
    n_pixels = math.floor(float(high - low))
    # Column 0 at the short end (or the long one, mirrored); the axis where λ_c falls.
    axis_px = -float(low) if orientation > 0 else float(high)
    mapping = SpectrographMapping(spacing, focal, alpha, beta_c, axis_px, orientation, k1, tilt)
    return mapping, n_pixels
