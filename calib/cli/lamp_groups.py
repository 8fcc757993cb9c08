"""``calib estimate``'s per-lamp option groups: ``--lamp NAME`` and the options that follow it.

click (under typer) has no repeated option groups, so :class:`LampGroupsCommand` takes them out of
the command line before click parses the rest: a group starts at ``--lamp NAME``; the lamp options
after it (:func:`lamp_options`: ``--images``, ``--spectrum`` …) belong to that lamp until the next
``--lamp``. The command's own options (``--out``, ``--method`` …) may stand anywhere, also between
a lamp's options. An option takes its value after it or after ``=`` (``--kind=led``); the list options
(``--images``, ``--spectrum``, ``--dark``, ``--exposure``, ``--dark-exposure``, ``--profile``) take
every value up to the next option.

Each group is then validated by the same model as the lamps of an inputs file
(:class:`calib.pipeline.inputs_file.LampEntry`), so a lamp reads the same from either. Mistakes are
:class:`calib.core.errors.InputError` naming the lamp and the option.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Annotated, Any

import typer

from calib.cli.command_line import (
    ARGUMENTS,
    ClickContext,
    Command,
    declared_parameters,
    help_choices,
    is_option,
)
from calib.core.errors import InputError

#: Where :class:`LampGroupsCommand` leaves the groups for the command (``ctx.meta[...]``).
LAMP_GROUPS = "calib.lamp_groups"
#: The option that starts a group.
LAMP = "--lamp"
#: The help panel of the per-lamp options.
LAMP_PANEL = "Per lamp: after --lamp NAME, repeated for every lamp (or an --inputs file)"


def _lamp_options(
    lamp: Annotated[
        str | None, typer.Option("--lamp", metavar="NAME", help="Starts a lamp's options.")
    ] = None,
    images: Annotated[
        list[str] | None,
        typer.Option(
            "--images",
            metavar="RAW ...",
            help="The lamp's RAW bracket (any format LibRaw reads: DNG, CR2, CR3, NEF, ARW …).",
        ),
    ] = None,
    spectrum: Annotated[
        list[str] | None,
        typer.Option(
            "--spectrum",
            metavar="CSV ...",
            help="The lamp's spectrum (required): wavelength_nm,value (# units: and "
            "# bandwidth_nm: header lines are read; several files: their mean), or a named one "
            "(a colour-science illuminant or light source such as FL11, builtin:NAME[:FWHM_NM] "
            "for a line list, gauss:CENTRE:FWHM).",
        ),
    ] = None,
    kind: Annotated[
        str | None,
        typer.Option(
            "--kind",
            metavar="KIND",
            help="{lamp_kinds} (default other); a fluorescent lamp's lines give the "
            "pixel→wavelength mapping.",
        ),
    ] = None,
    darks: Annotated[
        list[str] | None,
        typer.Option(
            "--dark",
            metavar="RAW ...",
            help="Dark frames at the bracket's exposure times (subtracted per exposure).",
        ),
    ] = None,
    exposure_s: Annotated[
        list[str] | None,
        typer.Option(
            "--exposure",
            metavar="S ...",
            help="Exposure times in seconds overriding the files', one per image.",
        ),
    ] = None,
    dark_exposure_s: Annotated[
        list[str] | None,
        typer.Option("--dark-exposure", metavar="S ...", help="The same for the dark frames."),
    ] = None,
    profile: Annotated[
        list[str] | None,
        typer.Option(
            "--profile",
            metavar="FILE ...",
            help="Instead of images: a 1-D profile, CSV pixel,r,g,b or wavelength_nm,r,g,b "
            "(optional r_sigma,g_sigma,b_sigma columns), a rawproc .dat export, a FITS cube "
            "of the R, G, B planes, or those planes as three FITS files (R G B).",
        ),
    ] = None,
    channel_gains: Annotated[
        str | None,
        typer.Option(
            "--channel-gains",
            metavar="raw|unknown",
            help="With --profile: raw (default) when the channels keep the raw data's gains; "
            "unknown when a conversion scaled them (white balance, a demosaicked RGB export): "
            "the channel balance is then the camera population's, its spread in σ.",
        ),
    ] = None,
    direct_rgb: Annotated[
        str | None,
        typer.Option(
            "--direct",
            metavar="R,G,B",
            help="With --profile: the direct (0th-order) RGB in the profile's units.",
        ),
    ] = None,
    bandwidth_nm: Annotated[
        str | None,
        typer.Option(
            "--bandwidth",
            metavar="NM",
            help="The spectrometer's bandwidth (FWHM of its slit function) when broader than the "
            "camera resolves, e.g. 8 for a PR-655, 5 for a CS-2000.",
        ),
    ] = None,
) -> None:
    """The per-lamp options as the help lists them: each parameter is named as the inputs file's
    key (:class:`calib.pipeline.inputs_file.LampEntry`); their values never reach a command, the
    splitter takes them (:func:`split_lamp_groups`)."""


@dataclass(frozen=True)
class LampOption:
    """One per-lamp option: its flag, the inputs-file key it stands for, whether it takes a list."""

    flag: str
    key: str
    takes_list: bool


@cache
def lamp_parameters() -> tuple[Any, ...]:
    """The per-lamp options as click parameters, shown in the help panel :data:`LAMP_PANEL`."""
    parameters = declared_parameters(_lamp_options)
    for parameter in parameters:
        parameter.expose_value = False
        parameter.rich_help_panel = LAMP_PANEL  # type: ignore[attr-defined]  # typer's help reads it
    return tuple(parameters)


@cache
def lamp_options() -> dict[str, LampOption]:
    """The per-lamp options by flag (``--lamp`` itself excepted)."""
    options = (
        LampOption(parameter.opts[0], str(parameter.name), bool(parameter.multiple))
        for parameter in lamp_parameters()
    )
    return {option.flag: option for option in options if option.flag != LAMP}


def option_names() -> dict[str, str]:
    """Inputs-file key → its option (to name a command-line mistake by its option)."""
    return {option.key: option.flag for option in lamp_options().values()}


@dataclass
class LampGroup:
    """One ``--lamp NAME`` group: its options' values as given (strings), by inputs-file key."""

    name: str
    values: dict[str, list[str] | str] = field(default_factory=dict)

    def entry(self) -> dict[str, Any]:
        """The group as an inputs-file lamp entry (validated by the caller)."""
        return {"name": self.name, **self.values}


def _flag_and_value(token: str) -> tuple[str, str | None]:
    flag, equals, value = token.partition("=")
    return flag, (value if equals else None)


def _single(flag: str, values: list[str], where: str) -> str:
    if len(values) != 1:
        what = "a value" if not values else f"one value, got {len(values)}: {' '.join(values)}"
        raise InputError(f"{flag} needs {what}", source=where)
    if not values[0]:
        raise InputError(f"{flag} needs a non-empty value", source=where)
    return values[0]


@help_choices("lamp_kinds")
def lamp_kinds() -> tuple[str, ...]:
    """:data:`calib.core.lamp_kinds.LAMP_KINDS`."""
    from calib.core.lamp_kinds import LAMP_KINDS

    return LAMP_KINDS


def split_lamp_groups(
    args: Sequence[str], command_options: Sequence[str] = ()
) -> tuple[list[LampGroup], list[str]]:
    """The ``--lamp`` groups of ``args`` and the arguments left for the command's own options.

    ``command_options`` are the command's own option names: a lamp option misspelt is named with
    the closest option of either kind.

    Raises
    ------
    InputError
        A lamp option before any ``--lamp``, one given twice for a lamp, a missing value, more than
        one value for a single-valued option.
    """
    options = lamp_options()
    groups: list[LampGroup] = []
    rest: list[str] = []
    flag: str | None = None  # the lamp option whose values are being collected
    collected: list[str] = []

    def close() -> None:
        nonlocal flag
        if flag is None:
            return
        if flag == LAMP:
            groups.append(LampGroup(_single(LAMP, collected, LAMP)))
        else:
            option = options[flag]
            group = groups[-1]
            where = f"lamp {group.name!r} {flag}"
            if option.key in group.values:
                raise InputError("given twice for the same lamp", source=where)
            if option.takes_list:
                if not collected:
                    raise InputError(f"{flag} needs at least one value", source=where)
                group.values[option.key] = list(collected)
            else:
                group.values[option.key] = _single(flag, collected, where)
        flag = None

    for token in args:
        if not is_option(token):
            (collected if flag is not None else rest).append(token)
            continue
        close()
        name, value = _flag_and_value(token)
        if name == LAMP or name in options:
            if name != LAMP and not groups:
                raise InputError(
                    f"{name} before any --lamp; lamp options follow the --lamp NAME they belong to",
                    source=name,
                )
            flag = name
            collected = [] if value is None else [value]
        else:
            close_match = difflib.get_close_matches(name, [LAMP, *options, *command_options], n=1)
            if name.startswith("--") and name not in command_options and close_match:
                raise InputError(f"unknown option; did you mean {close_match[0]}?", source=name)
            rest.append(token)
    close()
    return groups, rest


class LampGroupsCommand(Command):
    """A command that takes ``--lamp NAME …`` groups out of its arguments (:func:`split_lamp_groups`)
    into ``ctx.meta[LAMP_GROUPS]``, and lists the lamp options in its help."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.params.extend(lamp_parameters())

    def parse_args(self, ctx: ClickContext, args: list[str]) -> list[str]:
        ctx.meta[ARGUMENTS] = tuple(args)
        if any(token in ctx.help_option_names or token == "--version" for token in args):
            # Help and version need no lamp: asking for them never fails on a half-typed lamp.
            ctx.meta[LAMP_GROUPS] = []
            shown = [token for token in args if token in (*ctx.help_option_names, "--version")]
            return super().parse_args(ctx, shown[:1])
        # a flag pair's "--no-…" half is a secondary name (``--report/--no-report``)
        own = [
            name
            for parameter in self.params
            for name in (*parameter.opts, *parameter.secondary_opts)
        ]
        groups, rest = split_lamp_groups(args, own)
        ctx.meta[LAMP_GROUPS] = groups
        return super().parse_args(ctx, rest)
