"""Opening and closing, the same for every driver: ``with`` support, no half-open devices, and a
close that always releases the port even when the device has gone."""

from __future__ import annotations

import logging
from collections.abc import Callable
from types import TracebackType
from typing import Protocol, Self, TypeVar

from drivers.base import DeviceError

_log = logging.getLogger(__name__)


class _Closeable(Protocol):
    def close(self) -> None: ...


ClosableT = TypeVar("ClosableT", bound=_Closeable)


class ClosesOnExit:
    """Mixin: ``with driver: ...`` calls ``driver.close()`` on the way out."""

    def close(self) -> None:  # pragma: no cover - every user defines it
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()


def connect_or_close(device: ClosableT, connect: Callable[[], object]) -> ClosableT:
    """Run ``connect``; if it fails, close ``device`` (releasing its port) and re-raise."""
    try:
        connect()
    except BaseException:
        device.close()
        raise
    return device


def farewell_then_close(
    label: str, farewell: Callable[[], object] | None, link: _Closeable
) -> None:
    """Run ``farewell`` (leave remote mode …) if given, then close ``link``.

    A device error during the farewell is logged, not raised: closing happens in cleanup paths
    (after an error, on Ctrl-C) where a second exception would hide the first, and the port must be
    released whatever state the instrument is in.
    """
    try:
        if farewell is not None:
            farewell()
    except DeviceError as exc:
        _log.warning("%s: could not leave remote mode on close: %s", label, exc)
    finally:
        link.close()
