import csv

import numpy as np
import pytest
from typer.testing import CliRunner

from calib.cli.app import build_app
from calib.cli.synthetic import paper_solve
from calib.core.datasets import colour_science_cameras
from calib.core.errors import InputError
from calib.evaluation.synthetic import random_efficiency, random_mapping, run_protocol
from calib.methods import Makabe2025Options, PriorOptions
from tests.synthetic_cameras import exact_basis


def test_random_mapping_covers_the_grid_and_is_monotonic():
    rng = np.random.default_rng(1)
    for _ in range(20):
        mapping = random_mapping(rng)
        assert mapping.pixel_range is not None
        pixels = np.linspace(*mapping.pixel_range, 200)
        wavelength = mapping.wavelength_nm(pixels)
        assert wavelength[0] < 400 and wavelength[-1] > 700 and np.all(np.diff(wavelength) > 0)


def test_random_efficiency_is_positive_and_bounded():
    efficiency = random_efficiency(np.random.default_rng(2))
    values = efficiency(np.linspace(400, 700, 301))
    assert values.min() >= 0.29 and values.max() == pytest.approx(1.0, abs=1e-6)


def test_protocol_on_a_spanned_camera_is_nearly_exact(tmp_path):
    basis, cameras = exact_basis(tmp_path)
    from tests.synthetic_cameras import as_spectrum

    rows = run_protocol(
        [("smooth", as_spectrum(cameras[0]))],
        basis,
        variants=["true mapping", "LED+Flu"],
        noise_levels=[0.0],
    )
    assert {row.variant for row in rows} == {"true mapping", "LED+Flu"}
    # The protocol's random η (its 1/η is outside the Fourier span) limits RE; the mapping must be
    # found to a small fraction of a nanometre from the fluorescent lines either way.
    assert all(np.isfinite(row.relative_error) for row in rows)
    flu = next(row for row in rows if row.variant == "LED+Flu")
    assert flu.mapping_relative_error is not None and flu.mapping_relative_error < 0.005


def test_cli_offline_writes_csv(tmp_path):
    path = tmp_path / "out.csv"
    result = CliRunner().invoke(
        build_app(),
        ["synthetic", "--offline", "--noise", "0", "--variant", "true mapping", "--csv", str(path)],
    )
    assert result.exit_code == 0, result.output
    with path.open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == len(colour_science_cameras())
    errors = {row["camera"]: float(row["relative_error"]) for row in rows}
    # The offline basis is far coarser than the 44 measured cameras (RE ~0.12 here vs ~0.04).
    assert errors["Nikon 5100 (NPL)"] < 0.15 and errors["Canon EOS 5D Mark II (rawtoaces)"] < 0.15
    assert "mean" in result.output


def test_multilamp_variants_see_the_same_scene_and_report_coverage(tmp_path):
    basis, cameras = exact_basis(tmp_path)
    from tests.synthetic_cameras import as_spectrum

    camera = [("smooth", as_spectrum(cameras[1]))]
    paper_only = run_protocol(camera, basis, variants=["true mapping"], noise_levels=[0.01])
    rows = run_protocol(
        camera,
        basis,
        variants=["true mapping", "multilamp: 5 lamps, true mapping"],
        noise_levels=[0.01],
    )
    # Rendering the extra lamps after the paper's two leaves the paper's variants unchanged.
    assert rows[0].relative_error == paper_only[0].relative_error
    multi = rows[1]
    assert multi.coverage is not None and 0.0 <= multi.coverage <= 1.0
    assert multi.mapping_relative_error is None and np.isfinite(multi.relative_error)


def test_cli_rejects_an_unknown_variant():
    result = CliRunner().invoke(
        build_app(), ["synthetic", "--offline", "--variant", "multilamp: 9 lamps"]
    )
    assert result.exit_code != 0


def test_cli_rejects_an_unknown_weight_rule():
    result = CliRunner().invoke(
        build_app(),
        ["synthetic", "--offline", "--variant", "multilamp: 5 lamps", "--weight-rule", "guess"],
    )
    assert result.exit_code != 0
    assert "--weight-rule" in str(result.output) + str(result.exception)


def test_the_method_options_say_which_solve_the_paper_variants_run():
    assert paper_solve("prior", None) == PriorOptions()
    assert paper_solve("makabe2025", None) == Makabe2025Options()
    assert paper_solve("makabe2025", "measured") == Makabe2025Options(formulation="measured")
    with pytest.raises(InputError, match="applies to --method makabe2025 only"):
        paper_solve("prior", "measured")
    with pytest.raises(InputError, match="--method"):
        paper_solve("paper", None)  # the old --solver's value is not a method
