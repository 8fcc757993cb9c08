"""A fake ``gphoto2`` module: the call surface the camera driver uses, served by fake bodies.

Build one per test and pass it as the driver's ``gphoto2_module``::

    gp = FakeGphoto2([canon_eos_body(clock=clock)])
    camera = open_camera(gphoto2_module=gp)

It offers what python-gphoto2 offers to the rig: ``Camera`` (``autodetect``, ``init``, ``exit``,
configuration, ``capture``, ``wait_for_event``, ``file_get``, ``file_delete``), ``CameraWidget``
trees with choices, ``GPhoto2Error`` with the real codes and texts, ``CameraFilePath``,
``CameraList``, ``PortInfoList``, ``CameraAbilitiesList``, the ``GP_*`` constants and
``gp_library_version``. Bodies carry realistic widget sets (:mod:`.bodies`), render frames through a
pluggable frame source, and take injected faults (:class:`CameraFault`): PTP busy, I/O in progress,
the same file returned twice, unplug, a call that hangs, claim errors, a setting that does not stick.
"""

from __future__ import annotations

from collections.abc import Sequence

from mocks.fake_gphoto2 import constants
from mocks.fake_gphoto2.bodies import canon_eos_body, minimal_body, nikon_body
from mocks.fake_gphoto2.body import (
    CameraFault,
    FakeBody,
    FaultKind,
    FrameRequest,
    FrameSource,
    StorageLayout,
    placeholder_frame,
)
from mocks.fake_gphoto2.camera import (
    Camera,
    CameraAbilitiesList,
    CameraFile,
    CameraFilePath,
    CameraList,
    PortInfoList,
)
from mocks.fake_gphoto2.errors import GPhoto2Error, gp_result_as_string
from mocks.fake_gphoto2.widgets import CameraWidget, WidgetSpec

__all__ = [
    "CameraFault",
    "FakeBody",
    "FakeGphoto2",
    "FaultKind",
    "FrameRequest",
    "FrameSource",
    "GPhoto2Error",
    "StorageLayout",
    "WidgetSpec",
    "canon_eos_body",
    "minimal_body",
    "nikon_body",
    "placeholder_frame",
]


class FakeGphoto2:
    """A stand-in for the ``gphoto2`` module, with its own set of plugged-in bodies.

    Every ``GP_*`` constant of :mod:`mocks.fake_gphoto2.constants` is an attribute, as on the real
    module.
    """

    GPhoto2Error = GPhoto2Error
    CameraWidget = CameraWidget
    CameraFilePath = CameraFilePath
    CameraFile = CameraFile
    CameraList = CameraList
    PortInfoList = PortInfoList

    def __init__(self, bodies: Sequence[FakeBody]) -> None:
        ports = [b.port for b in bodies]
        if len(set(ports)) != len(ports):
            raise ValueError(f"two bodies on one port: {ports}")
        self.bodies = list(bodies)
        self.calls: list[str] = []
        """Module-level calls (``autodetect``)."""
        self.calls_after_exit: list[str] = []
        """Calls made on a Camera object after its ``exit()`` (a driver bug; must stay empty)."""
        world = self
        models = tuple(dict.fromkeys(b.model for b in bodies))

        class BoundCamera(Camera):
            pass

        class BoundAbilitiesList(CameraAbilitiesList):
            pass

        BoundCamera.world = world
        BoundAbilitiesList.models = models
        self.Camera = BoundCamera
        self.CameraAbilitiesList = BoundAbilitiesList
        for name in dir(constants):
            if name.startswith("GP_"):
                setattr(self, name, getattr(constants, name))

    def __getattr__(self, name: str) -> int:
        # Only reached for names not set in __init__: keep mypy aware that GP_* exist.
        raise AttributeError(f"fake gphoto2 has no attribute {name!r}")

    @staticmethod
    def gp_library_version(verbosity: int) -> tuple[str, ...]:
        return constants.LIBRARY_VERSION

    @staticmethod
    def gp_result_as_string(code: int) -> str:
        return gp_result_as_string(code)

    def release_hangs(self) -> None:
        """Let every hung call on every body return (call it in test teardown)."""
        for body in self.bodies:
            body.release_hangs()
