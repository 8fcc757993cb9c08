"""CPU time of ``calib estimate`` on 2 lamps × 5-frame brackets of 24 MP DNGs, against bare decoding.

Renders the rig's scene with :mod:`calib.model.forward` (LED-B3 and FL2 through a 300 l/mm grating, 0.3 nm
per sensor pixel, colour-science's Canon 5D Mark II as the camera) into 6000 × 4000 Bayer DNG brackets
(:mod:`mocks.forward_scene`, :mod:`mocks.scene`, :mod:`mocks.dng`), then runs in fresh processes, in
turn (decode, estimate, decode, estimate …) after one warm-up of each (page cache, bytecode, basis
cache):

* bare decoding: ``python -c 'import rawpy; …'`` decoding every file with LibRaw
  (``raw_image_visible``), what any tool reading these files pays at least;
* ``calib estimate`` on the same files (every output, report included), with ``--json``.

The figure is CPU time (user + system of the whole process, interpreter start included), not wall
time: on a shared machine the wall time depends on whether a second core happens to be idle (the
estimate decodes on two threads), the CPU time hardly. The ratio is taken pair by pair (a drifting
machine speed cancels) and its median printed with its spread, against the target ≤ 1.3. Wall times,
the estimate's stages (its ``--json`` timings), its peak resident memory (``wait4``) and the CPU of
decode + merge + detection + extraction alone are printed too, and the RE of the result against the
rendering camera (for information: it depends on the basis found).

The frames are stored as cameras and Adobe's DNG Converter store them, in lossless-JPEG tiles
(``--compression lossless-jpeg``, the default): the estimate then decodes only the tiles that meet
the region of interest (:mod:`calib.image.dng_tiles`). ``--compression none`` writes uncompressed
strips instead, which LibRaw merely copies (about 0.06 s per 24 MP frame), so the ratio then
measures the pipeline's fixed costs against a copy. ``--capture-dir DIR`` keeps the rendered files
(and reuses them when they are there), so other tools can time the same files.

Usage::

    .venv/bin/python bench/estimate_offline.py [--data-dir DIR] [--frames 5] [--width 6000] [--height 4000]
        [--compression lossless-jpeg|none] [--repeats 3] [--capture-dir DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

RATIO_TARGET = 1.3
MEMORY_LIMIT_MB = 1500.0

#: Prints the CPU seconds of its own decode loop (all threads).
_DECODE = """
import resource, sys, rawpy
def cpu():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime
start = cpu()
for path in sys.argv[1:]:
    with rawpy.imread(path) as raw:
        raw.raw_image_visible.copy()
print(cpu() - start)
"""

#: Prints the CPU seconds of decode + merge + detection + extraction (all threads).
_PROFILES = """
import resource, sys
from pathlib import Path
from calib.pipeline.brackets import bracket_profiles
from calib.pipeline.inputs import LampImages
def cpu():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime
lamps = []
for group in sys.argv[1:]:
    name, kind, *files = group.split("|")
    lamps.append(LampImages(name, kind, Path("unused.csv"), tuple(Path(f) for f in files)))
start = cpu()
bracket_profiles(lamps)
print(cpu() - start)
"""


@dataclass(frozen=True)
class _Run:
    """One finished child process."""

    wall_s: float
    cpu_s: float
    peak_mb: float
    stdout: str


def _run(command: list[str]) -> _Run:
    """Wall, CPU (user + system) and peak RSS of one child process (its own rusage, via wait4)."""
    start = time.perf_counter()
    with tempfile.TemporaryFile() as output:
        process = subprocess.Popen(command, stdout=output, stderr=subprocess.PIPE)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - start
        process.returncode = os.waitstatus_to_exitcode(status)
        stderr = process.stderr.read().decode() if process.stderr else ""
        output.seek(0)
        stdout = output.read().decode()
    if process.returncode != 0:
        raise RuntimeError(f"{command[:3]} failed ({process.returncode}): {stderr.strip()}")
    return _Run(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0, stdout)


def _spread(values: list[float], digits: int = 2) -> str:
    """``median (min–max)``."""
    return (
        f"{statistics.median(values):.{digits}f} "
        f"({min(values):.{digits}f}–{max(values):.{digits}f})"
    )


def _render(
    directory: Path, frames: int, width: int, height: int, compression: str
) -> dict[str, Any]:
    from calib.core.datasets import colour_science_cameras, find_camera
    from calib.core.lamp_specs import colour_lamp
    from calib.core.mapping import GratingGeometry
    from mocks.forward_scene import write_capture
    from mocks.scene import SceneLayout, SensorModel

    scale = width / 6000.0
    grating = GratingGeometry(300.0, 44.44 * scale, 4.0)  # ≈ 0.3 nm per pixel at full size
    sensor = SensorModel(height_px=height, width_px=width, cfa_pattern="RGGB")
    layout = SceneLayout(
        spot_centre_px=(600.0 * scale, height / 2 + 37.0),
        dispersion_angle_deg=1.5,
        spot_half_size_px=(8.0 * scale, 220.0 * scale),
        band_half_width_px=220.0 * scale,
    )
    camera = find_camera(colour_science_cameras(), "Canon EOS 5D Mark II")
    start, stop = (float(v) for v in grating.pixel_at([330.0, 780.0]))
    lamps = write_capture(
        directory,
        [("LED-B3", "led", colour_lamp("LED-B3")), ("FL2", "fluorescent", colour_lamp("FL2"))],
        camera.sensitivity,
        mapping=grating,
        sensor=sensor,
        layout=layout,
        exposures_s=[0.0005 * 4.0**k for k in range(frames)],
        rng=np.random.default_rng(2025),
        grating_efficiency=lambda w: 0.7 + 0.3 * np.cos(2 * np.pi * (w - 400.0) / 300.0),
        pixel_range_px=(start, stop),
        band_peak_dn_per_s=3000.0,
        direct_throughput=2.0,
        compression=compression,
    )
    return {"lamps": lamps, "camera": camera}


@dataclass(frozen=True)
class _Lamp:
    name: str
    kind: str
    frames: tuple[Path, ...]
    spectrum_csv: Path


def _capture(arguments: argparse.Namespace, directory: Path) -> list[_Lamp]:
    """The rendered lamps in ``directory`` (rendered now unless an index of them is there)."""
    index = directory / "lamps.json"
    if index.exists():
        print(f"reusing the capture in {directory}")
    else:
        started = time.perf_counter()
        scene = _render(
            directory, arguments.frames, arguments.width, arguments.height, arguments.compression
        )
        groups = [
            {
                "name": lamp.name,
                "kind": lamp.kind,
                "frames": [str(path) for path in lamp.frames],
                "spectrum_csv": str(lamp.spectrum_csv),
            }
            for lamp in scene["lamps"]
        ]
        index.write_text(json.dumps(groups, indent=1))
        files = [path for group in groups for path in group["frames"]]
        size_mb = sum(Path(f).stat().st_size for f in files) / 1e6
        print(
            f"wrote {len(files)} {arguments.compression} DNGs of {arguments.width}×"
            f"{arguments.height} ({size_mb:.0f} MB) in {time.perf_counter() - started:.1f} s"
        )
    return [
        _Lamp(
            group["name"],
            group["kind"],
            tuple(Path(f) for f in group["frames"]),
            Path(group["spectrum_csv"]),
        )
        for group in json.loads(index.read_text())
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--width", type=int, default=6000)
    parser.add_argument("--height", type=int, default=4000)
    parser.add_argument("--data-dir", type=Path, default=None, help="camera data for the basis")
    parser.add_argument("--repeats", type=int, default=3, help="pairs of runs timed")
    parser.add_argument("--compression", choices=("lossless-jpeg", "none"), default="lossless-jpeg")
    parser.add_argument("--capture-dir", type=Path, default=None, help="keep / reuse the DNGs here")
    arguments = parser.parse_args()
    executable = Path(sys.executable)
    calib = executable.with_name("calib")
    with tempfile.TemporaryDirectory(prefix="estimate-bench-") as folder:
        directory = arguments.capture_dir or Path(folder)
        directory.mkdir(parents=True, exist_ok=True)
        lamps = _capture(arguments, directory)
        files = [str(path) for lamp in lamps for path in lamp.frames]
        command = [str(calib), "estimate"]
        for lamp in lamps:
            command += [
                "--lamp",
                lamp.name,
                "--kind",
                lamp.kind,
                "--images",
                *map(str, lamp.frames),
            ]
            command += ["--spectrum", str(lamp.spectrum_csv)]
        if arguments.data_dir is not None:
            command += ["--data-dir", str(arguments.data_dir)]
        out = Path(folder) / "out"
        command += ["--out", str(out), "--force", "--json"]
        decode_command = [str(executable), "-c", _DECODE, *files]
        _run(decode_command)  # warm the page cache and Python's bytecode cache for both
        _run(command)  # … and the basis cache
        decode_runs: list[_Run] = []
        estimate_runs: list[_Run] = []
        for _ in range(arguments.repeats):  # in turn, so a drift of the machine's speed cancels
            decode_runs.append(_run(decode_command))
            estimate_runs.append(_run(command))
        groups = ["|".join([lamp.name, lamp.kind, *map(str, lamp.frames)]) for lamp in lamps]
        profiles_cpu = [
            float(_run([str(executable), "-c", _PROFILES, *groups]).stdout.strip())
            for _ in range(arguments.repeats)
        ]
        summary = json.loads(estimate_runs[-1].stdout)
        from calib.core.datasets import colour_science_cameras, find_camera
        from calib.core.formats.rgb_csv import read_camera_csv
        from calib.core.metrics import relative_error

        camera = find_camera(colour_science_cameras(), "Canon EOS 5D Mark II")
        estimated = read_camera_csv(Path(summary["files"]["sensitivity"]))
        truth = camera.sensitivity.resample(estimated_grid(estimated)).values
        relative = relative_error(estimated.values, truth)
    cpu_ratios = [e.cpu_s / d.cpu_s for e, d in zip(estimate_runs, decode_runs, strict=True)]
    wall_ratios = [e.wall_s / d.wall_s for e, d in zip(estimate_runs, decode_runs, strict=True)]
    decode_loop = [float(run.stdout.strip()) for run in decode_runs]
    memory = max(run.peak_mb for run in estimate_runs)
    timings = summary["timings_s"]
    inside = timings.get("total_s", math.nan)
    n = len(files)
    print(
        f"{arguments.repeats} pairs of runs, median (min–max); CPU = user + system, whole process"
    )
    print(
        f"bare rawpy decoding : CPU {_spread([r.cpu_s for r in decode_runs])} s "
        f"(decode loop {_spread(decode_loop)} s, {1e3 * statistics.median(decode_loop) / n:.0f} "
        f"ms per file); wall {_spread([r.wall_s for r in decode_runs])} s"
    )
    print(
        f"calib estimate      : CPU {_spread([r.cpu_s for r in estimate_runs])} s; wall "
        f"{_spread([r.wall_s for r in estimate_runs])} s; peak RSS {memory:.0f} MB"
    )
    print(
        f"  stages (wall, last run): checks {timings.get('checks_s', 0):.2f} + "
        f"decode/merge/detect/extract {timings.get('profiles_s', 0):.2f} + estimate "
        f"{timings.get('estimate_s', 0):.2f} + files {timings.get('outputs_s', 0):.2f} + report "
        f"{timings.get('report_s', 0):.2f} = {inside:.2f} s"
    )
    ratio = statistics.median(cpu_ratios)
    print(
        f"CPU ratio calib estimate / bare decoding: {_spread(cpu_ratios)} (target ≤ {RATIO_TARGET})"
    )
    print(f"  wall ratio, for information: {_spread(wall_ratios)}")
    print(
        f"  decode + HDR merge + detection + extraction alone: CPU {_spread(profiles_cpu)} s = "
        f"{statistics.median(profiles_cpu) / statistics.median(decode_loop):.2f} of the decode loop"
    )
    print(f"  load average now {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(
        f"peak memory ≤ {MEMORY_LIMIT_MB:.0f} MB: {'OK' if memory <= MEMORY_LIMIT_MB else 'OVER'}"
    )
    print(
        f"RE against the rendering camera {camera.name}: {relative:.4f} (mapping RE "
        f"estimate {summary['mapping_re_estimate']:.2e}; basis: "
        f"{'--data-dir' if arguments.data_dir else 'default'})"
    )
    return 0 if ratio <= RATIO_TARGET and memory <= MEMORY_LIMIT_MB else 1


def estimated_grid(curves: Any) -> Any:
    from calib.core.spectra import WavelengthGrid

    wavelength = curves.wavelength_nm
    return WavelengthGrid(
        float(wavelength[0]), float(wavelength[-1]), float(wavelength[1] - wavelength[0])
    )


if __name__ == "__main__":
    sys.exit(main())
