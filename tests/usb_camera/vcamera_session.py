"""Drive the gphoto2 wheel's virtual camera (libgphoto2 vusb) with the real driver; print JSON.

Run as ``python -m tests.usb_camera.vcamera_session CARD_DIR OUT_DIR`` with ``VCAMERADIR=CARD_DIR``
in the environment: python-gphoto2 only switches to the virtual USB iolib when that variable is set
before ``import gphoto2``, which is why this runs in its own process (it also keeps any libgphoto2
crash out of the test process). Prints one JSON object with what each step returned or raised.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable
from pathlib import Path

from drivers.base import DeviceError, ListTranscript
from drivers.camera import CameraTimeouts, RecoveryPolicy, open_camera
from drivers.discovery import list_devices


def _step(results: dict[str, object], name: str, action: Callable[[], object]) -> None:
    try:
        results[name] = {"ok": action()}
    except DeviceError as exc:
        results[name] = {"error": type(exc).__name__, "message": str(exc)}


def main(argv: list[str]) -> int:
    card_dir, out_dir = Path(argv[0]), Path(argv[1])
    if os.environ.get("VCAMERADIR") != str(card_dir):
        print(json.dumps({"unusable": "VCAMERADIR must be set to the card directory"}))
        return 2
    import gphoto2

    results: dict[str, object] = {
        "library": list(gphoto2.gp_library_version(gphoto2.GP_VERSION_SHORT))
    }
    transcript = ListTranscript()
    try:
        camera = open_camera(
            gphoto2_module=gphoto2,
            transcript=transcript,
            timeouts=CameraTimeouts(call_s=20.0, init_s=30.0, drain_ms=50),
            recovery=RecoveryPolicy(busy_backoff_s=0.1, reinit_backoff_s=0.2),
        )
    except DeviceError as exc:
        print(json.dumps({"unusable": f"{type(exc).__name__}: {exc}"}))
        return 0
    with camera:
        identity = camera.identify()
        results["identity"] = {"model": identity.model, "port": identity.port,
                               "serial": identity.serial, "firmware": identity.firmware}  # fmt: skip
        settings = camera.list_settings()
        results["shutter_choices"] = list(settings["shutterspeed"].choices)
        results["capturetarget"] = settings["capturetarget"].value
        _step(results, "shutter_1/20", lambda: camera.set_setting("shutterspeed", "1/20"))
        _step(results, "exposure_0.3", lambda: camera.set_exposure(0.3))
        _step(results, "exposure_0.007", lambda: camera.set_exposure(0.007))
        _step(results, "aperture_5.6", lambda: camera.set_setting("aperture", "5.6"))
        _step(results, "aperture_f/7", lambda: camera.set_setting("aperture", "f/7"))
        _step(results, "iso", lambda: camera.set_setting("iso", "100"))
        _step(results, "exposure_range", camera.exposure_range_s)
        _step(results, "exposure_5", lambda: camera.set_exposure(5.0))
        _step(results, "target_card", lambda: camera.set_setting("capturetarget", "card"))

        def capture(name: str) -> dict[str, object]:
            captured = camera.capture(out_dir / name)
            return {"path": str(captured.path), "camera_path": captured.camera_path,
                    "exposure_s": captured.exposure_s, "size": captured.path.stat().st_size,
                    "settings": captured.settings}  # fmt: skip

        _step(results, "capture_1", lambda: capture("frame_1"))
        _step(results, "capture_2", lambda: capture("frame_2"))
        _step(results, "reinitialise", camera.reinitialise)
        _step(results, "shutter_after_reinit", lambda: camera.get_setting("shutterspeed"))
        _step(results, "capture_3", lambda: capture("frame_3"))
    directions = [entry.direction for entry in transcript.entries]
    results["transcript"] = {d: directions.count(d) for d in sorted(set(directions))}
    results["transcript_json_ok"] = all(
        isinstance(json.loads(entry.payload.decode("utf-8")), dict) for entry in transcript.entries
    )
    report = list_devices(
        gphoto2_module=gphoto2, include_serial=False, include_usb_relays=False, include_ocean=False
    )
    results["discovered"] = [
        {"kind": d.kind, "name": d.name, "address": d.address, "snippet": d.config_snippet}
        for d in report.devices
    ]
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
