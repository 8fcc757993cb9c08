"""``calib estimate``: standalone offline estimation from RAW brackets (or profiles) and lamp spectra.

See :data:`calib.cli.estimate_args.USAGE` for the options. Exit codes: 0 ok, 2 bad input (the reason on
one line on stderr, naming the file, field or option), 1 internal error (``CALIB_DEBUG=1`` shows the
traceback). With ``--json`` a summary (or the error) is printed as one JSON object on stdout.
"""

from __future__ import annotations

import json
import os
import sys
import traceback
from collections.abc import Mapping, Sequence
from typing import Any, TextIO

import typer

from calib.cli.estimate_args import USAGE, EstimateArguments, parse_estimate_arguments
from calib.core.errors import CalibError, InputError
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import format_re
from calib.core.result import json_safe
from calib.pipeline.estimate import OfflineSettings
from calib.pipeline.outputs import check_out_dir
from calib.pipeline.progress import RichFrameProgress
from calib.pipeline.run import OfflineOutcome, run_offline


def summary(outcome: OfflineOutcome) -> dict[str, Any]:
    """The ``--json`` summary of an :class:`calib.pipeline.OfflineOutcome`."""
    estimate = outcome.estimate
    result = estimate.result
    mapping = result.mapping
    mapping_record: dict[str, Any] | None = None
    if isinstance(mapping, QuadraticMapping):
        mapping_record = {"a": mapping.a, "b": mapping.b, "c": mapping.c, "method": mapping.method}
    elif mapping is not None:
        mapping_record = dict(mapping.to_dict())
    record: dict[str, Any] = json_safe(
        {
            "status": "ok",
            "method": result.method,
            "method_choice": result.diagnostics.get("method_choice"),
            "out_dir": str(outcome.files["result"].parent),
            "files": {key: str(path) for key, path in outcome.files.items() if ":" not in key},
            "camera": estimate.provenance.camera.get("camera"),
            "lamps": [{"name": obs.name, "kind": obs.kind} for obs in estimate.observations],
            "mapping": mapping_record,
            "mapping_re_estimate": result.mapping_re_estimate,
            "reduced_chi2": result.diagnostics.get("reduced_chi2"),
            "uncertainty": result.sensitivity_sigma is not None,
            "warnings": list(estimate.warnings),
            "timings_s": dict(outcome.timings),
        }
    )
    return record


def _print_summary(outcome: OfflineOutcome, stream: TextIO) -> None:
    record = summary(outcome)
    lamps = ", ".join(f"{lamp['name']} ({lamp['kind']})" for lamp in record["lamps"])
    print(f"estimate: {record['method']} from {lamps}", file=stream)
    if record["method_choice"]:
        print(
            f"method: auto chose {record['method']}: {record['method_choice']['reason']}",
            file=stream,
        )
    if record["camera"]:
        print(f"camera: {record['camera']}", file=stream)
    mapping = record["mapping"]
    if mapping and "a" in mapping:
        line = (
            f"mapping: λ = {mapping['a']:.4g} p² {mapping['b']:+.5g} p {mapping['c']:+.5g} nm "
            f"({mapping['method']})"
        )
        if record["mapping_re_estimate"] is not None:
            line += f", mapping RE estimate {format_re(record['mapping_re_estimate'])}"
        print(line, file=stream)
    for key in (
        "sensitivity",
        "result",
        "report",
        "camera_json",
        "dcamprof",
        "vkdt",
        "dcp",
        "icc",
        "grating",
    ):
        if key in record["files"]:
            print(f"{key:>11}: {record['files'][key]}", file=stream)


def run(argv: Sequence[str], *, stdout: TextIO | None = None, stderr: TextIO | None = None) -> int:
    """Run ``calib estimate`` with ``argv`` (without the command name); return the exit code."""
    out = stdout or sys.stdout
    err = stderr or sys.stderr
    json_output = "--json" in argv
    command_line = ("calib", "estimate", *argv)
    try:
        arguments = parse_estimate_arguments(argv)
        if arguments.show_help:
            print(USAGE, file=out, end="")
            return 0
        outcome = _estimate(arguments, command_line, err)
    except InputError as exc:
        return _fail(exc, 2, json_output, out, err)
    except CalibError as exc:
        return _fail(exc, 1, json_output, out, err)
    except KeyboardInterrupt:
        print("calib estimate: interrupted", file=err)
        return 130
    except Exception as exc:
        if os.environ.get("CALIB_DEBUG"):
            traceback.print_exc(file=err)
        return _fail(exc, 1, json_output, out, err, internal=True)
    for warning in outcome.estimate.warnings:
        print(f"calib estimate: warning: {warning}", file=err)
    if arguments.json_output:
        print(json.dumps(summary(outcome), allow_nan=False), file=out)
    elif not arguments.quiet:
        _print_summary(outcome, out)
    return 0


def _estimate(
    arguments: EstimateArguments, command_line: tuple[str, ...], err: TextIO
) -> OfflineOutcome:
    assert arguments.out_dir is not None
    check_out_dir(arguments.out_dir, arguments.force)
    settings = OfflineSettings(
        method=arguments.method,
        method_options=arguments.method_options,
        grid=arguments.grid,
        mapping_lamp=arguments.mapping_lamp,
        data_dir=arguments.data_dir,
        grating=arguments.grating,
        command_line=command_line,
    )
    if arguments.quiet or not RichFrameProgress.wanted(err):
        return run_offline(arguments.lamps, arguments.out_dir, settings)
    with RichFrameProgress(err) as progress:
        return run_offline(arguments.lamps, arguments.out_dir, settings, progress=progress)


def _fail(
    exc: BaseException,
    code: int,
    json_output: bool,
    out: TextIO,
    err: TextIO,
    *,
    internal: bool = False,
) -> int:
    message = " ".join(str(exc).split()) or type(exc).__name__
    if internal:
        message = (
            f"internal error: {type(exc).__name__}: {message} (set CALIB_DEBUG=1 for the traceback)"
        )
    kind = "error" if code == 2 else "failed"
    print(f"calib estimate: {kind}: {message}", file=err)
    if json_output:
        record: Mapping[str, Any] = {
            "status": "error",
            "exit_code": code,
            "error": message,
            "source": getattr(exc, "source", None),
        }
        print(json.dumps(record), file=out)
    return code


def register(app: typer.Typer) -> None:
    """Add ``calib estimate`` to the ``calib`` app (arguments parsed by :mod:`estimate_args`)."""

    @app.command(
        "estimate",
        context_settings={
            "allow_extra_args": True,
            "ignore_unknown_options": True,
            "help_option_names": [],
        },
        add_help_option=False,
        help="Estimate a camera's sensitivity from RAW brackets (or profiles) and lamp spectra "
        "(calib estimate --help for the options).",
    )
    def estimate_command(ctx: typer.Context) -> None:
        raise typer.Exit(run(list(ctx.args)))
