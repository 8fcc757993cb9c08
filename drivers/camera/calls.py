"""The libgphoto2 call boundary: every call on the watchdog thread, recorded in the transcript.

gphoto2 is a C library, not a byte stream, so the camera's transcript records it at its API: one
``call`` entry (name and arguments), then a ``return`` (a summary of the result, never image bytes:
their size and sha256; a configuration tree in full, so that replay can rebuild it)
or an ``error`` (libgphoto2 code and text, or the deadline that passed), each a UTF-8 JSON object
with the elapsed time. This is what session replay reads back.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import time
from collections.abc import Callable
from typing import Any, Literal, TypeVar

from drivers.base import DeviceTimeout, TranscriptEntry, TranscriptSink
from drivers.camera.watchdog import CallTimedOut, CallWatchdog

__all__ = ["LibraryCalls", "summarise"]

T = TypeVar("T")


def summarise(value: object) -> object:
    """A JSON-friendly summary of a libgphoto2 argument or result (no image bytes)."""
    if value is None or isinstance(value, str | int | float | bool):
        return value
    if isinstance(value, tuple | list):
        return [summarise(v) for v in value]
    if hasattr(value, "folder") and hasattr(value, "name"):
        return {"folder": str(value.folder), "name": str(value.name)}
    if hasattr(value, "get_name") and hasattr(value, "get_type"):
        widget: Any = value
        summary: dict[str, object] = {"widget": str(widget.get_name())}
        with contextlib.suppress(Exception):  # containers have no value
            summary["value"] = summarise(widget.get_value())
        if _count_children(widget):
            summary["tree"] = [_describe_widget(child) for child in _children(widget)]
        return summary
    if hasattr(value, "get_name") and hasattr(value, "get_value") and hasattr(value, "__len__"):
        pairs: Any = value  # a CameraList (autodetect, folder listings)
        return [[str(pairs.get_name(i)), pairs.get_value(i)] for i in range(len(pairs))]
    if isinstance(value, bytes | bytearray | memoryview):
        return {"bytes": len(value), "sha256": hashlib.sha256(value).hexdigest()}
    return {"type": type(value).__name__}


def _count_children(widget: Any) -> int:
    try:
        return int(widget.count_children())
    except Exception:  # not a widget container (port info), or the bindings refuse
        return 0


def _children(widget: Any) -> list[Any]:
    return [widget.get_child(index) for index in range(_count_children(widget))]


def _describe_widget(widget: Any) -> dict[str, object]:
    """A configuration (sub)tree in full: what session replay needs to rebuild it.

    Name, type code, read-only flag, value, choices or range, and the children; a ``get_config``
    result is recorded this way so that replay can hand the driver the same tree.
    """
    node: dict[str, object] = {
        "widget": str(widget.get_name()),
        "type": int(widget.get_type()),
        "readonly": bool(widget.get_readonly()),
    }
    with contextlib.suppress(Exception):  # containers have no value
        node["value"] = summarise(widget.get_value())
    with contextlib.suppress(Exception):  # only RADIO and MENU widgets have choices
        count = int(widget.count_choices())
        if count:
            node["choices"] = [str(widget.get_choice(index)) for index in range(count)]
    with contextlib.suppress(Exception):  # only RANGE widgets have a range
        node["range"] = [float(bound) for bound in widget.get_range()]
    children = _children(widget)
    if children:
        node["children"] = [_describe_widget(child) for child in children]
    return node


class LibraryCalls:
    """Runs and records the library calls of one camera.

    Parameters
    ----------
    device
        Label for errors and transcript entries (may change when the camera moves port).
    error_type
        The library's exception class (``gphoto2.GPhoto2Error``), recorded with code and text.
    transcript
        Where entries go (``None``: not recorded).
    default_timeout_s
        Deadline of a call that does not give its own.
    on_timeout
        Called when a call misses its deadline (the camera marks its session as stuck).
    """

    def __init__(
        self,
        device: str,
        error_type: type[BaseException],
        transcript: TranscriptSink | None,
        default_timeout_s: float,
        on_timeout: Callable[[], None],
    ) -> None:
        self.device = device
        self._error_type = error_type
        self._transcript = transcript
        self._default_timeout_s = default_timeout_s
        self._on_timeout = on_timeout
        self._watchdog = CallWatchdog(f"gphoto2-{device}")
        self.stuck_calls = 0
        """Calls abandoned after missing their deadline (their thread may still be inside)."""

    def record(self, direction: Literal["call", "return", "error", "event"], body: object) -> None:
        if self._transcript is None:
            return
        payload = json.dumps(body, ensure_ascii=False, default=str).encode("utf-8")
        self._transcript.record(TranscriptEntry(self.device, direction, payload, time.monotonic()))

    def event(self, name: str, **details: object) -> None:
        """Record a driver decision (retry, re-init, download …) among the calls."""
        self.record("event", {"event": name, **details})

    def call(
        self, name: str, function: Callable[..., T], *args: object, timeout_s: float | None = None
    ) -> T:
        """Run ``function(*args)`` on the watchdog thread; record call and return/error.

        Raises
        ------
        DeviceTimeout
            The call did not return within ``timeout_s``; its thread is abandoned.
        """
        deadline_s = self._default_timeout_s if timeout_s is None else timeout_s
        self.record("call", {"call": name, "args": [summarise(a) for a in args]})
        started = time.monotonic()
        try:
            result = self._watchdog.call(lambda: function(*args), timeout_s=deadline_s, name=name)
        except CallTimedOut as exc:
            self.stuck_calls += 1
            self._on_timeout()
            self.record("error", {"call": name, "timeout_s": exc.timeout_s})
            raise DeviceTimeout(
                self.device,
                f"libgphoto2 {name} did not return within {exc.timeout_s:g} s; the camera "
                "will be re-initialised before its next use",
                command=name,
                timeout_s=exc.timeout_s,
            ) from None
        except self._error_type as exc:
            error: Any = exc
            self.record(
                "error",
                {
                    "call": name,
                    "code": error.code,
                    "message": str(error.string),
                    "elapsed_s": round(time.monotonic() - started, 6),
                },
            )
            raise
        self.record(
            "return",
            {
                "call": name,
                "result": summarise(result),
                "elapsed_s": round(time.monotonic() - started, 6),
            },
        )
        return result

    def close(self) -> None:
        self._watchdog.close()
