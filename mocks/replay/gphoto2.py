"""A ``gphoto2`` module stand-in that plays a recorded camera transcript back.

The real camera driver (:mod:`drivers.camera.gphoto`) runs on it. Its library calls were checked
against the recording by the transcript sink before they reach this module; every call here then
answers with the recorded ``return`` (rebuilt from its JSON summary: a camera list, a configuration
tree, a file path, an event) or raises the recorded ``error``. Downloads serve the session's own
frame files, in the order they were downloaded (checked by size and, when recorded, sha256).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any

from mocks.fake_gphoto2 import constants
from mocks.fake_gphoto2.camera import CameraFile, CameraFilePath, CameraList
from mocks.fake_gphoto2.errors import GPhoto2Error
from mocks.fake_gphoto2.widgets import CameraWidget
from mocks.replay.script import ReplayScript

__all__ = ["FrameSource", "ReplayGphoto2", "ReplayUnsupported"]

FrameSource = Callable[[int, int, "str | None"], bytes]
"""The bytes of the n-th download (from 0), given the recorded size and sha256 (if recorded)."""


class ReplayUnsupported(ValueError):
    """The recording lacks something replay needs, or names a device replay has no driver for."""


#: A call recorded as stuck blocks this much longer than its deadline, so the driver gives up again.
_STUCK_MARGIN_S = 0.5


class _Recorded:
    """Serves the recorded outcome of each library call."""

    def __init__(self, script: ReplayScript) -> None:
        self.script = script
        self.tree: dict[str, dict[str, Any]] = {}
        """The leaf widgets of the last configuration tree, by name."""

    def result(self) -> Any:
        served = self.script.take("a library call's result")
        body = json.loads(served.entry.payload)
        if served.entry.direction == "error":
            if "timeout_s" in body:
                time.sleep(float(body["timeout_s"]) + _STUCK_MARGIN_S)
                return None
            raise GPhoto2Error(int(body["code"]))
        return body.get("result")

    def widget(self, summary: dict[str, Any]) -> CameraWidget:
        """A widget as recorded (a tree from ``get_config``, or one leaf with its new value)."""
        if "tree" in summary:
            root = CameraWidget(constants.GP_WIDGET_WINDOW, str(summary["widget"]))
            self.tree = {}
            for node in summary["tree"]:
                root.append(self._node(node))
            return root
        name = str(summary["widget"])
        known = self.tree.get(name, {"widget": name, "type": constants.GP_WIDGET_TEXT})
        return _ReplayWidget(self, {**known, "value": summary.get("value")})

    def _node(self, node: dict[str, Any]) -> CameraWidget:
        widget = _ReplayWidget(self, node)
        if "children" not in node:
            self.tree[str(node["widget"])] = node
        for child in node.get("children", ()):
            widget.append(self._node(child))
        return widget


class _ReplayWidget(CameraWidget):
    """A recorded widget; ``set_value`` is a library call, so it is served from the recording."""

    def __init__(self, recorded: _Recorded, node: dict[str, Any]) -> None:
        value_range = node.get("range") or (0.0, 0.0, 0.0)
        super().__init__(
            int(node["type"]),
            str(node["widget"]),
            value=node.get("value"),
            choices=[str(choice) for choice in node.get("choices", ())],
            read_only=bool(node.get("readonly", False)),
            value_range=(float(value_range[0]), float(value_range[1]), float(value_range[2])),
        )
        self._recorded = recorded

    def set_value(self, value: str | int | float) -> None:
        self._recorded.result()
        super().set_value(value)


class _Handle:
    """An object the driver only passes back to the library (abilities, port info)."""

    def get_name(self) -> str:
        return "replayed"


def _event_data(data: Any) -> Any:
    if isinstance(data, dict) and {"folder", "name"} <= set(data):
        return CameraFilePath(str(data["folder"]), str(data["name"]))
    return data


class ReplayGphoto2:
    """The module: ``Camera``, ``CameraAbilitiesList``, ``PortInfoList``, errors and constants.

    Parameters
    ----------
    script
        The camera transcript.
    frames
        Serves the downloaded files.
    library_version
        What ``gp_library_version`` says (the recorded camera identity has it).
    """

    GPhoto2Error = GPhoto2Error

    def __init__(self, script: ReplayScript, frames: FrameSource, library_version: str) -> None:
        recorded = _Recorded(script)
        self._library_version = library_version
        downloads = [0]

        class Camera:
            @staticmethod
            def autodetect() -> CameraList:
                pairs = recorded.result() or []
                return CameraList([(str(name), str(port)) for name, port in pairs])

            def __init__(self) -> None:
                recorded.result()

            def set_abilities(self, abilities: object) -> None:
                recorded.result()

            def set_port_info(self, info: object) -> None:
                recorded.result()

            def init(self) -> None:
                recorded.result()

            def exit(self) -> None:
                recorded.result()

            def get_config(self) -> CameraWidget:
                tree = recorded.result()
                if not isinstance(tree, dict) or "tree" not in tree:
                    raise ReplayUnsupported(
                        "the camera transcript has no configuration tree (recorded by a version "
                        "that did not record it); this session cannot be replayed"
                    )
                return recorded.widget(tree)

            def get_single_config(self, name: str) -> CameraWidget:
                return recorded.widget(recorded.result())

            def set_single_config(self, name: str, widget: object) -> None:
                recorded.result()

            def capture(self, capture_type: int) -> CameraFilePath:
                path = recorded.result()
                return CameraFilePath(str(path["folder"]), str(path["name"]))

            def wait_for_event(self, timeout_ms: int) -> tuple[int, Any]:
                event_type, data = recorded.result()
                return int(event_type), _event_data(data)

            def file_get(self, folder: str, name: str, file_type: int) -> CameraFile:
                summary = recorded.result()
                number = downloads[0]
                downloads[0] += 1
                data = frames(number, int(summary["bytes"]), summary.get("sha256"))
                return CameraFile(name, data, "application/octet-stream")

            def file_delete(self, folder: str, name: str) -> None:
                recorded.result()

        class CameraAbilitiesList:
            def __init__(self) -> None:
                recorded.result()

            def load(self) -> None:
                recorded.result()

            def lookup_model(self, model: str) -> int:
                return int(recorded.result())

            def __getitem__(self, index: int) -> _Handle:
                return _Handle()

        class PortInfoList(CameraAbilitiesList):
            def lookup_path(self, path: str) -> int:
                return int(recorded.result())

        self.Camera = Camera
        self.CameraAbilitiesList = CameraAbilitiesList
        self.PortInfoList = PortInfoList
        for name in dir(constants):
            if name.startswith("GP_"):
                setattr(self, name, getattr(constants, name))

    def __getattr__(self, name: str) -> int:
        raise AttributeError(f"replayed gphoto2 has no attribute {name!r}")

    def gp_library_version(self, verbosity: int) -> tuple[str, ...]:
        return (self._library_version,)
