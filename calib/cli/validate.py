"""``calib validate``: the validation protocol (decision 0023) as tables per split, and CSVs.

The paper's own protocol stays ``calib synthetic`` ("paper reproduction").
"""

from __future__ import annotations

import os
import shlex
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, get_args

import typer
from rich.console import Console

from calib.cli.command_line import help_choices
from calib.cli.options import DataDirOption, ExcludeCameraOption
from calib.core.errors import InputError

if TYPE_CHECKING:
    from calib.evaluation.validation.splits import Split

# The protocol is imported by the command when it runs (building ``calib`` imports this module);
# the variants its help lists are read when the help is shown ({validation_variants}).

SPLIT_CHOICES = ("validation", "test", "both")
#: ``--quick``: the first camera of each group, these variants, one scene.
QUICK_VARIANTS = ("LED+FL", "5 lamps")


@help_choices("validation_variants")
def validation_variants() -> Sequence[str]:
    """The labels ``--variant`` takes (a label may hold a comma: one "; "-separated entry)."""
    from calib.evaluation.validation.protocol import DEFAULT_VARIANTS, EXTRA_VARIANTS

    return ("; ".join(v.label for v in (*DEFAULT_VARIANTS, *EXTRA_VARIANTS)),)


def _quick(split: Split) -> Split:
    from calib.evaluation.validation.splits import SplitCamera

    firsts: dict[str, SplitCamera] = {}
    for camera in split.cameras:
        firsts.setdefault(camera.group, camera)
    return replace(split, cameras=tuple(firsts.values()))


def register(app: typer.Typer) -> None:
    @app.command("validate")
    def validate(
        split: Annotated[
            str, typer.Option(help="Which split to run: " + ", ".join(SPLIT_CHOICES) + ".")
        ] = "both",
        data_dir: DataDirOption = None,
        exclude_camera: ExcludeCameraOption = None,
        seed: Annotated[int, typer.Option(help="Master seed (scenes depend on it alone).")] = 0,
        scenes: Annotated[int, typer.Option(min=1, help="Scenes per camera.")] = 1,
        jobs: Annotated[
            int, typer.Option(min=1, help="Worker processes (results do not depend on it).")
        ] = max(1, os.cpu_count() or 1),
        grating: Annotated[
            str,
            typer.Option(
                help="Grating kinds drawn per scene: sinusoidal (default), blazed, catalogue, a "
                "comma-separated list, or mix (all three; catalogue needs --catalogue)."
            ),
        ] = "sinusoidal",
        catalogue: Annotated[
            Path | None,
            typer.Option(
                help="A maker's first-order efficiency curve (wavelength_nm, efficiency; per cent "
                "or fraction) for the catalogue grating."
            ),
        ] = None,
        variant: Annotated[
            list[str] | None,
            typer.Option(
                help="Method variants to run (repeatable; default the first four): "
                "{validation_variants}"
            ),
        ] = None,
        predictions: Annotated[
            int,
            typer.Option(
                min=0,
                help="Add this many of Solomatov & Akkaynak's predicted curves to the validation "
                "split.",
            ),
        ] = 0,
        transformed: Annotated[
            int,
            typer.Option(
                min=0,
                help="Add this many physically transformed validation cameras (IR-cut edge moved, "
                "blue edge, dye shifts, colour filters) to the validation split.",
            ),
        ] = 0,
        errors: Annotated[
            str,
            typer.Option(
                help="all (the rig's errors, default) or noise-only (shot and read noise alone)."
            ),
        ] = "all",
        pixel_origin: Annotated[
            str,
            typer.Option(
                help="direct_spot (profiles as the rig extracts them, default) or arbitrary "
                "(profile CSVs without the spot's position)."
            ),
        ] = "direct_spot",
        quick: Annotated[
            bool,
            typer.Option(
                help="A smoke run: the first camera of each group, variants "
                + " and ".join(QUICK_VARIANTS)
                + "."
            ),
        ] = False,
        out: Annotated[
            Path, typer.Option(help="Directory for report.md, summary.csv and rows.csv.")
        ] = Path("validation-output"),
    ) -> None:
        """The validation protocol: splits that cannot be tuned to, physical gratings, the rig's
        errors (decision 0023). Prints the report; writes it with the CSVs to --out."""
        from calib.evaluation.validation.protocol import (
            DEFAULT_VARIANTS,
            EXTRA_VARIANTS,
            PixelOrigin,
            ProtocolSettings,
            ValidationRow,
            protocol_gratings,
            run_split,
        )
        from calib.evaluation.validation.report import (
            markdown_report,
            write_rows_csv,
            write_summary_csv,
        )
        from calib.evaluation.validation.rig_errors import RigErrors
        from calib.evaluation.validation.splits import load_splits

        if split not in SPLIT_CHOICES:
            raise InputError(
                f"unknown split {split}; choose one of {', '.join(SPLIT_CHOICES)}", source="--split"
            )
        if errors not in ("all", "noise-only"):
            raise InputError(
                f"unknown errors {errors}; choose all or noise-only", source="--errors"
            )
        if pixel_origin not in get_args(PixelOrigin):
            raise InputError(
                f"unknown pixel origin {pixel_origin}; choose direct_spot or arbitrary",
                source="--pixel-origin",
            )
        origin: PixelOrigin = "direct_spot" if pixel_origin == "direct_spot" else "arbitrary"
        kinds, curve = protocol_gratings(grating, catalogue)
        labels = list(variant or (QUICK_VARIANTS if quick else [v.label for v in DEFAULT_VARIANTS]))
        known = {v.label: v for v in (*DEFAULT_VARIANTS, *EXTRA_VARIANTS)}
        unknown = [label for label in labels if label not in known]
        if unknown:
            raise InputError(
                f"unknown variant {'; '.join(unknown)}; choose from {'; '.join(known)}",
                source="--variant",
            )
        settings = ProtocolSettings(
            seed=seed,
            scenes=scenes,
            grating_kinds=kinds,
            catalogue=curve,
            errors=RigErrors() if errors == "all" else RigErrors.noise_only(),
            variants=tuple(known[label] for label in labels),
            pixel_origin=origin,
        )
        excluded = tuple(exclude_camera or ())
        loaded, missing = load_splits(
            data_dir,
            predictions=predictions,
            seed=seed,
            exclude=excluded,
            transformed=transformed,
        )
        chosen: list[Split] = [
            s for s in (loaded.validation, loaded.test) if split in ("both", s.role)
        ]
        if quick:
            chosen = [_quick(s) for s in chosen]
        console = Console(stderr=True)
        for note in missing:
            console.print(f"[yellow]note:[/] collection not used — {note}")
        # Every choice spelled out (defaults too): the line reproduces the tables.
        arguments = [
            "validate",
            f"--split={split}",
            f"--seed={seed}",
            f"--scenes={scenes}",
            f"--grating={grating}",
            f"--errors={errors}",
            f"--pixel-origin={pixel_origin}",
            f"--predictions={predictions}",
            *(f"--variant={label}" for label in labels),
            *([f"--catalogue={catalogue}"] if catalogue is not None else []),
            *(["--quick"] if quick else []),
            *([f"--data-dir={data_dir}"] if data_dir is not None else []),
            *(f"--exclude-camera={pattern}" for pattern in excluded),
        ]
        command = "calib " + " ".join(shlex.quote(arg) for arg in arguments)
        rows: list[ValidationRow] = []
        report = ""
        out.mkdir(parents=True, exist_ok=True)
        with console.status("estimating…") as status:
            for part in chosen:
                rows += run_split(
                    part,
                    settings,
                    jobs=jobs,
                    progress=lambda row: status.update(
                        f"{row.split} · {row.camera} · {row.variant}"
                    ),
                )
                # Written after each split: an interrupted run keeps what it finished.
                report = markdown_report(chosen, rows, settings, command=command)
                (out / "report.md").write_text(report + "\n", encoding="utf-8")
                write_summary_csv(out / "summary.csv", rows)
                write_rows_csv(out / "rows.csv", rows)
        typer.echo(report)
        console.print(f"wrote {out / 'report.md'}, {out / 'summary.csv'}, {out / 'rows.csv'}")
