"""A tethered camera over python-gphoto2 (libgphoto2); implements :class:`drivers.base.Camera`.

What the driver does for the rig
--------------------------------
- Finds the camera by model and/or port (``usb:001,004``) among those libgphoto2 autodetects.
- Reads and sets configuration widgets by name. Logical names (``shutterspeed``, ``aperture``,
  ``iso``, ``whitebalance``, ``imageformat``, ``capturetarget``) map to whichever widget the body
  has (``f-number`` or ``aperture``, ``imageformat`` or ``imagequality`` …); any raw widget name
  works too. Requested values are matched to the widget's choices (exposure strings and apertures to
  the nearest in stops, ``RAW`` to the full RAW format), the value is written, **read back**, and the
  read-back value is returned; a camera that does not take the value raises
  :class:`~drivers.base.StateMismatch`.
- Captures to SDRAM or card, waits for every file the capture produces (RAW+JPEG arrives as a second
  file-added event), downloads the RAW to the given path (temporary name, fsync, rename) and deletes
  the files on the camera. Exposures longer than the longest shutter choice are made in bulb with the
  host timing the exposure.
- Every libgphoto2 call runs on a worker thread with a deadline (:mod:`drivers.camera.watchdog`): a
  call that never returns ends in :class:`~drivers.base.DeviceTimeout`, and the camera is
  re-initialised with a new ``gp.Camera`` before it is used again.
- Recovers from the known failure modes with bounded retries: PTP busy / I/O in progress (-110:
  drain events, back off, retry), claim errors (-53) and I/O errors (re-init with a new ``gp.Camera``,
  then retry; settings the driver made are re-applied and verified), the same file returned twice
  (retake). A camera that has gone raises :class:`~drivers.base.Disconnected`.
- Records every libgphoto2 call in the transcript as ``call``/``return``/``error`` entries, each a
  UTF-8 JSON object.

The ``gphoto2`` module is a parameter (default: ``import gphoto2``) so tests can pass a stand-in with
the same call surface (``mocks.fake_gphoto2``).
"""

from __future__ import annotations

import contextlib
import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol, TypeVar

from drivers.base import (
    CapturedFile,
    DeviceBusy,
    DeviceError,
    DeviceIdentity,
    DeviceTimeout,
    Disconnected,
    InstrumentError,
    ProtocolError,
    SettingInfo,
    StateMismatch,
    TranscriptSink,
)
from drivers.camera.calls import LibraryCalls
from drivers.camera.detect import GphotoModule, camera_list_pairs, load_gphoto2, select_camera
from drivers.camera.errors import (
    BUSY_ADVICE,
    CLAIM_ADVICE,
    GP_FILE_NOT_FOUND,
    SettingValueError,
    UnsupportedSetting,
    classify_gphoto_error,
)
from drivers.camera.exposure import ExposureTable, format_exposure, is_bulb_choice, parse_exposure_s
from drivers.camera.files import CameraPath, files_per_capture, local_path, primary_file
from drivers.camera.widgets import SETTING_WIDGETS, WidgetTable, same_value, value_text
from drivers.local_files import write_atomically

__all__ = [
    "BULB_MAX_EXPOSURE_S",
    "SETTING_WIDGETS",
    "CameraTimeouts",
    "ExposureTimer",
    "GphotoCamera",
    "RecoveryPolicy",
    "open_camera",
]

T = TypeVar("T")
CaptureTarget = Literal["sdram", "card"]

BULB_MAX_EXPOSURE_S = 3600.0
"""Longest bulb exposure the driver will time."""
READBACK_ATTEMPTS = 3
"""Reads of a setting after writing it before a difference counts (bodies apply some late)."""
READBACK_INTERVAL_S = 0.2


@dataclass(frozen=True)
class CameraTimeouts:
    """Deadlines of libgphoto2 calls, seconds unless named ``_ms``.

    Attributes
    ----------
    call_s
        Configuration reads/writes and other short calls.
    init_s
        ``init`` (camlib load, USB claim, PTP session open).
    capture_overhead_s
        A capture may take the exposure time plus this (mirror, processing, writing).
    download_s
        ``file_get`` of one file (a 60 MB RAW over USB 2 takes a few seconds).
    event_poll_ms
        ``wait_for_event`` timeout while waiting for a file (bulb, RAW+JPEG companion).
    drain_ms
        ``wait_for_event`` timeout while emptying the queue after a capture whose files have all
        arrived, on bodies that do not signal capture-complete.
    companion_wait_s
        How long a RAW+JPEG capture waits for its second file.
    """

    call_s: float = 10.0
    init_s: float = 30.0
    capture_overhead_s: float = 30.0
    download_s: float = 120.0
    event_poll_ms: int = 500
    drain_ms: int = 100
    companion_wait_s: float = 5.0


@dataclass(frozen=True)
class RecoveryPolicy:
    """Bounded retries for the known libgphoto2 failure modes.

    Attributes
    ----------
    max_attempts
        Attempts of one operation (and retakes of one frame) before giving up.
    busy_backoff_s
        Wait after a busy answer, doubled on each further attempt.
    reinit_backoff_s
        Wait before re-initialising after an I/O or claim error.
    max_drain_events
        Events read at most while draining the queue (a body that floods events cannot stall us).
    """

    max_attempts: int = 3
    busy_backoff_s: float = 0.5
    reinit_backoff_s: float = 1.0
    max_drain_events: int = 50


class ExposureTimer(Protocol):
    """Times bulb exposures: ``now()`` in seconds and ``sleep(seconds)`` (a simulated clock fits)."""

    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class _WallTimer:
    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))


class GphotoCamera:
    """A camera driven through libgphoto2. Open it with :func:`open_camera`.

    Notes
    -----
    Not thread-safe: one caller at a time (all library calls run on the driver's own worker thread
    anyway). After a watchdog timeout the old ``gp.Camera`` object is abandoned, never touched again
    (calling into it while a call is stuck in it could corrupt libgphoto2's state).
    """

    def __init__(
        self,
        gp: GphotoModule,
        model: str | None = None,
        port: str | None = None,
        *,
        transcript: TranscriptSink | None = None,
        timeouts: CameraTimeouts | None = None,
        recovery: RecoveryPolicy | None = None,
        capture_target: CaptureTarget | None = "sdram",
        delete_after_download: bool = True,
        exposure_timer: ExposureTimer | None = None,
    ) -> None:
        self._gp = gp
        self._timeouts = timeouts or CameraTimeouts()
        self._recovery = recovery or RecoveryPolicy()
        if self._recovery.max_attempts < 1:
            raise ValueError("RecoveryPolicy.max_attempts must be at least 1")
        self._delete_after_download = delete_after_download
        self._timer: ExposureTimer = exposure_timer or _WallTimer()
        self._lib = LibraryCalls(
            f"gphoto2 camera {model or ''} {port or ''}".strip(),
            gp.GPhoto2Error,
            transcript,
            self._timeouts.call_s,
            on_timeout=self._session_stuck,
        )
        self._camera: Any = None
        self._camera_stuck = False
        self._needs_init = True
        self._closed = False
        self._widgets = WidgetTable({})
        self._applied: dict[str, str] = {}
        """Widget values this driver set; re-applied after a re-init."""
        self._seen_files: set[CameraPath] = set()
        self._bulb_exposure_s: float | None = None
        self._reinit_count = 0
        self._sessions_opened = 0
        try:
            self._model, self._port = self._locate(model, port)
            self._lib.device = f"{self._model} on {self._port}"
            self._with_recovery("init", lambda: None)
            if capture_target is not None and self._widgets.find("capturetarget") is not None:
                self.set_setting("capturetarget", capture_target)
        except BaseException:
            self._lib.close()
            raise

    @property
    def device(self) -> str:
        """Label in errors and transcripts: ``"<model> on <port>"``."""
        return self._lib.device

    # ==================================================================== Camera protocol

    def identify(self) -> DeviceIdentity:
        self._check_open()
        extra = {
            "libgphoto2": self._library_version(),
            "reinitialisations": str(self._reinit_count),
        }
        manufacturer = self._widgets.identity("manufacturer")
        if manufacturer:
            extra["manufacturer"] = manufacturer
        return DeviceIdentity(
            kind="camera",
            model=self._model,
            serial=self._widgets.identity("serial"),
            firmware=self._widgets.identity("firmware"),
            port=self._port,
            extra=extra,
        )

    def list_settings(self) -> dict[str, SettingInfo]:
        """Every configuration widget (by widget name) with its value and choices, freshly read."""
        self._check_open()
        self._with_recovery("get_config", self._load_config)
        return {
            name: SettingInfo(name, w.value, w.choices, w.read_only)
            for name, w in self._widgets.widgets.items()
        }

    def get_setting(self, name: str) -> str:
        """Read a setting (logical or widget name) from the camera."""
        self._check_open()
        widget = self._resolve(name)
        return self._with_recovery(f"read {widget}", lambda: self._read_value(widget))

    def set_setting(self, name: str, value: str) -> str:
        """Set a setting by logical or widget name; return the value read back.

        Choice widgets take the matching choice (see the module docstring); the shutter widget
        takes exposure strings (``"1/125"``, ``"0.3"``, ``"30"``, ``'1"'``, ``"bulb"``) and snaps to
        the nearest available speed.

        Raises
        ------
        UnsupportedSetting
            No such widget on this camera, or it is read-only.
        SettingValueError
            The value matches no choice or is outside the range.
        StateMismatch
            The camera did not take the value (e.g. mode dial not on M for the shutter speed).
        """
        self._check_open()
        widget_name = self._resolve(name)
        widget = self._widgets[widget_name]
        if widget.read_only:
            raise UnsupportedSetting(self.device, f"setting {widget_name!r} is read-only")
        try:
            choice = self._widgets.choose(name, widget_name, str(value))
        except ValueError as exc:
            raise SettingValueError(self.device, f"{widget_name}: {exc}") from exc
        read_back = self._write_verified(widget_name, choice)
        if self._widgets.is_shutter(widget_name) and not is_bulb_choice(read_back):
            self._bulb_exposure_s = None
        return read_back

    def apply_settings(
        self, settings: dict[str, str], *, skip_unsupported: bool = False
    ) -> dict[str, str]:
        """Set several settings in order; return the values read back.

        With ``skip_unsupported`` a setting the camera does not offer is left out of the result
        instead of raising (ISO, white balance … "when the camera offers them").
        """
        read_back: dict[str, str] = {}
        for name, value in settings.items():
            if skip_unsupported and self._widgets.find(name) is None:
                self._lib.record("event", {"event": "setting_not_offered", "setting": name})
                continue
            read_back[name] = self.set_setting(name, value)
        return read_back

    def exposure_range_s(self) -> tuple[float, float]:
        """Shortest timed exposure and longest exposure (bulb-timed when the camera has bulb)."""
        table = self._exposure_table()
        try:
            shortest, longest = table.shortest_s, table.longest_s
        except ValueError as exc:
            raise SettingValueError(self.device, str(exc)) from exc
        if self._bulb_usable(table):
            longest = max(longest, BULB_MAX_EXPOSURE_S)
        return shortest, longest

    def set_exposure(self, exposure_s: float) -> float:
        """Select the exposure nearest to ``exposure_s``; return what was set, read back.

        Longer than the longest timed choice (by more than
        :data:`~drivers.camera.exposure.BULB_THRESHOLD_STOPS`) on a camera with bulb: the shutter
        widget is set to bulb and the next :meth:`capture` holds the shutter open for
        ``exposure_s`` seconds (timed by the host).
        """
        self._check_open()
        table = self._exposure_table()
        shutter = self._resolve("shutterspeed")
        if not (exposure_s > 0 and math.isfinite(exposure_s)):
            raise SettingValueError(self.device, f"exposure must be > 0 s, got {exposure_s}")
        if table.needs_bulb(exposure_s) and self._bulb_usable(table):
            if exposure_s > BULB_MAX_EXPOSURE_S:
                raise SettingValueError(
                    self.device,
                    f"exposure {format_exposure(exposure_s)} exceeds the bulb limit of "
                    f"{format_exposure(BULB_MAX_EXPOSURE_S)}",
                )
            assert table.bulb_choice is not None
            self._write_verified(shutter, table.bulb_choice)
            self._bulb_exposure_s = exposure_s
            return exposure_s
        try:
            choice, _ = table.nearest(exposure_s)
        except ValueError as exc:
            raise SettingValueError(self.device, str(exc)) from exc
        read_back = self._write_verified(shutter, choice)
        self._bulb_exposure_s = None
        return parse_exposure_s(read_back)

    def capture(self, destination: Path, *, sync: bool = True) -> CapturedFile:
        """Expose one frame, download it to ``destination`` and delete it on the camera.

        Parameters
        ----------
        destination
            File path for the frame. Without a suffix, the camera file's (lower-case) suffix is
            appended. Parent directories are created. The file appears atomically (temporary name,
            fsync, rename), so a crash never leaves a truncated frame under the final name.
        sync
            ``False`` leaves the fsyncs to the caller, which syncs the file before it acknowledges
            it (the rig's session does, off the camera's critical path); the rename stays atomic.

        Returns
        -------
        CapturedFile
            The local path, the path on the camera, the exposure (for bulb: as timed by the host)
            and the exposure-relevant settings read back.

        Notes
        -----
        RAW+JPEG captures produce two files; the RAW one is downloaded and both are deleted from
        the camera. A capture that returns a file already downloaded in this session is retaken
        (up to ``RecoveryPolicy.max_attempts`` frames).
        """
        self._check_open()
        destination = Path(destination)
        if destination.is_dir():
            raise ValueError(f"capture destination {destination} is a directory; give a file path")
        exposure_s, bulb = self._pending_exposure()
        repeated: CameraPath | None = None
        for frame_attempt in range(1, self._recovery.max_attempts + 1):
            if bulb:
                camera_path, exposure_s = self._bulb_capture(exposure_s)
            else:
                camera_path = self._with_recovery(
                    "capture", functools.partial(self._timed_capture, exposure_s)
                )
            added = self._collect_added_files(files_per_capture(self._image_format()))
            produced = [p for p in [camera_path, *added] if p not in self._seen_files]
            if camera_path in self._seen_files:
                repeated = camera_path
                self._lib.record(
                    "event",
                    {
                        "event": "same_file_returned",
                        "file": "/".join(camera_path),
                        "attempt": frame_attempt,
                    },
                )
            if not produced:
                continue  # nothing new came out of this capture: take the frame again
            primary = primary_file(produced)
            local = local_path(destination, primary)
            try:
                self._with_recovery(
                    "download", functools.partial(self._download, primary, local, sync=sync)
                )
            except InstrumentError as exc:
                if exc.code != str(GP_FILE_NOT_FOUND):
                    raise
                self._lib.record("event", {"event": "file_vanished", "file": "/".join(primary)})
                continue  # lost in a re-init (SDRAM is cleared): take the frame again
            self._seen_files.update(produced)
            if self._delete_after_download:
                for camera_file in produced:
                    self._delete(camera_file)
            return CapturedFile(
                path=local,
                camera_path="/".join(primary).replace("//", "/"),
                exposure_s=exposure_s,
                settings=self._capture_settings(bulb),
            )
        shown = "/".join(repeated) if repeated else "nothing"
        raise ProtocolError(
            self.device,
            f"{self._recovery.max_attempts} captures in a row produced no new file",
            command="capture",
            reply=shown,
        )

    def reinitialise(self) -> None:
        """Drop the libgphoto2 session and open a new one with a new ``gp.Camera`` object."""
        self._check_open()
        self._needs_init = True
        self._with_recovery("init", lambda: None)

    def close(self) -> None:
        """End the libgphoto2 session (``exit``) and stop the worker thread. Idempotent."""
        if self._closed:
            return
        self._closed = True
        camera, self._camera = self._camera, None
        if camera is not None and not self._camera_stuck:
            with contextlib.suppress(self._gp.GPhoto2Error, DeviceTimeout):
                self._lib.call("exit", camera.exit)
        self._lib.close()

    def __enter__(self) -> GphotoCamera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ==================================================================== library calls

    def _session_stuck(self) -> None:
        """A call missed its deadline: never touch this session again; open a new one."""
        self._camera_stuck = True
        self._needs_init = True

    def _with_recovery(self, what: str, operation: Callable[[], T]) -> T:
        """Run ``operation`` (re-initialising first when needed), recovering per error class."""
        last_error: Any = None
        for attempt in range(1, self._recovery.max_attempts + 1):
            try:
                if self._needs_init:
                    self._initialise()
                return operation()
            except self._gp.GPhoto2Error as exc:
                last_error = exc
                error_class = classify_gphoto_error(exc.code)
                if error_class not in ("busy", "claim", "io", "timeout"):
                    raise self._typed_error(exc, what) from exc
                if attempt == self._recovery.max_attempts:
                    break
                self._lib.record(
                    "event",
                    {"event": "retry", "operation": what, "attempt": attempt, "code": exc.code},
                )
                if error_class == "busy":
                    self._drain_events()
                    time.sleep(self._recovery.busy_backoff_s * 2 ** (attempt - 1))
                else:
                    self._needs_init = True
                    time.sleep(self._recovery.reinit_backoff_s)
        raise self._typed_error(last_error, what, attempts=self._recovery.max_attempts)

    def _typed_error(self, exc: Any, what: str, attempts: int | None = None) -> DeviceError:
        code = int(exc.code)
        message = f"{what}: libgphoto2 error {code} ({exc.string})"
        if attempts is not None:
            message += f" after {attempts} attempts"
        error_class = classify_gphoto_error(code)
        if error_class == "busy":
            return DeviceBusy(self.device, f"{message}; {BUSY_ADVICE}")
        if error_class == "claim":
            if self._lib.stuck_calls:
                return DeviceBusy(
                    self.device,
                    f"{message}; a libgphoto2 call of this process is still stuck in an earlier "
                    "session and may hold the USB device: replug the camera or restart the rig",
                )
            return DeviceBusy(self.device, f"{message}; {CLAIM_ADVICE}")
        if error_class == "gone":
            return Disconnected(self.device, f"{message}; the camera is no longer reachable")
        if error_class == "timeout":
            return DeviceTimeout(
                self.device, message, command=what, timeout_s=self._timeouts.call_s
            )
        return InstrumentError(self.device, message, code=str(code), command=what)

    # ==================================================================== session

    def _autodetect(self) -> list[tuple[str, str]]:
        return camera_list_pairs(self._lib.call("autodetect", self._gp.Camera.autodetect))

    def _locate(self, model: str | None, port: str | None) -> tuple[str, str]:
        try:
            detected = self._autodetect()
        except self._gp.GPhoto2Error as exc:
            raise self._typed_error(exc, "autodetect") from exc
        return select_camera(detected, model, port)

    def _relocate(self) -> None:
        """After a failure: find our camera again (a replug changes its USB address)."""
        detected = self._autodetect()
        if (self._model, self._port) in detected:
            return
        same_model = [d for d in detected if d[0] == self._model]
        if len(same_model) != 1:
            raise Disconnected(
                self.device,
                f"the camera is no longer detected (detected now: "
                f"{', '.join(f'{m!r} on {p}' for m, p in detected) or 'none'}); "
                "check the cable, power and battery",
            )
        self._lib.record(
            "event", {"event": "port_changed", "old": self._port, "new": same_model[0][1]}
        )
        self._port = same_model[0][1]
        self._lib.device = f"{self._model} on {self._port}"

    def _initialise(self) -> None:
        """(Re-)open the session with a new ``gp.Camera``; re-apply and verify our settings."""
        old, self._camera = self._camera, None
        if old is not None and not self._camera_stuck:
            with contextlib.suppress(self._gp.GPhoto2Error, DeviceTimeout):
                self._lib.call("exit", old.exit)
        if self._sessions_opened:
            self._reinit_count += 1
            self._lib.record("event", {"event": "reinitialise", "count": self._reinit_count})
            self._relocate()
        self._camera_stuck = False
        gp = self._gp
        camera = self._lib.call("Camera", gp.Camera)
        abilities_list = self._lib.call("CameraAbilitiesList", gp.CameraAbilitiesList)
        self._lib.call("CameraAbilitiesList.load", abilities_list.load)
        model_index = self._lib.call("lookup_model", abilities_list.lookup_model, self._model)
        self._lib.call("set_abilities", camera.set_abilities, abilities_list[model_index])
        port_list = self._lib.call("PortInfoList", gp.PortInfoList)
        self._lib.call("PortInfoList.load", port_list.load)
        port_index = self._lib.call("lookup_path", port_list.lookup_path, self._port)
        self._lib.call("set_port_info", camera.set_port_info, port_list[port_index])
        self._lib.call("init", camera.init, timeout_s=self._timeouts.init_s)
        self._camera = camera
        self._sessions_opened += 1
        self._needs_init = False
        self._load_config()
        # Re-apply what this driver set (a new session may start from defaults). Errors here
        # belong to the enclosing recovery loop, so no nested retries.
        for widget_name, value in self._applied.items():
            self._write_widget(widget_name, value)
            self._verify(widget_name, value, recover=False)

    def _load_config(self) -> None:
        root = self._lib.call("get_config", self._camera.get_config)
        self._widgets = WidgetTable.from_tree(root, self._gp)

    # ==================================================================== settings

    def _resolve(self, name: str) -> str:
        widget_name = self._widgets.find(name)
        if widget_name is None:
            raise UnsupportedSetting(self.device, self._widgets.missing_message(name))
        return widget_name

    def _read_value(self, widget_name: str) -> str:
        widget = self._lib.call("get_single_config", self._camera.get_single_config, widget_name)
        value = value_text(widget.get_value())
        if widget_name in self._widgets.widgets:
            self._widgets[widget_name].value = value
        return value

    def _write_widget(self, widget_name: str, value: str) -> None:
        widget = self._lib.call("get_single_config", self._camera.get_single_config, widget_name)
        self._lib.call("CameraWidget.set_value", widget.set_value, self._typed_value(widget, value))
        self._lib.call("set_single_config", self._camera.set_single_config, widget_name, widget)

    def _typed_value(self, widget: Any, value: str) -> object:
        widget_type = widget.get_type()
        if widget_type in (self._gp.GP_WIDGET_TOGGLE, self._gp.GP_WIDGET_DATE):
            return int(value)
        if widget_type == self._gp.GP_WIDGET_RANGE:
            return float(value)
        return value

    def _write_verified(self, widget_name: str, value: str) -> str:
        self._with_recovery(f"set {widget_name}", lambda: self._write_widget(widget_name, value))
        read_back = self._verify(widget_name, value)
        self._applied[widget_name] = value
        return read_back

    def _verify(self, widget_name: str, value: str, *, recover: bool = True) -> str:
        """Read ``widget_name`` back until it equals ``value`` (a few tries), else StateMismatch."""
        read_back = ""
        for attempt in range(READBACK_ATTEMPTS):
            if attempt:
                time.sleep(READBACK_INTERVAL_S)
            if recover:
                read_back = self._with_recovery(
                    f"read {widget_name}", lambda: self._read_value(widget_name)
                )
            else:
                read_back = self._read_value(widget_name)
            if same_value(read_back, value):
                return read_back
        hint = ""
        if self._widgets.is_shutter(widget_name):
            hint = " (is the mode dial on M, or B for bulb?)"
        raise StateMismatch(
            self.device,
            f"{widget_name} read back after setting it{hint}",
            expected=value,
            actual=read_back,
        )

    def _library_version(self) -> str:
        try:
            version = self._gp.gp_library_version(self._gp.GP_VERSION_SHORT)
        except (AttributeError, self._gp.GPhoto2Error):
            return "unknown"
        return str(version[0]) if version else "unknown"

    # ==================================================================== exposure

    def _exposure_table(self) -> ExposureTable:
        self._check_open()
        self._resolve("shutterspeed")
        return self._widgets.exposure_table()

    def _bulb_usable(self, table: ExposureTable) -> bool:
        return table.bulb_choice is not None and self._widgets.bulb_trigger() is not None

    def _pending_exposure(self) -> tuple[float, bool]:
        """The exposure the next capture makes, and whether it is a bulb exposure."""
        shutter = self._resolve("shutterspeed")
        current = self._with_recovery(f"read {shutter}", lambda: self._read_value(shutter))
        if is_bulb_choice(current):
            if self._bulb_exposure_s is None:
                raise SettingValueError(
                    self.device,
                    "the shutter is on bulb but no exposure time was given; call "
                    "set_exposure(seconds) first",
                )
            return self._bulb_exposure_s, True
        try:
            return parse_exposure_s(current), False
        except ValueError as exc:
            raise SettingValueError(
                self.device, f"cannot tell the exposure from {shutter}={current!r}: {exc}"
            ) from exc

    def _capture_settings(self, bulb: bool) -> dict[str, str]:
        settings: dict[str, str] = {}
        for logical in (
            "shutterspeed",
            "aperture",
            "iso",
            "whitebalance",
            "imageformat",
            "capturetarget",
        ):
            name = self._widgets.find(logical)
            if name is not None:
                settings[name] = self._widgets[name].value
        if bulb and self._bulb_exposure_s is not None:
            settings["bulb_requested_s"] = f"{self._bulb_exposure_s:g}"
        return settings

    # ==================================================================== capture

    def _timed_capture(self, exposure_s: float) -> CameraPath:
        path = self._lib.call(
            "capture",
            self._camera.capture,
            self._gp.GP_CAPTURE_IMAGE,
            timeout_s=exposure_s + self._timeouts.capture_overhead_s,
        )
        return (str(path.folder), str(path.name))

    def _bulb_capture(self, exposure_s: float) -> tuple[CameraPath, float]:
        trigger = self._widgets.bulb_trigger()
        if trigger is None:
            raise UnsupportedSetting(self.device, "no bulb control widget (bulb, eosremoterelease)")
        self._with_recovery("bulb press", lambda: self._write_widget(trigger.widget, trigger.press))
        opened = self._timer.now()
        try:
            self._timer.sleep(exposure_s)
        finally:
            closing = self._timer.now()
            # Always close the shutter, even when interrupted.
            self._with_recovery(
                "bulb release", lambda: self._write_widget(trigger.widget, trigger.release)
            )
        measured_s = closing - opened
        self._lib.record(
            "event", {"event": "bulb", "requested_s": exposure_s, "timed_s": measured_s}
        )
        return self._wait_for_new_file(self._timeouts.capture_overhead_s), measured_s

    def _wait_for_event(self, timeout_ms: int) -> tuple[int, Any]:
        event_type, data = self._lib.call(
            "wait_for_event",
            self._camera.wait_for_event,
            timeout_ms,
            timeout_s=timeout_ms / 1000.0 + self._timeouts.call_s,
        )
        return int(event_type), data

    def _wait_for_new_file(self, within_s: float) -> CameraPath:
        deadline = time.monotonic() + within_s
        while time.monotonic() < deadline:
            event_type, data = self._with_recovery(
                "wait_for_event", lambda: self._wait_for_event(self._timeouts.event_poll_ms)
            )
            if event_type == self._gp.GP_EVENT_FILE_ADDED:
                return (str(data.folder), str(data.name))
        raise DeviceTimeout(
            self.device,
            f"no new file {within_s:g} s after the bulb exposure ended",
            command="wait_for_event",
            timeout_s=within_s,
        )

    def _collect_added_files(self, expected_files: int) -> list[CameraPath]:
        """Read the events a capture queued; return the further files they announce.

        Stops as soon as the body signals capture-complete with every expected file seen;
        otherwise at the first empty wait once the files are in, or when a missing companion
        file (RAW+JPEG) has not come within ``companion_wait_s``.
        """
        added: list[CameraPath] = []
        complete = False
        deadline = time.monotonic() + self._timeouts.companion_wait_s
        for _ in range(self._recovery.max_drain_events):
            have_all = 1 + len(added) >= expected_files
            if have_all and complete:
                break
            wait_ms = self._timeouts.drain_ms if have_all else self._timeouts.event_poll_ms
            event_type, data = self._with_recovery(
                "wait_for_event", functools.partial(self._wait_for_event, wait_ms)
            )
            if event_type == self._gp.GP_EVENT_FILE_ADDED:
                added.append((str(data.folder), str(data.name)))
            elif event_type == self._gp.GP_EVENT_CAPTURE_COMPLETE:
                complete = True
            elif event_type == self._gp.GP_EVENT_TIMEOUT and (
                have_all or time.monotonic() > deadline
            ):
                break
        return added

    def _image_format(self) -> str | None:
        name = self._widgets.find("imageformat")
        return None if name is None else self._widgets[name].value

    def _drain_events(self) -> None:
        """Empty the event queue after a busy answer (best effort, errors ignored)."""
        if self._camera is None or self._needs_init:
            return
        with contextlib.suppress(self._gp.GPhoto2Error):
            for _ in range(self._recovery.max_drain_events):
                event_type, _ = self._wait_for_event(self._timeouts.drain_ms)
                if event_type == self._gp.GP_EVENT_TIMEOUT:
                    return

    def _download(self, camera_file: CameraPath, local: Path, *, sync: bool) -> None:
        folder, name = camera_file

        def fetch() -> bytes:
            data = self._camera.file_get(folder, name, self._gp.GP_FILE_TYPE_NORMAL)
            return bytes(data.get_data_and_size())

        data = self._lib.call("file_get", fetch, timeout_s=self._timeouts.download_s)
        if not data:
            raise ProtocolError(
                self.device,
                "camera sent an empty file",
                command=f"file_get {folder}/{name}",
                reply=b"",
            )
        write_atomically(local, data, sync=sync)
        self._lib.record(
            "event",
            {
                "event": "downloaded",
                "file": f"{folder}/{name}",
                "path": str(local),
                "bytes": len(data),
            },
        )

    def _delete(self, camera_file: CameraPath) -> None:
        folder, name = camera_file
        try:
            self._with_recovery(
                "file_delete",
                lambda: self._lib.call("file_delete", self._camera.file_delete, folder, name),
            )
        except InstrumentError as exc:
            if exc.code != str(GP_FILE_NOT_FOUND):
                raise

    def _check_open(self) -> None:
        if self._closed:
            raise Disconnected(self.device, "the camera driver was closed; open it again")


def open_camera(
    model: str | None = None,
    port: str | None = None,
    *,
    gphoto2_module: GphotoModule | None = None,
    transcript: TranscriptSink | None = None,
    timeouts: CameraTimeouts | None = None,
    recovery: RecoveryPolicy | None = None,
    capture_target: CaptureTarget | None = "sdram",
    delete_after_download: bool = True,
    exposure_timer: ExposureTimer | None = None,
) -> GphotoCamera:
    """Find and open a camera.

    Parameters
    ----------
    model, port
        Select among autodetected cameras (``None`` = the only one present).
    gphoto2_module
        The ``gphoto2`` module; default the real python-gphoto2.
    transcript
        Where every libgphoto2 call is recorded (JSON ``call``/``return``/``error`` entries).
    timeouts, recovery
        Deadlines and retry policy.
    capture_target
        ``"sdram"`` (fast, nothing left on the card) or ``"card"``; ``None`` leaves the camera's
        setting alone. Ignored when the camera has no ``capturetarget`` widget.
    delete_after_download
        Delete each captured file on the camera once it is downloaded.
    exposure_timer
        Clock that times bulb exposures (default wall clock).
    """
    gp = gphoto2_module if gphoto2_module is not None else load_gphoto2()
    return GphotoCamera(
        gp,
        model,
        port,
        transcript=transcript,
        timeouts=timeouts,
        recovery=recovery,
        capture_target=capture_target,
        delete_after_download=delete_after_download,
        exposure_timer=exposure_timer,
    )
