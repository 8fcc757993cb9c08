"""Bases for the unknowns: per-channel SVD bases of camera sensitivities, a Fourier basis for 1/η.

Makabe et al. (2025) write each channel's sensitivity as ``s_c = B_s,c c_s,c`` with ``B_s,c`` the
leading right-singular vectors of the training cameras' channel-``c`` curves (each camera divided by
its maximum over all channels, no mean-centring), and the inverse grating efficiency as
``η⁻¹ = B_η c_η`` with a Fourier basis (Supp. E). The mean training sensitivity ``ŝ`` is used to find
the pixel→wavelength mapping (§3.2).

Bases are cheap to compute but the camera sets they come from are not, so a basis is cached on disk
(``.npz``, loaded without pickle) under the user cache directory, keyed by a hash of its content.

The default basis (:func:`default_camera_basis`) is built from the measured cameras of
:func:`calib.core.datasets.reference_cameras`: the Solomatov & Akkaynak ground truths when the data
directory holds them, else the rawtoaces-data cameras bundled with spectral-rig (Apache-2.0), with a
warning (:attr:`CameraBasis.fallback`) naming what to fetch. Cameras may be kept out of it by name
(``exclude``, ``--exclude-camera``: the camera under test when validating); the basis records which.
:func:`fallback_camera_basis` builds a toy basis from colour-science's built-in curves (its cameras,
CIE colour-matching functions and cone fundamentals turned into camera-like curves, and perturbations
of them), for examples and ``--offline`` smoke runs. Results record which basis was used
(:meth:`CameraBasis.to_dict`).

References
----------
Makabe et al. (2025), §3.1 and Supp. E; Jiang, Liu, Gu, Süsstrunk (2013), "What is the space of
spectral sensitivity functions for digital color cameras?", WACV.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
import platformdirs
from numpy.typing import ArrayLike

from calib.core.arrays import FloatArray
from calib.core.camera_bodies import names_camera
from calib.core.camera_curves import as_camera
from calib.core.colour_data import colour_matching_functions
from calib.core.datasets import colour_science_cameras, exclude_cameras, reference_cameras
from calib.core.errors import InputError
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, WavelengthGrid

FourierConvention = Literal["paired", "paper"]

#: Number of basis vectors per channel used by the paper (and by default here).
DEFAULT_N_VECTORS = 7

#: Bumped whenever the cached content's meaning changes.
_CACHE_FORMAT = "camera-basis-v4"


def default_cache_dir() -> Path:
    """``platformdirs.user_cache_dir("spectral-rig")`` — never inside the repository."""
    return Path(platformdirs.user_cache_dir("spectral-rig"))


@dataclass(frozen=True, eq=False)
class CameraBasis:
    """A per-channel linear basis of camera sensitivities on one wavelength grid.

    Attributes
    ----------
    grid
        The working grid (``f`` wavelengths).
    vectors
        Shape ``(3, f, k)``: basis vectors per channel (R, G, B), orthonormal columns.
    mean
        Shape ``(f, 3)``: the mean (max-normalised) training sensitivity ``ŝ``.
    singular_values
        Shape ``(3, k)``.
    source
        Human-readable origin, e.g. ``"solomatov-akkaynak-2023 (Makabe 2025 train split, 44)"``.
    camera_names
        The training cameras.
    content_hash
        SHA-256 of the training curves, grid and ``k`` (the cache key).
    covariance
        Shape ``(3, f, f)``: sample covariance of each channel's (max-normalised) training curves.
    ledoit_wolf_shrinkage
        Shape ``(3,)``: Ledoit & Wolf's (2004) optimal shrinkage of each covariance toward a scaled
        identity, for reference (:meth:`prior` takes the shrinkage as a parameter).
    typical_distance
        The median over the training cameras of each one's :func:`prior_distance` from the
        default prior of the others (leave one out): how far a camera of this population lies
        from the prior; NaN with fewer than 3 cameras.
    exclusions
        The name patterns cameras were kept out by (``--exclude-camera``).
    excluded_cameras
        The cameras they kept out.
    unmatched_exclusions
        The patterns of ``exclusions`` that named no camera of the basis' source (a misspelt
        camera under test stays in the basis: the pipeline warns).
    fallback
        Why this is not the default basis and what to fetch (a warning for the result), or
        ``None``.
    """

    grid: WavelengthGrid
    vectors: FloatArray
    mean: FloatArray
    singular_values: FloatArray
    source: str
    camera_names: tuple[str, ...]
    content_hash: str
    covariance: FloatArray
    ledoit_wolf_shrinkage: FloatArray
    typical_distance: float = float("nan")
    exclusions: tuple[str, ...] = ()
    excluded_cameras: tuple[str, ...] = ()
    unmatched_exclusions: tuple[str, ...] = ()
    fallback: str | None = None

    @property
    def n_vectors(self) -> int:
        return int(self.vectors.shape[2])

    def channel(self, index: int) -> FloatArray:
        """Basis matrix ``B_s,c`` of shape ``(f, k)`` for channel ``index`` (0 = R, 1 = G, 2 = B)."""
        return np.asarray(self.vectors[index], dtype=np.float64)

    def project(self, sensitivity: ArrayLike) -> FloatArray:
        """Least-squares fit of curves ``(f, 3)`` in the basis span; returns the fitted ``(f, 3)``."""
        curves = np.asarray(sensitivity, dtype=np.float64)
        if curves.shape != (self.grid.size, 3):
            raise InputError(
                f"expected shape ({self.grid.size}, 3) on grid {self.grid}, got {curves.shape}",
                source="sensitivity",
            )
        fitted = [self.vectors[c] @ (self.vectors[c].T @ curves[:, c]) for c in range(3)]
        return np.stack(fitted, axis=1)

    def prior(self, shrinkage: float | None = None) -> CameraPrior:
        """The Gaussian camera prior of these curves: mean ŝ and a shrunk covariance per channel.

        ``shrinkage`` ∈ [0, 1] blends each channel's sample covariance with ``tr(Σ)/f · I``;
        ``None`` (default) uses each channel's Ledoit–Wolf intensity — on the 44 training cameras of
        the synthetic protocol, leave-one-camera-out agrees (``bench/tune_prior.py``).
        """
        if shrinkage is None:
            weights = np.asarray(self.ledoit_wolf_shrinkage, dtype=np.float64)
        else:
            weights = np.full(3, float(shrinkage))
        if np.any((weights < 0.0) | (weights > 1.0)):
            raise InputError(f"shrinkage must be in [0, 1], got {shrinkage}", source="shrinkage")
        prior = shrunk_prior(self.grid, self.mean, self.covariance, weights)
        if shrinkage is None and np.isfinite(self.typical_distance):
            prior = replace(prior, typical_distance=float(self.typical_distance))
        return prior

    def warnings(self) -> list[str]:
        """What a result built on this basis says: why it is not the default basis
        (:attr:`fallback`), and each ``--exclude-camera`` pattern that kept nothing out."""
        drawn_on = len(self.camera_names) + len(self.excluded_cameras)
        return [
            *([self.fallback] if self.fallback is not None else []),
            *(
                f"--exclude-camera {pattern!r} names none of the {drawn_on} cameras the basis "
                "draws on and kept nothing out: if the camera under test is among them, check the "
                "spelling (result.json's diagnostics.basis.cameras lists them)"
                for pattern in self.unmatched_exclusions
            ),
        ]

    def to_dict(self) -> dict[str, object]:
        """A JSON-safe summary (not the vectors: they may derive from unlicensed data)."""
        return {
            "source": self.source,
            "grid": str(self.grid),
            "n_vectors": self.n_vectors,
            "n_cameras": len(self.camera_names),
            "cameras": list(self.camera_names),
            "content_hash": self.content_hash,
            "exclusions": list(self.exclusions),
            "excluded_cameras": list(self.excluded_cameras),
            "unmatched_exclusions": list(self.unmatched_exclusions),
            "fallback": self.fallback,
        }


@dataclass(frozen=True, eq=False)
class CameraPrior:
    """A Gaussian prior on a camera's (normalised) sensitivity, per channel, on one grid.

    ``s_c ~ N(α ŝ_c, α² Σ_c)`` with ``α`` the camera's unknown overall scale.

    Attributes
    ----------
    grid
        The working grid (``f`` wavelengths).
    mean
        ``ŝ``, shape ``(f, 3)``.
    covariance
        ``Σ_c``, shape ``(3, f, f)``, positive definite.
    shrinkage
        The shrinkage used to build each channel's covariance, shape ``(3,)``.
    typical_distance
        :attr:`CameraBasis.typical_distance` (the default shrinkage only; else ``None``).
    """

    grid: WavelengthGrid
    mean: FloatArray
    covariance: FloatArray
    shrinkage: FloatArray
    typical_distance: float | None = None

    def precision_factor(self) -> FloatArray:
        """``L_c`` with ``L_cᵀ L_c = Σ_c⁻¹``, shape ``(3, f, f)`` (see :func:`whitening`)."""
        return np.stack([whitening(self.covariance[c]) for c in range(3)])


def shrunk_prior(
    grid: WavelengthGrid, mean: FloatArray, covariance: FloatArray, weights: FloatArray
) -> CameraPrior:
    """Each channel's covariance blended with ``tr(Σ)/f · I`` by ``weights`` ``(3,)``, floored."""
    size = grid.size
    identity = np.eye(size)
    shrunk = np.stack(
        [
            (1.0 - weights[c]) * covariance[c]
            + weights[c] * float(np.trace(covariance[c])) / size * identity
            for c in range(3)
        ]
    )
    # A floor keeps the precision finite where every training curve is zero (e.g. a grid edge).
    floor = 1e-6 * float(np.max(np.trace(covariance, axis1=1, axis2=2))) / size
    return CameraPrior(grid, mean, _frozen(shrunk + floor * identity[None]), _frozen(weights))


def prior_distance(prior: CameraPrior, sensitivity: FloatArray) -> float:
    """Squared Mahalanobis distance of a camera ``(f, 3)`` from the prior, at its best scale.

    ``min_β Σ_c ‖L_c (β s_c − ŝ_c)‖²`` with ``L_cᵀ L_c = Σ_c⁻¹`` (the prior's covariance alone, not
    the measurement's noise): the camera's overall scale does not count.
    """
    factors = prior.precision_factor()
    curves = np.asarray(sensitivity, dtype=np.float64)
    whitened = np.concatenate([factors[c] @ curves[:, c] for c in range(3)])
    target = np.concatenate([factors[c] @ prior.mean[:, c] for c in range(3)])
    norm = float(whitened @ whitened)
    scale = float(whitened @ target) / norm if norm > 0 else 0.0
    residual = scale * whitened - target
    return float(residual @ residual)


def typical_distance(
    curves: FloatArray, weights: FloatArray, grid: WavelengthGrid, groups: Sequence[str]
) -> float:
    """Median leave-one-camera-out :func:`prior_distance` of ``curves`` ``(n, f, 3)``.

    Each curve against the prior of the other cameras, shrunk by ``weights`` (the full set's). Curves
    with the same ``groups`` label (a camera and its perturbed variants) are left out together.
    NaN with fewer than 3 cameras.
    """
    if len(set(groups)) < 3:
        return float("nan")
    distances: list[float] = []
    for label in dict.fromkeys(groups):
        inside = np.array([other == label for other in groups])
        others = curves[~inside]
        covariance = np.stack([np.atleast_2d(np.cov(others[:, :, c].T)) for c in range(3)])
        prior = shrunk_prior(grid, others.mean(axis=0), covariance, weights)
        distances.extend(prior_distance(prior, curve) for curve in curves[inside])
    return float(np.median(distances))


#: How :func:`fallback_camera_basis` names a perturbed copy (of the same camera: same group).
_VARIANT_NAME = "{camera} variant {index}"


#: :func:`whitening`'s relative eigenvalue floor (of the largest eigenvalue).
WHITENING_FLOOR = 1e-10


def whitening(covariance: FloatArray, relative_floor: float = WHITENING_FLOOR) -> FloatArray:
    """Symmetric ``Σ^{-1/2}`` (so ``Lᵀ L = Σ⁻¹``), eigenvalues floored at ``relative_floor · max``.

    Robust where a Cholesky factorisation of ``Σ⁻¹`` is not: covariances built from a few curves or
    smooth kernels are numerically rank-deficient.
    """
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    floor = relative_floor * max(float(values.max()), 1e-300)
    return np.asarray((vectors / np.sqrt(np.maximum(values, floor))) @ vectors.T, dtype=np.float64)


def whitening_stack(covariances: FloatArray) -> FloatArray:
    """:func:`whitening` (its default floor) of each matrix of a stack
    ``(k, n, n)``, to the bit, in one pass: the same symmetrisation, ``eigh``, floor (of each
    matrix's own largest eigenvalue) and product per matrix."""
    values, vectors = np.linalg.eigh(0.5 * (covariances + np.swapaxes(covariances, -1, -2)))
    floor = WHITENING_FLOOR * np.maximum(values.max(axis=-1, keepdims=True), 1e-300)
    scaled = vectors / np.sqrt(np.maximum(values, floor))[..., None, :]
    return np.asarray(scaled @ np.swapaxes(vectors, -1, -2), dtype=np.float64)


def ledoit_wolf_shrinkage(samples: FloatArray) -> float:
    """Ledoit & Wolf (2004) shrinkage intensity toward ``tr(S)/p · I`` for samples ``(n, p)``."""
    centred = samples - samples.mean(axis=0)
    n, p = centred.shape
    sample_cov = centred.T @ centred / n
    target = float(np.trace(sample_cov)) / p
    dispersion = float(np.sum((sample_cov - target * np.eye(p)) ** 2)) / p
    if dispersion <= 0:
        return 1.0
    spread = sum(float(np.sum((np.outer(x, x) - sample_cov) ** 2)) for x in centred) / n**2 / p
    return float(min(spread, dispersion) / dispersion)


def _as_curve_stack(
    cameras: Sequence[MultiSpectrum] | ArrayLike, grid: WavelengthGrid
) -> FloatArray:
    """Curves of shape ``(n_cameras, f, 3)`` on ``grid``, each divided by its overall maximum."""
    if (
        isinstance(cameras, Sequence)
        and cameras
        and not np.isscalar(cameras[0])
        and (isinstance(cameras[0], MultiSpectrum) or hasattr(cameras[0], "wavelengths"))
    ):
        # MultiSpectrum or colour-science cameras: R, G, B by channel name
        stack = np.stack([as_camera(camera).at(grid.wavelength_nm) for camera in cameras])
    else:
        stack = np.array(cameras, dtype=np.float64)
    if stack.ndim != 3 or stack.shape[1:] != (grid.size, 3):
        raise InputError(
            f"camera curves must have shape (n_cameras, {grid.size}, 3) on grid {grid}, "
            f"got {stack.shape}",
            source="basis cameras",
        )
    peaks = stack.reshape(stack.shape[0], -1).max(axis=1)
    if np.any(peaks <= 0) or not np.all(np.isfinite(stack)):
        raise InputError("a camera curve is all zero or not finite", source="basis cameras")
    return np.asarray(stack / peaks[:, None, None], dtype=np.float64)


def _content_hash(
    curves: FloatArray, grid: WavelengthGrid, n_vectors: int, groups: Sequence[str]
) -> str:
    digest = hashlib.sha256()
    digest.update(f"{_CACHE_FORMAT}|{grid}|{n_vectors}|{curves.shape}".encode())
    # Which curves are one camera decides the typical distance (leave-one-camera-out).
    digest.update("|".join(str(groups.index(label)) for label in groups).encode())
    digest.update(np.ascontiguousarray(curves, dtype="<f8").tobytes())
    return digest.hexdigest()


def _load_cached(path: Path) -> dict[str, FloatArray] | None:
    try:
        with np.load(path, allow_pickle=False) as data:
            return {
                key: np.asarray(data[key])
                for key in (
                    "vectors",
                    "mean",
                    "singular_values",
                    "covariance",
                    "shrinkage",
                    "typical_distance",
                )
            }
    except (OSError, KeyError, ValueError):
        return None  # a missing or damaged cache entry is recomputed


def _store_cached(path: Path, arrays: dict[str, FloatArray]) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_name(f".{path.name}.{np.random.default_rng().integers(1 << 30)}.tmp")
        with temporary.open("wb") as handle:
            np.savez(handle, **arrays)  # type: ignore[arg-type]
        temporary.replace(path)
    except OSError:
        pass  # a read-only cache only costs recomputation


def camera_basis(
    cameras: Sequence[MultiSpectrum] | ArrayLike,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    n_vectors: int = DEFAULT_N_VECTORS,
    source: str = "custom",
    camera_names: Sequence[str] | None = None,
    groups: Sequence[str] | None = None,
    cache: bool = True,
    cache_dir: Path | None = None,
) -> CameraBasis:
    """Per-channel SVD basis of a set of cameras (Makabe et al. 2025, §3.1).

    Parameters
    ----------
    cameras
        ``MultiSpectrum`` sensitivities (any grid, resampled with zero fill outside their range),
        or an array ``(n_cameras, f, 3)`` already on ``grid``.
    grid
        The working grid.
    n_vectors
        Basis vectors per channel ``k`` (1 ≤ k ≤ min(n_cameras, f)).
    source
        Where the cameras come from (recorded in results).
    camera_names
        Names of the cameras (defaults to the spectra's names).
    groups
        Which camera each curve belongs to, one label per curve: curves with the same label (a
        camera and its perturbed variants) are left out together for
        :attr:`CameraBasis.typical_distance`. Defaults to ``camera_names``.
    cache, cache_dir
        Cache the result as ``<cache_dir>/bases/<hash>.npz`` (default: :func:`default_cache_dir`).

    Returns
    -------
    CameraBasis
    """
    curves = _as_curve_stack(cameras, grid)
    n_cameras = curves.shape[0]
    if not 1 <= n_vectors <= min(n_cameras, grid.size):
        raise InputError(
            f"n_vectors must be between 1 and min(n_cameras={n_cameras}, f={grid.size}), "
            f"got {n_vectors}",
            source="n_vectors",
        )
    if camera_names is None:
        camera_names = [
            camera.name if isinstance(camera, MultiSpectrum) else f"camera {index}"
            for index, camera in enumerate(
                cameras if isinstance(cameras, Sequence) else range(n_cameras)
            )
        ]
    labels = list(camera_names if groups is None else groups)
    if len(labels) != n_cameras:
        what = "camera names" if groups is None else "group labels"
        raise InputError(f"{len(labels)} {what} for {n_cameras} cameras", source="basis cameras")
    key = _content_hash(curves, grid, n_vectors, labels)
    path = (cache_dir or default_cache_dir()) / "bases" / f"{key}.npz"
    arrays = _load_cached(path) if cache else None
    if arrays is None:
        vectors = np.empty((3, grid.size, n_vectors))
        singular_values = np.empty((3, n_vectors))
        for channel in range(3):
            _, sigma, vt = np.linalg.svd(curves[:, :, channel], full_matrices=False)
            basis = vt[:n_vectors].T
            # Deterministic signs: each vector's largest-magnitude entry is positive.
            signs = np.sign(basis[np.argmax(np.abs(basis), axis=0), np.arange(n_vectors)])
            vectors[channel] = basis * np.where(signs == 0, 1.0, signs)
            singular_values[channel] = sigma[:n_vectors]
        arrays = {
            "vectors": vectors,
            "mean": curves.mean(axis=0),
            "singular_values": singular_values,
            "covariance": np.stack(
                [np.atleast_2d(np.cov(curves[:, :, c].T)) for c in range(3)]
                if n_cameras > 1
                else [np.zeros((grid.size, grid.size))] * 3
            ),
            "shrinkage": np.array(
                [ledoit_wolf_shrinkage(curves[:, :, c]) if n_cameras > 1 else 1.0 for c in range(3)]
            ),
        }
        arrays["typical_distance"] = np.array(
            typical_distance(curves, arrays["shrinkage"], grid, labels)
        )
        if cache:
            _store_cached(path, arrays)
    return CameraBasis(
        grid=grid,
        vectors=_frozen(arrays["vectors"]),
        mean=_frozen(arrays["mean"]),
        singular_values=_frozen(arrays["singular_values"]),
        source=source,
        camera_names=tuple(camera_names),
        content_hash=key,
        covariance=_frozen(arrays["covariance"]),
        ledoit_wolf_shrinkage=_frozen(arrays["shrinkage"]),
        typical_distance=float(arrays["typical_distance"]),
    )


def _frozen(array: FloatArray) -> FloatArray:
    out = np.array(array, dtype=np.float64)
    out.flags.writeable = False
    return out


def fourier_basis(
    grid: WavelengthGrid = DEFAULT_GRID,
    n_terms: int = DEFAULT_N_VECTORS,
    *,
    convention: FourierConvention = "paired",
) -> FloatArray:
    """Fourier basis ``B_η`` for the inverse grating efficiency (Makabe et al. 2025, Supp. E).

    Parameters
    ----------
    grid
        The working grid; ``t_i = (λ_i − λ_l) / (λ_u − λ_l)`` runs from 0 to 1 over it.
    n_terms
        Number of basis vectors ``b_η`` (≥ 1).
    convention
        ``"paired"`` (default): ``1, cos 2πt, sin 2πt, cos 4πt, sin 4πt, …`` — the usual real
        Fourier series, a cosine and a sine per frequency. ``"paper"``: Supp. Eq. 7 as printed,
        ``b_k = cos(2πk f_i)`` for odd k, ``sin(2πk f_i)`` for even k, with ``f_i = λ_i/(λ_u − λ_l)``.

    Returns
    -------
    numpy.ndarray
        Shape ``(f, n_terms)``.
    """
    if n_terms < 1:
        raise InputError(f"need at least one Fourier term, got {n_terms}", source="n_terms")
    wavelength = grid.wavelength_nm
    span = grid.stop_nm - grid.start_nm
    columns = [np.ones_like(wavelength)]
    if convention == "paired":
        position = (wavelength - grid.start_nm) / span
        for k in range(1, n_terms):
            frequency = (k + 1) // 2
            trig = np.cos if k % 2 == 1 else np.sin
            columns.append(trig(2 * np.pi * frequency * position))
    elif convention == "paper":
        position = wavelength / span
        for k in range(1, n_terms):
            trig = np.cos if k % 2 == 1 else np.sin
            columns.append(trig(2 * np.pi * k * position))
    else:
        raise InputError(f"unknown convention {convention!r}; use 'paired' or 'paper'")
    return np.stack(columns, axis=1)


# ------------------------------------------------------------------------- offline fallback basis


def _colour_camera_like_curves() -> list[MultiSpectrum]:
    """Camera-like RGB curves from data that ships inside colour-science (no download)."""
    curves: list[MultiSpectrum] = [camera.sensitivity for camera in colour_science_cameras()]

    def from_columns(key: str, name: str, transform: FloatArray | None = None) -> MultiSpectrum:
        wavelength, values = colour_matching_functions(key)
        if transform is not None:
            values = values @ transform.T
        values = np.clip(values, 0.0, None)
        return MultiSpectrum(wavelength, values, name=name)

    # XYZ: drop x̄'s short-wavelength lobe so the "red" channel looks like a red filter.
    for key, label in (
        ("CIE 1931 2 Degree Standard Observer", "CIE 1931 XYZ camera-like"),
        ("CIE 1964 10 Degree Standard Observer", "CIE 1964 XYZ camera-like"),
        ("CIE 2015 2 Degree Standard Observer", "CIE 2015 2° XYZ camera-like"),
    ):
        wavelength, values = colour_matching_functions(key)
        values[wavelength < 505, 0] = 0.0
        curves.append(MultiSpectrum(wavelength, np.clip(values, 0, None), name=label))
    for key, label in (
        ("Stockman & Sharpe 2 Degree Cone Fundamentals", "LMS 2° camera-like"),
        ("Stockman & Sharpe 10 Degree Cone Fundamentals", "LMS 10° camera-like"),
        ("Smith & Pokorny 1975 Normal Trichromats", "Smith-Pokorny LMS camera-like"),
    ):
        # Sharpen L and M apart (cameras' R and G overlap far less than cones do).
        sharpen = np.array([[1.6, -0.6, 0.0], [-0.35, 1.35, 0.0], [0.0, 0.0, 1.0]])
        curves.append(from_columns(key, label, sharpen))
    for key, label in (
        ("Wright & Guild 1931 2 Degree RGB CMFs", "Wright-Guild RGB camera-like"),
        ("Stiles & Burch 1955 2 Degree RGB CMFs", "Stiles-Burch 2° RGB camera-like"),
        ("Stiles & Burch 1959 10 Degree RGB CMFs", "Stiles-Burch 10° RGB camera-like"),
    ):
        curves.append(from_columns(key, label))
    return curves


def _perturbed(camera: MultiSpectrum, grid: WavelengthGrid, rng: np.random.Generator) -> FloatArray:
    """One plausible variant of a camera on ``grid``: shifted/stretched channels, filters, tilt."""
    wavelength = grid.wavelength_nm
    out = np.empty((grid.size, 3))
    for channel in range(3):
        curve = camera.values[:, channel]
        peak_nm = camera.wavelength_nm[int(np.argmax(curve))]
        shift_nm = rng.uniform(-10.0, 10.0)
        stretch = rng.uniform(0.88, 1.12)
        source_nm = peak_nm + (wavelength - peak_nm - shift_nm) / stretch
        out[:, channel] = np.interp(source_nm, camera.wavelength_nm, curve, left=0.0, right=0.0)
    ir_cut_nm = rng.uniform(630.0, 700.0)
    uv_cut_nm = rng.uniform(385.0, 420.0)
    ir = 1.0 / (1.0 + np.exp((wavelength - ir_cut_nm) / rng.uniform(6.0, 15.0)))
    uv = 1.0 / (1.0 + np.exp(-(wavelength - uv_cut_nm) / rng.uniform(4.0, 10.0)))
    tilt = 1.0 + rng.uniform(-0.3, 0.3) * (wavelength - 550.0) / 150.0
    gains = rng.uniform(0.6, 1.0, size=3)
    return np.clip(out * (ir * uv * np.clip(tilt, 0.2, None))[:, None] * gains[None, :], 0, None)


#: The warning every use of :func:`fallback_camera_basis` carries (:attr:`CameraBasis.fallback`).
FALLBACK_WARNING = (
    "the camera basis is the colour-science fallback (12 built-in curves: 3 cameras, "
    "colour-matching functions and cone fundamentals made camera-like, and perturbations of "
    "them), meant for "
    "examples and --offline smoke runs: an estimate leans on it where the lamps leave the camera "
    "open; without --offline the basis is the measured cameras (rawtoaces-data is bundled)"
)

#: How a fallback basis' ``source`` begins (:func:`is_fallback_basis`).
FALLBACK_SOURCE = "colour-science built-ins"


def is_fallback_basis(basis: CameraBasis) -> bool:
    """Whether ``basis`` is :func:`fallback_camera_basis`'s (CIE-derived curves, no measured camera)."""
    return basis.source.startswith(FALLBACK_SOURCE)


def fallback_camera_basis(
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    n_vectors: int = DEFAULT_N_VECTORS,
    exclude: Sequence[str] = (),
    variants_per_curve: int = 12,
    seed: int = 2025,
    cache: bool = True,
    cache_dir: Path | None = None,
) -> CameraBasis:
    """A camera basis from colour-science's built-in curves only (works offline, no dataset).

    Parameters
    ----------
    grid, n_vectors
        As for :func:`camera_basis`.
    exclude
        Patterns of curves to leave out (:func:`calib.core.camera_bodies.names_camera`), e.g. the
        camera under test (``"Nikon 5100"``), so that a test does not see its own answer in the
        basis.
    variants_per_curve
        Perturbed variants generated per base curve (shifts ±10 nm, width ±12 %, IR/UV cut-off
        filters, a spectral tilt, channel gains), seeded.
    seed
        Seed of the perturbations.
    """
    curves = _colour_camera_like_curves()
    bases = [
        curve
        for curve in curves
        if not any(names_camera(pattern, curve.name) for pattern in exclude)
    ]
    if not bases:
        raise InputError(
            f"excluding {', '.join(exclude)} leaves no built-in curve", source="exclude"
        )
    rng = np.random.default_rng(seed)
    stack: list[FloatArray] = []
    names: list[str] = []
    groups: list[str] = []
    for camera in bases:
        stack.append(camera.resample(grid, "interpolate", out_of_range="zero").values)
        names.append(camera.name)
        for index in range(variants_per_curve):
            stack.append(_perturbed(camera, grid, rng))
            names.append(_VARIANT_NAME.format(camera=camera.name, index=index + 1))
        groups.extend([camera.name] * (variants_per_curve + 1))
    label = f"{FALLBACK_SOURCE} + perturbations ({len(bases)} curves × {variants_per_curve + 1})"
    if exclude:
        label += f", excluding {', '.join(exclude)}"
    basis = camera_basis(
        np.stack(stack),
        grid=grid,
        n_vectors=n_vectors,
        source=label,
        camera_names=names,
        groups=groups,
        cache=cache,
        cache_dir=cache_dir,
    )
    left_out = tuple(curve.name for curve in curves if curve not in bases)
    return replace(
        basis,
        exclusions=tuple(exclude),
        excluded_cameras=left_out,
        fallback=FALLBACK_WARNING,
    )


def default_camera_basis(
    grid: WavelengthGrid = DEFAULT_GRID,
    *,
    n_vectors: int = DEFAULT_N_VECTORS,
    data_dir: str | Path | None = None,
    exclude: Sequence[str] = (),
) -> CameraBasis:
    """The basis of the measured reference cameras (:func:`calib.core.datasets.reference_cameras`).

    The Solomatov & Akkaynak ground truths when the data directory holds them; else the
    rawtoaces-data cameras bundled with spectral-rig, with :attr:`CameraBasis.fallback` saying so
    and what to fetch (the pipeline turns it into a warning on stderr, in ``result.json`` and in the
    report).

    Parameters
    ----------
    grid, n_vectors
        As for :func:`camera_basis`.
    data_dir
        The camera data directory; ``None`` looks in ``$SPECTRAL_RIG_DATA`` and the user cache.
    exclude
        Patterns of cameras to keep out (:func:`calib.core.camera_bodies.names_camera`: a camera's
        name, every curve of that body, or a shell wildcard); recorded in the basis.

    Raises
    ------
    InputError
        A named ``data_dir`` that does not exist; exclusions that leave fewer cameras than
        ``n_vectors``.
    """
    reference = reference_cameras(data_dir)
    kept, excluded = exclude_cameras(reference.records, exclude)
    needed = max(n_vectors, 3)
    if len(kept) < needed and excluded:
        raise InputError(
            f"excluding {', '.join(exclude)} leaves {len(kept)} of {len(reference.records)} "
            f"cameras in the basis ({reference.source}); it needs at least {needed}",
            source="--exclude-camera",
        )
    if len(kept) < needed:
        raise InputError(
            f"the basis has {len(kept)} cameras ({reference.source}); it needs at least {needed}",
            source=str(data_dir) if data_dir is not None else "camera data",
        )
    source = reference.source
    if excluded:
        source += f", without {', '.join(record.name for record in excluded)}"
    basis = camera_basis(
        [record.sensitivity for record in kept],
        grid=grid,
        n_vectors=n_vectors,
        source=source,
        camera_names=[record.name for record in kept],
    )
    return replace(
        basis,
        exclusions=tuple(exclude),
        excluded_cameras=tuple(record.name for record in excluded),
        unmatched_exclusions=tuple(
            pattern for pattern in exclude if not exclude_cameras(excluded, [pattern])[1]
        ),
        fallback=reference.fallback,
    )
