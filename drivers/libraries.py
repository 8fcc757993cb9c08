"""The one seam where drivers import their hardware libraries: pyserial, pyusb, python-gphoto2 and
python-seabreeze.

They are optional (the ``[rig]`` extra): an analysis-only installation (``pip install spectral-rig``)
has none of them, and importing ``drivers`` must still work there (the session reader, ``rig
estimate`` and ``calib`` never talk to a device). Each function here imports its library when a
driver first needs it and turns a missing library into :class:`HardwareLibraryMissing`, which names
the library and the extra that brings it.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from drivers.base import DeviceNotFound

__all__ = [
    "RIG_EXTRA",
    "HardwareLibraryMissing",
    "gphoto2",
    "pyseabreeze",
    "pyserial",
    "pyusb",
]

RIG_EXTRA = "pip install 'spectral-rig[rig]'"
"""What installs every hardware library the drivers use."""


class HardwareLibraryMissing(DeviceNotFound):
    """A driver's hardware library is not installed; the message says what to install."""

    reason = "library_missing"

    def __init__(self, library: str, distribution: str, error: ImportError) -> None:
        self.library = library
        self.distribution = distribution
        super().__init__(
            library,
            f"{distribution} is not installed ({error}); install the hardware libraries with "
            f"`{RIG_EXTRA}` (or `pip install {distribution}`)",
        )


def _load(module: str, library: str, distribution: str) -> ModuleType:
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise HardwareLibraryMissing(library, distribution, exc) from exc


def pyserial() -> ModuleType:
    """``serial`` (pyserial), for every serial instrument and relay board."""
    return _load("serial", "pyserial", "pyserial")


def pyusb() -> ModuleType:
    """``usb.core`` (pyusb), for the HID relay boards and Ocean Optics spectrometers.

    ``usb.util`` and ``usb.backend`` are imported with it (``usb.core`` imports both).
    """
    return _load("usb.core", "pyusb", "pyusb")


def gphoto2() -> ModuleType:
    """``gphoto2`` (python-gphoto2; its wheels bundle libgphoto2), for tethered cameras."""
    return _load("gphoto2", "python-gphoto2", "gphoto2")


def pyseabreeze() -> ModuleType:
    """``seabreeze.pyseabreeze`` (python-seabreeze's pure-Python backend, on pyusb).

    The C backend (``cseabreeze``) is never used: pyseabreeze runs on pyusb, so a pyusb backend can
    stand in for the bus (the twin, replay and the exchange tests).
    """
    pyusb()
    return _load("seabreeze.pyseabreeze", "python-seabreeze", "seabreeze")
