"""A lamp whose spectrum contradicts its declared kind is warned (lamp_kind_mismatch).

FL2 declared ``--kind led`` (or LED-B3 declared ``--kind fluorescent``) gave exit 0 without a word
and a curve off by up to 0.2. The check reads the lamp's spectrum alone
(:func:`calib.wavelength.peaks.narrow_lines`); its rule was judged on colour-science's tables.
"""

from __future__ import annotations

import numpy as np
import pytest

from calib.core.lamp_kinds import LampKind
from calib.core.lamp_specs import RGB_LEDS, lamp_from_spec
from calib.core.observations import LampObservation
from calib.core.spectra import Spectrum
from calib.pipeline.estimate import input_flags, lamp_kind_mismatch
from calib.wavelength.peaks import narrow_lines

FLUORESCENT = [f"FL{k}" for k in range(1, 13)] + [f"FL3.{k}" for k in range(1, 16)]
BROADBAND = [
    *(f"LED-B{k}" for k in range(1, 6)),
    "LED-BH1",
    "LED-RGB1",
    "LED-V1",
    "LED-V2",
    "A",
    "D50",
    "D55",
    "D65",
    "D75",
    *RGB_LEDS,
]
#: The built-in emission line lists (solar/fraunhofer are absorption features on a continuum).
BUILTIN_EMISSION = ["hg", "ne", "ar", "hg-ar", "na", "he", "h", "cd", "cfl-triphosphor"]


@pytest.mark.parametrize("name", FLUORESCENT)
def test_every_fluorescent_table_shows_a_mercury_line(name: str) -> None:
    labels = {peak.label for peak in narrow_lines(lamp_from_spec(name))}
    assert labels & {"Hg 404.7", "Hg 435.8", "Hg 546.1"}


@pytest.mark.parametrize("name", BROADBAND)
def test_no_led_daylight_or_incandescent_table_shows_a_line(name: str) -> None:
    assert narrow_lines(lamp_from_spec(name)) == []


@pytest.mark.parametrize("name", BUILTIN_EMISSION)
def test_the_builtin_line_spectra_show_lines(name: str) -> None:
    assert narrow_lines(lamp_from_spec(f"builtin:{name}"))


def _observation(
    spectrum: Spectrum, kind: LampKind, bandwidth_nm: float | None = None
) -> LampObservation:
    pixel = np.arange(10.0)
    return LampObservation(
        name="L1",
        spectrum=spectrum,
        pixel=pixel,
        profile=np.repeat(np.exp(-0.25 * (pixel - 4.5) ** 2)[:, None], 3, axis=1),
        kind=kind,
        spectrum_bandwidth_nm=bandwidth_nm,
    )


def test_a_fluorescent_spectrum_declared_led_is_warned() -> None:
    message = lamp_kind_mismatch(_observation(lamp_from_spec("FL2"), "led"))
    assert message is not None
    assert message.startswith("lamp 'L1' is declared --kind led but its spectrum has narrow")
    assert "looks fluorescent: declare it --kind fluorescent" in message
    assert "kind: fluorescent in config.yaml) to map from its lines" in message
    assert "435 nm" in message


def test_an_led_spectrum_declared_fluorescent_is_warned() -> None:
    message = lamp_kind_mismatch(_observation(lamp_from_spec("LED-B3"), "fluorescent"))
    assert message is not None
    assert "looks broadband/LED; its lines cannot anchor the mapping" in message


@pytest.mark.parametrize(
    ("spec", "kind"),
    [
        ("FL2", "fluorescent"),
        ("LED-B3", "led"),
        ("A", "halogen"),
        ("builtin:cfl-triphosphor", "fluorescent"),
        ("builtin:hg", "fluorescent"),
        ("FL2", "other"),
        ("LED-B3", "narrowband"),
    ],
)
def test_a_kind_its_spectrum_agrees_with_is_not_warned(spec: str, kind: LampKind) -> None:
    assert lamp_kind_mismatch(_observation(lamp_from_spec(spec), kind)) is None


def test_a_spectrum_through_a_broad_slit_is_not_judged() -> None:
    """Through an i1Pro-class slit a line is about as wide as an LED band: no verdict."""
    assert lamp_kind_mismatch(_observation(lamp_from_spec("FL2"), "led", 15.0)) is None


def test_the_mismatch_is_a_quality_flag_of_the_inputs() -> None:
    flags = input_flags(
        [
            _observation(lamp_from_spec("FL2"), "led"),
            _observation(lamp_from_spec("LED-B3"), "led"),
        ],
        image_input=False,
    )
    assert [flag.code for flag in flags] == ["lamp_kind_mismatch"]
    assert flags[0].severity == "warning"
