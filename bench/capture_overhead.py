"""Capture overhead on the digital twin: wall time / Σ(exposure + download) of the captured frames.

Issue 5's target is ≤ 1.10. The twin runs in real time for its camera (``realtime: true``: every
frame takes its exposure plus the simulated download time in wall time, as a tethered camera
would), while warm-up waits run on the simulated clock and the spectrometer measures at a
thousandth of its real pace. Everything else in the wall time is the rig's own cost: the real
drivers (gphoto2 calls, USB control transfers, serial exchanges on ptys), the runner's worker
hand-offs, hashing and fsyncs of every record and file, and the frame analysis (RAW decoding, spot
and band statistics) that drives the bracketing. Frame rendering happens inside the camera's busy
time, as a camera's own processing does.

The figure is for the run (first step to stop record); opening the station (importing
colour-science, rendering each lamp's noiseless image once, starting the emulators) is printed
separately.

Run: ``.venv/bin/python bench/capture_overhead.py [--config config.yaml] [--out DIR] [--repeats N]``
(sessions in a temporary directory on the default temp file system, or under ``--out``; the figure
is printed for each run and as the median, since other load on the machine slows single runs).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from rig.capture import run_capture
from rig.config import RigConfig, TwinCameraConfig, load_config
from rig.records import StepRecord
from rig.session import read_session
from rig.station_devices import Station, TranscriptFactory
from rig.twin import open_twin_station


def realtime_config(config: RigConfig) -> RigConfig:
    """``config`` with the twin camera taking its exposure and download time in wall time."""
    camera = config.devices.camera
    if not isinstance(camera, TwinCameraConfig):
        raise SystemExit("the overhead bench runs on the twin: every device's kind must be 'twin'")
    devices = config.devices.model_copy(
        update={"camera": camera.model_copy(update={"realtime": True})}
    )
    return config.model_copy(update={"devices": devices})


def measure(config: RigConfig, out: Path | None) -> tuple[float, float, float, int, int]:
    """One capture: (run s, opening s, Σ(exposure + download) s, frames, records)."""
    camera = config.devices.camera
    assert isinstance(camera, TwinCameraConfig)
    opening: list[float] = []

    def timed_builder(rig_config: RigConfig, transcripts: TranscriptFactory) -> Station:
        started = time.perf_counter()
        station = open_twin_station(rig_config, transcripts)
        opening.append(time.perf_counter() - started)
        return station

    with tempfile.TemporaryDirectory(dir=out) as directory:
        started = time.perf_counter()
        outcome = run_capture(config, out_dir=Path(directory), builder=timed_builder)
        total_s = time.perf_counter() - started
        session = read_session(outcome.session)
    if outcome.exit_status != "success":
        raise SystemExit(f"the capture did not complete: {outcome.reason}: {outcome.message}")
    frames = [
        r
        for r in session.records
        if isinstance(r, StepRecord) and r.action in ("Capture", "DarkFrame") and r.status == "done"
    ]
    busy_s = sum(float(r.params["exposure_s"]) + camera.download_s for r in frames)
    return total_s - opening[0], opening[0], busy_s, len(frames), len(session.records)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=Path("config.yaml"))
    parser.add_argument("--out", type=Path, default=None, help="directory for the sessions")
    parser.add_argument("--repeats", type=int, default=3)
    arguments = parser.parse_args()
    config = realtime_config(load_config(arguments.config))
    camera = config.devices.camera
    assert isinstance(camera, TwinCameraConfig)
    ratios = []
    for _ in range(arguments.repeats):
        run_s, opening_s, busy_s, frames, records = measure(config, arguments.out)
        ratios.append(run_s / busy_s)
        print(
            f"  run {run_s:.2f} s / Σ(exposure + download) {busy_s:.2f} s = {run_s / busy_s:.3f} "
            f"({frames} frames, {records} records; opening the station {opening_s:.2f} s)"
        )
    print(
        f"capture overhead on the twin: {statistics.median(ratios):.3f} (median of "
        f"{len(ratios)}; target ≤ 1.10; {camera.sensor.width_px}×{camera.sensor.height_px} px "
        f"frames, download {camera.download_s:g} s each)"
    )


if __name__ == "__main__":
    main()
