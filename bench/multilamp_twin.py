"""Several lamps through the whole rig: the twin's RAW frames, the pipeline, then each estimator.

Takes ``config.yaml`` (the digital twin: Nikon 5100, a 500 grooves/mm grating) and switches the
issue-7 lamp set, LED-B1, LED-B3, LED-B5, FL2 and A, on one 8-channel relay board. It captures a session as
``rig demo`` does (warm-up, spectra, HDR brackets, dark frames, written as DNGs), then runs
``rig compare``'s columns on it (:func:`rig.compare.compare_sessions`: the offline pipeline, a camera
basis without the twin's camera). It prints RE ×10⁻² per column against the twin's true camera.
Unlike ``calib synthetic``, the noise here is what the twin's sensor and HDR merge give, not a
protocol parameter.

    python bench/multilamp_twin.py [--config config.yaml] [--keep DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from calib.evaluation.synthetic import FIVE_LAMPS, LAMP_SETS, lamp_kind
from rig.compare import compare_sessions
from rig.config import RigConfig, load_config
from rig.demo import run_demo

LAMPS = tuple((spec, lamp_kind(spec)) for spec in LAMP_SETS[FIVE_LAMPS])


def five_lamp_config(config: RigConfig) -> RigConfig:
    """``config`` with the five lamps on channels 1–5 of an 8-channel twin relay board."""
    data = config.model_dump(mode="json")
    template = data["lamps"][0]
    data["lamps"] = [
        {**template, "name": name, "kind": kind, "channel": channel}
        for channel, (name, kind) in enumerate(LAMPS, start=1)
    ]
    data["devices"]["relays"]["channels"] = 8
    return RigConfig.model_validate(data)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--config", type=Path, default=Path("config.yaml"))
    parser.add_argument(
        "--keep", type=Path, default=None, help="Keep the session and outputs here."
    )
    args = parser.parse_args()
    config = five_lamp_config(load_config(args.config))
    with tempfile.TemporaryDirectory() as temporary:
        out = args.keep or Path(temporary)
        started = time.perf_counter()
        demo = run_demo(config, out)
        captured = time.perf_counter() - started
        if demo.capture.exit_status != "success":
            raise SystemExit(f"the capture did not complete: {demo.capture.message}")
        comparison = compare_sessions(
            [demo.capture.session], out / "compare", methods=["prior", "multilamp"]
        )
        print(
            f"5 lamps on the twin ({', '.join(name for name, _ in LAMPS)}), capture + demo "
            f"{captured:.1f} s; RE ×10⁻² against the twin's camera:"
        )
        for row in comparison.rows:
            print(f"  {row.label:<28} {100 * row.relative_error:6.2f}   ({row.time_s:.2f} s)")


if __name__ == "__main__":
    main()
