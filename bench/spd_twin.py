"""The rig as a spectrometer on twin-rendered DNGs: SPD error, recognition and CCT for every source.

Renders (as the digital twin does: ``calib.model.forward`` at 1 nm → ``mocks.scene`` → ``mocks.dng``, with
shot and read noise) a fluorescent mapping lamp (FL2, its spectrum measured) and then every source of
the colour-science library plus two halogen lamps (Planckian at 3000 and 3200 K), each as its own
HDR bracket, and runs ``calib spd``'s pipeline (:func:`calib.spd.pipeline.measure_spd`) on each. Prints
one line per source and the issue-8 targets: RMS of the normalised SPD (LED and halogen ≤ 5 %),
recognition (every library source), CCT within 50 K of the true SPD's (Ohno 2013).

    python bench/spd_twin.py [--slit-px 12] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np

from calib.core.lamp_specs import colour_lamp
from calib.core.spectra import Spectrum, write_csv
from calib.spd.alvarez2014 import spd_rms_error
from calib.spd.light_sources import colour_library, correlated_colour_temperature
from calib.spd.pipeline import SpdRequest, measure_spd

# The twin-rendering helpers live with the tests (tests/spd_scenes.py): run from the checkout.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.spd_scenes import efficiency_spectrum, nikon_camera, render_lamp


def planckian(temperature_k: float) -> Spectrum:
    import colour

    sd = colour.sd_blackbody(temperature_k, colour.SpectralShape(360, 830, 1))
    return Spectrum(
        sd.wavelengths, sd.values / sd.values.max(), name=f"halogen {temperature_k:g} K"
    )


def is_led_or_halogen(name: str) -> bool:
    return "LED" in name or name.startswith(("halogen", "PHOS", "Luxeon"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slit-px", type=float, default=12.0)
    parser.add_argument("--only", nargs="*", default=None, help="library names to run")
    options = parser.parse_args()
    camera, efficiency = nikon_camera(), efficiency_spectrum()
    library = colour_library()
    sources: list[tuple[Spectrum, str | None]] = [
        (entry.spectrum, entry.name) for entry in library.entries
    ]
    sources += [(planckian(3000.0), None), (planckian(3200.0), None)]
    if options.only:
        sources = [(s, n) for s, n in sources if s.name in options.only]
    with tempfile.TemporaryDirectory() as temporary:
        root = Path(temporary)
        mapping = render_lamp(
            root / "fl2",
            colour_lamp("FL2"),
            camera=camera,
            efficiency=efficiency,
            rng=np.random.default_rng(11),
            slit_px=options.slit_px,
        )
        camera_csv = write_csv(root / "camera.csv", camera)
        efficiency_csv = write_csv(root / "efficiency.csv", efficiency)
        mapping_spectrum = write_csv(root / "fl2.csv", colour_lamp("FL2"))

        def request(images: list[Path], out: Path, name: str) -> SpdRequest:
            return SpdRequest(
                images=tuple(images),
                camera=camera_csv,
                out=out,
                grating_efficiency=efficiency_csv,
                mapping_images=tuple(mapping.frames),
                mapping_spectrum=mapping_spectrum,
                name=name,
                plots=False,
            )

        print(
            f"{'source':42s} {'RMS %':>6s} {'match':>5s} {'dist':>7s} {'margin':>7s} "
            f"{'ΔCCT K':>7s} {'ΔCCT lib':>8s} {'time s':>6s}"
        )
        wrong, rows = [], []
        for index, (spectrum, library_name) in enumerate(sources):
            directory = root / f"lamp{index:03d}"
            rendered = render_lamp(
                directory / "frames",
                spectrum,
                camera=camera,
                efficiency=efficiency,
                rng=np.random.default_rng(zlib.crc32(spectrum.name.encode())),
                slit_px=options.slit_px,
            )
            started = time.perf_counter()
            measurement = measure_spd(request(rendered.frames, directory / "out", spectrum.name))
            elapsed = time.perf_counter() - started
            rms = spd_rms_error(measurement.spd, spectrum)
            recognised = library_name is None or library_name in measurement.recognition.names
            if not recognised:
                wrong.append((library_name, measurement.recognition.name))
            true_cct = correlated_colour_temperature(spectrum).cct_k["Ohno 2013"]
            cct = measurement.summary["cct"]
            delta = cct["recovered (completed with the match)"]["cct_k"]["Ohno 2013"] - true_cct
            delta_library = cct["library match (paper)"]["cct_k"]["Ohno 2013"] - true_cct
            if library_name is None:  # not in the library: no match to compare with
                delta_library = float("nan")
            rows.append((spectrum.name, rms, delta, delta_library))
            print(
                f"{spectrum.name[:42]:42s} {100 * rms:6.2f} {'yes' if recognised else 'NO':>5s} "
                f"{measurement.recognition.distance:7.4f} {measurement.recognition.margin:7.4f} "
                f"{delta:+7.0f} {delta_library:+8.0f} "
                f"{elapsed:6.2f}",
                flush=True,
            )
    led_halogen = [r for r in rows if is_led_or_halogen(r[0])]
    print()
    print(
        f"LED and halogen sources: {len(led_halogen)}, max RMS "
        f"{100 * max(r[1] for r in led_halogen):.2f} % (target ≤ 5 %), max |ΔCCT| "
        f"{max(abs(r[2]) for r in led_halogen):.0f} K (target ≤ 50 K)"
    )
    print(
        f"all sources: {len(rows)}, max RMS {100 * max(r[1] for r in rows):.2f} %, "
        f"max |ΔCCT| {max(abs(r[2]) for r in rows):.0f} K (recovered, completed), "
        f"{max(abs(r[3]) for r in rows if not np.isnan(r[3])):.0f} K (library match)"
    )
    library_rows = sum(1 for _, n in sources if n is not None)
    print(
        f"recognised: {library_rows - len(wrong)} / {library_rows} library sources"
        + (f"; wrong: {wrong}" if wrong else "")
    )


if __name__ == "__main__":
    main()
