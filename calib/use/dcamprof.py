"""DCP and ICC camera profiles through dcamprof, when it is installed (run as a program).

dcamprof (GPL-3, Anders Torger; not bundled, not linked: run as a separate program found on
``PATH`` or given) turns the SSF JSON (:mod:`calib.core.formats.dcamprof`) into profiles the way
its documentation does it:

1. ``dcamprof make-target -c SSF.json -p cc24 target.ti3`` — the ColorChecker as this camera sees it;
2. ``dcamprof make-profile -c SSF.json -i StdA target.ti3 profile-StdA.json`` and the same with
   ``-i D65`` — a profile per calibration illuminant;
3. ``dcamprof make-dcp -n NAME -d DESCRIPTION profile-StdA.json profile-D65.json NAME.dcp`` — a
   dual-illuminant DCP (tungsten first, as dcamprof requires), for Adobe's raw converters and
   RawTherapee; NAME must be the raw converter's make and model;
4. ``dcamprof make-icc -n NAME profile-D65.json NAME.icc`` — an ICC input profile.

Each step is a subprocess with a timeout; a failure raises :class:`DcamprofError` with dcamprof's
last line of output. :func:`find_dcamprof` returns ``None`` when the program is absent: the caller
then says so and skips the profiles.
"""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from calib.core.errors import CalibError, InputError

#: Seconds one dcamprof step may take.
STEP_TIMEOUT_S = 300.0
DCAMPROF = "dcamprof"


class DcamprofError(CalibError):
    """dcamprof failed (the message names the step and repeats dcamprof's own last line)."""


@dataclass(frozen=True)
class DcamprofProfiles:
    """What the dcamprof route wrote.

    Attributes
    ----------
    dcp, icc
        The profiles.
    intermediate
        The target and the per-illuminant profile JSONs (kept: they are dcamprof's own reports).
    commands
        Every command run, in order.
    """

    dcp: Path
    icc: Path
    intermediate: tuple[Path, ...]
    commands: tuple[tuple[str, ...], ...]


def find_dcamprof(executable: str | Path | None = None) -> Path | None:
    """The dcamprof program: ``executable`` if given (must exist), else ``dcamprof`` on ``PATH``.

    Raises
    ------
    InputError
        When ``executable`` is given but is not an executable file.
    """
    if executable is not None:
        path = Path(executable)
        found = shutil.which(str(path))
        if found is None:
            raise InputError("not an executable program", source=str(executable))
        return Path(found)
    found = shutil.which(DCAMPROF)
    return None if found is None else Path(found)


def _run(command: Sequence[str], step: str) -> None:
    try:
        completed = subprocess.run(
            list(command), capture_output=True, text=True, timeout=STEP_TIMEOUT_S, check=False
        )
    except subprocess.TimeoutExpired:
        raise DcamprofError(f"dcamprof {step} took longer than {STEP_TIMEOUT_S:g} s") from None
    except OSError as exc:
        raise DcamprofError(f"dcamprof {step} could not be started: {exc.strerror}") from None
    if completed.returncode != 0:
        output = (completed.stderr or completed.stdout).strip().splitlines()
        last = output[-1] if output else "no output"
        raise DcamprofError(f"dcamprof {step} failed (exit {completed.returncode}): {last}")


def make_profiles(
    ssf_json: Path,
    camera_name: str,
    out_dir: Path,
    *,
    executable: Path,
    description: str = "spectral-rig: from measured spectral sensitivities",
) -> DcamprofProfiles:
    """Run the four dcamprof steps of the module docstring; write into ``out_dir``.

    Parameters
    ----------
    ssf_json
        The camera's dcamprof SSF JSON.
    camera_name
        The make and model the raw converters use (the DCP's unique camera name).
    out_dir
        Created if missing; receives ``target.ti3``, ``profile-StdA.json``, ``profile-D65.json``,
        ``<camera_name>.dcp`` and ``<camera_name>.icc``.
    executable
        The dcamprof program (:func:`find_dcamprof`).

    Raises
    ------
    DcamprofError
        A step failed or did not write its file.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    program = str(executable)
    target = out_dir / "target.ti3"
    profiles = {ill: out_dir / f"profile-{ill}.json" for ill in ("StdA", "D65")}
    stem = camera_name.replace("/", "_").strip() or "camera"
    dcp, icc = out_dir / f"{stem}.dcp", out_dir / f"{stem}.icc"
    commands: list[tuple[str, ...]] = [
        ("make-target", "-c", str(ssf_json), "-p", "cc24", str(target)),
        *(
            ("make-profile", "-c", str(ssf_json), "-i", ill, str(target), str(path))
            for ill, path in profiles.items()
        ),
        (
            "make-dcp",
            "-n",
            camera_name,
            "-d",
            description,
            str(profiles["StdA"]),
            str(profiles["D65"]),
            str(dcp),
        ),
        ("make-icc", "-n", camera_name, str(profiles["D65"]), str(icc)),
    ]
    for arguments in commands:
        _run([program, *arguments], arguments[0])
        written = Path(arguments[-1])
        if not written.is_file() or written.stat().st_size == 0:
            raise DcamprofError(f"dcamprof {arguments[0]} wrote no {written.name}")
    return DcamprofProfiles(
        dcp=dcp,
        icc=icc,
        intermediate=(target, *profiles.values()),
        commands=tuple((program, *arguments) for arguments in commands),
    )
