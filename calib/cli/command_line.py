"""The one style of both command lines, ``calib`` and ``rig``: how a command is built and how it ends.

- ``-h`` and ``--help`` on every command and group; ``--version`` on every one too
  (:func:`click_command` adds it to the whole tree), printing spectral-rig's version.
- A mistake on the command line (an unknown option, a bad or missing value, a missing argument) is
  one line on stderr, ``calib: error: No such option: --imgs Did you mean --images? (calib estimate
  -h for help)``, exit 2; typer's own display is a framed box over several lines with the usage.
- Ctrl-C at any moment of a command: ``<program>: interrupted``, exit 130 (typer ≥ 0.16 would end
  with a silent ``Exit(130)``).
- What the commands raise themselves (:class:`calib.core.errors.InputError` …) is mapped to a line
  and an exit code by each program's ``main`` around :func:`run_app` (``calib``'s own mapping is
  :func:`error_code_and_line`).

Options whose value is a list (``--images A.dng B.dng …``) take the values after one option; click
takes one value per option, so :class:`Command` rewrites ``--images A B`` into ``--images A --images
B`` for the options it is told (declared ``multiple``, a ``list[...]`` parameter) before parsing.
Repeating the option works as well.

typer (≥ 0.26) vendors click and exposes no public class for a command-line mistake; this module is
the one place that names typer's click (``typer._click``). Importing it imports no heavy library
(``rig`` and ``calib`` import it at start-up).
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Sequence
from typing import Annotated, Any, ClassVar, TypeVar

import typer
from typer import _click
from typer.core import TyperCommand, TyperGroup

from calib.core.errors import CalibError, InputError

#: A click command (typer's own click), for annotations.
ClickCommand = _click.Command
#: Its context.
ClickContext = _click.Context
CommandFunction = TypeVar("CommandFunction", bound=Callable[..., Any])

#: Exit code of a command stopped by Ctrl-C (128 + SIGINT, as a shell reports it).
INTERRUPTED_EXIT_CODE = 130
#: Exit code of a mistake on the command line or any other bad input.
BAD_INPUT_EXIT_CODE = 2

#: Where :class:`Command` keeps its arguments as typed (``ctx.meta[ARGUMENTS]``), for the record.
ARGUMENTS = "calib.arguments"

#: Context settings of every command: ``-h`` as well as ``--help``.
CONTEXT_SETTINGS: dict[str, Any] = {"help_option_names": ["-h", "--help"]}


class CommandInterrupted(Exception):
    """Ctrl-C inside a command (raised instead of typer's silent ``Exit(130)``)."""


class CommandGroup(TyperGroup):
    """The group class of both apps: a Ctrl-C anywhere below it becomes :class:`CommandInterrupted`."""

    def make_context(
        self,
        info_name: str | None,
        args: list[str],
        parent: ClickContext | None = None,
        **extra: Any,
    ) -> ClickContext:
        # A Ctrl-C while the command line is parsed (typer would end with a silent Exit(130)).
        try:
            return super().make_context(info_name, args, parent, **extra)
        except KeyboardInterrupt:
            raise CommandInterrupted from None

    def invoke(self, ctx: ClickContext) -> Any:
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            raise CommandInterrupted from None


# ------------------------------------------------------------------------------ help choices

#: Placeholders a command's help may hold (``{methods}``), each filled by a function listing the
#: choices when the help is shown: the lists come from modules (the methods registry …) that a
#: command line need not import to start (:func:`help_choices` adds one).
HELP_CHOICES: dict[str, Callable[[], Sequence[str]]] = {}

_PLACEHOLDER = re.compile(r"\{(\w+)\}")

ChoicesFunction = Callable[[], Sequence[str]]


def help_choices(name: str) -> Callable[[ChoicesFunction], ChoicesFunction]:
    """Register the function that lists the choices of the help placeholder ``{name}``."""

    def register(function: ChoicesFunction) -> ChoicesFunction:
        HELP_CHOICES[name] = function
        return function

    return register


def fill_help(text: str) -> str:
    """``text`` with every known placeholder (:data:`HELP_CHOICES`) replaced by its choices."""

    def choices(match: re.Match[str]) -> str:
        function = HELP_CHOICES.get(match[1])
        return match[0] if function is None else ", ".join(function())

    return _PLACEHOLDER.sub(choices, text)


# ------------------------------------------------------------------------------ the commands


def is_option(token: str) -> bool:
    """Whether ``token`` is an option name (``--images``, ``-q``, ``--grid=…``), not a value."""
    if not token.startswith("-") or len(token) < 2:
        return False
    try:
        float(token)
    except ValueError:
        return True
    return False  # a negative number is a value


def expand_list_options(args: Sequence[str], names: frozenset[str]) -> list[str]:
    """``--images a b`` → ``--images a --images b`` for the option ``names`` (see :class:`Command`).

    ``--images=a`` stays as it is; ``--`` ends the options.
    """
    out: list[str] = []
    current: str | None = None
    follows_option = False
    for index, token in enumerate(args):
        if token == "--":
            out.extend(args[index:])
            break
        if is_option(token):
            current = token if token in names else None
            follows_option = True
            out.append(token)
            continue
        if current is not None and not follows_option:
            out.append(current)
        out.append(token)
        follows_option = False
    return out


class Command(TyperCommand):
    """The command class of both apps.

    - :attr:`list_options` take every value up to the next option (``--images a.dng b.dng``).
      A value that starts with ``-`` and is not a number ends the list; a command with positional
      arguments would see them taken as such an option's values, so those commands have none.
      Subclass with the names (:func:`list_options_command`).
    - Help placeholders (``{methods}``, :data:`HELP_CHOICES`) are filled when the help is shown.
    - The arguments as typed are kept in ``ctx.meta[ARGUMENTS]`` (for a result's record).
    """

    list_options: ClassVar[frozenset[str]] = frozenset()

    def parse_args(self, ctx: ClickContext, args: list[str]) -> list[str]:
        ctx.meta.setdefault(ARGUMENTS, tuple(args))
        return super().parse_args(ctx, expand_list_options(args, self.list_options))

    def format_help(self, ctx: ClickContext, formatter: _click.HelpFormatter) -> None:
        for parameter in self.params:
            text = getattr(parameter, "help", None)
            if isinstance(text, str):
                parameter.help = fill_help(text)  # type: ignore[attr-defined]
        if self.help:
            self.help = fill_help(self.help)
        super().format_help(ctx, formatter)


def list_options_command(*names: str) -> type[Command]:
    """A :class:`Command` class whose options ``names`` (``"--images"``, …) take value lists."""
    return type("ListOptionsCommand", (Command,), {"list_options": frozenset(names)})


def declared_parameters(function: Callable[..., None]) -> list[_click.Parameter]:
    """The click parameters typer makes of ``function``'s signature (to add to other commands)."""
    app = typer.Typer(add_completion=False)
    app.command()(function)
    return list(typer.main.get_command(app).params)


def _show_version(ctx: typer.Context, value: bool) -> None:
    if not value or ctx.resilient_parsing:
        return
    # Deferred: importlib.metadata costs ~15 ms that `--help` need not pay.
    from calib.core.software import current_software

    typer.echo(f"spectral-rig {current_software().version}")
    raise typer.Exit(0)


def _version_option(
    version: Annotated[
        bool,
        typer.Option(
            "--version",
            is_eager=True,
            expose_value=False,
            callback=_show_version,
            help="Show spectral-rig's version and exit.",
        ),
    ] = False,
) -> None:
    """Declares ``--version`` (:func:`click_command` adds it to every command)."""


def typed_on_command_line(ctx: ClickContext, parameter: str) -> bool:
    """Whether ``parameter`` (its Python name, ``grooves_per_mm``) was typed on the command line,
    not left at its default (click's parameter source)."""
    return ctx.get_parameter_source(parameter) is _click.core.ParameterSource.COMMANDLINE


def subcommands(command: ClickCommand) -> dict[str, ClickCommand]:
    """A group's commands by name (``{}`` for a command)."""
    return dict(getattr(command, "commands", {}))


def _every_command(command: ClickCommand) -> list[ClickCommand]:
    commands = [command]
    for child in subcommands(command).values():
        commands.extend(_every_command(child))
    return commands


def click_command(app: typer.Typer) -> ClickCommand:
    """The click command of ``app`` with ``--version`` on it and on every command below it."""
    command = typer.main.get_command(app)
    (version,) = declared_parameters(_version_option)
    for each in _every_command(command):
        if not any("--version" in parameter.opts for parameter in each.params):
            each.params.append(version)
        if each.short_help is None and each.help:
            # The group's list shows a command's first paragraph; its docstring's line breaks
            # would break it mid-sentence there.
            each.short_help = " ".join(each.help.split("\n\n", 1)[0].split())
    return command


def command_path(command: ClickCommand, program: str, args: Sequence[str]) -> str:
    """``"calib data fetch"``: the program and the sub-commands ``args`` name (for messages)."""
    words = [program]
    for token in args:
        children = subcommands(command)
        if token not in children:
            break
        command = children[token]
        words.append(token)
    return " ".join(words)


# ------------------------------------------------------------------------------ how it ends


def one_line(exc: BaseException | str) -> str:
    """An exception's message on one line (lines joined by ``; ``; never empty)."""
    lines = [" ".join(line.split()) for line in str(exc).splitlines()]
    text = "; ".join(line for line in lines if line)
    return text or (type(exc).__name__ if isinstance(exc, BaseException) else "")


#: Operating-system errors that mean the user named a file that cannot be used.
_BAD_PATH_ERRORS = (FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError)


def error_code_and_line(exc: BaseException) -> tuple[int, str]:
    """``calib``'s exit code and line (after ``calib: ``) for an exception a command raised.

    :class:`InputError` (and a file that cannot be opened) is bad input, 2: ``error: …``;
    :class:`CalibError` a failed estimation, 1: ``failed: …``; anything else an internal error, 1.
    """
    if isinstance(exc, InputError):
        return BAD_INPUT_EXIT_CODE, f"error: {one_line(exc)}"
    if isinstance(exc, CalibError):
        return 1, f"failed: {one_line(exc)}"
    if isinstance(exc, _BAD_PATH_ERRORS):
        where = f"{exc.filename}: " if exc.filename else ""
        return BAD_INPUT_EXIT_CODE, f"error: {where}{exc.strerror or one_line(exc)}"
    return 1, (
        f"internal error: {type(exc).__name__}: {one_line(exc)} (set CALIB_DEBUG=1 for the "
        "traceback)"
    )


def warn(program: str, text: str) -> None:
    """``<program>: warning: <text>`` on stderr, on one line (warnings are never silenced by -q)."""
    print(f"{program}: warning: {one_line(text)}", file=sys.stderr)


def usage_error_line(error: _click.ClickException, program: str, path: str) -> str:
    """One line for a mistake on the command line: ``<program>: error: <what> (<path> -h for help)``."""
    message = one_line(error.format_message()).replace("Value error, ", "")
    return f"{program}: error: {message} ({path} -h for help)"


def run_app(app: typer.Typer, program: str, args: Sequence[str] | None = None) -> int:
    """Run ``app`` as ``program`` with ``args`` (default ``sys.argv[1:]``); return the exit code.

    Mistakes on the command line and Ctrl-C are handled here (one line on stderr); what the commands
    raise otherwise propagates, for the program's ``main`` to map.
    """
    arguments = list(sys.argv[1:] if args is None else args)
    command = click_command(app)
    try:
        code = command.main(args=arguments, prog_name=program, standalone_mode=False)
    except CommandInterrupted:
        print(f"{program}: interrupted", file=sys.stderr)
        return INTERRUPTED_EXIT_CODE
    except _click.exceptions.NoArgsIsHelpError as exc:
        # `calib` or `calib data` alone: the help, and click's exit code for it (2).
        help_text = exc.format_message()
        if help_text.strip():
            print(help_text, file=sys.stderr)
        return exc.exit_code
    except _click.ClickException as exc:
        path = command_path(command, program, arguments)
        print(usage_error_line(exc, program, path), file=sys.stderr)
        return exc.exit_code
    except typer.Abort:
        print(f"{program}: aborted", file=sys.stderr)
        return 1
    return code if isinstance(code, int) else 0


class App(typer.Typer):
    """A typer app whose commands are :class:`Command` unless told otherwise."""

    def command(
        self, name: str | None = None, *, cls: type[TyperCommand] | None = None, **settings: Any
    ) -> Callable[[CommandFunction], CommandFunction]:
        return super().command(name, cls=cls or Command, **settings)


def new_app(name: str, help_text: str, *, no_args_is_help: bool = True) -> App:
    """A typer app (or sub-app) in the one style: :class:`CommandGroup` and :class:`Command`,
    ``-h``, no completion."""
    return App(
        name=name,
        help=help_text,
        cls=CommandGroup,
        context_settings=CONTEXT_SETTINGS,
        no_args_is_help=no_args_is_help,
        add_completion=False,
        pretty_exceptions_enable=False,
    )
