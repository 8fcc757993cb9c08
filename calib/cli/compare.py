"""``calib compare``: every registered method on the synthetic protocol, as Markdown + CSV + plots."""

from __future__ import annotations

import shlex
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console

from calib.cli.command_line import one_line, warn
from calib.cli.options import DataDirOption, EnsembleOption, EpochsOption, ExcludeCameraOption
from calib.cli.synthetic import _parse_noise
from calib.core.errors import InputError

if TYPE_CHECKING:
    from calib.model.bases import CameraBasis

# The comparison and the bases are imported by the command when it runs (building ``calib``
# imports this module); the defaults its options show are kept here, checked against
# calib.evaluation.compare by tests/test_cli_startup.py.

#: ``calib.evaluation.compare.DEFAULT_NOISE_LEVELS`` as ``--noise`` takes them.
DEFAULT_NOISE = "0,0.01"
#: ``calib.evaluation.compare.DEFAULT_TRANSMISSIVE_PATCHES``.
DEFAULT_PATCHES = 16


def register(app: typer.Typer) -> None:
    @app.command("compare")
    def compare(
        out: Annotated[
            Path,
            typer.Option("--out", "-o", help="Directory for compare.md, compare.csv, plots."),
        ] = Path("compare"),
        data_dir: DataDirOption = None,
        exclude_camera: ExcludeCameraOption = None,
        offline: Annotated[
            bool,
            typer.Option(
                "--offline",
                help="colour-science cameras and the offline basis (no dataset needed).",
            ),
        ] = False,
        method: Annotated[
            list[str] | None,
            typer.Option(help="Methods to run (repeatable; default: all): {registered_methods}."),
        ] = None,
        noise: Annotated[
            str, typer.Option(help="Noise levels, fractions of the peak.")
        ] = DEFAULT_NOISE,
        lamp: Annotated[str, typer.Option(help="Broadband lamp (colour-science name).")] = "D65",
        repeats: Annotated[int, typer.Option(min=1, help="Scenes per camera and noise.")] = 1,
        seed: Annotated[int, typer.Option(help="Master seed.")] = 0,
        patches: Annotated[
            int, typer.Option(min=2, help="Gaussian transmissive filters (Toivonen, many-patch).")
        ] = DEFAULT_PATCHES,
        ensemble: EnsembleOption = None,
        epochs: EpochsOption = None,
    ) -> None:
        """Compare every registered method on the synthetic protocol (RE per camera × method)."""
        from calib.core.datasets import colour_science_cameras, makabe2025_split
        from calib.core.spectra import WavelengthGrid
        from calib.evaluation.compare import (
            SyntheticSource,
            active_adapters,
            run_comparison,
            synthetic_adapters,
        )
        from calib.evaluation.compare_report import markdown_report, plot_grid, write_csv
        from calib.model.bases import (
            FALLBACK_WARNING,
            default_camera_basis,
            fallback_camera_basis,
        )

        grid = WavelengthGrid()
        excluded = list(exclude_camera or ())
        fallback_used = offline
        if not offline:
            try:
                _train, test = makabe2025_split(data_dir)
            except InputError as exc:
                if data_dir is not None:
                    raise
                warn(
                    "calib",
                    f"no measured test cameras ({one_line(exc)}); comparing on the offline "
                    "colour-science cameras",
                )
                fallback_used = True
        basis: CameraBasis | Callable[[str], CameraBasis]
        if fallback_used:
            cameras = [
                (r.name, r.sensitivity.resample(grid, "interpolate", out_of_range="zero"))
                for r in colour_science_cameras()
            ]

            def basis_for(name: str) -> CameraBasis:
                return fallback_camera_basis(grid=grid, exclude=[name.split(" (")[0], *excluded])

            basis = basis_for
            basis_description = (
                "colour-science built-ins (offline), each camera excluded from its own basis"
            )
            warn("calib", FALLBACK_WARNING)
        else:
            cameras = [(r.camera, r.sensitivity) for r in test]
            measured = default_camera_basis(
                grid, data_dir=data_dir, exclude=[*(r.name for r in test), *excluded]
            )
            basis, basis_description = measured, measured.source
        source = SyntheticSource(
            cameras,
            basis,
            noise_levels=_parse_noise(noise),
            repeats=repeats,
            seed=seed,
            broadband_lamp=lamp,
            n_patches=patches,
            grid=grid,
            basis_description=basis_description,
        )
        toivonen: dict[str, Any] = {}
        if ensemble is not None:
            toivonen["ensemble_size"] = ensemble
        if epochs is not None:
            toivonen["epochs"] = epochs
        adapters, skipped = active_adapters(
            synthetic_adapters(n_patches=patches, toivonen=toivonen), method
        )
        console = Console(stderr=True)
        with console.status("comparing…") as status:
            rows = run_comparison(
                source,
                adapters,
                grid=grid,
                progress=lambda row: status.update(
                    f"{row.camera} · {row.label} · noise {row.noise:g}"
                ),
            )
        command = "calib " + " ".join(shlex.quote(arg) for arg in sys.argv[1:])
        report = markdown_report(
            rows, adapters, description=source.description, skipped=skipped, command=command
        )
        out.mkdir(parents=True, exist_ok=True)
        (out / "compare.md").write_text(report, encoding="utf-8")
        write_csv(out / "compare.csv", rows)
        plots = [
            plot_grid(out / f"compare_noise-{level:g}.png", rows, level, grid=grid)
            for level in sorted({row.noise for row in rows})
        ]
        from rich.markdown import Markdown  # deferred: markdown-it and pygments, ~60 ms

        Console().print(Markdown(report))
        console.print(
            f"wrote {out / 'compare.md'}, {out / 'compare.csv'}, "
            + ", ".join(str(p) for p in plots)
        )
