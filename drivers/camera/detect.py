"""Finding cameras: importing python-gphoto2, autodetection, choosing one by model or port."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from drivers.base import DeviceNotFound, DeviceTimeout
from drivers.camera.watchdog import CallTimedOut, CallWatchdog
from drivers.libraries import gphoto2

__all__ = ["GphotoModule", "list_cameras", "load_gphoto2", "select_camera"]

GphotoModule = Any
"""The ``gphoto2`` module, or a stand-in with the same call surface (it is untyped C bindings)."""


def load_gphoto2() -> GphotoModule:
    """Import the real python-gphoto2 (:func:`drivers.libraries.gphoto2`), or explain how to get it."""
    return gphoto2()


def camera_list_pairs(camera_list: Any) -> list[tuple[str, str]]:
    """(name, value) pairs of a libgphoto2 ``CameraList`` (autodetect: model, port)."""
    return [
        (str(camera_list.get_name(i)), str(camera_list.get_value(i)))
        for i in range(len(camera_list))
    ]


def select_camera(
    detected: Sequence[tuple[str, str]], model: str | None, port: str | None
) -> tuple[str, str]:
    """Pick (model, port) among autodetected cameras.

    ``model`` matches exactly (case-insensitive) or, failing that, as a unique substring; ``port``
    matches exactly. Raises :class:`DeviceNotFound` naming what was found when nothing or more than
    one camera fits.
    """
    found = ", ".join(f"{m!r} on {p}" for m, p in detected) or "none"
    candidates = [d for d in detected if port is None or d[1] == port]
    if model is not None:
        exact = [d for d in candidates if d[0].casefold() == model.casefold()]
        candidates = exact or [d for d in candidates if model.casefold() in d[0].casefold()]
    wanted = " ".join(
        part
        for part in (f"model {model!r}" if model else "", f"port {port}" if port else "")
        if part
    )
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        what = f"no camera with {wanted}" if wanted else "no camera detected"
        raise DeviceNotFound(
            "gphoto2 camera",
            f"{what}; detected: {found} (is it on, in PTP mode, and not held by another program?)",
        )
    raise DeviceNotFound(
        "gphoto2 camera",
        f"{len(candidates)} cameras match{' ' + wanted if wanted else ''}: {found}; "
        "set the model and/or port of the one to use",
    )


def list_cameras(
    gphoto2_module: GphotoModule | None = None, *, timeout_s: float = 10.0
) -> list[tuple[str, str]]:
    """(model, port) of every camera libgphoto2 autodetects, under a watchdog deadline."""
    gp = gphoto2_module if gphoto2_module is not None else load_gphoto2()
    watchdog = CallWatchdog("gphoto2-autodetect")
    try:
        camera_list = watchdog.call(gp.Camera.autodetect, timeout_s=timeout_s, name="autodetect")
    except CallTimedOut as exc:
        raise DeviceTimeout(
            "gphoto2",
            f"camera autodetection did not return within {timeout_s:g} s",
            command="autodetect",
            timeout_s=timeout_s,
        ) from exc
    finally:
        watchdog.close()
    return camera_list_pairs(camera_list)
