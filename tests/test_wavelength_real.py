"""The mapping on real grating captures (``../shared/data/real-grating``; skipped when absent).

Nikon D7000: the CFL through the built-in tri-phosphor list (no CFL spectrum was measured) puts the
mercury lines — the only lines of the lamp whose wavelengths are known to better than a phosphor
band's ±0.5 nm — where the mapping says, and the mirrored export gives the same curve. Canon 10D:
sunlight's Fraunhofer and telluric features, at the columns the upstream author marked (read from
his R Markdown at run time), sit where the mapping found from the profile and the solar spectrum
puts them.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calib.core.lamp_specs import lamp_from_spec
from calib.core.line_lists import line_list
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, Spectrum, read_spectrum_csv
from calib.image.profile_files import read_fits_profile, read_rawproc_dat
from calib.model.bases import CameraPrior, default_camera_basis
from calib.wavelength.locate import MappingSolution, locate_mapping
from tests.conftest import SHARED_CAMERA_DATA, SHARED_REAL_GRATING

pytestmark = pytest.mark.shared_data


@pytest.fixture(scope="module")
def d7000_lamps() -> list[LampObservation]:
    if not SHARED_REAL_GRATING.is_dir():
        pytest.skip(f"real grating data not found at {SHARED_REAL_GRATING}")
    folder = SHARED_REAL_GRATING / "butcher-nikon-d7000-2020-08"
    return [
        read_rawproc_dat(folder / "D7000_calibration.dat").to_observation(
            "CFL", lamp_from_spec("builtin:cfl-triphosphor"), kind="fluorescent"
        ),
        read_rawproc_dat(folder / "D7000_spectrum.dat").to_observation(
            "halogen", read_spectrum_csv(folder / "Dedolight_5nm.csv"), kind="halogen"
        ),
    ]


@pytest.fixture(scope="module")
def d7000_prior() -> CameraPrior:
    if not SHARED_CAMERA_DATA.is_dir():
        pytest.skip(f"reference camera data not found at {SHARED_CAMERA_DATA}")
    return default_camera_basis(data_dir=SHARED_CAMERA_DATA).prior()


@pytest.fixture(scope="module")
def d7000_solution(d7000_lamps, d7000_prior) -> MappingSolution:
    return locate_mapping(d7000_lamps, d7000_prior, DEFAULT_GRID)


def test_d7000_cfl_lines(d7000_solution):
    rows = {row["line"]: row for row in d7000_solution.matched_lines}
    mercury = [rows[label] for label in ("Hg 435.8", "Hg 546.1")]
    assert all(row["weight"] > 0 and abs(row["residual_nm"]) < 0.15 for row in mercury)
    # The phosphor peaks are listed to ±0.5 nm: their residuals stay within 2σ of it.
    used = [row for row in d7000_solution.matched_lines if row["weight"] > 0]
    assert len(used) >= 8 and all(abs(row["residual_nm"]) < 1.0 for row in used)
    assert not d7000_solution.warnings


def test_d7000_mirrored_gives_the_same_curve(d7000_lamps, d7000_prior, d7000_solution):
    mirrored = [
        replace(lamp, profile=lamp.profile[::-1], profile_sigma=None) for lamp in d7000_lamps
    ]
    flipped = locate_mapping(mirrored, d7000_prior, DEFAULT_GRID)
    pixel = d7000_lamps[0].pixel
    difference = d7000_solution.exact.wavelength_nm(pixel) - flipped.exact.wavelength_nm(
        pixel[::-1]
    )
    assert float(np.max(np.abs(difference))) < 0.15
    ends = flipped.exact.wavelength_nm(pixel[[0, -1]])
    assert ends[0] > ends[1]  # the mirrored profile's wavelength falls with the column


def _authors_markers(rmd: Path) -> dict[str, int]:
    """The four columns (1-based) the author marked, by Fraunhofer name, read from his R Markdown."""
    text = rmd.read_text(encoding="utf-8")
    columns = re.search(r"x\s*=\s*c\(([\d,\s]+)\)", text)
    names = re.search(r"name\s*=\s*c\(([^)]*)\)", text)
    assert columns and names, "the upstream R Markdown no longer holds its calibration table"
    labels = [name.strip().strip('"') for name in names.group(1).split(",")]
    return dict(zip(labels, (int(v) for v in columns.group(1).split(",")), strict=True))


def test_canon_10d_fraunhofer_mapping(shared_real_grating, shared_camera_data):
    folder = shared_real_grating / "rrogge-canon-eos-10d"
    wehrli = np.loadtxt(folder / "Wehrli85.csv", skiprows=1, usecols=(0, 1))
    atmosphere = np.loadtxt(folder / "Atmosphere Transmission.csv", skiprows=1)
    keep = (wehrli[:, 0] >= 350) & (wehrli[:, 0] <= 800)
    axis = wehrli[keep, 0]
    sun = Spectrum(
        axis, wehrli[keep, 1] * np.interp(axis, atmosphere[:, 0], atmosphere[:, 1]), name="sun"
    )
    paths = [folder / f"Solar Spectrum Canon EOS 10D {c}.fit" for c in "RGB"]
    observation = read_fits_profile(paths).to_observation(
        "sunlight", sun, kind="other", spectrum_bandwidth_nm=1.0
    )
    prior = default_camera_basis(data_dir=shared_camera_data, exclude=["Canon 10D"]).prior()
    solution = locate_mapping([observation], prior, DEFAULT_GRID)
    assert "absorption" in str(solution.details.get("line_source"))
    # The dips sit at the list's wavelengths: the solar spectrum's scale adds nothing to σ
    # (decision 0077), the listed lines' floor does.
    assert "listed_lines_floor_nm" in solution.details
    assert "spectrometer_scale_sigma_nm" not in solution.details
    solar = {line.label: line.wavelength_nm for line in line_list("solar")}
    reference = {
        "G": solar["Fraunhofer G"],
        "H β": solar["Fraunhofer F (H-beta)"],
        "D1+D2": 0.5 * (solar["Fraunhofer D1"] + solar["Fraunhofer D2"]),
        "H α": solar["Fraunhofer C (H-alpha)"],
    }
    markers = _authors_markers(folder / "Spectral Response Canon EOS 10D.Rmd")
    # The author's columns are whole pixels, 1-based: ±0.5 column is ~0.1 nm here.
    columns = np.array([markers[name] - 1 for name in reference], dtype=float)
    fitted = solution.exact.wavelength_nm(observation.pixel[0] + columns)
    residual = fitted - np.array(list(reference.values()))
    rms_nm = float(np.sqrt(np.mean(residual**2)))
    # Issue 16's target is 0.5 nm; the converged fit gave 0.67 here (decision 0064: the 0.43
    # before was a 50-iteration stop on the way), G 1.3 nm off; with the absorption blends at
    # their first moments (decision 0095) 0.45, G 0.88 nm off.
    assert rms_nm < 0.75
    # The stated σ is the scatter the family leaves (decision 0064), within 2× of the actual.
    stated_nm = solution.mapping.wavelength_rms_nm
    assert stated_nm is not None and 0.5 < rms_nm / stated_nm < 2.0
