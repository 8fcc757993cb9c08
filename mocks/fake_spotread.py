#!/usr/bin/env python3
"""A stand-in for ArgyllCMS's ``spotread`` that answers as the real one does.

Run as an executable (``python mocks/fake_spotread.py -a -s -N -O reading.sp``) on a terminal.
It parses spotread's options, prints what spotread 2.x/3.x prints on its terminal
(``spectro/spotread.c``, ``spectro/instappsup.c``: the measuring prompt, the spectrum, the result
lines, and its errors word for word), reads single keys from its terminal in raw mode where
spotread waits for one, and writes the CGATS ``.sp`` file spotread writes (``xicc/xspect.c``).

What it "measures" comes from a scene file named by ``$FAKE_SPOTREAD_SCENE`` (JSON), written by
whoever plays the light: the twin (:mod:`mocks.bench.station`, the instrument's readings of its
lamps) or a test:

``instruments``
    How many instruments spotread finds (0: ``No instrument at port 1``).
``spectra``
    ``{"standard": {"start_nm", "end_nm", "values"}, "high_resolution": {…}}``: the reading in
    each mode (``-H`` picks the second), mW/(m²·nm).
``fault``
    ``null`` or one of :data:`FAULTS`: how this run goes wrong.
``delay_s``
    Seconds the measurement takes.

It imports only the standard library, so a run costs a Python start-up and no more.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

try:
    import termios
except ImportError:  # pragma: no cover - Windows has no terminals of this kind
    termios = None  # type: ignore[assignment]

#: The faults a scene may ask for.
FAULTS = (
    "no_instrument",
    "comms",
    "init",
    "no_ambient",
    "needs_calibration",
    "misread",
    "comms_problem",
    "wrong_position",
    "not_spectral",
    "fatal",
    "hang",
    "garbled_file",
)
SCENE_VARIABLE = "FAKE_SPOTREAD_SCENE"
VERSION = "2.3.1"
PROMPT = (
    "\nPlace instrument on spot to be measured,\n"
    "and hit [A-Z] to read white and setup FWA compensation (keyed to letter)\n"
    "[a-z] to read and make FWA compensated reading from keyed reference\n"
    "'r' to set reference, 's' to save spectrum,\n"
    "'f' to report cal. refresh rate, 'F' to measure refresh rate\n"
    "'h' to toggle high res., 'k' to do a calibration\n"
    "Hit ESC or Q to exit, instrument switch or any other key to take a reading: "
)
CALIBRATION_PROMPT = (
    "\nSpot read needs a calibration before continuing\n"
    "Place cap on the instrument, or place on a dark surface,\n"
    "or place on the calibration reference,\n"
    " and then hit any key to continue,\n"
    " or hit Esc or Q to abort: "
)


def say(text: str) -> None:
    sys.stdout.write(text)
    sys.stdout.flush()


def error(text: str) -> None:
    """Argyll's ``error()``: ``spotread: Error - …`` on stderr, exit status 1."""
    sys.stdout.flush()
    sys.stderr.write(f"spotread: Error - {text}\n")
    sys.stderr.flush()
    raise SystemExit(1)


def usage(diagnostic: str, instruments: int) -> None:
    """spotread's usage screen (abridged) with a diagnostic; exit status 1."""
    lines = [f"Measure spot values, Version {VERSION}"]
    lines.append("Author: Graeme W. Gill, licensed under the GPL Version 2 or later")
    lines.append(f"Diagnostic: {diagnostic}")
    lines.append("usage: spotread [-options] [logfile]")
    lines.append(" -c listno            Set instrument port from the following list (default 1)")
    if instruments:
        lines += [
            f"    {i + 1} = 'usb:/bus1/dev{i + 4}/ (X-Rite i1 Pro 2)'" for i in range(instruments)
        ]
    else:
        lines.append("    ** No ports found **")
    sys.stderr.write("\n".join(lines) + "\n")
    raise SystemExit(1)


def key() -> str:
    """One key from the terminal, as spotread's ``next_con_char`` takes it: canonical mode and
    echo off *now* (a key typed before the prompt is kept, not flushed), one byte, then back."""
    if termios is None or not os.isatty(0):
        return sys.stdin.read(1)
    saved = termios.tcgetattr(0)
    changed = list(saved)
    changed[3] = saved[3] & ~(termios.ICANON | termios.ECHO)
    try:
        termios.tcsetattr(0, termios.TCSANOW, changed)
        return os.read(0, 1).decode("latin-1")
    finally:
        termios.tcsetattr(0, termios.TCSANOW, saved)


def gives_up(pressed: str) -> bool:
    return pressed in ("\x1b", "\x03", "q", "Q")


def wyman_xyz(wavelength_nm: float) -> tuple[float, float, float]:
    """CIE 1931 colour matching functions, multi-lobe Gaussian fit (Wyman, Sloan, Shirley 2013)."""

    def g(x: float, mu: float, s1: float, s2: float) -> float:
        return math.exp(-0.5 * ((x - mu) / (s1 if x < mu else s2)) ** 2)

    x = 1.056 * g(wavelength_nm, 599.8, 37.9, 31.0) + 0.362 * g(wavelength_nm, 442.0, 16.0, 26.7)
    x -= 0.065 * g(wavelength_nm, 501.1, 20.4, 26.2)
    y = 0.821 * g(wavelength_nm, 568.8, 46.9, 40.5) + 0.286 * g(wavelength_nm, 530.9, 16.3, 31.1)
    z = 1.217 * g(wavelength_nm, 437.0, 11.8, 36.0) + 0.681 * g(wavelength_nm, 459.0, 26.0, 13.8)
    return x, y, z


def results(start_nm: float, end_nm: float, values: list[float]) -> str:
    """The result lines spotread prints after an ambient reading."""
    count = len(values)
    step = (end_nm - start_nm) / (count - 1)
    xyz = [0.0, 0.0, 0.0]
    for index, value in enumerate(values):
        for axis, weight in enumerate(wyman_xyz(start_nm + index * step)):
            xyz[axis] += 0.683 * value * weight * step  # lm/W, with values in mW/(m²·nm)
    total = sum(xyz) or 1.0
    x, y = xyz[0] / total, xyz[1] / total
    n = (x - 0.3320) / (0.1858 - y) if y != 0.1858 else 0.0
    cct = 449.0 * n**3 + 3525.0 * n**2 + 6823.3 * n + 5520.33  # McCamy
    white = (96.42, 100.0, 82.49)

    def f(t: float) -> float:
        return t ** (1 / 3) if t > 216 / 24389 else (24389 / 27 * t + 16) / 116

    fx, fy, fz = (f(v / w) for v, w in zip(xyz, white, strict=True))
    lab = (116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz))
    lux = xyz[1]
    ev = math.log(lux / 2.5) / math.log(2.0) if lux > 0 else 0.0
    return (
        f"\n Result is XYZ: {xyz[0]:f} {xyz[1]:f} {xyz[2]:f}, D50 Lab: {lab[0]:f} {lab[1]:f} "
        f"{lab[2]:f}\n"
        f" Ambient = {lux:.1f} Lux, CCT = {cct:.0f}K (Duv 0.0000)\n"
        f" Suggested EV @ ISO100 for {lux:.1f} Lux incident light = {ev:.1f}\n"
        f" Closest Planckian temperature = {cct:.0f}K (DE2K 0.0)\n"
        f" Closest Daylight temperature  = {cct:.0f}K (DE2K 0.0)\n"
    )


def sp_text(start_nm: float, end_nm: float, values: list[float]) -> str:
    """The ``.sp`` file ``write_xspect`` writes for an ambient reading."""
    count = len(values)
    step = (end_nm - start_nm) / (count - 1)
    names = [f"SPEC_{int(start_nm + i * step + 0.5):03d}" for i in range(count)]
    lines = [
        "SPECT",
        "",
        'DESCRIPTOR "Argyll Spectral power/reflectance information"',
        "",
        'ORIGINATOR "Argyll CMS"',
        "",
        'CREATED "Wed Nov 26 00:00:00 2026"',
        'KEYWORD "MEAS_TYPE"',
        'MEAS_TYPE "AMBIENT"',
        'KEYWORD "SPECTRAL_BANDS"',
        f'SPECTRAL_BANDS "{count}"',
        'KEYWORD "SPECTRAL_START_NM"',
        f'SPECTRAL_START_NM "{start_nm:f}"',
        'KEYWORD "SPECTRAL_END_NM"',
        f'SPECTRAL_END_NM "{end_nm:f}"',
        'KEYWORD "SPECTRAL_NORM"',
        'SPECTRAL_NORM "1.000000"',
        "",
        *[f'KEYWORD "{name}"' for name in names],
        f"NUMBER_OF_FIELDS {count}",
        "BEGIN_DATA_FORMAT",
        " ".join(names),
        "END_DATA_FORMAT",
        "",
        "NUMBER_OF_SETS 1",
        "BEGIN_DATA",
        " ".join(f"{value:.6g}" for value in values) + " ",
        "END_DATA",
        "",
    ]
    return "\n".join(lines)


def parse(argv: list[str]) -> dict[str, object]:
    """spotread's options that matter here; others are accepted and ignored, as spotread does."""
    options: dict[str, object] = {"ambient": False, "spectrum": False, "port": 1}
    options.update({"high_resolution": False, "once": False, "output": None, "nocal": False})
    index = 0
    while index < len(argv):
        argument = argv[index]
        if argument in ("-?", "--", "-h") or not argument.startswith("-"):
            usage("Usage requested", 1)
        flag = argument[1:2]
        if flag == "a":
            options["ambient"] = True
        elif flag == "s":
            options["spectrum"] = True
        elif flag == "N":
            options["nocal"] = True
        elif flag == "H":
            options["high_resolution"] = True
        elif flag == "c":
            value = argument[2:] or (argv[index + 1] if index + 1 < len(argv) else "")
            if not argument[2:]:
                index += 1
            if not value.isdigit():
                usage("Paramater expected following -c", 1)
            options["port"] = int(value)
        elif flag == "O":
            options["once"] = True
            if index + 1 < len(argv) and not argv[index + 1].startswith("-"):
                options["output"] = argv[index + 1]
                index += 1
        index += 1
    return options


def measure(scene: dict[str, object], options: dict[str, object]) -> None:
    """One reading as spotread -O takes it, then the file; raises SystemExit when it ends."""
    fault = scene.get("fault")
    spectra = scene.get("spectra") or {}
    assert isinstance(spectra, dict)
    # -H is honoured "if available": a model without high-resolution bands reads its standard ones.
    mode = (
        "high_resolution"
        if options["high_resolution"] and "high_resolution" in spectra
        else "standard"
    )
    while True:
        if fault == "needs_calibration":
            say(CALIBRATION_PROMPT)
            if gives_up(key()):
                say("\n\nSpot read got abort or error from calibration\n")
                raise SystemExit(0)
            say("\nCalibration complete\n")
            fault = None
        say(PROMPT)
        time.sleep(float(str(scene.get("delay_s") or 0.0)))
        if fault == "hang":
            while True:
                time.sleep(1.0)
        if fault == "wrong_position":
            say("\n\nSpot read failed due to the sensor being in the wrong position\n")
            say("(Sensor is in wrong position)\n")
            time.sleep(0.05)
            continue
        if fault in ("misread", "comms_problem"):
            if fault == "misread":
                say("\n\nSpot read failed due to misread (Reading is saturated)\n")
            else:
                say("\n\nSpot read failed due to communication problem.\n")
            say("Hit Esc or Q to give up, any other key to retry:")
            pressed = key()
            say("\n")
            if gives_up(pressed):
                raise SystemExit(0)
            fault = None
            continue
        if fault == "fatal":
            say("\n\nGot fatal error 'Hardware Failure' (Lamp failure)\n")
            raise SystemExit(0)
        if fault == "not_spectral" or mode not in spectra:
            error("Print: Instrument didn't return spectral data")
        break
    reading = spectra[mode]
    assert isinstance(reading, dict)
    start_nm, end_nm = float(reading["start_nm"]), float(reading["end_nm"])
    values = [float(v) for v in reading["values"]]
    if options["spectrum"]:
        peak = max(range(len(values)), key=lambda i: values[i])
        step = (end_nm - start_nm) / (len(values) - 1)
        say(f"Spectrum from {start_nm:.3f} to {end_nm:.3f} nm in {len(values)} steps\n")
        say(", ".join(f"{value:g}" for value in values) + "\n")
        say(f"Peak value {values[peak]:f} at (aprox.) {start_nm + peak * step:.1f} nm\n")
    say(results(start_nm, end_nm, values))
    output = options["output"]
    if isinstance(output, str):
        text = sp_text(start_nm, end_nm, values)
        if fault == "garbled_file":
            text = text.replace("BEGIN_DATA\n", "BEGIN_DATA\n\x91\x92 ", 1)
        try:
            Path(output).write_text(text, encoding="utf-8")
        except OSError:
            say(f"Writing file '{output}' failed\n")
        else:
            say(f"Writing file '{output}' succeeded\n")
    raise SystemExit(0)


def main(argv: list[str]) -> None:
    options = parse(argv)
    path = os.environ.get(SCENE_VARIABLE)
    scene: dict[str, object] = {"instruments": 0}
    if path:
        scene = json.loads(Path(path).read_text(encoding="utf-8"))
    instruments = int(scene.get("instruments", 1) or 0)  # type: ignore[call-overload]
    fault = scene.get("fault")
    if fault == "no_instrument" or instruments < int(options["port"]):  # type: ignore[call-overload]
        error(f"No instrument at port {options['port']}")
    if fault == "comms":
        say(
            "Failed to initialise communications with instrument\n"
            "or wrong instrument or bad configuration!\n"
            "('Communications failure' + 'USB transaction timed out')\n"
        )
        raise SystemExit(255)
    if fault == "init":
        say("Instrument initialisation failed with 'Hardware Failure' (EEPROM checksum failed)!\n")
        raise SystemExit(255)
    if options["ambient"] and fault == "no_ambient":
        say("Requested ambient light capability,\nand instrument doesn't support it.\n")
        raise SystemExit(255)
    if not options["once"]:
        error("this stand-in only takes single readings (-O)")
    measure(scene, options)


if __name__ == "__main__":
    main(sys.argv[1:])
