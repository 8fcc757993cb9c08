"""Wall time of ``calib estimate`` on 2 lamps × 5-frame brackets of 24 MP DNGs, against bare decoding.

Renders the rig's scene with :mod:`calib.model.forward` (LED-B3 and FL2 through a 300 l/mm grating, 0.3 nm
per sensor pixel, colour-science's Canon 5D Mark II as the camera) into 6000 × 4000 Bayer DNG brackets
(:mod:`mocks.forward_scene`, :mod:`mocks.scene`, :mod:`mocks.dng`), then measures in fresh processes,
each twice after a warm-up (page cache), the best of the two:

The frames are stored as cameras and Adobe's DNG Converter store them, in lossless-JPEG tiles
(``--compression lossless-jpeg``, the default), so that decoding costs what it costs on a user's
files; ``--compression none`` writes uncompressed strips instead, which LibRaw merely copies (about
0.06 s per 24 MP frame), so the ratio then measures the pipeline's fixed costs against a copy.

* bare decoding: ``python -c 'import rawpy; …'`` decoding every file (``raw_image_visible``);
* ``calib estimate`` on the same files (every output, report included), with ``--json``.

Prints both wall times (whole processes, interpreter start included), their ratio (target ≤ 1.3), the
estimate's stages from its ``--json`` timings, its peak resident memory (``wait4``), and the RE of
the result against the rendering camera (for information: it depends on the basis found).

Usage::

    .venv/bin/python bench/estimate_offline.py [--data-dir DIR] [--frames 5] [--width 6000] [--height 4000]
        [--compression lossless-jpeg|none]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

RATIO_TARGET = 1.3
MEMORY_LIMIT_MB = 1500.0

_DECODE = """
import sys, time, rawpy
start = time.perf_counter()
for path in sys.argv[1:]:
    with rawpy.imread(path) as raw:
        raw.raw_image_visible.copy()
print(time.perf_counter() - start)
"""


_PROFILES = """
import sys, time
from pathlib import Path
from calib.pipeline.brackets import bracket_profiles
from calib.pipeline.inputs import LampImages
lamps = []
for group in sys.argv[1:]:
    name, kind, *files = group.split("|")
    lamps.append(LampImages(name, kind, Path("unused.csv"), tuple(Path(f) for f in files)))
start = time.perf_counter()
bracket_profiles(lamps)
print(time.perf_counter() - start)
"""


def _run(command: list[str]) -> tuple[float, float, str, float]:
    """``(wall s, peak RSS MB, stdout, CPU s)`` of one child process (its own rusage, via wait4)."""
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
    return wall, usage.ru_maxrss / 1024.0, stdout, usage.ru_utime + usage.ru_stime


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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--width", type=int, default=6000)
    parser.add_argument("--height", type=int, default=4000)
    parser.add_argument("--data-dir", type=Path, default=None, help="camera data for the basis")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--compression", choices=("lossless-jpeg", "none"), default="lossless-jpeg")
    arguments = parser.parse_args()
    executable = Path(sys.executable)
    calib = executable.with_name("calib")
    with tempfile.TemporaryDirectory(prefix="estimate-bench-") as folder:
        directory = Path(folder)
        started = time.perf_counter()
        scene = _render(
            directory, arguments.frames, arguments.width, arguments.height, arguments.compression
        )
        files = [str(path) for lamp in scene["lamps"] for path in lamp.frames]
        size_mb = sum(Path(f).stat().st_size for f in files) / 1e6
        print(
            f"wrote {len(files)} {arguments.compression} DNGs of {arguments.width}×{arguments.height} "
            f"({size_mb:.0f} MB) "
            f"in {time.perf_counter() - started:.1f} s"
        )
        command = [str(calib), "estimate"]
        for lamp in scene["lamps"]:
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
        decode_command = [str(executable), "-c", _DECODE, *files]
        _run(decode_command)  # warm the page cache (and Python's bytecode cache) alike for both
        decode_runs = [_run(decode_command) for _ in range(arguments.repeats)]
        estimate_runs = []
        for repeat in range(arguments.repeats + 1):
            out = directory / f"out-{repeat}"
            estimate_runs.append(_run([*command, "--out", str(out), "--json"]))
        estimate_runs = estimate_runs[1:]  # the first run fills the basis cache
        groups = [
            "|".join([lamp.name, lamp.kind, *map(str, lamp.frames)]) for lamp in scene["lamps"]
        ]
        profiles_s = min(
            float(_run([str(executable), "-c", _PROFILES, *groups])[2].strip())
            for _ in range(arguments.repeats)
        )
        decode_wall = min(run[0] for run in decode_runs)
        decode_loop = min(float(run[2].strip()) for run in decode_runs)
        wall, memory, stdout, cpu = min(estimate_runs, key=lambda run: run[0])
        decode_cpu = min(run[3] for run in decode_runs)
        summary = json.loads(stdout)
        from calib.core.metrics import relative_error
        from calib.core.spectra import read_multispectrum_csv

        estimated = read_multispectrum_csv(Path(summary["files"]["sensitivity"]))
        truth = scene["camera"].sensitivity.resample(estimated_grid(estimated)).values
        relative = relative_error(estimated.values, truth)
    timings = summary["timings_s"]
    inside = timings.get("total_s", math.nan)
    print(
        f"bare rawpy decoding : process {decode_wall:6.2f} s (decode loop {decode_loop:.2f} s, "
        f"{1e3 * decode_loop / len(files):.0f} ms per file)"
    )
    print(
        f"calib estimate      : process {wall:6.2f} s, peak RSS {memory:.0f} MB; pipeline "
        f"{inside:.2f} s = checks {timings.get('checks_s', 0):.2f} + decode/merge/detect/extract "
        f"{timings.get('profiles_s', 0):.2f} + estimate {timings.get('estimate_s', 0):.2f} + files "
        f"{timings.get('outputs_s', 0):.2f} + report {timings.get('report_s', 0):.2f} s; start-up "
        f"and imports {wall - inside:.2f} s"
    )
    ratio = wall / decode_wall
    print(f"ratio calib estimate / bare decoding: {ratio:.2f} (target ≤ {RATIO_TARGET})")
    print(
        f"  CPU time: calib estimate {cpu:.2f} s, bare decoding {decode_cpu:.2f} s "
        f"(ratio {cpu / decode_cpu:.2f}); load average now {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} cores"
    )
    print(
        f"  without start-up, imports and report: "
        f"{(inside - timings.get('report_s', 0)) / decode_loop:.2f} of the decode loop"
    )
    print(
        f"  decode + HDR merge + detection + extraction alone (no hashing, no estimate): "
        f"{profiles_s:.2f} s = {profiles_s / decode_loop:.2f} of the decode loop"
    )
    print(
        f"peak memory ≤ {MEMORY_LIMIT_MB:.0f} MB: {'OK' if memory <= MEMORY_LIMIT_MB else 'OVER'}"
    )
    print(
        f"RE against the rendering camera {scene['camera'].name}: {relative:.4f} (mapping RE "
        f"estimate {summary['mapping_re_estimate']:.2e}; basis: {'--data-dir' if arguments.data_dir else 'default'})"
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
