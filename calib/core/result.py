"""The result every estimation method returns: :class:`EstimateResult`."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.camera_curves import CHANNEL_LABELS, CameraCurves
from calib.core.errors import InputError
from calib.core.mapping import GratingGeometry, QuadraticMapping
from calib.core.spectra import MultiSpectrum, Spectrum


def json_safe(value: Any) -> Any:
    """Plain JSON data: arrays → lists, NaN/inf → ``None``, mappings/sequences recursively."""
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, np.generic):
        return json_safe(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if hasattr(value, "to_dict"):
        return json_safe(value.to_dict())
    if value is None or isinstance(value, bool | int | str):
        return value
    return str(value)


def physical_curves(sensitivity: Any) -> FloatArray:
    """Sensitivity curves ``(f, 3)`` as delivered: negative values (a solve's ringing at a dim grid
    edge) set to zero, then the maximum over all channels 1."""
    curves = np.clip(np.asarray(sensitivity, dtype=np.float64), 0.0, None)
    peak = float(curves.max())
    return curves / peak if peak > 0 else curves


def _frozen(array: Any, shape: tuple[int, ...], name: str) -> FloatArray:
    out = np.array(array, dtype=np.float64)
    if out.shape != shape:
        raise InputError(f"expected shape {shape}, got {out.shape}", source=name)
    out.flags.writeable = False
    return out


Severity = Literal["info", "warning", "serious"]

#: What each quality code means (a flag's ``code``); the stage that finds it adds the flag. The
#: mapping's and the grating's entries are slots their stages fill (:mod:`calib.wavelength`, the
#: grating file); the others are found by the σ budget (:mod:`calib.methods.uncertainty`) and the
#: offline pipeline's input checks.
QUALITY_CODES: dict[str, str] = {
    "model_misfit": "the fit's reduced χ² ≫ 1: the model does not describe the data; σ inflated",
    "fallback_basis": "no measured camera data: the built-in fallback prior (CIE-derived curves)",
    "grid_beyond_basis": "part of the grid lies outside the camera basis' range",
    "no_spectrometer_bandwidth": "no spectrometer bandwidth given: a typical one is assumed in σ",
    "coarse_lamp_spectrum": "a lamp spectrum is sampled too coarsely for its emission lines",
    "line_lamp_unmeasured": "a line lamp's spectrum is not a measurement of it (a nominal spectrum "
    "or a built-in line list): it places the mapping and stays out of the solve",
    "lamp_kind_mismatch": "a lamp's spectrum contradicts its declared kind: narrow emission lines "
    "in a lamp declared LED or halogen, or none in one declared fluorescent",
    "coarse_spectrometer": "a lamp spectrum comes through a slit broader than the sensitivity's "
    "detail (an i1Pro-class instrument)",
    "saturated_frames": "frames with clipped pixels on the spot or the band",
    "blank_frames": "frames with no signal above the dark level",
    "uncertainty_incomplete": "some σ components could not be evaluated",
    "uncertainty_unvalidated": "the method's ±2σ band was not judged on the validation split",
    "grating_sigma_missing": "the given grating efficiency states no σ: its error is not in σ",
    "mapping_ambiguous": "the pixel→wavelength mapping has competing solutions (mapping stage)",
    "mapping_imprecise": "the pixel→wavelength mapping has one solution, but its likelihood holds "
    "an end looser than ±3 nm at 2σ: add a line lamp (mapping stage)",
    "mapping_nonmonotonic": "the mapping is not monotonic over the profile (mapping stage)",
    "mapping_line_residuals": "known lines sit far from the mapping (mapping stage)",
    "mapping_extrapolated": "the mapping is extrapolated beyond its lamp's lines with a large σ "
    "there (mapping stage)",
    "flat_grating_assumed": "the grating efficiency was assumed flat, not measured (grating stage)",
    "grating_assumed": "the grating efficiency was not measured: marginalised over the physical "
    "grating families, their spread in σ (grating stage)",
    "assumed_grating_reused": "a grating file holding an assumed η is reused (grating stage)",
    "grating_other_order": "the first order runs opposite to the one the grating file was "
    "measured on: the camera turned round, or the other first order (grating stage)",
    "grating_family_unresolved": "the direct signals do not tell the physical grating families "
    "apart: measure the 2nd order or η with the rig's spectrometer (grating stage)",
    "spectrometer_out_of_spec": "the lamp's own Hg lines put the spectrometer's wavelength scale "
    "beyond its tolerance: the spectra were corrected by the lines; recalibrate the instrument",
    "channel_gains_unknown": "the profile's channel gains are not the raw data's: the channel "
    "balance is the camera population's, its spread in σ",
    "lamp_spectrum_uncalibrated": "a lamp's spectrum is, by its own units, not its emission as "
    "power per nm: a spectrometer's raw counts or a reflectance; the sensitivity carries it",
}


#: A mapping further off than this (nm) is a wrong one: issue 16's bar, which the validation tables
#: count failures by and a broadband-only mapping's stated ±2σ is read against (decision 0158).
MAPPING_FAILURE_NM = 3.0
#: The mapping stage's codes that say its answer may be off by more than
#: :data:`MAPPING_FAILURE_NM` (competing basins, or one basin whose end the likelihood holds
#: loosely): a mapping further off than that without one of them is a silent wrong answer.
MAPPING_WARNING_CODES: tuple[str, ...] = ("mapping_ambiguous", "mapping_imprecise")


def mapping_warned(codes: str | Iterable[str]) -> bool:
    """Whether a mapping's quality codes (``details["warning_codes"]``, or their text as a CSV
    field holds them) include one of :data:`MAPPING_WARNING_CODES`."""
    text = codes if isinstance(codes, str) else " ".join(codes)
    return any(code in text for code in MAPPING_WARNING_CODES)


@dataclass(frozen=True)
class QualityFlag:
    """One finding about a result: a code of :data:`QUALITY_CODES`, what a person should know, and
    how much it matters (``"serious"``: the curve may be wrong beyond its σ)."""

    code: str
    message: str
    severity: Severity = "warning"

    def to_dict(self) -> dict[str, str]:
        return {"code": self.code, "severity": self.severity, "message": self.message}

    def line(self) -> str:
        """One line for stderr and the report (serious findings say so)."""
        prefix = "SERIOUS: " if self.severity == "serious" else ""
        return f"{prefix}{self.message} [{self.code}]"


@dataclass(frozen=True)
class Quality:
    """A result's self-diagnosis (``quality`` in ``result.json``, the report's banner).

    Attributes
    ----------
    flags
        Findings, in the order the stages added them.
    uncertainty
        What the σ band holds: the budget's components and their RMS share
        (:class:`calib.methods.uncertainty.UncertaintyBudget.summary`), empty when none was made.
    """

    flags: tuple[QualityFlag, ...] = ()
    uncertainty: Mapping[str, Any] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        """``"ok"`` (no warning), ``"caution"`` (warnings) or ``"doubtful"`` (a serious one)."""
        severities = {flag.severity for flag in self.flags}
        if "serious" in severities:
            return "doubtful"
        return "caution" if "warning" in severities else "ok"

    def with_flags(self, *flags: QualityFlag) -> Quality:
        """A copy with ``flags`` added (one per code: a later flag of the same code replaces it)."""
        codes = {flag.code for flag in flags}
        kept = tuple(flag for flag in self.flags if flag.code not in codes)
        return replace(self, flags=kept + tuple(flags))

    def warnings(self) -> list[str]:
        """The lines stderr and the banner show (warnings and serious findings)."""
        return [flag.line() for flag in self.flags if flag.severity != "info"]

    def to_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "flags": [flag.to_dict() for flag in self.flags],
            "uncertainty": json_safe(self.uncertainty),
        }


def mapping_flags(mapping: object) -> list[QualityFlag]:
    """What the mapping search said for the user (an ambiguous mapping, lines that disagree with
    the whole-profile fit, a failed refinement), as quality flags."""
    details = getattr(mapping, "details", None) or {}
    texts = [str(text) for text in details.get("warnings", ())]
    codes = list(details.get("warning_codes", ())) or ["mapping_line_residuals"] * len(texts)
    return [QualityFlag(str(code), text) for code, text in zip(codes, texts, strict=True)]


@dataclass(frozen=True, eq=False)
class EstimateResult:
    """A camera sensitivity estimate and everything needed to judge it.

    Attributes
    ----------
    method
        Registry name of the method (``"makabe2025"`` …).
    wavelength_nm
        Shape ``(f,)``: the working grid.
    sensitivity
        Shape ``(f, 3)``: R, G, B, maximum over all channels = 1.
    sensitivity_sigma
        Shape ``(f, 3)`` standard deviation (same scale), or ``None`` when not estimated.
    grating_efficiency, grating_efficiency_sigma
        Shape ``(f,)``: relative first-order efficiency (maximum 1) and its σ, or ``None``.
    mapping
        The pixel→wavelength mapping used (with how it was found and its error estimate), or ``None``
        for methods that need none.
    residuals
        Fit residuals (e.g. ``"profile"`` ``(n, 3)`` measured − model, ``"direct"`` ``(3,)``).
    diagnostics
        Condition numbers, the basis used, timings (s), per-step details.
    quality
        The self-diagnosis (:class:`Quality`): flags and what the σ band holds.
    """

    method: str
    wavelength_nm: FloatArray
    sensitivity: FloatArray
    sensitivity_sigma: FloatArray | None = None
    grating_efficiency: FloatArray | None = None
    grating_efficiency_sigma: FloatArray | None = None
    mapping: QuadraticMapping | GratingGeometry | None = None
    residuals: Mapping[str, Any] = field(default_factory=dict)
    diagnostics: Mapping[str, Any] = field(default_factory=dict)
    quality: Quality = field(default_factory=Quality)

    def __post_init__(self) -> None:
        wavelength = np.array(self.wavelength_nm, dtype=np.float64)
        f = wavelength.size
        object.__setattr__(self, "wavelength_nm", _frozen(wavelength, (f,), "wavelength_nm"))
        object.__setattr__(self, "sensitivity", _frozen(self.sensitivity, (f, 3), "sensitivity"))
        for name, shape in (
            ("sensitivity_sigma", (f, 3)),
            ("grating_efficiency", (f,)),
            ("grating_efficiency_sigma", (f,)),
        ):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _frozen(value, shape, name))

    @property
    def mapping_re_estimate(self) -> float | None:
        """Estimated mapping RE (Supp. Eq. 1) from the mapping fit's covariance, when known."""
        if not isinstance(self.mapping, QuadraticMapping) or self.mapping.wavelength_rms_nm is None:
            return None
        span = float(self.wavelength_nm[-1] - self.wavelength_nm[0])
        return self.mapping.wavelength_rms_nm / span

    def physical_sensitivity(self) -> FloatArray:
        """What ``sensitivity.csv`` holds, and what RE is scored on (:func:`physical_curves`)."""
        return physical_curves(self.sensitivity)

    def camera_curves(self, name: str = "estimated sensitivity") -> CameraCurves:
        """The delivered curves (:meth:`physical_sensitivity`) with their σ on the same scale."""
        clipped = np.clip(self.sensitivity, 0.0, None)
        peak = float(clipped.max())
        scale = 1.0 / peak if peak > 0 else 1.0
        sigma = None if self.sensitivity_sigma is None else self.sensitivity_sigma * scale
        return CameraCurves(self.wavelength_nm, clipped * scale, sigma, name=name)

    def to_colour(self, name: str = "estimated sensitivity") -> Any:
        """colour-science's ``RGB_CameraSensitivities`` of the delivered curves (on this grid).

        Examples
        --------
        >>> result = EstimateResult("demo", [400, 500, 600], [[0, 0.2, 1], [0.1, 1, 0.2], [1, 0.1, 0]])
        >>> result.to_colour().values[:, 2].tolist()
        [1.0, 0.2, 0.0]
        """
        return self.camera_curves(name).to_colour()

    def sensitivity_spectrum(self, name: str = "estimated sensitivity") -> MultiSpectrum:
        return MultiSpectrum(self.wavelength_nm, np.clip(self.sensitivity, 0, None), name=name)

    def efficiency_spectrum(self) -> Spectrum | None:
        if self.grating_efficiency is None or not np.all(np.isfinite(self.grating_efficiency)):
            return None
        return Spectrum(
            self.wavelength_nm, np.clip(self.grating_efficiency, 0, None), name="grating efficiency"
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-safe data (lists, floats, strings; NaN → ``None``); channels ``R, G, B``."""
        return {
            "method": self.method,
            "wavelength_nm": json_safe(self.wavelength_nm),
            "sensitivity": {
                channel: json_safe(self.sensitivity[:, k])
                for k, channel in enumerate(CHANNEL_LABELS)
            },
            "sensitivity_sigma": None
            if self.sensitivity_sigma is None
            else {
                channel: json_safe(self.sensitivity_sigma[:, k])
                for k, channel in enumerate(CHANNEL_LABELS)
            },
            "grating_efficiency": json_safe(self.grating_efficiency),
            "grating_efficiency_sigma": json_safe(self.grating_efficiency_sigma),
            "mapping": json_safe(self.mapping),
            "mapping_re_estimate": json_safe(self.mapping_re_estimate),
            "residuals": json_safe(self.residuals),
            "diagnostics": json_safe(self.diagnostics),
            "quality": self.quality.to_dict(),
        }

    def with_quality(self, *flags: QualityFlag) -> EstimateResult:
        """A copy whose :attr:`quality` has ``flags`` added."""
        return replace(self, quality=self.quality.with_flags(*flags))
