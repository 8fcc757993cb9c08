"""Tethered cameras over python-gphoto2.

- :mod:`.gphoto` — the driver (:class:`GphotoCamera`, :func:`open_camera`), implementing
  :class:`drivers.base.Camera`.
- :mod:`.detect` — autodetection and choosing a camera by model or port.
- :mod:`.widgets`, :mod:`.choices`, :mod:`.exposure` — configuration widgets and matching requested
  values (exposure strings, apertures, ISO, RAW format) to the camera's choices.
- :mod:`.calls`, :mod:`.watchdog` — the recorded, deadline-bounded libgphoto2 call boundary.
- :mod:`.errors` — libgphoto2 error classes and the camera's own error types.
- :mod:`.files` — picking the RAW file and writing it atomically.
"""

from drivers.camera.detect import list_cameras, load_gphoto2, select_camera
from drivers.camera.errors import SettingValueError, UnsupportedSetting, classify_gphoto_error
from drivers.camera.exposure import ExposureTable, parse_exposure_s
from drivers.camera.gphoto import (
    BULB_MAX_EXPOSURE_S,
    CameraTimeouts,
    ExposureTimer,
    GphotoCamera,
    RecoveryPolicy,
    open_camera,
)

__all__ = [
    "BULB_MAX_EXPOSURE_S",
    "CameraTimeouts",
    "ExposureTable",
    "ExposureTimer",
    "GphotoCamera",
    "RecoveryPolicy",
    "SettingValueError",
    "UnsupportedSetting",
    "classify_gphoto_error",
    "list_cameras",
    "load_gphoto2",
    "open_camera",
    "parse_exposure_s",
    "select_camera",
]
