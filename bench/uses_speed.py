"""CPU time of the uses delivered with every estimate: the ACES IDTs, the colour-correction matrices.

Every ``calib estimate`` / ``rig estimate`` writes, beside the curves, an ACES IDT for each of
:data:`calib.use.idt.IDT_ILLUMINANTS` and a colour-correction matrix for each use illuminant
(:func:`calib.use.camera_uses`). This bench times that step on the bundled rawtoaces-data
cameras (no data directory needed): each camera as measured, and each with 3 % multiplicative
noise drawn per sample (seed 0), as an estimate's curves are less smooth than a measured camera's.

Per pass over the cameras: the CPU time (``time.process_time``, one BLAS thread) of
:func:`calib.use.camera_uses` and of its IDTs alone, per camera; the median of ``--repeats``
passes after a warm-up camera. It imports only public functions, so the same file times another
checkout (``PYTHONPATH=that/checkout python bench/uses_speed.py ...``).

    python bench/uses_speed.py [--cameras 12] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from calib.core.camera_curves import CameraCurves
from calib.core.formats.ampas import reference_cameras
from calib.use import camera_uses
from calib.use.idt import IDT_ILLUMINANTS, aces_idt

#: Multiplicative noise of the "estimate-like" copy of each camera.
NOISE = 0.03


def cameras(count: int) -> list[CameraCurves]:
    """The first ``count`` bundled cameras (by file name), each as measured and with noise."""
    rng = np.random.default_rng(0)
    found: list[CameraCurves] = []
    for reference in reference_cameras()[:count]:
        camera = reference.curves.normalised()
        noisy = camera.values * (1.0 + NOISE * rng.standard_normal(camera.values.shape))
        found += [
            camera,
            CameraCurves(camera.wavelength_nm, np.clip(noisy, 0.0, None), name="noisy"),
        ]
    return found


def one_pass(curves: list[CameraCurves]) -> tuple[float, float]:
    """CPU seconds per camera of ``camera_uses`` and of the IDTs alone."""
    start = time.process_time()
    for camera in curves:
        camera_uses(camera)
    uses = time.process_time() - start
    start = time.process_time()
    for camera in curves:
        for name in IDT_ILLUMINANTS:
            aces_idt(camera, name)
    idts = time.process_time() - start
    return uses / len(curves), idts / len(curves)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", type=int, default=12)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    curves = cameras(args.cameras)
    camera_uses(curves[0])  # warm-up: colour-science's import and its tables
    passes = [one_pass(curves) for _ in range(args.repeats)]
    uses = statistics.median(p[0] for p in passes)
    idts = statistics.median(p[1] for p in passes)
    print(
        f"{len(curves)} cameras ({args.cameras} bundled, each also with {NOISE:.0%} noise), "
        f"median of {args.repeats} passes, CPU per camera: uses {uses * 1e3:.1f} ms, "
        f"of which the {len(IDT_ILLUMINANTS)} IDTs {idts * 1e3:.1f} ms"
    )


if __name__ == "__main__":
    main()
