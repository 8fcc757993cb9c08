"""Peak memory and wall time of merging a 10 × 24 MP RAW bracket, against bare rawpy decoding.

Renders the rig's scene (direct spot + first-order band) on a 6000 × 4000 Bayer sensor, writes a
bracket of DNG files to a temporary directory, then measures in fresh processes (so each peak RSS
belongs to one job):

* bare decoding: ``rawpy.imread`` and a copy of ``raw_image_visible`` for every file;
* the merge: :func:`calib.image.hdr.merge_bracket` on the same files (noise model estimated).

Target (issue 4): peak RSS of the merge ≤ 1.5 GB. Exit status 1 when it is missed.

Usage::

    .venv/bin/python bench/hdr_memory.py [--frames 10] [--width 6000] [--height 4000]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

MEMORY_LIMIT_MB = 1500.0


def _peak_rss_mb() -> float:
    """This process's peak resident set (VmHWM; getrusage's maxrss survives exec on Linux)."""
    status = Path("/proc/self/status")
    if status.exists():
        for line in status.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _decode(files: list[Path]) -> dict[str, float]:
    import rawpy

    baseline, cpu = _peak_rss_mb(), _cpu_s()
    start = time.perf_counter()
    for path in files:
        with rawpy.imread(str(path)) as raw:
            raw.raw_image_visible.copy()
    return {
        "wall_s": time.perf_counter() - start,
        "cpu_s": _cpu_s() - cpu,
        "peak_rss_mb": _peak_rss_mb(),
        "baseline_mb": baseline,
    }


def _merge(files: list[Path]) -> dict[str, float]:
    from calib.image.hdr import merge_bracket

    baseline, cpu = _peak_rss_mb(), _cpu_s()
    start = time.perf_counter()
    image = merge_bracket(files)
    wall = time.perf_counter() - start
    return {
        "wall_s": wall,
        "cpu_s": _cpu_s() - cpu,
        "peak_rss_mb": _peak_rss_mb(),
        "baseline_mb": baseline,
        "saturated_fraction": float(image.saturated.mean()),
    }


def _write_bracket(directory: Path, frames: int, width: int, height: int) -> list[Path]:
    from mocks.scene import (
        SceneLayout,
        SensorModel,
        render_mosaic_radiance,
        smooth_signal,
        write_bracket,
    )

    sensor = SensorModel(height_px=height, width_px=width, cfa_pattern="RGGB")
    scale = width / 6000.0
    signal = smooth_signal(
        start_px=400 * scale,
        stop_px=3200 * scale,
        peak_dn_per_s=(4000, 5000, 3000),
        direct_rgb=(4e8, 6e8, 3e8),
    )
    layout = SceneLayout(
        spot_centre_px=(1200 * scale, height / 2),
        dispersion_angle_deg=4.0,
        spot_half_size_px=(15 * scale, 220 * scale),
        band_half_width_px=220 * scale,
        minus_first_strength=0.0,
    )
    mosaic = render_mosaic_radiance(layout, signal, sensor)
    exposures = [0.001 * 2.0**k for k in range(frames)]
    return write_bracket(directory, mosaic, sensor, exposures, np.random.default_rng(2025))


def _run_child(mode: str, directory: Path) -> dict[str, float]:
    output = subprocess.run(
        [sys.executable, __file__, f"--{mode}", str(directory)],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    result: dict[str, float] = json.loads(output.strip().splitlines()[-1])
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--width", type=int, default=6000)
    parser.add_argument("--height", type=int, default=4000)
    parser.add_argument("--decode", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--merge", type=Path, help=argparse.SUPPRESS)
    arguments = parser.parse_args()
    for mode, job in (("decode", _decode), ("merge", _merge)):
        directory = getattr(arguments, mode)
        if directory is not None:
            print(json.dumps(job(sorted(directory.glob("*.dng")))))
            return 0

    with tempfile.TemporaryDirectory(prefix="hdr-bench-") as folder:
        directory = Path(folder)
        start = time.perf_counter()
        files = _write_bracket(directory, arguments.frames, arguments.width, arguments.height)
        size_mb = sum(path.stat().st_size for path in files) / 1e6
        print(
            f"wrote {len(files)} DNGs of {arguments.width}×{arguments.height} "
            f"({size_mb:.0f} MB) in {time.perf_counter() - start:.1f} s"
        )
        _run_child("decode", directory)  # warm the page cache the same way for both
        decode = _run_child("decode", directory)
        merge = _run_child("merge", directory)
    for name, result in (("bare rawpy decoding", decode), ("merge_bracket", merge)):
        print(
            f"{name:20s}: wall {result['wall_s']:6.2f} s  CPU {result['cpu_s']:6.2f} s  "
            f"peak RSS {result['peak_rss_mb']:6.0f} MB (after imports {result['baseline_mb']:.0f} MB)"
        )
    print(
        f"merge / decode: wall {merge['wall_s'] / decode['wall_s']:.2f}, "
        f"CPU {merge['cpu_s'] / decode['cpu_s']:.2f} (the merge decodes on background threads)"
    )
    verdict = "OK" if merge["peak_rss_mb"] <= MEMORY_LIMIT_MB else "OVER"
    print(f"peak memory target ≤ {MEMORY_LIMIT_MB:.0f} MB: {verdict}")
    return 0 if verdict == "OK" else 1


if __name__ == "__main__":
    sys.exit(main())
