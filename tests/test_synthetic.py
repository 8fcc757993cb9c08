import csv
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from calib.cli.app import build_app
from calib.cli.synthetic import paper_solve
from calib.core.datasets import colour_science_cameras
from calib.core.errors import InputError
from calib.evaluation.synthetic import (
    band_coverage,
    random_efficiency,
    random_mapping,
    run_protocol,
)
from calib.methods import Makabe2025Options, PriorOptions
from tests.synthetic_cameras import exact_basis, small_data_dir


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

    seen = []
    rows = run_protocol(
        [("smooth", as_spectrum(cameras[0]))],
        basis,
        variants=["true mapping", "LED+Flu"],
        noise_levels=[0.0],
        on_result=lambda scene, row, result: seen.append((scene, row, result)),
    )
    assert {row.variant for row in rows} == {"true mapping", "LED+Flu"}
    # The band judged is the one users get: the σ budget of calib.methods.estimate (decision 0129),
    # the method's own σ (kept in the diagnostics) judged beside it.
    for scene, row, result in seen:
        assert result.quality.uncertainty is not None
        own = result.diagnostics["method_sigma"]
        assert result.sensitivity_sigma is not None
        assert not np.allclose(own, result.sensitivity_sigma)
        assert row.coverage == band_coverage(result, scene.truth)
        assert row.method_coverage == band_coverage(
            replace(result, sensitivity_sigma=own), scene.truth
        )
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
    # The methods' own σ (no budget): this test is about the scene, not the σ.
    paper_only = run_protocol(
        camera, basis, variants=["true mapping"], noise_levels=[0.01], budget=None
    )
    rows = run_protocol(
        camera,
        basis,
        variants=["true mapping", "multilamp: 5 lamps, true mapping"],
        noise_levels=[0.01],
        budget=None,
    )
    # Rendering the extra lamps after the paper's two leaves the paper's variants unchanged.
    assert rows[0].relative_error == paper_only[0].relative_error
    multi = rows[1]
    assert multi.coverage is not None and 0.0 <= multi.coverage <= 1.0
    assert multi.method_coverage == multi.coverage  # without a budget the stated σ is the method's
    assert multi.mapping_relative_error is None and np.isfinite(multi.relative_error)


def test_a_subset_of_the_protocol_renders_the_very_scenes_the_whole_one_does(tmp_path):
    basis, cameras = exact_basis(tmp_path)
    from tests.synthetic_cameras import as_spectrum

    pairs = [("first", as_spectrum(cameras[0])), ("second", as_spectrum(cameras[1]))]
    noise = [0.0, 0.01]
    whole = run_protocol(pairs, basis, variants=["true mapping"], noise_levels=noise, budget=None)
    subset = run_protocol(
        pairs,
        basis,
        variants=["true mapping"],
        noise_levels=noise,
        budget=None,
        only=lambda name, level: name == "second" and level > 0,
    )
    assert [(r.camera, r.noise) for r in subset] == [("second", 0.01)]
    # The scene's seed is its place in the whole protocol, not in the subset: the same noise draw.
    assert subset[0].relative_error == whole[-1].relative_error
    first_noisy = next(r for r in whole if r.camera == "first" and r.noise > 0)
    assert subset[0].relative_error != first_noisy.relative_error


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


def test_the_validation_split_leaves_each_camera_out_of_its_basis(tmp_path):
    from calib.evaluation.synthetic_splits import validation_cameras

    cameras, basis_for, _source = validation_cameras(small_data_dir(tmp_path, 5), n_vectors=3)
    names = [name for name, _ in cameras]
    assert len(names) == 5 and all(name.startswith("Camera") for name in names)
    for name in names:
        kept = basis_for(name).camera_names
        assert name not in kept and len(kept) == 4
        assert not any("600D" in other for other in kept)  # no paper test camera in any basis


@pytest.mark.slow
def test_cli_runs_the_validation_split(tmp_path):
    path = tmp_path / "out.csv"
    arguments = ["synthetic", "--data-dir", str(small_data_dir(tmp_path, 3)), "--split"]
    options = ["--n-vectors", "2", "--noise", "0", "--variant", "true mapping", "--csv", str(path)]
    result = CliRunner().invoke(build_app(), [*arguments, "validation", *options])
    assert result.exit_code == 0, result.output + str(result.exception)
    assert "validation split" in result.output
    with path.open() as handle:
        rows = list(csv.DictReader(handle))
    assert [row["camera"].split(" (")[0] for row in rows] == [f"Camera {k}" for k in range(3)]
    assert all(row["coverage_2sigma"] and row["method_coverage_2sigma"] for row in rows)
    refused = CliRunner().invoke(build_app(), [*arguments, "validation", "--offline"])
    assert refused.exit_code != 0 and "--split" in str(refused.output) + str(refused.exception)


def test_the_table_says_whose_sigma_each_coverage_is():
    from rich.console import Console

    from calib.cli.synthetic import summary_table
    from calib.evaluation.synthetic import SyntheticRow

    rows = [
        SyntheticRow(
            "A (x)", "LED+Flu", 0.0, 0.02, 0.001, 0.002, 0.1, coverage=c, method_coverage=m
        )
        for c, m in ((0.9, 0.5), (1.0, 0.3))
    ]
    console = Console(record=True, width=300)
    console.print(summary_table(rows, "title"))
    text = " ".join(console.export_text().split())  # the caption wraps at the table's width
    assert "[95 % / 40 %]" in text
    assert "[share of the truth inside ±2σ: the stated σ (budget) / the method's own σ]" in text
