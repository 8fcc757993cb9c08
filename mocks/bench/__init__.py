"""The digital twin: the whole rig simulated, with the real drivers speaking to emulated hardware.

Lamps (colour-science spectra with warm-up drift) sit on relay channels of an emulated relay board
(HID over a fake pyusb backend, or LCUS/Numato on a pty); an emulated spectroradiometer (PR-655/670,
CS-2000, byte-level firmware on a pty) measures the lit lamps; a fake gphoto2 body renders every
frame the real camera driver asks for from the lamps that are on: slit, grating (first order,
efficiency, mapping from grooves/mm and geometry), the true camera's sensitivity, Bayer CFA, black
and white level, shot and read noise, saturation, exposure and ISO, written as real DNG files.
Time runs on a simulated clock: warm-ups of minutes take no wall time.

``mocks`` never imports ``rig``: the rig opens the twin through :func:`open_twin` with a
:class:`TwinSpec` built from its configuration data (``rig.twin`` does this), and wraps the result
into its station.

Modules: :mod:`.spec` (what the twin is made of), :mod:`.lamps`, :mod:`.optics` (image formation via
``calib.model.forward``), :mod:`.camera` (frames), :mod:`.truth` (what an estimate is judged against),
:mod:`.station` (opening it all).
"""

from mocks.bench.camera import FrameRenderer
from mocks.bench.optics import TwinOptics
from mocks.bench.spec import CameraSpec, LampSpec, TwinSpec, TwinSpecError
from mocks.bench.station import TwinBench, TwinFaults, open_twin
from mocks.bench.truth import TRUTH_FILE_NAME, TruthFormatError, TwinTruth

__all__ = [
    "TRUTH_FILE_NAME",
    "CameraSpec",
    "FrameRenderer",
    "LampSpec",
    "TruthFormatError",
    "TwinBench",
    "TwinFaults",
    "TwinOptics",
    "TwinSpec",
    "TwinSpecError",
    "TwinTruth",
    "open_twin",
]
