"""The session objects python-gphoto2 exposes: ``Camera``, ``CameraFile``, ``CameraFilePath``,
``CameraList``, ``PortInfoList``, ``CameraAbilitiesList``.

A :class:`Camera` belongs to one :class:`~mocks.fake_gphoto2.FakeGphoto2` "module" (its ``world``),
which knows the plugged bodies. After ``exit()`` a Camera object must not be used again: the real
library fails with -1 and can abort the process at exit, so the fake raises -1 and counts the misuse
in ``world.calls_after_exit``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from mocks.fake_gphoto2.body import FakeBody
from mocks.fake_gphoto2.constants import (
    GP_CAPTURE_IMAGE,
    GP_ERROR,
    GP_ERROR_BAD_PARAMETERS,
    GP_ERROR_IO_USB_FIND,
    GP_ERROR_MODEL_NOT_FOUND,
    GP_ERROR_NOT_SUPPORTED,
    GP_EVENT_TIMEOUT,
)
from mocks.fake_gphoto2.errors import GPhoto2Error
from mocks.fake_gphoto2.widgets import CameraWidget

if TYPE_CHECKING:
    from mocks.fake_gphoto2 import FakeGphoto2


class CameraFilePath:
    """``folder`` and ``name`` of a file on the camera."""

    def __init__(self, folder: str = "", name: str = "") -> None:
        self.folder = folder
        self.name = name

    def __repr__(self) -> str:
        return f"CameraFilePath({self.folder!r}, {self.name!r})"


class CameraFile:
    """A downloaded file held in memory."""

    def __init__(self, name: str, data: bytes, mime_type: str) -> None:
        self._name = name
        self._data = data
        self._mime_type = mime_type

    def get_data_and_size(self) -> memoryview:
        return memoryview(self._data)

    def get_mime_type(self) -> str:
        return self._mime_type

    def get_name(self) -> str:
        return self._name

    def save(self, path: str) -> None:
        Path(path).write_bytes(self._data)


class CameraList:
    """(name, value) pairs, accessed with ``len``, ``get_name(i)``, ``get_value(i)``."""

    def __init__(self, pairs: Sequence[tuple[str, str | None]] = ()) -> None:
        self._pairs = list(pairs)

    def __len__(self) -> int:
        return len(self._pairs)

    def count(self) -> int:
        return len(self._pairs)

    def get_name(self, index: int) -> str:
        return self._pairs[index][0]

    def get_value(self, index: int) -> str | None:
        return self._pairs[index][1]

    def __iter__(self) -> Iterator[tuple[str, str | None]]:
        return iter(list(self._pairs))


class PortInfo:
    def __init__(self, path: str) -> None:
        self._path = path

    def get_path(self) -> str:
        return self._path

    def get_name(self) -> str:
        return "Universal Serial Bus" if self._path.startswith("usb") else self._path

    def get_type(self) -> int:
        return 4


class PortInfoList:
    """Ports libgphoto2 knows. Like the real list, any ``usb:BBB,DDD`` path resolves (whether a
    camera is there is found out by ``init``)."""

    def __init__(self) -> None:
        self._ports: list[PortInfo] = []

    def load(self) -> None:
        self._ports = [PortInfo("usb:")]

    def count(self) -> int:
        return len(self._ports)

    def lookup_path(self, path: str) -> int:
        for index, port in enumerate(self._ports):
            if port.get_path() == path:
                return index
        if not path.startswith("usb:"):
            raise GPhoto2Error(-5)
        self._ports.append(PortInfo(path))
        return len(self._ports) - 1

    def __getitem__(self, index: int) -> PortInfo:
        return self._ports[index]


class CameraAbilities:
    def __init__(self, model: str) -> None:
        self.model = model


class CameraAbilitiesList:
    """The camlibs' model table: the models of every body the fake module was given."""

    models: tuple[str, ...] = ()

    def __init__(self) -> None:
        self._models: list[str] = []

    def load(self) -> None:
        self._models = list(self.models)

    def count(self) -> int:
        return len(self._models)

    def lookup_model(self, model: str) -> int:
        try:
            return self._models.index(model)
        except ValueError:
            raise GPhoto2Error(GP_ERROR_MODEL_NOT_FOUND) from None

    def __getitem__(self, index: int) -> CameraAbilities:
        return CameraAbilities(self._models[index])

    def get_abilities(self, index: int) -> CameraAbilities:
        return self[index]


class Camera:
    """One libgphoto2 session (the real ``gp.Camera`` call surface the rig uses)."""

    world: FakeGphoto2

    def __init__(self) -> None:
        self._abilities: CameraAbilities | None = None
        self._port: PortInfo | None = None
        self._body: FakeBody | None = None
        self._exited = False

    @classmethod
    def autodetect(cls) -> CameraList:
        world = cls.world
        world.calls.append("autodetect")
        return CameraList([(b.model, b.port) for b in world.bodies if b.plugged])

    # ---------------------------------------------------------------- session

    def set_abilities(self, abilities: CameraAbilities) -> None:
        self._abilities = abilities

    def set_port_info(self, info: PortInfo) -> None:
        self._port = info

    def init(self) -> None:
        self._check_not_exited("init")
        plugged = [b for b in self.world.bodies if b.plugged]
        if self._port is not None:
            plugged = [b for b in plugged if b.port == self._port.get_path()]
        body = plugged[0] if plugged else None
        if body is None:
            # The real library reports the USB lookup failure when nothing answers on the port.
            unplugged = [
                b for b in self.world.bodies if self._port and b.port == self._port.get_path()
            ]
            if unplugged:
                unplugged[0].calls.append("init")
            raise GPhoto2Error(GP_ERROR_IO_USB_FIND)
        body.enter("init")
        if self._abilities is not None and self._abilities.model != body.model:
            raise GPhoto2Error(GP_ERROR_MODEL_NOT_FOUND)
        body.open_session()
        self._body = body

    def exit(self) -> None:
        if self._body is not None and not self._exited:
            self._body.calls.append("exit")
        self._exited = True
        self._body = None

    # ---------------------------------------------------------------- configuration

    def get_config(self) -> CameraWidget:
        body = self._session("get_config")
        body.enter("get_config")
        return body.widget_tree()

    def set_config(self, root: CameraWidget) -> None:
        body = self._session("set_config")
        fault = body.enter("set_config")
        for widget in root.leaves():
            if widget.changed():
                body.apply(widget, fault)
                widget.set_changed(0)

    def get_single_config(self, name: str) -> CameraWidget:
        body = self._session("get_single_config")
        body.enter("get_single_config", name)
        return body.single_widget(name)

    def set_single_config(self, name: str, widget: CameraWidget) -> None:
        body = self._session("set_single_config")
        fault = body.enter("set_single_config", name)
        if widget.get_name() != name:
            raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)
        body.apply(widget, fault)

    # ---------------------------------------------------------------- capture and files

    def capture(self, capture_type: int) -> CameraFilePath:
        body = self._session("capture")
        fault = body.enter("capture")
        if capture_type != GP_CAPTURE_IMAGE:
            raise GPhoto2Error(GP_ERROR_NOT_SUPPORTED)
        folder, name = body.capture(fault)
        return CameraFilePath(folder, name)

    def wait_for_event(self, timeout_ms: int) -> tuple[int, object]:
        body = self._session("wait_for_event")
        body.enter("wait_for_event")
        event = body.next_event()
        if event is None:
            body.clock.sleep(timeout_ms / 1000.0)
            return (GP_EVENT_TIMEOUT, None)
        event_type, data = event
        if isinstance(data, tuple):
            return (event_type, CameraFilePath(*data))
        return (event_type, data)

    def file_get(self, folder: str, name: str, file_type: int) -> CameraFile:
        body = self._session("file_get")
        body.enter("file_get")
        data = body.read_file((folder, name))
        mime = "image/jpeg" if name.lower().endswith((".jpg", ".jpeg")) else "image/x-raw"
        return CameraFile(name, data, mime)

    def file_delete(self, folder: str, name: str) -> None:
        body = self._session("file_delete")
        body.enter("file_delete")
        body.delete_file((folder, name))

    def folder_list_files(self, folder: str) -> CameraList:
        body = self._session("folder_list_files")
        body.enter("folder_list_files")
        return CameraList([(name, None) for f, name in sorted(body.files) if f == folder])

    # ---------------------------------------------------------------- internals

    def _check_not_exited(self, call: str) -> None:
        if self._exited:
            self.world.calls_after_exit.append(call)
            raise GPhoto2Error(GP_ERROR)

    def _session(self, call: str) -> FakeBody:
        self._check_not_exited(call)
        if self._body is None:
            raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)  # not initialised
        return self._body
