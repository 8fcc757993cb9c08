"""A stand-in for the ``dcamprof`` program: checks its arguments and input files as dcamprof does
(the SSF JSON's fields, the target's and profiles' existence, the options each command takes) and
writes files of the right kind; logs every call (argv as a JSON line) to ``$FAKE_DCAMPROF_LOG``.

Run as ``python fake_dcamprof.py COMMAND …``; :func:`install` writes an executable ``dcamprof``
wrapper into a directory for ``PATH``.
"""

from __future__ import annotations

import json
import os
import stat
import sys
from pathlib import Path

ILLUMINANTS = {"StdA", "D50", "D55", "D65", "D75", "Flash", "Shade"}
PATCH_SETS = {"cc24", "ccsg", "kuopio-natural", "white"}


def fail(message: str) -> None:
    print(f"Error: {message}", file=sys.stderr)
    sys.exit(1)


def options(arguments: list[str], allowed: set[str]) -> tuple[dict[str, list[str]], list[str]]:
    found: dict[str, list[str]] = {}
    rest: list[str] = []
    index = 0
    while index < len(arguments):
        argument = arguments[index]
        if argument.startswith("-") and len(argument) == 2:
            if argument not in allowed:
                fail(f"unknown option {argument}")
            if index + 1 >= len(arguments):
                fail(f"option {argument} needs a value")
            found.setdefault(argument, []).append(arguments[index + 1])
            index += 2
        else:
            rest.append(argument)
            index += 1
    return found, rest


def check_ssf(path: str) -> None:
    try:
        document = json.loads(Path(path).read_text())  # strict: no comments accepted here
    except (OSError, json.JSONDecodeError) as exc:
        fail(f"could not parse {path}: {exc}")
    name = document.get("camera_name")
    if not isinstance(name, str) or not name:
        fail("camera_name missing")
    bands = document.get("ssf_bands")
    if not (isinstance(bands, list) and len(bands) == 3 and all(isinstance(b, int) for b in bands)):
        fail("ssf_bands must be [start, end, step] integers")
    start, end, step = bands
    if (end - start) % step:
        fail("ssf_bands does not come out even")
    count = (end - start) // step + 1
    for field in ("red_ssf", "green_ssf", "blue_ssf"):
        values = document.get(field)
        if not isinstance(values, list) or len(values) != count:
            fail(f"{field} must have {count} values")


def main(argv: list[str]) -> None:
    log = os.environ.get("FAKE_DCAMPROF_LOG")
    if log:
        with Path(log).open("a") as stream:
            stream.write(json.dumps(argv) + "\n")
    if not argv:
        fail("no command")
    command, arguments = argv[0], argv[1:]
    if command == "make-target":
        found, rest = options(arguments, {"-c", "-p", "-i", "-b"})
        if "-c" not in found or len(rest) != 1:
            fail("usage: make-target -c ssf.json -p patches out.ti3")
        check_ssf(found["-c"][0])
        if not set(found.get("-p", [])) <= PATCH_SETS:
            fail(f"unknown patch set {found.get('-p')}")
        Path(rest[0]).write_text('CTI3\nDESCRIPTOR "fake target"\n')
    elif command == "make-profile":
        found, rest = options(arguments, {"-c", "-i", "-n", "-r", "-g"})
        if len(rest) != 2:
            fail("usage: make-profile [flags] target.ti3 profile.json")
        if "-c" in found:
            check_ssf(found["-c"][0])
        if found.get("-i", ["D50"])[0] not in ILLUMINANTS:
            fail(f"unknown illuminant {found['-i'][0]}")
        target = Path(rest[0])
        if not target.is_file() or not target.read_text().startswith("CTI3"):
            fail(f"{target} is not a ti3 target")
        Path(rest[1]).write_text(
            json.dumps({"CalibrationIlluminant1": found.get("-i", ["D50"])[0]})
        )
    elif command == "make-dcp":
        found, rest = options(arguments, {"-n", "-d", "-c", "-t", "-o", "-g", "-b"})
        if not found.get("-n", [""])[0]:
            fail("make-dcp needs -n camera name")
        if not 2 <= len(rest) <= 3:
            fail("usage: make-dcp [flags] profile.json [profile2.json] out.dcp")
        for profile in rest[:-1]:
            json.loads(Path(profile).read_text())
        Path(rest[-1]).write_bytes(b"IIRC" + b"\0" * 60)
    elif command == "make-icc":
        found, rest = options(arguments, {"-n", "-c", "-p", "-t", "-f"})
        if len(rest) != 2:
            fail("usage: make-icc [flags] profile.json out.icc")
        json.loads(Path(rest[0]).read_text())
        header = bytearray(128)
        header[36:40] = b"acsp"
        Path(rest[1]).write_bytes(bytes(header))
    else:
        fail(f"unknown command {command}")


def install(directory: Path) -> Path:
    """An executable ``dcamprof`` in ``directory`` that runs this fake with this interpreter."""
    directory.mkdir(parents=True, exist_ok=True)
    program = directory / "dcamprof"
    program.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{Path(__file__).resolve()}" "$@"\n')
    program.chmod(program.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    return program


if __name__ == "__main__":
    main(sys.argv[1:])
