"""A fake camera body: its widgets and their values, its storage, its event queue, its faults.

The body is the physical camera; :class:`mocks.fake_gphoto2.camera.Camera` objects are libgphoto2
sessions talking to it (a new ``gp.Camera`` after a re-init talks to the same body, whose settings
persist, as on a real camera). Frames come from a pluggable :data:`FrameSource` so that the digital
twin can render real DNGs; the default writes a small self-describing placeholder.
"""

from __future__ import annotations

import json
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Literal

from mocks.fake_gphoto2.constants import (
    GP_ERROR,
    GP_ERROR_BAD_PARAMETERS,
    GP_ERROR_CAMERA_BUSY,
    GP_ERROR_CAMERA_ERROR,
    GP_ERROR_FILE_NOT_FOUND,
    GP_ERROR_IO,
    GP_ERROR_IO_USB_CLAIM,
    GP_ERROR_TIMEOUT,
    GP_EVENT_CAPTURE_COMPLETE,
    GP_EVENT_FILE_ADDED,
    GP_WIDGET_MENU,
    GP_WIDGET_RADIO,
    GP_WIDGET_RANGE,
)
from mocks.fake_gphoto2.errors import GPhoto2Error
from mocks.fake_gphoto2.widgets import CameraWidget, WidgetSpec, WidgetValue
from mocks.lamps import Clock, WallClock

__all__ = [
    "CameraFault",
    "FakeBody",
    "FaultKind",
    "FrameRequest",
    "FrameSource",
    "placeholder_frame",
]

FileFormat = Literal["raw", "jpeg"]
FaultKind = Literal[
    "busy",
    "io_error",
    "timeout",
    "claim",
    "camera_error",
    "same_file",
    "stale_frame",
    "unplug",
    "hang",
    "slow",
    "ignore_setting",
]
#: The call each fault kind hits unless told otherwise.
DEFAULT_FAULT_CALL: dict[str, str] = {
    "busy": "capture",
    "io_error": "capture",
    "timeout": "capture",
    "claim": "init",
    "camera_error": "capture",
    "same_file": "capture",
    "stale_frame": "capture",
    "unplug": "capture",
    "hang": "capture",
    "slow": "capture",
    "ignore_setting": "set_single_config",
}
_ERROR_CODES = {
    "busy": GP_ERROR_CAMERA_BUSY,
    "io_error": GP_ERROR_IO,
    "timeout": GP_ERROR_TIMEOUT,
    "claim": GP_ERROR_IO_USB_CLAIM,
    "camera_error": GP_ERROR_CAMERA_ERROR,
}
MAX_HANG_S = 60.0
"""A hung call gives up after this long even if nobody releases it (keeps test processes clean)."""


@dataclass
class CameraFault:
    """One injected failure.

    Parameters
    ----------
    kind
        ``busy`` (-110 "I/O in progress": PTP Device Busy on capture, or I/O in progress on any
        call), ``io_error`` (-7), ``timeout`` (-10), ``claim`` (-53 "Could not claim the USB
        device", on ``init``), ``camera_error`` (-113), ``same_file`` (``capture`` returns the path
        of the previous capture again), ``stale_frame`` (``capture`` stores a new file, but exposed
        with the previous capture's shutter time: a frame taken before a new setting took
        effect), ``unplug`` (the body disconnects during the call: -7 now,
        every later session call -7, ``init`` -52, absent from autodetect), ``hang`` (the call never
        returns until :meth:`FakeBody.release_hangs`), ``slow`` (the call answers normally after
        ``delay_s`` of wall time: a late reply), ``ignore_setting`` (``set_single_config``
        accepts the value but the body keeps the old one, like a dial not on M).
    call
        The libgphoto2 call it hits (``capture``, ``file_get``, ``file_delete``,
        ``wait_for_event``, ``init``, ``get_single_config``, ``set_single_config`` …); default
        per kind.
    skip
        Let this many matching calls pass first (``unplug`` on the 4th capture: ``skip=3``).
    times
        How many calls it hits; ``None`` = every matching call from then on.
    new_file_event
        For ``same_file``: the new frame is still taken and announced by a FILE_ADDED event
        (otherwise no frame is taken).
    widget
        For ``ignore_setting``: only this widget (``None`` = any).
    """

    kind: FaultKind
    call: str | None = None
    skip: int = 0
    times: int | None = 1
    new_file_event: bool = False
    widget: str | None = None
    delay_s: float = 0.0
    fired: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if self.call is None:
            self.call = DEFAULT_FAULT_CALL[self.kind]

    def hits(self, call: str, widget: str | None) -> bool:
        if call != self.call or (self.widget is not None and widget != self.widget):
            return False
        if self.skip > 0:
            self.skip -= 1
            return False
        return self.times is None or self.fired < self.times


@dataclass(frozen=True)
class FrameRequest:
    """What the frame source is asked to render.

    Attributes
    ----------
    index
        Frame number on this body, from 1.
    exposure_s
        Exposure actually made (for bulb: as the body timed it).
    settings
        Every widget value at capture time (``iso``, ``aperture``, ``whitebalance`` …), as text.
    file_format
        ``raw`` or ``jpeg`` (RAW+JPEG captures ask twice).
    time_s
        Body clock when the exposure ended.
    model
        Camera model.
    """

    index: int
    exposure_s: float
    settings: Mapping[str, str]
    file_format: FileFormat
    time_s: float
    model: str


FrameSource = Callable[[FrameRequest], bytes]


def placeholder_frame(request: FrameRequest) -> bytes:
    """A small self-describing file: a header line, the request as JSON, padding to 4 KiB."""
    header = b"FAKE-RAW\n" if request.file_format == "raw" else b"FAKE-JPEG\n"
    body = json.dumps(
        {
            "index": request.index,
            "exposure_s": request.exposure_s,
            "settings": dict(request.settings),
            "model": request.model,
        },
        sort_keys=True,
    ).encode("utf-8")
    content = header + body + b"\n"
    return content.ljust(4096, b"\x00")


def exposure_seconds(text: str) -> float | None:
    """Seconds of a fake body's shutter choice (``1/125``, ``0.3``, ``30``, ``0.0100s``)."""
    cleaned = text.strip().removesuffix("s")
    if re.fullmatch(r"\d+/\d+", cleaned):
        numerator, denominator = cleaned.split("/")
        return float(Fraction(int(numerator), int(denominator)))
    if re.fullmatch(r"\d+(\.\d+)?", cleaned):
        return float(cleaned)
    return None


def formats_for(image_format: str) -> list[FileFormat]:
    """Files a capture produces for an ``imageformat`` / ``imagequality`` value, RAW first."""
    folded = image_format.casefold()
    has_raw = "raw" in folded or "nef" in folded
    has_jpeg = "jpeg" in folded or "fine" in folded or "normal" in folded or "basic" in folded
    if has_raw and (has_jpeg or "+" in folded):
        return ["raw", "jpeg"]
    return ["raw"] if has_raw else ["jpeg"]


@dataclass(frozen=True)
class StorageLayout:
    """Where a body puts its captures and how it names them."""

    ram_folder: str = "/"
    ram_name: str = "capt{index:04d}"
    card_folder: str = "/store_00020001/DCIM/100CANON"
    card_name: str = "IMG_{index:04d}"
    raw_extension: str = ".CR2"
    jpeg_extension: str = ".JPG"


class FakeBody:
    """A camera body.

    Parameters
    ----------
    model, port
        What autodetect reports (``"Canon EOS 5D Mark III"``, ``"usb:001,004"``).
    widgets
        The configuration widgets it offers.
    layout
        Folders and file names of captures.
    frame_source
        Renders each frame's bytes (default :func:`placeholder_frame`).
    clock
        Time for exposures and bulb timing.
    sdram_capacity
        Undownloaded captures the SDRAM holds; a capture beyond it answers busy (gphoto2#308).
    reset_on_init
        Widgets that return to their power-on value when a new session opens (Canon's
        ``capturetarget`` is a driver-side setting that does). SDRAM captures are always lost
        when a session opens.
    signals_capture_complete
        Whether a capture ends with a CAPTURE_COMPLETE event (not every camlib sends one).
    """

    def __init__(
        self,
        model: str,
        port: str,
        widgets: Sequence[WidgetSpec],
        *,
        layout: StorageLayout | None = None,
        frame_source: FrameSource | None = None,
        clock: Clock | None = None,
        sdram_capacity: int = 4,
        reset_on_init: Sequence[str] = (),
        signals_capture_complete: bool = True,
    ) -> None:
        names = [w.name for w in widgets]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate widget names in {model}: {names}")
        self.model = model
        self.port = port
        self.specs: dict[str, WidgetSpec] = {w.name: w for w in widgets}
        self.values: dict[str, WidgetValue] = {w.name: w.value for w in widgets}
        self.layout = layout or StorageLayout()
        self.frame_source: FrameSource = frame_source or placeholder_frame
        self.clock: Clock = clock or WallClock()
        self.sdram_capacity = sdram_capacity
        unknown = set(reset_on_init) - set(names)
        if unknown:
            raise ValueError(f"reset_on_init names unknown widgets: {sorted(unknown)}")
        self.reset_on_init = tuple(reset_on_init)
        self.signals_capture_complete = signals_capture_complete
        self.plugged = True
        self.files: dict[tuple[str, str], bytes] = {}
        self.ram_files: set[tuple[str, str]] = set()
        self.events: deque[tuple[int, object]] = deque()
        self.faults: list[CameraFault] = []
        self.calls: list[str] = []
        """Every call the body received, by name, in order."""
        self.frames: list[FrameRequest] = []
        self.session_generation = 0
        self._file_counter = 0
        self._last_capture: tuple[str, str] | None = None
        self._last_exposure_s: float | None = None
        self._bulb_opened_at: float | None = None
        self._lock = threading.RLock()
        self._release = threading.Event()

    # ---------------------------------------------------------------- test controls

    def inject(self, fault: CameraFault) -> CameraFault:
        with self._lock:
            if fault.kind == "hang":
                self._release.clear()
            self.faults.append(fault)
        return fault

    def release_hangs(self) -> None:
        """Let every hung call return (with -7 I/O problem)."""
        self._release.set()

    def unplug(self) -> None:
        with self._lock:
            self.plugged = False

    def replug(self, port: str | None = None) -> None:
        """Plug the body back in, possibly on another port; SDRAM content is lost."""
        with self._lock:
            self.plugged = True
            if port is not None:
                self.port = port
            for path in self.ram_files:
                self.files.pop(path, None)
            self.ram_files.clear()
            self.events.clear()

    def count(self, call: str) -> int:
        return self.calls.count(call)

    # ---------------------------------------------------------------- library side

    def enter(self, call: str, widget: str | None = None) -> CameraFault | None:
        """Account for a call: apply the first matching fault (raise, hang) or return it."""
        with self._lock:
            self.calls.append(call)
            if not self.plugged:
                raise GPhoto2Error(GP_ERROR_IO)
            fault = next((f for f in self.faults if f.hits(call, widget)), None)
            if fault is None:
                return None
            fault.fired += 1
            if fault.kind == "unplug":
                self.plugged = False
                raise GPhoto2Error(GP_ERROR_IO)
            if fault.kind in _ERROR_CODES:
                raise GPhoto2Error(_ERROR_CODES[fault.kind])
        if fault.kind == "hang":
            self._release.wait(MAX_HANG_S)
            raise GPhoto2Error(GP_ERROR_IO)
        if fault.kind == "slow":
            # Wall time, not the body clock: this is how long the library call itself takes.
            time.sleep(fault.delay_s)
            return None
        return fault

    def open_session(self) -> None:
        """A new libgphoto2 session: SDRAM and pending events are gone, some settings reset."""
        with self._lock:
            self.session_generation += 1
            for path in self.ram_files:
                self.files.pop(path, None)
            self.ram_files.clear()
            self.events.clear()
            self._bulb_opened_at = None
            for name in self.reset_on_init:
                self.values[name] = self.specs[name].value

    def widget_tree(self) -> CameraWidget:
        with self._lock:
            root = CameraWidget(0, "main", "Camera and Driver Configuration")
            sections: dict[str, CameraWidget] = {}
            for spec in self.specs.values():
                section = sections.get(spec.section)
                if section is None:
                    section = CameraWidget(1, spec.section, spec.section.title())
                    sections[spec.section] = section
                    root.append(section)
                section.append(CameraWidget.from_spec(spec, self.values[spec.name]))
            return root

    def single_widget(self, name: str) -> CameraWidget:
        with self._lock:
            spec = self.specs.get(name)
            if spec is None:
                raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)
            return CameraWidget.from_spec(spec, self.values[name])

    def apply(self, widget: CameraWidget, fault: CameraFault | None) -> None:
        """Write a widget's value to the body, validating it as the camlib would."""
        with self._lock:
            name = widget.get_name()
            spec = self.specs.get(name)
            if spec is None or spec.read_only:
                raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)
            value = widget.get_value()
            if spec.widget_type in (GP_WIDGET_RADIO, GP_WIDGET_MENU) and value not in spec.choices:
                raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)
            if spec.widget_type == GP_WIDGET_RANGE:
                low, high, _ = spec.value_range
                if not low <= float(value) <= high:
                    raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)
            if fault is not None and fault.kind == "ignore_setting":
                return
            if name == "bulb":
                self._bulb(bool(value))
                return
            if name == "eosremoterelease":
                if str(value).startswith("Press Full"):
                    self._bulb(True)
                elif str(value) == "Release Full":
                    self._bulb(False)
                return
            self.values[name] = value

    def capture(self, fault: CameraFault | None) -> tuple[str, str]:
        """A timed capture; returns the (folder, name) of its first file."""
        with self._lock:
            if fault is not None and fault.kind == "same_file" and self._last_capture is not None:
                if fault.new_file_event:
                    files = self._expose(self._timed_exposure_s())
                    self.events.extend((GP_EVENT_FILE_ADDED, f) for f in files)
                return self._last_capture
            exposure_s = self._timed_exposure_s()
            if fault is not None and fault.kind == "stale_frame" and self._last_exposure_s:
                exposure_s = self._last_exposure_s
            files = self._expose(exposure_s)
            self.events.extend((GP_EVENT_FILE_ADDED, f) for f in files[1:])
            self._complete()
            self._last_capture = files[0]
            return files[0]

    def _complete(self) -> None:
        if self.signals_capture_complete:
            self.events.append((GP_EVENT_CAPTURE_COMPLETE, None))

    def next_event(self) -> tuple[int, object] | None:
        with self._lock:
            return self.events.popleft() if self.events else None

    def read_file(self, path: tuple[str, str]) -> bytes:
        with self._lock:
            if path not in self.files:
                raise GPhoto2Error(GP_ERROR_FILE_NOT_FOUND)
            return self.files[path]

    def delete_file(self, path: tuple[str, str]) -> None:
        with self._lock:
            if path not in self.files:
                raise GPhoto2Error(GP_ERROR_FILE_NOT_FOUND)
            del self.files[path]
            self.ram_files.discard(path)

    def settings_text(self) -> dict[str, str]:
        with self._lock:
            return {name: str(value) for name, value in self.values.items()}

    # ---------------------------------------------------------------- internals

    def _shutter_name(self) -> str | None:
        for name in ("shutterspeed", "shutterspeed2"):
            if name in self.values:
                return name
        return None

    def _timed_exposure_s(self) -> float:
        name = self._shutter_name()
        if name is None:
            return 1.0 / 60.0
        seconds = exposure_seconds(str(self.values[name]))
        if seconds is None:
            # A capture with the shutter on bulb/time: the camlib cannot complete it.
            raise GPhoto2Error(GP_ERROR)
        return seconds

    def _bulb(self, press: bool) -> None:
        shutter = self._shutter_name()
        if shutter is None or str(self.values[shutter]).casefold() != "bulb":
            raise GPhoto2Error(GP_ERROR)  # bulb needs the shutter on bulb (dial on M/B)
        if press:
            self._bulb_opened_at = self.clock.now()
            return
        if self._bulb_opened_at is None:
            return
        exposure_s = self.clock.now() - self._bulb_opened_at
        self._bulb_opened_at = None
        files = self._store(exposure_s)
        self.events.extend((GP_EVENT_FILE_ADDED, f) for f in files)
        self._complete()
        self._last_capture = files[0]

    def _expose(self, exposure_s: float) -> list[tuple[str, str]]:
        in_ram = self._target_is_ram()
        if in_ram and len(self.ram_files) >= self.sdram_capacity:
            raise GPhoto2Error(GP_ERROR_CAMERA_BUSY)
        self.clock.sleep(exposure_s)
        return self._store(exposure_s)

    def _target_is_ram(self) -> bool:
        return "ram" in str(self.values.get("capturetarget", "Internal RAM")).casefold()

    def _store(self, exposure_s: float) -> list[tuple[str, str]]:
        self._last_exposure_s = exposure_s
        in_ram = self._target_is_ram()
        layout = self.layout
        image_format = str(self.values.get("imageformat", self.values.get("imagequality", "RAW")))
        paths: list[tuple[str, str]] = []
        for file_format in formats_for(image_format):
            self._file_counter += 1
            request = FrameRequest(
                index=len(self.frames) + 1,
                exposure_s=exposure_s,
                settings=self.settings_text(),
                file_format=file_format,
                time_s=self.clock.now(),
                model=self.model,
            )
            self.frames.append(request)
            extension = layout.raw_extension if file_format == "raw" else layout.jpeg_extension
            if in_ram:
                folder = layout.ram_folder
                name = layout.ram_name.format(index=self._file_counter) + extension.lower()
            else:
                folder = layout.card_folder
                name = layout.card_name.format(index=self._file_counter) + extension
            path = (folder, name)
            self.files[path] = self.frame_source(request)
            if in_ram:
                self.ram_files.add(path)
            paths.append(path)
        return paths
