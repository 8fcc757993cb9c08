"""The real driver against the gphoto2 wheel's own virtual camera (libgphoto2 vusb, VCAMERADIR).

The virtual camera is a Nikon-like PTP device with shutter speeds 1/10000 … 1 s, ``f-number``,
``capturetarget`` and no ISO, image format, white balance or bulb (protocols.md §5). It runs in a
subprocess because python-gphoto2 selects the virtual iolib only when ``VCAMERADIR`` is set before
its import.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("gphoto2", reason="python-gphoto2 wheel not installed")

ROOT = Path(__file__).resolve().parents[2]
SESSION_TIMEOUT_S = 90.0
#: A minimal JFIF file; the virtual camera's capture returns a copy of the first JPEG on its card.
SOURCE_JPEG = bytes.fromhex("ffd8ffe000104a46494600010100000100010000ffd9")


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    card = tmp_path_factory.mktemp("vcamera_card")
    out = tmp_path_factory.mktemp("vcamera_out")
    (card / "DSC_0001.JPG").write_bytes(SOURCE_JPEG)
    environment = dict(os.environ, VCAMERADIR=str(card), PYTHONPATH=str(ROOT))
    for inherited in ("IOLIBS", "CAMLIBS"):  # set by an earlier `import gphoto2` in this process
        environment.pop(inherited, None)
    completed = subprocess.run(
        [sys.executable, "-m", "tests.usb_camera.vcamera_session", str(card), str(out)],
        cwd=ROOT,
        env=environment,
        capture_output=True,
        text=True,
        timeout=SESSION_TIMEOUT_S,
        check=False,
    )
    assert completed.returncode == 0, completed.stderr[-3000:]
    results: dict[str, object] = json.loads(completed.stdout.strip().splitlines()[-1])
    if "unusable" in results:
        pytest.skip(f"the wheel's virtual camera is unusable here: {results['unusable']}")
    results["out"] = str(out)
    return results


def ok(results: dict[str, object], step: str) -> object:
    outcome = results[step]
    assert isinstance(outcome, dict) and "ok" in outcome, f"{step}: {outcome}"
    return outcome["ok"]


def test_detects_and_identifies_the_virtual_camera(session: dict[str, object]) -> None:
    assert session["identity"] == {
        "model": "Nikon DSC D750",
        "port": "usb:001,001",
        "serial": "0.1",
        "firmware": "2.5.11",
    }
    assert session["library"][0] == "2.5.34"  # type: ignore[index]
    assert session["capturetarget"] == "Internal RAM"  # the driver's default: SDRAM


def test_settings_snap_to_choices_and_are_read_back(session: dict[str, object]) -> None:
    assert ok(session, "shutter_1/20") == "0.0500s"
    assert ok(session, "exposure_0.3") == pytest.approx(0.1)
    assert ok(session, "exposure_0.007") == pytest.approx(0.005)
    assert ok(session, "aperture_5.6") == "f/5.6"
    assert ok(session, "aperture_f/7") == "f/7.1"
    assert ok(session, "target_card") == "Memory card"
    assert ok(session, "exposure_range") == [0.0001, 1.0]


def test_missing_features_raise_typed_errors(session: dict[str, object]) -> None:
    assert session["iso"]["error"] == "UnsupportedSetting"  # type: ignore[index]
    assert session["exposure_5"]["error"] == "SettingValueError"  # type: ignore[index]
    assert "no bulb choice" in session["exposure_5"]["message"]  # type: ignore[index]


def test_captures_download_the_camera_file(session: dict[str, object]) -> None:
    first = ok(session, "capture_1")
    second = ok(session, "capture_2")
    assert isinstance(first, dict) and isinstance(second, dict)
    assert first["camera_path"] != second["camera_path"]
    assert first["camera_path"].startswith("/store_00010001/DCIM/")
    for captured in (first, second):
        assert Path(captured["path"]).read_bytes() == SOURCE_JPEG
        assert Path(captured["path"]).suffix == ".jpg"
        assert captured["exposure_s"] == pytest.approx(0.005)
        assert captured["settings"]["shutterspeed"] == "0.0050s"
    leftovers = [p.name for p in Path(str(session["out"])).iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_reinitialise_uses_a_new_camera_and_restores_settings(session: dict[str, object]) -> None:
    # A new gp.Camera on the virtual camera starts from its defaults (shutter 0.0100s); the
    # driver re-applies what it set before, and captures keep working.
    assert ok(session, "reinitialise") is None
    assert ok(session, "shutter_after_reinit") == "0.0050s"
    third = ok(session, "capture_3")
    assert isinstance(third, dict) and Path(third["path"]).read_bytes() == SOURCE_JPEG


def test_transcript_and_discovery(session: dict[str, object]) -> None:
    counts = session["transcript"]
    assert isinstance(counts, dict)
    assert counts["call"] == counts["return"] > 50
    assert session["transcript_json_ok"] is True
    assert session["discovered"] == [
        {
            "kind": "camera",
            "name": "Nikon DSC D750",
            "address": "usb:001,001",
            "snippet": "# Nikon DSC D750 on usb:001,001\n"
            "kind: gphoto2\nmodel: Nikon DSC D750\nport: usb:001,001\n",
        }
    ]
