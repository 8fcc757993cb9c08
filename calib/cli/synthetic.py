"""``calib synthetic``: the synthetic protocol of Makabe et al. (2025) §4.1, as a table and a CSV."""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from calib.cli.command_line import warn
from calib.cli.options import DataDirOption, ExcludeCameraOption, WeightRuleOption
from calib.core.errors import InputError

if TYPE_CHECKING:
    from calib.core.spectra import MultiSpectrum, WavelengthGrid
    from calib.evaluation.synthetic import PaperSolve, SyntheticRow
    from calib.methods.multilamp import MultilampOptions
    from calib.model.bases import CameraBasis

# The protocol, the methods and the bases are imported by the functions that use them: building
# the ``calib`` command (``calib --help``, any command) imports this module. What the options'
# help and defaults show is kept here, checked against its source by tests/test_cli_startup.py.

#: The solves ``--method`` offers for the paper's variants: ``calib.methods.prior_solve.PRIOR_METHOD``
#: and ``calib.methods.makabe2025.MAKABE2025_METHOD``.
PAPER_METHODS: tuple[str, ...] = ("prior", "makabe2025")
#: ``calib.evaluation.synthetic.NOISE_LEVELS`` as ``--noise`` takes them.
DEFAULT_NOISE = "0,0.003,0.01,0.03"
#: The camera splits ``--split`` offers (``calib.evaluation.validation.splits``' roles), the default
#: first.
SPLITS: tuple[str, ...] = ("test", "validation")


def paper_solve(method: str, formulation: str | None) -> PaperSolve:
    """The typed options ``--method`` (and ``--formulation``) stand for.

    Raises
    ------
    InputError
        An unknown method or formulation, or a formulation with a method that has none.
    """
    from calib.methods.makabe2025 import FORMULATIONS, MAKABE2025_METHOD, Makabe2025Options
    from calib.methods.prior_solve import PRIOR_METHOD, PriorOptions

    if method not in PAPER_METHODS:
        raise InputError(
            f"must be one of {', '.join(PAPER_METHODS)}, got {method!r}", source="--method"
        )
    if method == PRIOR_METHOD:
        if formulation is not None:
            raise InputError(
                f"applies to --method {MAKABE2025_METHOD} only", source="--formulation"
            )
        return PriorOptions()
    if formulation is None:
        return Makabe2025Options()
    if formulation not in FORMULATIONS:
        raise InputError(
            f"must be one of {', '.join(FORMULATIONS)}, got {formulation!r}",
            source="--formulation",
        )
    return Makabe2025Options(formulation="measured" if formulation == "measured" else "printed")


def _parse_noise(text: str) -> list[float]:
    try:
        values = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise InputError(
            f"expected comma-separated fractions like 0,0.003,0.01, got {text!r}", source="--noise"
        ) from None
    if not values or any(v < 0 or not math.isfinite(v) for v in values):
        raise InputError(
            f"noise levels must be finite fractions >= 0, got {text!r}", source="--noise"
        )
    return values


def _format(value: float | None, scale: float, digits: int) -> str:
    if value is None or not math.isfinite(value):
        return "—"
    return f"{value * scale:.{digits}f}"


def _short_camera(name: str) -> str:
    """``"Canon 600D (Jiang-et-al-2013)"`` → ``"Canon 600D"`` (table headers must stay narrow)."""
    return name.split(" (")[0]


def summary_table(rows: list[SyntheticRow], title: str) -> Table:
    """Rich table: one row per variant × noise, a column per camera and the mean.

    Cells are RE ×10⁻²; the mean column adds the mean mapping RE (×10⁻²) when the mapping was
    estimated, and the mean share of the truth inside ±2σ: the stated σ's (the σ budget users get),
    then the method's own σ's.
    """
    import numpy as np

    from calib.evaluation.synthetic import VARIANTS

    keys = sorted(
        {(row.variant, row.noise) for row in rows}, key=lambda k: (VARIANTS.index(k[0]), k[1])
    )
    cameras = list(dict.fromkeys(row.camera for row in rows))
    cells: dict[tuple[str, str, float], list[SyntheticRow]] = defaultdict(list)
    for row in rows:
        cells[(row.camera, row.variant, row.noise)].append(row)
    table = Table(
        title=title,
        # Escaped: rich would read the bracket as a markup tag and drop it.
        caption=escape(
            "RE ×10⁻² per camera; mean RE (mean mapping RE ×10⁻²) [share of the truth inside ±2σ: "
            "the stated σ (budget) / the method's own σ]"
        ),
    )
    table.add_column("variant")
    table.add_column("noise", justify="right")
    for camera in cameras:
        table.add_column(_short_camera(camera), justify="right")
    table.add_column("mean", justify="right")

    def mean_error(selected: list[SyntheticRow]) -> str:
        errors = [r.relative_error for r in selected]
        return _format(float(np.mean(errors)) if errors else None, 100, 2)

    for variant, noise in keys:
        selected = [r for r in rows if (r.variant, r.noise) == (variant, noise)]
        mapping = [
            r.mapping_relative_error for r in selected if r.mapping_relative_error is not None
        ]
        mean = mean_error(selected)
        if mapping:
            mean += f" ({_format(float(np.mean(mapping)), 100, 3)})"
        coverage = [r.coverage for r in selected if r.coverage is not None]
        own = [r.method_coverage for r in selected if r.method_coverage is not None]
        if coverage:
            mean += f" [{float(np.mean(coverage)) * 100:.0f} %"
            mean += f" / {float(np.mean(own)) * 100:.0f} %]" if own else "]"
        table.add_row(
            variant,
            f"{noise * 100:g} %",
            *(mean_error(cells[(camera, variant, noise)]) for camera in cameras),
            mean,
        )
    return table


def write_rows_csv(path: Path, rows: list[SyntheticRow]) -> None:
    """One line per estimate: camera, variant, noise, RE, mapping RE (and its estimate), time."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(
            [
                "camera",
                "variant",
                "noise_fraction",
                "repeat",
                "relative_error",
                "mapping_relative_error",
                "mapping_re_estimate",
                "time_s",
                "failure",
                "coverage_2sigma",
                "method_coverage_2sigma",
            ]
        )
        for r in rows:
            writer.writerow(
                [
                    r.camera,
                    r.variant,
                    r.noise,
                    r.repeat,
                    r.relative_error,
                    r.mapping_relative_error,
                    r.mapping_re_estimate,
                    f"{r.time_s:.4f}",
                    r.failure or "",
                    "" if r.coverage is None else f"{r.coverage:.4f}",
                    "" if r.method_coverage is None else f"{r.method_coverage:.4f}",
                ]
            )


def register(app: typer.Typer) -> None:
    @app.command("synthetic")
    def synthetic(
        data_dir: DataDirOption = None,
        exclude_camera: ExcludeCameraOption = None,
        lamp: Annotated[
            str, typer.Option(help="Broadband lamp: D65 (the paper) or LED-B3.")
        ] = "D65",
        noise: Annotated[
            str, typer.Option(help="Profile noise levels, fractions of the peak.")
        ] = DEFAULT_NOISE,
        variant: Annotated[
            list[str] | None,
            typer.Option(
                help="Variants (repeatable): 'true mapping', LED+Flu, 'LED only', "
                "'LED only (paper ICP)' (the default four); beyond the paper: 'multilamp: 5 lamps', "
                "'multilamp: 5 lamps, true mapping', 'multilamp: 3 lamps + RGB LEDs', "
                "'grating file: 1 LED', or 'multilamp' for all four."
            ),
        ] = None,
        method: Annotated[
            str,
            typer.Option(
                help="How the paper's variants solve: prior (the camera-prior solve, default) or "
                "makabe2025 (the paper's solve)."
            ),
        ] = PAPER_METHODS[0],
        formulation: Annotated[
            str | None,
            typer.Option(
                help="With --method makabe2025: printed (Eq. 12 as printed, default) or measured "
                "(the paper's 7-vector model in measured units)."
            ),
        ] = None,
        repeats: Annotated[
            int, typer.Option(min=1, help="Random scenes per camera and noise level.")
        ] = 1,
        seed: Annotated[int, typer.Option(help="Master seed.")] = 0,
        n_vectors: Annotated[
            int, typer.Option(min=1, help="Camera basis vectors per channel.")
        ] = 7,
        offline: Annotated[
            bool,
            typer.Option(
                "--offline", help="Use colour-science cameras and the offline basis (no dataset)."
            ),
        ] = False,
        out_of_basis: Annotated[
            bool,
            typer.Option(
                "--out-of-basis",
                help="Cameras unlike the basis instead of the 5 test cameras: Sigma SDMerill (NPL, "
                "Foveon) and the first test camera behind a blue colour filter.",
            ),
        ] = False,
        direct_noise: Annotated[
            float | None,
            typer.Option(
                help="Direct-signal noise of the multi-lamp variants' lamps (fraction of the "
                "peak); default: the profile's level, as in the paper's variants. The twin's own "
                "captures have it 2.3× below the profile's (bench/direct_noise.py)."
            ),
        ] = None,
        weight_rule: WeightRuleOption = None,
        split: Annotated[
            str,
            typer.Option(
                help="Cameras: test (the paper's 5 test cameras under the 44 training curves' "
                "basis; report only) or validation (the training curves, each with its own body "
                "left out of its basis: the only cameras a tuning choice may look at)."
            ),
        ] = SPLITS[0],
        csv_path: Annotated[
            Path, typer.Option("--csv", help="Where to write every estimate as CSV.")
        ] = Path("synthetic.csv"),
    ) -> None:
        """Reproduce the paper's synthetic experiment (§4.1): RE per camera × variant × noise."""
        from calib.core.datasets import colour_science_cameras, makabe2025_split
        from calib.core.spectra import WavelengthGrid
        from calib.evaluation.synthetic import out_of_basis_cameras
        from calib.evaluation.synthetic_splits import validation_cameras
        from calib.methods.multilamp import MULTILAMP_METHOD, MultilampOptions, weight_rule_option
        from calib.model.bases import (
            FALLBACK_WARNING,
            default_camera_basis,
            fallback_camera_basis,
        )

        if split not in SPLITS:
            raise InputError(f"must be one of {', '.join(SPLITS)}, got {split!r}", source="--split")
        if split != SPLITS[0] and (offline or out_of_basis):
            raise InputError(
                "the validation split is the training curves of the camera data; it takes neither "
                "--offline nor --out-of-basis",
                source="--split",
            )
        solve = paper_solve(method, formulation)
        multilamp_options = weight_rule_option(MULTILAMP_METHOD, weight_rule) or MultilampOptions()
        excluded = list(exclude_camera or ())
        grid = WavelengthGrid()
        variants = _variants(variant)
        if offline:
            cameras = [
                (r.name, r.sensitivity.resample(grid, "interpolate", out_of_range="zero"))
                for r in colour_science_cameras()
            ]
            if out_of_basis:
                cameras = out_of_basis_cameras(*cameras[0])

            def basis_for(name: str) -> CameraBasis:
                return fallback_camera_basis(
                    grid=grid, n_vectors=n_vectors, exclude=[name.split(" (")[0], *excluded]
                )

            basis_source = "colour-science built-ins, each camera excluded from its own basis"
            warn("calib", FALLBACK_WARNING)
            basis_choice: CameraBasis | Callable[[str], CameraBasis] = basis_for
        elif split == "validation":
            cameras, basis_choice, basis_source = validation_cameras(
                data_dir, grid=grid, n_vectors=n_vectors, exclude=excluded
            )
        else:
            _train, test = makabe2025_split(data_dir)
            basis = default_camera_basis(
                grid,
                n_vectors=n_vectors,
                data_dir=data_dir,
                exclude=[*(r.name for r in test), *excluded],
            )
            basis_source = basis.source
            cameras = [(r.camera, r.sensitivity) for r in test]
            if out_of_basis:
                cameras = out_of_basis_cameras(test[0].camera, test[0].sensitivity)
            basis_choice = basis
        rows = _run(
            cameras,
            basis_choice,
            grid,
            variants,
            noise,
            lamp,
            solve,
            repeats,
            seed,
            direct_noise,
            multilamp_options,
        )
        console = Console()
        console.print(
            summary_table(
                rows,
                f"Makabe 2025 §4.1 — {split} split, lamp {lamp}, method {method}"
                + (f" ({formulation})" if formulation else "")
                + f", basis: {basis_source}",
            )
        )
        write_rows_csv(csv_path, rows)
        console.print(f"wrote {csv_path}")


def _variants(chosen: list[str] | None) -> list[str]:
    from calib.evaluation.synthetic import MULTILAMP_VARIANTS, PAPER_VARIANTS, VARIANTS

    if not chosen:
        return list(PAPER_VARIANTS)
    expanded: list[str] = []
    for name in chosen:
        expanded.extend(MULTILAMP_VARIANTS if name == "multilamp" else [name])
    unknown = [name for name in expanded if name not in VARIANTS]
    if unknown:
        raise InputError(
            f"unknown variants {unknown}; choose from {list(VARIANTS)} or 'multilamp'",
            source="--variant",
        )
    return expanded


def _run(
    cameras: list[tuple[str, MultiSpectrum]],
    basis: CameraBasis | Callable[[str], CameraBasis],
    grid: WavelengthGrid,
    variants: list[str],
    noise: str,
    lamp: str,
    solve: PaperSolve,
    repeats: int,
    seed: int,
    direct_noise: float | None,
    multilamp_options: MultilampOptions,
) -> list[SyntheticRow]:
    from calib.evaluation.synthetic import run_protocol

    console = Console(stderr=True)
    with console.status("estimating…") as status:
        return run_protocol(
            cameras,
            basis,
            grid=grid,
            variants=variants,
            noise_levels=_parse_noise(noise),
            broadband_lamp=lamp,
            paper_solve=solve,
            repeats=repeats,
            seed=seed,
            direct_noise=direct_noise,
            multilamp_options=multilamp_options,
            progress=lambda row: status.update(
                f"{row.camera} · {row.variant} · noise {row.noise:g}"
            ),
        )
