"""Fixtures for the camera tests: a fake gphoto2 world on a simulated clock, and fast policies."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from drivers.base import ListTranscript
from drivers.camera import CameraTimeouts, GphotoCamera, RecoveryPolicy, open_camera
from mocks.fake_gphoto2 import FakeBody, FakeGphoto2, canon_eos_body
from mocks.lamps import SimulatedClock

#: Short deadlines for the tests that inject a hang or a late answer, so that these end quickly.
FAST_TIMEOUTS = CameraTimeouts(
    call_s=0.5, init_s=0.5, capture_overhead_s=1.0, download_s=1.0, event_poll_ms=10, drain_ms=1
)
#: Deadlines where an answer is due: the fake answers in microseconds, so these cost nothing, and a
#: loaded machine (CI, a parallel suite) can starve the driver's worker thread for longer than
#: FAST_TIMEOUTS, which would turn an answer into a spurious timeout.
REPLY_TIMEOUTS = CameraTimeouts(
    call_s=10.0, init_s=10.0, capture_overhead_s=10.0, download_s=10.0, event_poll_ms=10, drain_ms=1
)
FAST_RECOVERY = RecoveryPolicy(max_attempts=3, busy_backoff_s=0.001, reinit_backoff_s=0.001)


@dataclass
class CameraRig:
    """A fake camera world and a driver opened on it."""

    gp: FakeGphoto2
    body: FakeBody
    camera: GphotoCamera
    clock: SimulatedClock
    transcript: ListTranscript


@pytest.fixture
def clock() -> SimulatedClock:
    return SimulatedClock()


def canon_rig(clock: SimulatedClock, timeouts: CameraTimeouts) -> Iterator[CameraRig]:
    body = canon_eos_body(clock=clock)
    gp = FakeGphoto2([body])
    transcript = ListTranscript()
    camera = open_camera(
        gphoto2_module=gp,
        transcript=transcript,
        timeouts=timeouts,
        recovery=FAST_RECOVERY,
        exposure_timer=clock,
    )
    yield CameraRig(gp, body, camera, clock, transcript)
    gp.release_hangs()
    camera.close()
    assert gp.calls_after_exit == [], "the driver used a gp.Camera after exit()"


@pytest.fixture
def canon(clock: SimulatedClock) -> Iterator[CameraRig]:
    """A Canon body and the driver on it, with deadlines for answers that come."""
    yield from canon_rig(clock, REPLY_TIMEOUTS)


@pytest.fixture
def canon_fast(clock: SimulatedClock) -> Iterator[CameraRig]:
    """The same with short deadlines, for a test that injects a hang or a late answer."""
    yield from canon_rig(clock, FAST_TIMEOUTS)


def open_on(gp: FakeGphoto2, clock: SimulatedClock, **kwargs: object) -> GphotoCamera:
    """Open a camera on ``gp`` with deadlines for answers that come (keyword arguments override)."""
    options: dict[str, object] = {
        "gphoto2_module": gp,
        "timeouts": REPLY_TIMEOUTS,
        "recovery": FAST_RECOVERY,
        "exposure_timer": clock,
    }
    options.update(kwargs)
    return open_camera(**options)  # type: ignore[arg-type]
