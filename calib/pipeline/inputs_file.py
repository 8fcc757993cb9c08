"""The lamps of an offline estimate as data: an inputs file (YAML), or the command line's lamp groups.

``calib estimate --inputs lamps.yaml`` reads a file like::

    lamps:
      - name: LED-B3
        kind: led
        images: [led/0001.dng, led/0002.dng, led/0003.dng]
        darks: [dark/0001.dng, dark/0002.dng, dark/0003.dng]
        spectrum: led.csv
        bandwidth_nm: 8
      - name: FL2
        kind: fluorescent
        profile: fl-profile.csv
        direct_rgb: [1200.0, 2100.0, 900.0]
        spectrum: fl.csv
    estimate:                    # optional: this file's settings
      method: prior
      grid: "400:700:5"
      pixel_pitch_um: 4.3

Relative paths are relative to the file's own directory. The keys are the command line's per-lamp
options, with their units in the name (``--exposure`` is ``exposure_s``, ``--dark`` is ``darks``,
``--direct`` is ``direct_rgb``, ``--bandwidth`` is ``bandwidth_nm``, ``--channel-gains`` is
``channel_gains``). A profile may be a FITS export's R, G and B planes as three files
(``profile: [sun-R.fit, sun-G.fit, sun-B.fit]``); ``channel_gains: unknown`` says a conversion
(white balance, a demosaicked RGB export) scaled its channels. One pydantic model,
:class:`LampEntry`, validates both the file and the command line's ``--lamp`` groups, so a lamp
reads the same from either; a problem names the file, its line and the field
(``lamps.yaml:7: lamps[1].images: required key is missing``), or on the command line the lamp and
the option (:func:`lamp_from_options`).

The optional ``estimate:`` block (:class:`EstimateBlock`) holds the estimate's options for these
lamps, named as ``calib estimate``'s: ``method``, ``grid`` (``"START:STOP:STEP"``),
``mapping_lamp``, ``grating`` (a path, relative to the file), ``assumed_grating`` (``flat`` or
``physical``, ``--assume-grating``), ``exclude_camera`` (a pattern or a list), ``weight_rule``
(the multilamp prior's, ``--weight-rule``: only with the method ``multilamp``), and the optics
``grooves_per_mm``, ``focal_length_mm``, ``pixel_pitch_um``. Each is checked as its option is,
and a mistake is named the same way (``lamps.yaml:9: estimate.grid: step must be > 0 nm``). An
option typed on the command line beats the file, the file beats the defaults, in ``calib
estimate`` and in each set of ``calib batch`` alike (:func:`own_settings_over`): a typed option
that contradicts the file is said in a warning naming both, and the block as read is recorded in
the result's notes.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, TypeVar

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from calib.core.errors import InputError
from calib.core.lamp_specs import is_spectrum_file
from calib.core.observations import LampKind
from calib.core.optics_ranges import FOCAL_LENGTH_MM, GROOVES_PER_MM, PIXEL_PITCH_UM
from calib.core.validated_yaml import issues_from_validation, parse_yaml_model
from calib.pipeline.inputs import ChannelGains, LampImages, LampInput, LampProfile

if TYPE_CHECKING:
    from calib.methods.multilamp import MultilampOptions
    from calib.pipeline.estimate import OfflineSettings

__all__ = [
    "EstimateBlock",
    "EstimateInputs",
    "LampEntry",
    "lamp_from_options",
    "own_settings_over",
    "read_estimate_inputs",
    "read_inputs_file",
]

T = TypeVar("T")
PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
#: Validation context key: how a field is called where the data came from (an option's name).
FIELD_NAMES = "field_names"


def _named(info: ValidationInfo, key: str) -> str:
    names: Mapping[str, str] = (info.context or {}).get(FIELD_NAMES, {})
    return names.get(key, key)


class LampEntry(BaseModel):
    """One lamp: RAW images (``images``, optional ``darks``) or a 1-D ``profile``, and a spectrum."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Annotated[str, Field(min_length=1)]
    kind: LampKind = "other"
    spectrum: Path | Annotated[list[Path], Field(min_length=1)]
    images: Annotated[list[Path], Field(min_length=1)] | None = None
    darks: list[Path] = Field(default_factory=list)
    exposure_s: Annotated[list[PositiveFloat], Field(min_length=1)] | None = None
    dark_exposure_s: Annotated[list[PositiveFloat], Field(min_length=1)] | None = None
    profile: Path | Annotated[list[Path], Field(min_length=1)] | None = None
    direct_rgb: tuple[NonNegativeFloat, NonNegativeFloat, NonNegativeFloat] | None = None
    bandwidth_nm: PositiveFloat | None = None
    channel_gains: ChannelGains = "raw"

    @field_validator("name")
    @classmethod
    def _name_not_blank(cls, value: str) -> str:
        if not value.strip():
            raise ValueError("a lamp name must not be blank")
        return value

    @field_validator("kind", mode="before")
    @classmethod
    def _lower_case_kind(cls, value: object) -> object:
        return value.lower() if isinstance(value, str) else value

    @field_validator("direct_rgb", mode="before")
    @classmethod
    def _direct_from_text(cls, value: object) -> object:
        """``"R,G,B"`` (the command line's form) as three values."""
        if isinstance(value, str):
            parts = [part.strip() for part in value.split(",")]
            if len(parts) != 3:
                raise ValueError(f"expected three numbers R,G,B, got {value!r}")
            return parts
        return value

    @model_validator(mode="after")
    def _one_kind_of_input(self, info: ValidationInfo) -> LampEntry:
        images, profile = _named(info, "images"), _named(info, "profile")
        if (self.images is None) == (self.profile is None):
            both = self.images is not None
            raise ValueError(
                f"give either {images} (a RAW bracket) or {profile} (a 1-D profile)"
                + (", not both" if both else "")
            )
        if self.profile is not None:
            files = self.profile if isinstance(self.profile, list) else [self.profile]
            if len(files) not in (1, 3):
                # Whether three files are FITS planes is known from what they hold, on reading.
                raise ValueError(
                    f"{_named(info, 'profile')} takes one file, or the R, G and B planes of a "
                    f"FITS export as three files; got {len(files)}"
                )
            for key in ("darks", "exposure_s", "dark_exposure_s"):
                if getattr(self, key):
                    raise ValueError(f"{_named(info, key)} goes with {images}, not {profile}")
            if self.direct_rgb is not None and not any(
                math.isfinite(value) and value > 0 for value in self.direct_rgb
            ):
                raise ValueError(f"{_named(info, 'direct_rgb')} must not be all zero")
        elif self.channel_gains != "raw":
            raise ValueError(
                f"{_named(info, 'channel_gains')} goes with {profile}; RAW images keep the "
                "raw data's gains"
            )
        elif self.direct_rgb is not None:
            raise ValueError(
                f"{_named(info, 'direct_rgb')} goes with {profile}; with images the direct spot "
                "is measured in them"
            )
        if self.dark_exposure_s is not None and not self.darks:
            raise ValueError(f"{_named(info, 'dark_exposure_s')} without {_named(info, 'darks')}")
        return self

    def to_input(self, base_dir: Path | None = None) -> LampInput:
        """The pipeline's input; relative paths are taken relative to ``base_dir`` when given."""

        def path(value: Path) -> Path:
            value = value.expanduser()
            return value if base_dir is None or value.is_absolute() else base_dir / value

        # Several spectrum files of one lamp are averaged (calib.pipeline.inputs.load_spectrum).
        # One value that is no file is a spectrum's name (FL2, builtin:NAME, gauss:…), which the
        # file's directory must not prefix.
        files = [self.spectrum] if isinstance(self.spectrum, Path) else self.spectrum
        spectrum: Path | tuple[Path, ...] = (
            (path(files[0]) if is_spectrum_file(path(files[0])) else files[0])
            if len(files) == 1
            else tuple(path(file) for file in files)
        )

        if self.profile is not None:
            planes = self.profile if isinstance(self.profile, list) else [self.profile]
            return LampProfile(
                name=self.name,
                kind=self.kind,
                spectrum=spectrum,
                profile=path(planes[0]) if len(planes) == 1 else tuple(map(path, planes)),
                direct_rgb=self.direct_rgb,
                spectrum_bandwidth_nm=self.bandwidth_nm,
                channel_gains=self.channel_gains,
            )
        assert self.images is not None  # checked by the model
        return LampImages(
            name=self.name,
            kind=self.kind,
            spectrum=spectrum,
            images=tuple(path(image) for image in self.images),
            darks=tuple(path(dark) for dark in self.darks),
            exposure_s=None if self.exposure_s is None else tuple(self.exposure_s),
            dark_exposure_s=None if self.dark_exposure_s is None else tuple(self.dark_exposure_s),
            spectrum_bandwidth_nm=self.bandwidth_nm,
        )


#: The optics as ``--grooves-per-mm``, ``--focal-length-mm`` and ``--pixel-pitch-um`` take them
#: (one range for both: :mod:`calib.core.optics_ranges`).
GroovesPerMm = Annotated[
    float, Field(ge=GROOVES_PER_MM[0], le=GROOVES_PER_MM[1], allow_inf_nan=False)
]
FocalLengthMm = Annotated[
    float, Field(ge=FOCAL_LENGTH_MM[0], le=FOCAL_LENGTH_MM[1], allow_inf_nan=False)
]
PixelPitchUm = Annotated[
    float, Field(ge=PIXEL_PITCH_UM[0], le=PIXEL_PITCH_UM[1], allow_inf_nan=False)
]
#: An ``estimate:`` key → the :class:`~calib.pipeline.OfflineSettings` field it sets (the optics'
#: as ``optics.<name>``, a field of :class:`~calib.pipeline.estimate.StatedOptics`) and the
#: command-line option that sets the same.
ESTIMATE_KEYS: dict[str, tuple[str, str]] = {
    "method": ("method", "--method"),
    "grid": ("grid", "--grid"),
    "mapping_lamp": ("mapping_lamp", "--mapping-lamp"),
    "grating": ("grating", "--grating"),
    "assumed_grating": ("assumed_grating", "--assume-grating"),
    "exclude_camera": ("exclude_cameras", "--exclude-camera"),
    "weight_rule": ("method_options.weight_rule", "--weight-rule"),
    "grooves_per_mm": ("optics.grooves_per_mm", "--grooves-per-mm"),
    "focal_length_mm": ("optics.focal_length_mm", "--focal-length-mm"),
    "pixel_pitch_um": ("optics.pixel_pitch_um", "--pixel-pitch-um"),
}


def _as_value_error(check: Callable[[str], T], value: str) -> T:
    """``check(value)``, its :class:`InputError` as the ``ValueError`` pydantic reports with the
    file's line and key (the option's own message, without the option's name)."""
    try:
        return check(value)
    except InputError as exc:
        raise ValueError(str(exc).removeprefix(f"{exc.source}: ")) from None


class EstimateBlock(BaseModel):
    """An inputs file's ``estimate:`` block: ``calib estimate``'s options for this file's lamps,
    each checked as the option is (:func:`calib.methods.check_method`,
    :meth:`calib.core.spectra.WavelengthGrid.parse`, the optics' ranges)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    method: str | None = None
    grid: str | None = None
    mapping_lamp: Annotated[str, Field(min_length=1)] | None = None
    grating: Path | None = None
    assumed_grating: Literal["flat", "physical"] | None = None
    exclude_camera: list[Annotated[str, Field(min_length=1)]] | None = None
    weight_rule: str | None = None
    grooves_per_mm: GroovesPerMm | None = None
    focal_length_mm: FocalLengthMm | None = None
    pixel_pitch_um: PixelPitchUm | None = None

    @field_validator("method")
    @classmethod
    def _registered_method(cls, value: str | None) -> str | None:
        from calib.methods import check_method

        return None if value is None else _as_value_error(check_method, value)

    @field_validator("grid")
    @classmethod
    def _parsed_grid(cls, value: str | None) -> str | None:
        from calib.core.spectra import WavelengthGrid

        if value is None:
            return None
        _as_value_error(WavelengthGrid.parse, value)
        return value.strip()

    @field_validator("weight_rule")
    @classmethod
    def _known_weight_rule(cls, value: str | None) -> str | None:
        from calib.methods.multilamp import MULTILAMP_METHOD, weight_rule_option

        if value is not None:  # the method is checked once merged (own_settings_over)
            _as_value_error(lambda rule: weight_rule_option(MULTILAMP_METHOD, rule), value)
        return value

    @field_validator("exclude_camera", mode="before")
    @classmethod
    def _one_pattern_as_list(cls, value: object) -> object:
        return [value] if isinstance(value, str) else value

    def fields(self, base_dir: Path) -> dict[str, Any]:
        """The keys the block gives, as :class:`~calib.pipeline.OfflineSettings` fields
        (:data:`ESTIMATE_KEYS`), the grating's path relative to ``base_dir``."""
        from calib.core.spectra import WavelengthGrid

        out: dict[str, Any] = {}
        for key in ESTIMATE_KEYS:
            value = getattr(self, key)
            if value is None:
                continue
            if key == "grid":
                value = WavelengthGrid.parse(value)
            elif key == "grating":
                value = value.expanduser()
                value = value if value.is_absolute() else base_dir / value
            elif key == "exclude_camera":
                value = tuple(value)
            out[ESTIMATE_KEYS[key][0]] = value
        return out

    def as_read(self) -> str:
        """The block as the file gives it, for the record: ``grid: 400:700:5, method: prior``."""
        given = self.model_dump(mode="json", exclude_none=True, exclude_unset=True)
        return ", ".join(f"{key}: {value}" for key, value in sorted(given.items()))


class EstimateInputs(BaseModel):
    """An inputs file: the lamps of one estimate, and optionally its settings (``estimate:``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    lamps: Annotated[list[LampEntry], Field(min_length=1)]
    estimate: EstimateBlock | None = None


@dataclasses.dataclass(frozen=True)
class InputsFileContents:
    """What an inputs file gives: its lamps, its ``estimate:`` block's settings and a note.

    Attributes
    ----------
    lamps
        The lamps, paths relative to the file's directory.
    settings
        The ``estimate:`` block as :class:`~calib.pipeline.OfflineSettings` fields
        (:meth:`EstimateBlock.fields`; the optics as a :class:`StatedOptics` of the values given):
        what :meth:`calib.pipeline.input_sets.InputSet.run` and :func:`own_settings_over` take.
    notes
        For the result's record: the file, and its ``estimate:`` block as read.
    """

    lamps: tuple[LampInput, ...]
    settings: Mapping[str, Any]
    notes: tuple[str, ...]


def read_estimate_inputs(path: str | Path) -> InputsFileContents:
    """An inputs file's lamps and settings (see the module docstring).

    Raises
    ------
    calib.core.validated_yaml.ConfigError
        The file is missing, not YAML, or not a valid inputs file: every problem with its line and
        field (``lamps.yaml:3: estimate.grid: …``).
    """
    from calib.pipeline.estimate import StatedOptics

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", source=str(path)) from None
    inputs = parse_yaml_model(text, EstimateInputs, str(path))
    lamps = tuple(entry.to_input(path.parent) for entry in inputs.lamps)
    notes = [f"inputs file {path}"]
    settings: dict[str, Any] = {}
    if inputs.estimate is not None:
        fields = inputs.estimate.fields(path.parent)
        settings = {key: value for key, value in fields.items() if not key.startswith("optics.")}
        optics = {
            key.removeprefix("optics."): value
            for key, value in fields.items()
            if key.startswith("optics.")
        }
        if optics:
            settings["optics"] = StatedOptics(**optics)
        notes.append(f"{path}'s estimate: {{{inputs.estimate.as_read()}}}")
    return InputsFileContents(lamps, settings, tuple(notes))


def read_inputs_file(path: str | Path) -> tuple[LampInput, ...]:
    """The lamps of an inputs file (see the module docstring), paths relative to its directory.

    Raises
    ------
    calib.core.validated_yaml.ConfigError
        The file is missing, not YAML, or not a valid inputs file: every problem with its line and
        field.
    """
    return read_estimate_inputs(path).lamps


def _shown(value: Any) -> str:
    from calib.core.spectra import WavelengthGrid

    if isinstance(value, WavelengthGrid):
        return f"{value.start_nm:g}:{value.stop_nm:g}:{value.step_nm:g}"
    if isinstance(value, tuple):
        return ",".join(map(str, value)) or "(none)"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def own_settings_over(
    settings: OfflineSettings, own: Mapping[str, Any], source: str
) -> OfflineSettings:
    """``settings`` with an input set's own fields (``own``, e.g. an inputs file's ``estimate:``
    block, :attr:`InputsFileContents.settings`) in, except where the command line typed the
    option (``settings.typed_options``): a typed option beats the file, the file beats the
    defaults. A typed option that contradicts the file is said in a warning naming both
    (``--grid 400:700:5 overrides lamps.yaml's estimate.grid 400:700:10``).

    ``own`` keys are :class:`~calib.pipeline.OfflineSettings` fields; ``optics`` is a
    :class:`~calib.pipeline.estimate.StatedOptics` whose ``None`` values are not given;
    ``method_options.weight_rule`` is the multilamp prior's weight rule.

    Raises
    ------
    InputError
        A weight rule (typed, or the file's) with a method other than ``multilamp``: the
        command line's message, from ``--weight-rule`` or ``{source}'s estimate.weight_rule``.
    """
    flat: dict[str, Any] = {}
    for name, value in own.items():
        if name == "optics":
            flat.update(
                {
                    f"optics.{key}": stated
                    for key, stated in dataclasses.asdict(value).items()
                    if stated is not None
                }
            )
        else:
            flat[name] = value
    by_field = {field: (key, option) for key, (field, option) in ESTIMATE_KEYS.items()}
    changes: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {"optics": {}, "method_options": {}}
    warnings: list[str] = []
    for name, value in flat.items():
        key, option = by_field.get(name, (name, name))
        group, _, attribute = name.rpartition(".")
        if key in settings.typed_options:
            typed = getattr(getattr(settings, group) if group else settings, attribute)
            same_file = isinstance(typed, Path) and isinstance(value, Path)
            if (typed.resolve() != value.resolve()) if same_file else (typed != value):
                warnings.append(
                    f"{option} {_shown(typed)} overrides {source}'s estimate.{key} {_shown(value)}"
                )
        elif group:
            nested[group][attribute] = value
        else:
            changes[name] = value
    if nested["optics"]:
        changes["optics"] = dataclasses.replace(settings.optics, **nested["optics"])
    method = changes.get("method", settings.method)
    rule = nested["method_options"].get("weight_rule")
    if rule is not None:
        options = _weight_rule_options(method, rule, f"{source}'s estimate.weight_rule")
        current = settings.method_options  # other multilamp options a caller set are kept
        changes["method_options"] = (
            dataclasses.replace(current, weight_rule=rule)
            if current is not None and hasattr(current, "weight_rule")
            else options
        )
    elif "weight_rule" in settings.typed_options and settings.method_options is not None:
        # The typed rule goes with the method the set will use (a batch's sets differ).
        _weight_rule_options(
            method, getattr(settings.method_options, "weight_rule", ""), "--weight-rule"
        )
    return dataclasses.replace(settings, **changes, warnings=(*settings.warnings, *warnings))


def _weight_rule_options(method: str, rule: str, source: str) -> MultilampOptions | None:
    """:func:`calib.methods.multilamp.weight_rule_option`, its error from ``source``."""
    from calib.methods.multilamp import weight_rule_option

    try:
        return weight_rule_option(method, rule)
    except InputError as exc:
        raise InputError(str(exc).removeprefix(f"{exc.source}: "), source=source) from None


def lamp_from_options(entry: Mapping[str, Any], option_names: Mapping[str, str]) -> LampInput:
    """A lamp from the command line: ``entry`` as an inputs-file lamp (strings are converted),
    problems named by the lamp and the option (``option_names``: key → option).

    Raises
    ------
    InputError
        The first problem, e.g. ``lamp 'LED' --exposure: -1.0 is out of range; must be > 0``.
    """
    name = str(entry.get("name", ""))
    try:
        lamp = LampEntry.model_validate(entry, context={FIELD_NAMES: option_names})
    except ValidationError as exc:
        issue = issues_from_validation(exc, LampEntry)[0]
        key = issue.field.split("[")[0].split(".")[0]
        where = f"lamp {name!r}"
        if key in option_names:
            where += f" {option_names[key]}"
        raise InputError(issue.message, source=where) from None
    return lamp.to_input()
