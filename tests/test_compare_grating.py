"""calib compare on grating-only scenes (captured sessions): columns, skipped methods, report, plot."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from calib.core.datasets import colour_science_cameras
from calib.core.errors import EstimationError, InputError
from calib.core.result import EstimateResult
from calib.evaluation.compare import (
    GRATING_SKIP_REASONS,
    GratingScene,
    SyntheticSource,
    active_grating_adapters,
    grating_adapters,
    run_grating_comparison,
)
from calib.evaluation.compare_report import plot_panels, sessions_markdown_report
from calib.methods import ESTIMATION_METHODS
from calib.model.bases import fallback_camera_basis

#: Toivonen options small enough for plumbing tests (not for accuracy).
TINY_TOIVONEN = {"ensemble_size": 2, "epochs": 200}


@dataclass
class _Scenes:
    """A grating scene source over fixed scenes."""

    items: list[GratingScene]
    description: str = "rendered grating scenes"

    def scenes(self) -> Iterator[GratingScene]:
        yield from self.items


@pytest.fixture(scope="module")
def scene() -> GratingScene:
    """A synthetic scene's lamps, as a captured session would give them (no chart)."""
    nikon = colour_science_cameras()[0]
    synthetic = SyntheticSource(
        [(nikon.name, nikon.sensitivity)],
        fallback_camera_basis(exclude=[nikon.camera]),
        noise_levels=(0.0,),
    )
    rendered = next(synthetic.scenes())
    return GratingScene(
        camera=rendered.camera,
        session="20260101T000000Z-abcdef",
        grid=rendered.grid,
        truth=rendered.truth,
        basis=rendered.basis,
        lamps=(rendered.fluorescent, rendered.broadband),
        mapping=rendered.mapping,
        seed=rendered.seed,
    )


def test_the_single_lamp_columns_take_the_broadband_lamp_with_a_direct_measurement(
    scene: GratingScene,
) -> None:
    assert scene.solve_lamp.kind != "fluorescent" and scene.solve_lamp.direct_rgb is not None
    assert scene.label == f"{scene.camera} · 20260101T000000Z-abcdef"


def test_chart_methods_are_skipped_with_their_reason(monkeypatch: pytest.MonkeyPatch) -> None:
    chosen, skipped = active_grating_adapters(grating_adapters(), n_patches=12)
    methods = {adapter.method for adapter in chosen}
    assert methods == {"prior", "makabe2025", "toivonen2020"} | (
        {"multilamp"} if "multilamp" in ESTIMATION_METHODS else set()
    )
    reasons = dict(skipped)
    for method in ("jiang2013", "solomatov2023", "han2012"):
        assert reasons[method] == GRATING_SKIP_REASONS[method]
    assert "transmissive" in reasons["toivonen2020 (12 patches)"]

    def unused(observations, **kwargs):
        raise AssertionError

    monkeypatch.setitem(ESTIMATION_METHODS, "multilamp", unused)
    monkeypatch.setitem(ESTIMATION_METHODS, "newmethod", unused)
    chosen, skipped = active_grating_adapters(grating_adapters())
    assert "multilamp" in [adapter.label for adapter in chosen]
    assert ("newmethod", "no adapter for captured sessions") in skipped
    only, skipped = active_grating_adapters(grating_adapters(), ["JIANG2013"])
    assert only == [] and [label for label, _ in skipped] == ["jiang2013"]
    with pytest.raises(InputError, match="unknown methods"):
        active_grating_adapters(grating_adapters(), ["nope"])


def test_rows_report_and_plot(
    scene: GratingScene, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    received: list[list[str]] = []

    def multilamp(observations, *, grid, **kwargs):
        received.append([lamp.name for lamp in observations])
        if len(received) > 1:
            raise EstimationError("the joint solve diverged")
        return EstimateResult("multilamp", grid.wavelength_nm, scene.truth * 2.0)

    monkeypatch.setitem(ESTIMATION_METHODS, "multilamp", multilamp)
    adapters, skipped = active_grating_adapters(
        [
            adapter
            for adapter in grating_adapters(toivonen=TINY_TOIVONEN)
            if adapter.label != "prior (all lamps)"
        ]
    )
    source = _Scenes([scene, scene])
    rows = run_grating_comparison(source, adapters)
    assert len(rows) == 2 * len(adapters)
    assert received == [[lamp.name for lamp in scene.lamps]] * 2
    good = [row for row in rows if row.failure is None]
    assert all(np.isfinite(row.relative_error) and row.time_s > 0 for row in good)
    assert all(np.isnan(row.noise) and row.camera == scene.label for row in rows)
    by_label = {row.label: row for row in good}
    assert by_label["multilamp"].relative_error == pytest.approx(0.0, abs=1e-12)
    # The offline basis limits the closed-form solve on this camera to RE ~0.1 (see test_synthetic).
    assert by_label["makabe2025 (true mapping)"].relative_error < 0.2

    report = sessions_markdown_report(
        rows,
        adapters,
        description=source.description,
        skipped=skipped,
        session_notes=["a note"],
        command="rig compare S",
    )
    header = next(line for line in report.splitlines() if line.startswith("| camera |"))
    assert header.count("|") == len(adapters) + 2
    assert f"| {scene.label} | " in report and "| **mean** |" in report
    assert "0.00 (1 failed)" in report  # the mean cell of the column that failed once
    assert f"multilamp, {scene.label}: the joint solve diverged" in report
    assert f"- **jiang2013**: {GRATING_SKIP_REASONS['jiang2013']}" in report
    assert "- a note" in report and "    rig compare S" in report
    png = plot_panels(tmp_path / "plot.png", rows, "title")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
