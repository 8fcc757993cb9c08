"""libgphoto2 error codes: which recovery each calls for, and the camera's own error types."""

from __future__ import annotations

from typing import Literal

from drivers.base import DeviceError

__all__ = [
    "BUSY_ADVICE",
    "CLAIM_ADVICE",
    "GP_FILE_NOT_FOUND",
    "ErrorClass",
    "SettingValueError",
    "UnsupportedSetting",
    "classify_gphoto_error",
]

ErrorClass = Literal["busy", "claim", "io", "timeout", "gone", "not_found", "fatal"]
GP_BUSY_CODES = frozenset({-110})
"""GP_ERROR_CAMERA_BUSY "I/O in progress"; libgphoto2 maps PTP 0x2019 Device Busy to it too."""
GP_CLAIM_CODES = frozenset({-53, -60})
"""Could not claim the USB device; could not lock the device."""
GP_IO_CODES = frozenset({-1, -7, -31, -34, -35, -37, -51, -113})
"""Unspecified, I/O problem, port init/read/write/update, clear halt, camera could not complete:
a new session often clears them."""
GP_TIMEOUT_CODES = frozenset({-10})
GP_GONE_CODES = frozenset({-52, -5, -105})
"""Device not found on the USB port, unknown port, unknown model: the camera is not there."""
GP_FILE_NOT_FOUND = -108
CLAIM_ADVICE = (
    "another process holds the camera — usually the desktop's gvfs-gphoto2-volume-monitor / "
    "gvfsd-gphoto2 (or KDE's kio): run `gio mount -s gphoto2`, stop those services, or replug"
)
BUSY_ADVICE = (
    "the camera kept answering busy: autofocus may fail to lock (set the lens to MF), "
    "mirror lock-up may be on, or undownloaded images fill its SDRAM"
)


def classify_gphoto_error(code: int) -> ErrorClass:
    """Which recovery a libgphoto2 error code calls for.

    ``busy``: drain events and retry after a back-off; ``claim``, ``io``, ``timeout``: open a new
    session and retry; ``gone``: the camera disappeared; ``not_found``: a file is not on the camera;
    ``fatal``: a bad request, not worth repeating.
    """
    if code in GP_BUSY_CODES:
        return "busy"
    if code in GP_CLAIM_CODES:
        return "claim"
    if code in GP_TIMEOUT_CODES:
        return "timeout"
    if code in GP_IO_CODES:
        return "io"
    if code in GP_GONE_CODES:
        return "gone"
    if code == GP_FILE_NOT_FOUND:
        return "not_found"
    return "fatal"


class UnsupportedSetting(DeviceError):
    """The camera has no such widget, or it is read-only."""

    reason = "unsupported_setting"


class SettingValueError(DeviceError):
    """The requested value matches none of the widget's choices, or is outside its range."""

    reason = "bad_setting_value"
