"""Session replay: the real drivers on stand-ins that serve a recorded session's transcripts.

- :mod:`.script` — a transcript as a script; the checking sink; :class:`ReplayMismatch`.
- :mod:`.serial_port`, :mod:`.usb_backend`, :mod:`.gphoto2` — the stand-ins of pyserial, pyusb and
  python-gphoto2.
- :mod:`.station` — opens the recorded devices' drivers on them (:func:`open_replay`);
  :class:`RecordingServer` is what ``rig replay`` loads through the ``spectral_rig.replay`` entry
  point.

The rig's side (reading the session safely, running the recorded plan, comparing the logs) is
:mod:`rig.replay`; this package never imports ``rig``.
"""

from mocks.replay.gphoto2 import FrameSource, ReplayGphoto2
from mocks.replay.script import CheckingSink, Mismatches, ReplayMismatch, ReplayScript
from mocks.replay.station import (
    RecordedDevice,
    RecordingServer,
    ReplayBench,
    ReplayUnsupported,
    open_replay,
)

__all__ = [
    "CheckingSink",
    "FrameSource",
    "Mismatches",
    "RecordedDevice",
    "RecordingServer",
    "ReplayBench",
    "ReplayGphoto2",
    "ReplayMismatch",
    "ReplayScript",
    "ReplayUnsupported",
    "open_replay",
]
