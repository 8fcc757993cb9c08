"""The twin's camera: a fake gphoto2 body whose frames are rendered from the lamps that are on.

The real camera driver (``drivers.camera``) talks to a :class:`mocks.fake_gphoto2.FakeBody` with a
Canon EOS widget set that stores DNG files; :class:`FrameRenderer` is the body's frame source. For
each frame it

1. mixes the noiseless radiance of the lit lamps from a cache (each lamp's two spectral components,
   rendered once: :func:`mocks.bench.lamps.drift_coefficients` gives the mix at the current
   warm-up state), scaled by ISO and aperture;
2. exposes it with shot noise (Poisson in electrons), read noise, dark current, black level and
   clipping (:func:`mocks.scene.expose`), from a generator seeded by the twin's seed and the rig's
   step (the frame's number when no step was announced), so a step gives the same frame in any
   process, retried or resumed; with the camera's flaws (:mod:`mocks.bench.flaws`) for the
   recorded time × (1 + ε), the shutter's error, keyed the same way;
3. writes a DNG (:func:`mocks.dng.write_dng`: ExposureTime in IFD0, ISO in the EXIF IFD) and hands
   back its bytes;
4. lets the download time pass on the twin's clock (the exposure itself already has: the body
   sleeps it), and with ``realtime`` also in wall time — exposure plus download, less the time the
   rendering took, as a real camera would be busy for.

A frame therefore costs about the noise and the file write.
"""

from __future__ import annotations

import contextlib
import tempfile
import threading
import time
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from calib.core.spectra import Spectrum
from mocks.bench.flaws import CameraFlaws
from mocks.bench.lamps import drift_coefficients, spectral_components
from mocks.bench.optics import REFERENCE_F_NUMBER, REFERENCE_ISO, TwinOptics
from mocks.dng import DngMetadata, write_dng
from mocks.fake_gphoto2 import FakeBody, FrameRequest, StorageLayout, canon_eos_body
from mocks.fake_gphoto2.body import placeholder_frame
from mocks.lamps import LampBank, SimulatedClock, VirtualLamp
from mocks.scene import expose, render_mosaic_radiance

Float32Array = NDArray[np.float32]

#: Random stream of the camera's noise (the spectrometer has its own), mixed with the seed.
CAMERA_NOISE_STREAM = 2
#: Capture times in the DNG files: this moment plus the twin clock's time.
TWIN_EPOCH = datetime(2025, 11, 21, 9, 0, 0)
TWIN_MAKE = "spectral-rig"
TWIN_MODEL = "TwinCam"
TWIN_PORT = "usb:001,009"


@dataclass(frozen=True)
class ExposureSettings:
    """What a frame was taken with: ISO and f-number, read from the body's widgets."""

    iso: float
    f_number: float

    @classmethod
    def from_widgets(cls, settings: Mapping[str, str]) -> ExposureSettings:
        aperture = settings.get("aperture", settings.get("f-number"))
        return cls(
            iso=_number(settings.get("iso"), REFERENCE_ISO),
            f_number=_number(aperture, REFERENCE_F_NUMBER),
        )

    @property
    def light_scale(self) -> float:
        """DN per DN at ISO 100 and f/8: the gain follows ISO, the light the aperture's area."""
        return (self.iso / REFERENCE_ISO) * (REFERENCE_F_NUMBER / self.f_number) ** 2


def _number(text: object, default: float) -> float:
    """``"100"``, ``"f/8"``, ``"8"`` → a number; ``"Auto"`` and anything else → ``default``."""
    if text is None:
        return default
    cleaned = str(text).strip().lower().removeprefix("f/")
    try:
        value = float(cleaned)
    except ValueError:
        return default
    return value if value > 0 else default


class FrameRenderer:
    """The frame source of the twin's body (see the module docstring).

    Parameters
    ----------
    optics
        Slit, grating, lens, sensor and the true camera.
    bank
        The lamps; what is lit at capture time is what the frame shows.
    clock
        The twin's clock (the download time is added to it).
    seed
        The twin's seed.
    download_s
        Simulated download time per frame.
    realtime
        Also let exposure + download pass in wall time.
    flaws
        The camera's stray light (already in ``optics``' layout) and shutter error (``None``: an
        exact shutter).
    """

    def __init__(
        self,
        optics: TwinOptics,
        bank: LampBank,
        clock: SimulatedClock,
        *,
        seed: int,
        download_s: float,
        realtime: bool = False,
        flaws: CameraFlaws | None = None,
    ) -> None:
        self.optics = optics
        self.flaws = flaws
        self.bank = bank
        self.clock = clock
        self.seed = seed
        self.download_s = download_s
        self.realtime = realtime
        self.noise_entropy: tuple[int, ...] | None = None
        """When set (the rig's step, :meth:`mocks.bench.TwinBench.begin_step`), a frame's noise is
        drawn from it instead of from the body's frame number."""
        self.rendered_frames = 0
        self.render_s = 0.0
        """Wall time spent rendering and encoding frames (the rest of a frame's time is waiting)."""
        self.render_cpu_s = 0.0
        """CPU time of the rendering: the frames and the lamps' images rendered in the background
        (the twin's stand-in for the camera and the scene, not the rig's own work)."""
        self._components = {lamp.name: spectral_components(lamp) for lamp in bank.lamps}
        self._cache: dict[tuple[str, int], Future[Float32Array]] = {}
        self._lock = threading.Lock()
        self._scratch = Path(tempfile.mkdtemp(prefix="spectral-rig-twin-"))
        self._preparing: ThreadPoolExecutor | None = None

    def prepare(self) -> None:
        """Start rendering every lamp's components in the background, before their first frame.

        The rendering stands for the physical scene the camera looks at: it runs while the
        station finishes opening and the plan's first steps (relays, warm-up, spectra) run, not
        before them. A frame that needs a component still being rendered waits for it, inside
        the camera's own time.
        """
        with self._lock:
            if self._preparing is not None:
                return
            self._preparing = ThreadPoolExecutor(1, thread_name_prefix="twin-render")
            for lamp in self.bank.lamps:
                for index in range(len(self._components[lamp.name])):
                    key = (lamp.name, index)
                    if key not in self._cache:
                        self._cache[key] = self._preparing.submit(
                            self._render_in_background, self._components[lamp.name][index]
                        )

    def close(self) -> None:
        """Stop the background rendering and remove the scratch directory."""
        if self._preparing is not None:
            self._preparing.shutdown(wait=True, cancel_futures=True)
        with contextlib.suppress(OSError):
            for path in self._scratch.iterdir():
                path.unlink()
            self._scratch.rmdir()

    # -------------------------------------------------------------------------- the scene

    def _render_in_background(self, spectrum: Spectrum) -> Float32Array:
        started = time.thread_time()
        try:
            return self._render(spectrum)
        finally:
            with self._lock:
                self.render_cpu_s += time.thread_time() - started

    def _render(self, spectrum: Spectrum) -> Float32Array:
        signal = self.optics.first_order(spectrum).signal
        return render_mosaic_radiance(self.optics.layout, signal, self.optics.sensor)

    def _component(self, lamp: VirtualLamp, index: int) -> Float32Array:
        key = (lamp.name, index)
        with self._lock:
            cached = self._cache.get(key)
            if cached is None:
                cached = self._cache[key] = Future()
                ours = True
            else:
                ours = False
        if ours:
            try:
                cached.set_result(self._render(self._components[lamp.name][index]))
            except BaseException as exc:
                cached.set_exception(exc)
                with self._lock:
                    del self._cache[key]
                raise
        return cached.result()

    def noiseless(self, settings: ExposureSettings) -> Float32Array:
        """Shape ``(height, width)``: what each pixel collects from the lit lamps now, DN/s."""
        sensor = self.optics.sensor
        radiance = np.zeros((sensor.height_px, sensor.width_px), dtype=np.float32)
        for lamp, seconds_on in self.bank.lit():
            components = self._components[lamp.name]
            weights = drift_coefficients(lamp, components, seconds_on)
            if weights is None:
                axis = lamp.spectrum.wavelength_nm
                now = Spectrum(axis, lamp.radiance(axis, seconds_on), name=lamp.name)
                radiance += self._render(now)
                continue
            for index, weight in enumerate(weights):
                radiance += np.float32(weight) * self._component(lamp, index)
        radiance *= np.float32(settings.light_scale)
        return radiance

    # -------------------------------------------------------------------------- frames

    def __call__(self, request: FrameRequest) -> bytes:
        started = time.perf_counter()
        cpu_started = time.thread_time()
        if request.file_format == "jpeg":
            data = placeholder_frame(request)
        else:
            data = self._raw_frame(request)
        self.clock.advance(self.download_s)
        elapsed = time.perf_counter() - started
        self.render_s += elapsed
        with self._lock:
            self.render_cpu_s += time.thread_time() - cpu_started
        self.rendered_frames += 1
        if self.realtime:
            remaining = request.exposure_s + self.download_s - elapsed
            if remaining > 0:
                time.sleep(remaining)
        return data

    def _raw_frame(self, request: FrameRequest) -> bytes:
        settings = ExposureSettings.from_widgets(request.settings)
        base = self.optics.sensor
        scale = settings.iso / REFERENCE_ISO
        sensor = replace(
            base,
            gain_dn_per_electron=base.gain_dn_per_electron * scale,
            dark_current_dn_per_s=base.dark_current_dn_per_s * scale,
        )
        frame = (request.index,) if self.noise_entropy is None else self.noise_entropy
        rng = np.random.default_rng(
            np.random.SeedSequence([self.seed, CAMERA_NOISE_STREAM, *frame])
        )
        exposed_s = request.exposure_s
        if (
            self.flaws is not None and self.flaws.exposure_sigma > 0
        ):  # the shutter's error: the DNG records the requested time
            exposed_s *= 1.0 + self.flaws.frame_exposure_error(self.seed, frame)
        raw = expose(self.noiseless(settings), exposed_s, sensor, rng)
        metadata = DngMetadata(
            exposure_s=request.exposure_s,
            iso=round(settings.iso),
            f_number=settings.f_number,
            make=TWIN_MAKE,
            model=TWIN_MODEL,
            cfa_pattern=base.cfa_pattern,
            black_level_dn=base.black_level_dn,
            white_level_dn=base.white_level_dn,
            capture_time=TWIN_EPOCH + timedelta(seconds=request.time_s),
        )
        path = write_dng(self._scratch / f"frame-{request.index:05d}.dng", raw, metadata)
        try:
            return path.read_bytes()
        finally:
            path.unlink(missing_ok=True)


def twin_body(renderer: FrameRenderer, clock: SimulatedClock, serial: str) -> FakeBody:
    """The twin's camera body: a Canon-like body (third-stop shutter table 30 s…1/8000 s and bulb,
    apertures, ISO, image formats with RAW) that stores its RAW frames as DNG files."""
    body = canon_eos_body(
        port=TWIN_PORT,
        model=f"{TWIN_MAKE} {TWIN_MODEL}",
        serial=serial,
        frame_source=renderer,
        clock=clock,
    )
    body.values["manufacturer"] = TWIN_MAKE
    body.layout = StorageLayout(
        card_folder="/store_00010001/DCIM/100TWIN",
        card_name="TWIN{index:04d}",
        raw_extension=".DNG",
    )
    return body
