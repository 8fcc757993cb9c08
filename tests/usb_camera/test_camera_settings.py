"""The gphoto2 camera driver against the fake module: detection, identity and every setting."""

from __future__ import annotations

import pytest

from drivers.base import Camera, DeviceNotFound, StateMismatch
from drivers.camera import SettingValueError, UnsupportedSetting, select_camera
from mocks.fake_gphoto2 import (
    CameraFault,
    FakeBody,
    FakeGphoto2,
    WidgetSpec,
    canon_eos_body,
    minimal_body,
    nikon_body,
)
from mocks.fake_gphoto2.constants import GP_WIDGET_RANGE
from mocks.lamps import SimulatedClock
from tests.usb_camera.conftest import CameraRig, open_on

# ------------------------------------------------------------------------------ detection


def test_select_camera_by_model_and_port() -> None:
    detected = [("Canon EOS 5D Mark III", "usb:001,004"), ("Nikon DSC D750", "usb:001,005")]
    assert select_camera(detected, "nikon dsc d750", None) == detected[1]
    assert select_camera(detected, "EOS 5D", None) == detected[0]
    assert select_camera(detected, None, "usb:001,005") == detected[1]
    assert select_camera(detected[:1], None, None) == detected[0]
    with pytest.raises(DeviceNotFound, match="2 cameras match"):
        select_camera(detected, None, None)
    with pytest.raises(DeviceNotFound, match=r"no camera with model 'Sony'.*'Nikon DSC D750'"):
        select_camera(detected, "Sony", None)
    with pytest.raises(DeviceNotFound, match="no camera with model 'Nikon' port usb:001,004"):
        select_camera(detected, "Nikon", "usb:001,004")
    with pytest.raises(DeviceNotFound, match="no camera detected; detected: none"):
        select_camera([], None, None)


def test_open_by_model_among_two_cameras(clock: SimulatedClock) -> None:
    gp = FakeGphoto2([canon_eos_body(clock=clock), nikon_body(clock=clock)])
    with open_on(gp, clock, model="Nikon") as camera:
        identity = camera.identify()
        assert isinstance(camera, Camera)
    assert identity.model == "Nikon DSC D750"
    assert identity.port == "usb:001,005"
    assert identity.serial == "3012345"
    assert identity.firmware == "V1.10"
    assert identity.extra["manufacturer"] == "Nikon Corporation"
    assert identity.extra["libgphoto2"] == "2.5.34"
    assert gp.bodies[0].count("init") == 0


def test_open_by_port(clock: SimulatedClock) -> None:
    gp = FakeGphoto2([canon_eos_body(clock=clock), nikon_body(clock=clock)])
    with open_on(gp, clock, port="usb:001,004") as camera:
        assert camera.identify().model == "Canon EOS 5D Mark III"


def test_open_with_no_camera(clock: SimulatedClock) -> None:
    with pytest.raises(DeviceNotFound, match="no camera detected"):
        open_on(FakeGphoto2([]), clock)


def test_identity_without_status_widgets(clock: SimulatedClock) -> None:
    with open_on(FakeGphoto2([minimal_body(clock=clock)]), clock) as camera:
        identity = camera.identify()
    assert identity.serial is None and identity.firmware is None


# ------------------------------------------------------------------------------ reading


def test_list_settings_has_values_choices_and_read_only(canon: CameraRig) -> None:
    settings = canon.camera.list_settings()
    assert settings["shutterspeed"].value == "1/125"
    assert settings["shutterspeed"].choices[0] == "bulb"
    assert settings["shutterspeed"].choices[-1] == "1/8000"
    assert settings["iso"].choices[:3] == ("Auto", "100", "125")
    assert settings["serialnumber"].read_only
    assert not settings["aperture"].read_only
    assert "main" not in settings and "capturesettings" not in settings


def test_get_setting_by_logical_and_widget_name(clock: SimulatedClock) -> None:
    with open_on(FakeGphoto2([nikon_body(clock=clock)]), clock) as camera:
        assert camera.get_setting("aperture") == "f/5.6"
        assert camera.get_setting("f-number") == "f/5.6"
        assert camera.get_setting("imageformat") == "JPEG Fine"
        assert camera.get_setting("shutterspeed") == "0.0080s"


def test_capture_target_defaults_to_sdram(canon: CameraRig) -> None:
    assert canon.camera.get_setting("capturetarget") == "Internal RAM"
    assert canon.camera.set_setting("capturetarget", "card") == "Memory card"
    assert canon.body.values["capturetarget"] == "Memory card"


# ------------------------------------------------------------------------------ exposure


@pytest.mark.parametrize(
    ("requested", "expected"),
    [
        ("1/125", "1/125"),
        ("0.3", "0.3"),
        ("30", "30"),
        ('1"', "1"),
        ('0"5', "0.5"),
        ("1/90", "1/100"),
        ("0.65", "0.6"),
        ("0.7", "0.8"),
        ("2.0", "2"),
        ("1/8000", "1/8000"),
        ("BULB", "bulb"),
    ],
)
def test_exposure_strings_snap_to_the_nearest_choice(
    canon: CameraRig, requested: str, expected: str
) -> None:
    assert canon.camera.set_setting("shutterspeed", requested) == expected
    assert canon.body.values["shutterspeed"] == expected


def test_exposure_out_of_range_is_refused_with_the_range(canon: CameraRig) -> None:
    with pytest.raises(SettingValueError, match=r"shortest shutter speed .*1/8000 s … 30 s"):
        canon.camera.set_setting("shutterspeed", "1/16000")
    with pytest.raises(SettingValueError, match="not an exposure time"):
        canon.camera.set_setting("shutterspeed", "fast")
    assert canon.body.values["shutterspeed"] == "1/125"


def test_set_exposure_returns_the_value_read_back(canon: CameraRig) -> None:
    assert canon.camera.set_exposure(1 / 100) == pytest.approx(0.01)
    assert canon.camera.set_exposure(0.011) == pytest.approx(0.01)
    assert canon.camera.set_exposure(31.0) == 30.0  # within the bulb threshold: timed
    assert canon.camera.exposure_range_s() == (1 / 8000, 3600.0)


def test_nikon_generic_ptp_strings(clock: SimulatedClock) -> None:
    with open_on(FakeGphoto2([nikon_body(clock=clock)]), clock) as camera:
        assert camera.set_setting("shutterspeed", "1/125") == "0.0080s"
        assert camera.set_exposure(1 / 60) == pytest.approx(0.0166)
        assert camera.set_setting("shutterspeed", "bulb") == "Bulb"
        low, high = camera.exposure_range_s()
        assert (low, high) == (0.0001, 3600.0)


def test_camera_without_bulb_refuses_long_exposures(clock: SimulatedClock) -> None:
    with open_on(FakeGphoto2([minimal_body(clock=clock)]), clock) as camera:
        assert camera.exposure_range_s() == (0.0025, 1.0)
        assert camera.set_exposure(1.2) == 1.0  # within a third of a stop
        with pytest.raises(SettingValueError, match="offers no bulb choice"):
            camera.set_exposure(5.0)
        with pytest.raises(SettingValueError, match=r"must be > 0 s"):
            camera.set_exposure(0.0)


def test_exposure_that_does_not_stick_raises_state_mismatch(canon: CameraRig) -> None:
    canon.body.inject(CameraFault("ignore_setting", widget="shutterspeed", times=None))
    with pytest.raises(StateMismatch, match="mode dial") as caught:
        canon.camera.set_exposure(1 / 30)
    assert caught.value.expected == "1/30" and caught.value.actual == "1/125"


# ------------------------------------------------------------------------------ other settings


@pytest.mark.parametrize(
    ("setting", "requested", "expected"),
    [
        ("iso", "100", "100"),
        ("iso", "110", "100"),
        ("iso", "ISO 1600", "1600"),
        ("iso", "auto", "Auto"),
        ("aperture", "5.6", "5.6"),
        ("aperture", "f/8", "8"),
        ("aperture", "f/7", "7.1"),
        ("imageformat", "RAW", "RAW"),
        ("imageformat", "raw + large fine jpeg", "RAW + Large Fine JPEG"),
        ("whitebalance", "daylight", "Daylight"),
        ("capturetarget", "sdram", "Internal RAM"),
    ],
)
def test_canon_setting_choices(
    canon: CameraRig, setting: str, requested: str, expected: str
) -> None:
    assert canon.camera.set_setting(setting, requested) == expected


def test_nikon_raw_and_aperture(clock: SimulatedClock) -> None:
    with open_on(FakeGphoto2([nikon_body(clock=clock)]), clock) as camera:
        assert camera.set_setting("imageformat", "RAW") == "NEF (Raw)"
        assert camera.set_setting("aperture", "5.6") == "f/5.6"
        assert camera.set_setting("aperture", "F11") == "f/11"
        assert camera.set_setting("whitebalance", "Daylight") == "Daylight"


@pytest.mark.parametrize(
    ("setting", "requested", "message"),
    [
        ("iso", "50", "outside the camera's range 100 … 25600"),
        ("iso", "fast", "ISO 'fast' is not available"),
        ("aperture", "f/1.2", "outside the camera's range 2.8 … 22"),
        ("whitebalance", "sunny", "value 'sunny' is not available"),
        ("imageformat", "TIFF", "image format 'TIFF' is not available"),
    ],
)
def test_bad_values_name_what_is_allowed(
    canon: CameraRig, setting: str, requested: str, message: str
) -> None:
    with pytest.raises(SettingValueError, match=message):
        canon.camera.set_setting(setting, requested)


def test_unsupported_and_read_only_settings(clock: SimulatedClock) -> None:
    with open_on(FakeGphoto2([minimal_body(clock=clock)]), clock) as camera:
        with pytest.raises(UnsupportedSetting, match=r"no 'iso' setting.*iso, isospeed"):
            camera.set_setting("iso", "100")
        assert camera.apply_settings(
            {"iso": "100", "aperture": "f/4", "imageformat": "RAW"}, skip_unsupported=True
        ) == {"aperture": "f/4"}
        with pytest.raises(UnsupportedSetting):
            camera.apply_settings({"whitebalance": "Daylight"})
    gp = FakeGphoto2([canon_eos_body(clock=clock)])
    with open_on(gp, clock) as camera, pytest.raises(UnsupportedSetting, match="read-only"):
        camera.set_setting("serialnumber", "1")


def test_range_and_toggle_widgets(clock: SimulatedClock) -> None:
    body = FakeBody(
        "Test Body",
        "usb:003,001",
        [
            WidgetSpec(
                "shutterspeed", "Shutter", 5, "capturesettings", "1/100", ("1/100", "1/50")
            ),
            WidgetSpec(
                "exposurecompensation", "EV", GP_WIDGET_RANGE, "capturesettings", 0.0,
                value_range=(-3.0, 3.0, 1 / 3),
            ),
            WidgetSpec("autofocus", "AF", 4, "settings", 1),
        ],
        clock=clock,
    )  # fmt: skip
    with open_on(FakeGphoto2([body]), clock) as camera:
        assert float(camera.set_setting("exposurecompensation", "0.7")) == pytest.approx(2 / 3)
        with pytest.raises(SettingValueError, match="outside -3"):
            camera.set_setting("exposurecompensation", "4")
        assert camera.set_setting("autofocus", "off") == "0"
        assert camera.set_setting("autofocus", "on") == "1"
        with pytest.raises(SettingValueError, match="on/off"):
            camera.set_setting("autofocus", "maybe")
