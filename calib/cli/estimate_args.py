"""Command-line arguments of ``calib estimate``: global options and repeated per-lamp groups.

typer/click do not group options, so the argument list is parsed here. A lamp group starts with
``--lamp NAME``; the lamp options after it (``--images``, ``--spectrum`` …) belong to that lamp until the
next ``--lamp``. Global options may stand anywhere. Options take their value(s) as the next
argument(s) or after ``=`` (``--grid=400:700:5``); list options (``--images``, ``--dark``,
``--exposure``, ``--dark-exposure``) take every argument up to the next option. Every mistake raises
:class:`calib.core.errors.InputError` naming the option (and lamp) and what was expected.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from calib.core.errors import InputError
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.methods import AUTO, MethodOptions
from calib.methods.multilamp import weight_rule_option
from calib.pipeline.inputs import LampImages, LampInput, LampProfile, check_kind, parse_direct

USAGE = """\
Usage: calib estimate --lamp NAME (--images PATH [PATH ...] | --profile CSV) --spectrum CSV
                      [--kind led|fluorescent|halogen|narrowband|other] [--dark PATH ...]
                      [--exposure S ...] [--dark-exposure S ...] [--direct R,G,B]
                      [--bandwidth NM]
                      [--lamp NAME … for every further lamp]
                      --out DIR [--method auto|prior|makabe2025|multilamp|known-grating]
                      [--weight-rule upre|typicality|evidence]
                      [--mapping-lamp NAME] [--grid 400:700:10]
                      [--data-dir DIR] [--grating FILE] [--force] [--quiet] [--json]

Estimate a camera's RGB spectral sensitivity from RAW brackets (or 1-D profiles) of lamps seen
through a diffraction grating, and each lamp's measured spectrum.

Per lamp (after --lamp NAME; repeat the group for every lamp):
  --images PATH ...      the lamp's RAW bracket (any format LibRaw reads: DNG, CR2, CR3, NEF, ARW …)
  --spectrum CSV ...     the lamp's spectrum, wavelength_nm,value (header optional, any spacing;
                         several files: their mean; # units:/# bandwidth_nm: lines are read)
  --kind KIND            led, fluorescent, halogen, narrowband or other (default: other);
                         a fluorescent lamp's lines give the pixel→wavelength mapping
  --dark PATH ...        dark frames at the bracket's exposure times (subtracted per exposure)
  --exposure S ...       exposure times in seconds overriding the files', one per image
  --dark-exposure S ...  the same for the dark frames
  --profile CSV          instead of images: a 1-D profile pixel,r,g,b or wavelength_nm,r,g,b
                         (optional r_sigma,g_sigma,b_sigma columns)
  --direct R,G,B         with --profile: the direct (0th-order) RGB in the profile's units
  --bandwidth NM         the spectrometer's bandwidth (FWHM of its slit function) when it is
                         broader than the camera resolves, e.g. 8 for a PR-655, 5 for a CS-2000

Global:
  --out DIR              where to write sensitivity.csv, result.json, report.html, the
                         rawtoaces camera JSON and grating.json (created if missing)
  --method NAME          estimation method: auto (default: multilamp when 3 or more lamps have a
                         direct measurement, else prior), prior (the camera-prior solve),
                         makabe2025 (the paper's solve as printed), multilamp, known-grating
  --weight-rule RULE     with --method multilamp: how the camera prior is weighted, upre (default),
                         typicality (better for cameras like the basis, worse for unusual ones)
                         or evidence (the marginal likelihood)
  --mapping-lamp NAME    the lamp that gives the pixel→wavelength mapping
  --grid START:STOP:STEP working wavelength grid in nm (default 400:700:10)
  --data-dir DIR         camera data for the basis (default $SPECTRAL_RIG_DATA or the user cache;
                         the built-in colour-science basis when none is found)
  --grating FILE         grating efficiency (grating.json of an earlier estimate) for lamps with
                         no direct measurement; without it a flat grating is assumed, with a warning
  --force                overwrite the results of an earlier estimate in --out
  --quiet, -q            no progress bar and no summary (warnings and errors still on stderr)
  --json                 print a JSON summary on stdout (for scripts)
  --help, -h             show this help

Exit codes: 0 ok, 2 bad input (the reason on one line), 1 internal error.
"""

_LAMP_MULTI = ("--images", "--dark", "--exposure", "--dark-exposure", "--spectrum")
_LAMP_SINGLE = ("--kind", "--profile", "--direct", "--bandwidth")
_GLOBAL_SINGLE = (
    "--out",
    "--method",
    "--weight-rule",
    "--mapping-lamp",
    "--grid",
    "--data-dir",
    "--grating",
)
_FLAGS = {"--quiet": "--quiet", "-q": "--quiet", "--json": "--json", "--force": "--force"}
_HELP = ("--help", "-h")
_KNOWN = ("--lamp", *_LAMP_MULTI, *_LAMP_SINGLE, *_GLOBAL_SINGLE, *_FLAGS, *_HELP)


@dataclass
class _LampGroup:
    name: str
    values: dict[str, str] = field(default_factory=dict)
    lists: dict[str, list[str]] = field(default_factory=dict)


@dataclass(frozen=True)
class EstimateArguments:
    """The parsed command line.

    Attributes
    ----------
    lamps
        One input per ``--lamp`` group, in order.
    out_dir
        ``--out``.
    method, mapping_lamp, grid, data_dir, grating
        The global options (``None`` when not given).
    method_options
        The method's typed options: what ``--weight-rule`` stands for
        (:func:`calib.methods.multilamp.weight_rule_option`), checked; ``None``: its defaults.
    force, quiet, json_output, show_help
        The flags.
    """

    lamps: tuple[LampInput, ...]
    out_dir: Path | None
    method: str = AUTO
    method_options: MethodOptions | None = None
    mapping_lamp: str | None = None
    grid: WavelengthGrid = DEFAULT_GRID
    data_dir: Path | None = None
    grating: Path | None = None
    force: bool = False
    quiet: bool = False
    json_output: bool = False
    show_help: bool = False


def _unknown(option: str) -> InputError:
    close = difflib.get_close_matches(option, _KNOWN, n=1)
    hint = f"; did you mean {close[0]}?" if close else "; see calib estimate --help"
    return InputError(f"unknown option {option}{hint}", source=option)


def _is_option(token: str) -> bool:
    return token.startswith("-") and len(token) > 1 and not _is_number(token)


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _positive_number(text: str, option: str, lamp: str, unit: str) -> float:
    """``text`` as a finite number > 0, else an :class:`InputError` naming the lamp and option."""
    try:
        value = float(text)
    except ValueError:
        raise InputError(
            f"{text!r} is not a number of {unit}", source=f"lamp {lamp!r} {option}"
        ) from None
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"must be > 0 {unit}, got {text}", source=f"lamp {lamp!r} {option}")
    return value


def _positive_seconds(text: str, option: str, lamp: str) -> float:
    return _positive_number(text, option, lamp, "s")


def _split_tokens(argv: Sequence[str]) -> list[tuple[str, list[str]]]:
    """``[(option, values)]`` in order; values are the arguments up to the next option."""
    items: list[tuple[str, list[str]]] = []
    for token in argv:
        if _is_option(token):
            option, equals, value = token.partition("=")
            if option not in _KNOWN:
                raise _unknown(option)
            items.append((option, [value] if equals else []))
        elif not items:
            raise InputError(
                f"unexpected argument {token!r}; every value follows its option (e.g. --images "
                "PATH ...)",
                source=token,
            )
        else:
            items[-1][1].append(token)
    return items


def _single(option: str, values: list[str], where: str) -> str:
    if len(values) != 1:
        what = "a value" if not values else f"one value, got {len(values)}: {' '.join(values)}"
        raise InputError(f"{option} needs {what}", source=where)
    if not values[0]:
        raise InputError(f"{option} needs a non-empty value", source=where)
    return values[0]


def parse_estimate_arguments(argv: Sequence[str]) -> EstimateArguments:
    """Parse ``calib estimate``'s arguments.

    Raises
    ------
    InputError
        Unknown options, values without an option, lamp options before ``--lamp``, an option
        repeated within a lamp, a missing or superfluous value, a lamp without ``--spectrum`` or
        without ``--images``/``--profile``, bad numbers; the option and lamp are named.
    """
    groups: list[_LampGroup] = []
    globals_: dict[str, str] = {}
    flags: set[str] = set()
    for option, values in _split_tokens(argv):
        if option in _HELP:
            return EstimateArguments(lamps=(), out_dir=None, show_help=True)
        if option in _FLAGS:
            if values:
                raise InputError(f"{option} takes no value, got {' '.join(values)}", source=option)
            flags.add(_FLAGS[option])
        elif option == "--lamp":
            groups.append(_LampGroup(_single(option, values, option)))
        elif option in _GLOBAL_SINGLE:
            if option in globals_:
                raise InputError(f"{option} is given twice", source=option)
            globals_[option] = _single(option, values, option)
        else:  # a lamp option
            if not groups:
                raise InputError(
                    f"{option} before any --lamp; lamp options follow the --lamp NAME they "
                    "belong to",
                    source=option,
                )
            group = groups[-1]
            where = f"lamp {group.name!r} {option}"
            if option in group.values or option in group.lists:
                raise InputError("given twice for the same lamp", source=where)
            if option in _LAMP_MULTI:
                if not values:
                    raise InputError(f"{option} needs at least one value", source=where)
                group.lists[option] = values
            else:
                group.values[option] = _single(option, values, where)
    if not groups:
        raise InputError(
            "no lamps; give --lamp NAME --images PATH ... --spectrum CSV", source="--lamp"
        )
    if "--out" not in globals_:
        raise InputError("--out DIR is required: where to write the results", source="--out")
    grid = DEFAULT_GRID
    if "--grid" in globals_:
        try:
            grid = WavelengthGrid.parse(globals_["--grid"])
        except InputError as exc:
            message = str(exc).removeprefix(f"{exc.source}: ")
            raise InputError(message, source="--grid") from None
    method = globals_.get("--method", AUTO)
    method_options = weight_rule_option(method, globals_.get("--weight-rule"))
    return EstimateArguments(
        lamps=tuple(_lamp_input(group) for group in groups),
        out_dir=Path(globals_["--out"]),
        method=method,
        method_options=method_options,
        mapping_lamp=globals_.get("--mapping-lamp"),
        grid=grid,
        data_dir=Path(globals_["--data-dir"]) if "--data-dir" in globals_ else None,
        grating=Path(globals_["--grating"]) if "--grating" in globals_ else None,
        force="--force" in flags,
        quiet="--quiet" in flags,
        json_output="--json" in flags,
    )


def _lamp_input(group: _LampGroup) -> LampInput:
    where = f"lamp {group.name!r}"
    if "--spectrum" not in group.lists:
        raise InputError("--spectrum CSV is required for every lamp", source=where)
    kind = check_kind(group.values.get("--kind", "other"), f"{where} --kind")
    paths = tuple(Path(p) for p in group.lists["--spectrum"])  # several: averaged
    spectrum = paths[0] if len(paths) == 1 else paths
    bandwidth = (
        None
        if "--bandwidth" not in group.values
        else _positive_number(group.values["--bandwidth"], "--bandwidth", group.name, "nm")
    )
    has_images = "--images" in group.lists
    has_profile = "--profile" in group.values
    if has_images == has_profile:
        raise InputError(
            "give either --images PATH ... (a RAW bracket) or --profile CSV (a 1-D profile)"
            + (", not both" if has_images else ""),
            source=where,
        )
    if has_profile:
        for option in ("--dark", "--exposure", "--dark-exposure"):
            if option in group.lists:
                raise InputError(f"{option} goes with --images, not --profile", source=where)
        direct = group.values.get("--direct")
        return LampProfile(
            name=group.name,
            kind=kind,
            spectrum=spectrum,
            profile=Path(group.values["--profile"]),
            direct_rgb=None if direct is None else parse_direct(direct, f"{where} --direct"),
            spectrum_bandwidth_nm=bandwidth,
        )
    if "--direct" in group.values:
        raise InputError(
            "--direct goes with --profile; with images the direct spot is measured in them",
            source=where,
        )
    if "--dark-exposure" in group.lists and "--dark" not in group.lists:
        raise InputError("--dark-exposure without --dark", source=where)
    exposures = group.lists.get("--exposure")
    dark_exposures = group.lists.get("--dark-exposure")
    return LampImages(
        name=group.name,
        kind=kind,
        spectrum=spectrum,
        images=tuple(Path(p) for p in group.lists["--images"]),
        darks=tuple(Path(p) for p in group.lists.get("--dark", [])),
        exposure_s=None
        if exposures is None
        else tuple(_positive_seconds(v, "--exposure", group.name) for v in exposures),
        dark_exposure_s=None
        if dark_exposures is None
        else tuple(_positive_seconds(v, "--dark-exposure", group.name) for v in dark_exposures),
        spectrum_bandwidth_nm=bandwidth,
    )
