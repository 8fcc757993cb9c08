"""calib compare: scenes, the adapter table over the registry, the run, the report and the CLI."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from typer.testing import CliRunner

from calib.cli.app import build_app
from calib.core.datasets import colour_science_cameras
from calib.core.errors import EstimationError, InputError
from calib.evaluation.compare import (
    SyntheticAdapter,
    SyntheticSource,
    active_adapters,
    run_comparison,
    synthetic_adapters,
)
from calib.evaluation.compare_report import markdown_report, plot_grid, write_csv
from calib.methods import ESTIMATION_METHODS
from calib.model.bases import fallback_camera_basis

#: Toivonen options small enough for plumbing tests (not for accuracy).
TINY_TOIVONEN = {"ensemble_size": 2, "epochs": 200}


@pytest.fixture(scope="module")
def nikon():
    return colour_science_cameras()[0]


@pytest.fixture(scope="module")
def source(nikon):
    return SyntheticSource(
        [(nikon.name, nikon.sensitivity)],
        fallback_camera_basis(exclude=[nikon.camera]),
        noise_levels=(0.0, 0.01),
        n_patches=12,
        basis_description="offline",
    )


def test_synthetic_scenes_hold_every_method_input_and_are_seeded(source):
    scenes = list(source.scenes())
    again = list(source.scenes())
    assert [scene.noise for scene in scenes] == [0.0, 0.01]
    clean, noisy = scenes
    assert clean.chart.patch_sigma is None and noisy.chart.patch_sigma is not None
    assert clean.chart.n_patches == 24 and clean.transmissive.n_patches == 12
    assert clean.transmissive.kind == "transmissive"
    assert clean.color_matrices.matrices.shape == (2, 3, 3)
    assert clean.color_matrices.illuminants == ("A", "D65")
    assert clean.fluorescent.kind == "fluorescent" and clean.broadband.direct_rgb is not None
    np.testing.assert_array_equal(noisy.chart.patch_rgb, again[1].chart.patch_rgb)
    np.testing.assert_array_equal(noisy.broadband.profile, again[1].broadband.profile)
    assert noisy.seed == again[1].seed and noisy.seed != clean.seed
    assert "synthetic protocol" in source.description and "noise 0 %, 1 %" in source.description


def test_columns_follow_the_registry(monkeypatch):
    adapters = synthetic_adapters(n_patches=12)
    chosen, skipped = active_adapters(adapters)
    methods = {adapter.method for adapter in chosen}
    assert {
        "prior",
        "makabe2025",
        "jiang2013",
        "han2012",
        "solomatov2023",
        "toivonen2020",
    } <= methods
    assert ("multilamp" in methods) == ("multilamp" in ESTIMATION_METHODS)
    assert "toivonen2020 (12 patches)" in [adapter.label for adapter in chosen]

    def unadapted(observations, **kwargs):
        raise AssertionError

    monkeypatch.setitem(ESTIMATION_METHODS, "newmethod", unadapted)
    _, skipped = active_adapters(adapters)
    assert "newmethod" in skipped
    only, _ = active_adapters(adapters, ["JIANG2013"])
    assert [adapter.label for adapter in only] == ["jiang2013 (CC)"]
    with pytest.raises(InputError, match="unknown methods \\['nope'\\]"):
        active_adapters(adapters, ["nope"])


def test_an_input_the_method_does_not_declare_fails_its_row(source):
    """Columns call the registry with explicit inputs; a mismatch is a named failure, not ignored."""
    wrong = SyntheticAdapter(
        "jiang2013 (given a mapping)",
        "jiang2013",
        lambda scene: ([scene.chart], {"basis": scene.basis, "mapping": scene.mapping}),
    )
    rows = run_comparison(source, [wrong])
    assert all(np.isnan(row.relative_error) for row in rows)
    assert all("'jiang2013' takes no option 'mapping'" in (row.failure or "") for row in rows)


def test_run_report_csv_and_plots(monkeypatch, source, tmp_path):
    def broken(observations, **kwargs):
        raise EstimationError("the solve diverged")

    monkeypatch.setitem(ESTIMATION_METHODS, "broken", broken)
    adapters = [
        adapter
        for adapter in synthetic_adapters(n_patches=12, toivonen=TINY_TOIVONEN)
        if adapter.label
        in {"makabe2025 (true mapping)", "jiang2013 (CC)", "solomatov2023 (Exif+CC)"}
        or adapter.method == "toivonen2020"
    ]
    adapters.append(SyntheticAdapter("broken", "broken", lambda scene: ([scene.chart], {})))
    rows = run_comparison(source, adapters)
    assert len(rows) == 2 * len(adapters)
    good = [row for row in rows if row.method != "broken"]
    assert all(np.isfinite(row.relative_error) and row.time_s > 0 for row in good)
    assert all(row.estimate is not None and row.estimate.shape == (31, 3) for row in good)
    # The offline basis limits every method on this camera to RE ~0.1 (see test_synthetic).
    assert all(row.relative_error < 0.2 for row in good if row.noise == 0)
    failed = [row for row in rows if row.method == "broken"]
    assert all(
        row.failure == "the solve diverged" and np.isnan(row.relative_error) for row in failed
    )

    report = markdown_report(
        rows, adapters, description=source.description, skipped=["han2012"], command="calib compare"
    )
    assert "## Noise 0 % of the peak" in report and "## Noise 1 % of the peak" in report
    header = next(line for line in report.splitlines() if line.startswith("| camera |"))
    assert header.count("|") == len(adapters) + 2
    assert "| time / estimate |" in report and "| **mean** |" in report
    assert "broken, Nikon 5100 (NPL), noise 0 %: the solve diverged" in report
    assert "no synthetic adapter): han2012." in report
    assert "    calib compare" in report

    csv_path = write_csv(tmp_path / "compare.csv", rows)
    with csv_path.open() as handle:
        lines = list(csv.DictReader(handle))
    assert len(lines) == len(rows)
    assert {line["failure"] for line in lines if line["method"] == "broken"} == {
        "the solve diverged"
    }
    png = plot_grid(tmp_path / "plot.png", rows, 0.0)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_han2012_column_photographs_a_fluorescent_chart_under_the_untold_lamp(source):
    (adapter,) = [a for a in synthetic_adapters() if a.method == "han2012"]
    rows = run_comparison(source, [adapter])
    assert [row.noise for row in rows] == [0.0, 0.01]
    assert all(row.failure is None and row.estimate is not None for row in rows)
    # Noise-free, the paper's 9-term Fourier basis recovers this camera to RE ~0.2 (the bench
    # han2012_unknown_light.py: 0.1-0.3 over cameras); at 1 % of the brightest patch the small
    # fluorescent part drowns (the paper's charts were averaged images).
    assert rows[0].relative_error < 0.3
    assert rows[1].relative_error > rows[0].relative_error


def test_cli_writes_the_table_offline(tmp_path):
    out = tmp_path / "cmp"
    result = CliRunner().invoke(
        build_app(),
        [
            "compare",
            "--offline",
            "--method",
            "jiang2013",
            "--method",
            "solomatov2023",
            "--noise",
            "0",
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    report = (out / "compare.md").read_text()
    assert "jiang2013 (CC)" in report and "solomatov2023 (Exif+CC)" in report
    assert "colour-science built-ins (offline)" in report
    for camera in colour_science_cameras():
        assert f"| {camera.name} |" in report
    assert (out / "compare.csv").is_file() and (out / "compare_noise-0.png").is_file()


def test_cli_rejects_bad_noise_and_unknown_methods(tmp_path):
    runner = CliRunner()
    bad_noise = runner.invoke(
        build_app(), ["compare", "--offline", "--noise", "loud", "--out", str(tmp_path)]
    )
    assert isinstance(bad_noise.exception, InputError)
    assert "--noise" in str(bad_noise.exception)
    unknown = runner.invoke(
        build_app(), ["compare", "--offline", "--method", "nope", "--out", str(tmp_path)]
    )
    assert isinstance(unknown.exception, InputError)
    assert "registered:" in str(unknown.exception)
