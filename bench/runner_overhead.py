"""Runner overhead: wall time of a capture / Σ(exposure + download) of its frames.

Issue 5's target is ≤ 1.10 on the digital twin. Until the twin lands this measures the runner alone:
the fake rig from the tests, whose camera takes exposure + a download time in real time while
everything else (warm-up waits, spectra, relays) runs on a simulated clock, so all remaining wall time
is the runner's own: worker hand-offs, fsyncs, hashing, records, frame analysis of the fake files.

Run: ``.venv/bin/python bench/runner_overhead.py [DOWNLOAD_S]`` (default 0.5 s per frame).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from rig.capture import run_capture
from rig.records import FileRecord, StepRecord
from rig.session import read_session

# The fake rig lives with the tests; make the checkout importable when run as a script.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.rig.fakes import fake_config, make_fake_rig


def main() -> None:
    download_s = float(sys.argv[1]) if len(sys.argv) > 1 else 0.5
    with tempfile.TemporaryDirectory() as directory:
        rig = make_fake_rig()
        rig.camera.real_time_download_s = download_s
        config = fake_config(Path(directory) / "sessions", dark_frames=2)
        began = time.perf_counter()
        outcome = run_capture(config, builder=rig.builder)
        wall_s = time.perf_counter() - began
        session = read_session(outcome.session)
        frames = [
            r
            for r in session.records
            if isinstance(r, StepRecord) and r.action in ("Capture", "DarkFrame")
        ]
        busy_s = sum(float(r.params["exposure_s"]) + download_s for r in frames)
        n_records = len(session.records)
        n_files = sum(isinstance(r, FileRecord) for r in session.records)
    assert outcome.exit_status == "success", outcome
    print(
        f"runner overhead: wall {wall_s:.2f} s / Σ(exposure + download) {busy_s:.2f} s = "
        f"{wall_s / busy_s:.3f} ({len(frames)} frames, {n_records} records, {n_files} files, "
        f"download {download_s:g} s per frame)"
    )


if __name__ == "__main__":
    main()
