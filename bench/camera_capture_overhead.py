"""Driver overhead per captured frame: the gphoto2 driver against the fake camera in real time.

Prints the wall time per frame beyond the exposure itself (library round trips, event drain,
download, atomic write, delete) and the libgphoto2 calls per frame, for single-file RAW and for
RAW+JPEG. The fake answers instantly, so the figure is the driver's own cost plus its event-drain
waits; on a real body add the camera's processing and USB transfer time.

Run: ``.venv/bin/python bench/camera_capture_overhead.py``
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from drivers.camera import open_camera
from mocks.fake_gphoto2 import FakeGphoto2, canon_eos_body

FRAMES = 40
EXPOSURE_S = 1 / 100


def measure(image_format: str) -> tuple[float, float]:
    """(overhead per frame in ms, library calls per frame) for ``FRAMES`` captures."""
    body = canon_eos_body()  # wall clock: exposures take real time
    with (
        tempfile.TemporaryDirectory() as directory,
        open_camera(gphoto2_module=FakeGphoto2([body])) as camera,
    ):
        camera.set_setting("imageformat", image_format)
        exposure_s = camera.set_exposure(EXPOSURE_S)
        calls_before = len(body.calls)
        started = time.perf_counter()
        for index in range(FRAMES):
            camera.capture(Path(directory) / f"frame_{index:03d}")
        elapsed_s = time.perf_counter() - started
    overhead_ms = (elapsed_s - FRAMES * exposure_s) / FRAMES * 1000.0
    return overhead_ms, (len(body.calls) - calls_before) / FRAMES


def main() -> None:
    for image_format in ("RAW", "RAW + Large Fine JPEG"):
        overhead_ms, calls = measure(image_format)
        print(
            f"camera capture overhead [{image_format}]: {overhead_ms:.1f} ms/frame beyond a "
            f"{EXPOSURE_S * 1000:g} ms exposure, {calls:.1f} libgphoto2 calls/frame "
            f"({FRAMES} frames, fake camera)"
        )


if __name__ == "__main__":
    main()
