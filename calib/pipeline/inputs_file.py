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
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any

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
from calib.core.validated_yaml import issues_from_validation, parse_yaml_model
from calib.pipeline.inputs import FITS_SUFFIXES, ChannelGains, LampImages, LampInput, LampProfile

__all__ = ["EstimateInputs", "LampEntry", "lamp_from_options", "read_inputs_file"]

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
            if len(files) not in (1, 3) or (
                len(files) == 3 and any(p.suffix.lower() not in FITS_SUFFIXES for p in files)
            ):
                raise ValueError(
                    f"{_named(info, 'profile')} takes one file, or the R, G and B planes of a "
                    f"FITS export as three files ({', '.join(FITS_SUFFIXES)}); got {len(files)}"
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


class EstimateInputs(BaseModel):
    """An inputs file: the lamps of one estimate."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    lamps: Annotated[list[LampEntry], Field(min_length=1)]


def read_inputs_file(path: str | Path) -> tuple[LampInput, ...]:
    """The lamps of an inputs file (see the module docstring), paths relative to its directory.

    Raises
    ------
    calib.core.validated_yaml.ConfigError
        The file is missing, not YAML, or not a valid inputs file: every problem with its line and
        field.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", source=str(path)) from None
    inputs = parse_yaml_model(text, EstimateInputs, str(path))
    return tuple(entry.to_input(path.parent) for entry in inputs.lamps)


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
