"""The spectrometers labs own estimate the camera as the PR-655 does (issue 20), on the shipped
configuration's twin (``bench/spectrometer_equivalence.py`` measures more draws).

- Ocean (``emulate: seabreeze``) and ArgyllCMS (``emulate: argyll``, spotread ``-H``) sessions
  land as close to the truth as the PR-655's (the issue's RE target, read against the truth:
  between estimates the PR-655's own 8 nm slit sets a floor above it, decision 0035).
- An i1Pro's standard bands (25 nm slit, 10 nm samples, ``high_resolution: false``): the
  whole-profile mapping fit through so broad a slit is several nm off, and the measured lamp's Hg
  lines must still place the mapping — or the estimate must say it could not, with a σ as broad as
  the slit (decision 0047)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import calib.wavelength.locate as locate
from calib.core.errors import EstimationError
from calib.core.mapping import QuadraticMapping
from calib.core.metrics import relative_error
from calib.core.spectra import DEFAULT_GRID
from calib.pipeline import OfflineEstimate, OfflineSettings, estimate_offline
from rig.capture import run_capture
from rig.compare import CheckedSession, check_session, twin_basis
from rig.config import RigConfig, load_config
from rig.twin import write_twin_truth

CONFIG = Path(__file__).resolve().parents[2] / "config.yaml"


def _captured(directory: Path, draw: int = 0, **spectrometer: object) -> CheckedSession:
    """The shipped configuration's twin measured by ``spectrometer`` (``devices.spectrometer``
    fields), its spectrometer's noise draw ``draw``, with the twin's truth written."""
    data = load_config(CONFIG).model_dump(mode="json")
    data["devices"]["spectrometer"].update(spectrometer, noise_draw=draw)
    data["output_dir"] = str(directory)
    config = RigConfig.model_validate(data)
    outcome = run_capture(config)
    assert outcome.exit_status == "success", outcome
    write_twin_truth(config, outcome.session)
    return check_session(outcome.session)


@pytest.fixture(scope="module")
def standard_bands_session(tmp_path_factory: pytest.TempPathFactory) -> CheckedSession:
    """spotread's standard bands, the noise draw whose whole-profile fit lands 4 nm off at
    550 nm (14 nm at the red end)."""
    directory = tmp_path_factory.mktemp("sessions")
    return _captured(directory, 1, emulate="argyll", high_resolution=False)


def _estimate(checked: CheckedSession) -> OfflineEstimate:
    basis = twin_basis(checked.truth.camera)
    return estimate_offline(checked.lamps, OfflineSettings(basis=basis), known_inputs=checked.known)


def _red_end_error_nm(checked: CheckedSession, extracted: OfflineEstimate) -> float:
    mapping = extracted.result.mapping
    assert mapping is not None
    red = next(o for o in extracted.observations if o.kind != "fluorescent").pixel[-1:]
    return float(mapping.wavelength_nm(red)[0] - checked.truth.mapping.wavelength_nm(red)[0])


def test_the_lines_place_the_mapping_from_the_profile_fits_next_basin(
    standard_bands_session: CheckedSession,
) -> None:
    extracted = _estimate(standard_bands_session)
    details = extracted.result.mapping.details  # type: ignore[union-attr]
    assert details["line_source"] == "Hg lines of FL2 (measured lamp)"
    assert abs(_red_end_error_nm(standard_bands_session, extracted)) < 1.0
    assert "coarse_spectrometer" in {flag.code for flag in extracted.result.quality.flags}


def test_a_broad_slit_whose_lines_fail_warns_and_states_the_slits_sigma(
    standard_bands_session: CheckedSession, monkeypatch: pytest.MonkeyPatch
) -> None:
    def unmatched(*_: object) -> None:
        raise EstimationError("none of the line matches held")

    monkeypatch.setattr(locate, "_lines_from_basins", unmatched)
    extracted = _estimate(standard_bands_session)
    result = extracted.result
    mapping = result.mapping
    assert isinstance(mapping, QuadraticMapping) and mapping.wavelength_rms_nm is not None
    slit_sigma_nm = 25.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    assert mapping.wavelength_rms_nm >= slit_sigma_nm - 1e-9
    # The stated σ holds the fit's actual miss at the red end within 2σ.
    assert abs(_red_end_error_nm(standard_bands_session, extracted)) < 2 * slit_sigma_nm
    warned = [flag.line() for flag in result.quality.flags if flag.code == "mapping_line_residuals"]
    assert any("25 nm slit" in text and "spotread -H" in text for text in warned), warned
    truth = standard_bands_session.truth.sensitivity.resample(DEFAULT_GRID, "interpolate").values
    assert result.sensitivity_sigma is not None
    found = result.physical_sensitivity()
    sigma = result.sensitivity_sigma * found.max() / result.sensitivity.max()
    assert np.mean(np.abs(found - truth) <= 2 * sigma) >= 0.9


@pytest.mark.slow
def test_ocean_and_argyll_sessions_estimate_as_the_pr655_does(tmp_path: Path) -> None:
    errors = {}
    found = {}
    for name, fields in (
        ("pr655", {"emulate": "pr655"}),
        ("usb2000plus", {"emulate": "seabreeze", "ocean_model": "USB2000PLUS"}),
        ("i1pro-hires", {"emulate": "argyll", "high_resolution": True}),
    ):
        checked = _captured(tmp_path / name, **fields)
        truth = checked.truth.sensitivity.resample(DEFAULT_GRID, "interpolate").values
        found[name] = _estimate(checked).result.physical_sensitivity()
        errors[name] = 100 * relative_error(found[name], truth)
    # bench/spectrometer_equivalence.py --draws 4 (×10⁻²), RE vs truth minus the PR-655's: +0.17 to
    # +0.31 (USB2000+), −0.41 to +0.31 (spotread -H); between the estimates 0.44–0.56 and
    # 0.83–1.38. Until decision 0176 the PR-655's estimate took its spectra at the stated 8 nm
    # while the twin's slit is ×0.886 of it (RE 1.26); at the slit its Hg lines measure, 1.15. The
    # USB2000+'s 1.5 nm slit is not corrected (the check's floor there is 20 %), and its estimate
    # is the same as before (1.37), so its margin over the PR-655 grew from 0.00–0.16 to this.
    # That margin is the camera's red edge on the 10 nm grid, not the spectra: solved on 5 nm
    # the two agree within 0.08 against the truth (decision 0177), but 5 nm loses on validation.
    for name in ("usb2000plus", "i1pro-hires"):
        assert errors[name] - errors["pr655"] <= 0.35, errors
    # Between the estimates: the PR-655's 8 nm and the i1Pro's 15 nm slits set floors of their
    # own (0.45 and 1.65 noise-free with the true mapping, decision 0035).
    between = {n: 100 * relative_error(found[n], found["pr655"]) for n in found if n != "pr655"}
    assert between["usb2000plus"] <= 1.0 and between["i1pro-hires"] <= 2.0, between
