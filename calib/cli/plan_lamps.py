"""``calib plan-lamps``: which of your lamps to use, and which extra lamp would help most."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.table import Table

from calib.cli.command_line import warn
from calib.cli.options import DataDirOption, JsonOption
from calib.core.errors import InputError

if TYPE_CHECKING:
    from calib.core.spectra import Spectrum
    from calib.evaluation.lamp_planning import SubsetScore

# The planning and the methods are imported by the command when it runs (building ``calib``
# imports this module); the defaults its options show are kept here, checked against their
# sources by tests/test_cli_startup.py.

#: ``calib.evaluation.lamp_planning.DEFAULT_NOISE_FRACTION``.
DEFAULT_NOISE_FRACTION = 0.01
#: ``calib.methods.multilamp.DEFAULT_EFFICIENCY_TERMS``.
DEFAULT_EFFICIENCY_TERMS = 7


def _lamps(specs: list[str], option: str) -> list[Spectrum]:
    from calib.core.lamp_specs import lamp_from_spec

    lamps = []
    for spec in specs:
        try:
            lamps.append(lamp_from_spec(spec))
        except InputError as exc:
            raise InputError(str(exc), source=f"{option} {spec}") from None
    return lamps


def _table(title: str, scores: list[SubsetScore]) -> Table:
    table = Table(
        title=title,
        caption="σ(η): predicted RMS relative σ of the efficiency's shape, with the camera prior "
        "and from the lamps' direct equations alone",
    )
    table.add_column("rank", justify="right")
    table.add_column("lamps")
    table.add_column("σ(η) %", justify="right")
    table.add_column("alone %", justify="right")
    table.add_column("condition", justify="right")
    for rank, score in enumerate(scores, start=1):
        condition = f"{score.condition:.3g}" if math.isfinite(score.condition) else "∞ (< terms)"
        alone = f"{score.data_sigma * 100:.2f}" if math.isfinite(score.data_sigma) else "∞"
        table.add_row(
            str(rank),
            ", ".join(score.lamps),
            f"{score.efficiency_sigma * 100:.2f}",
            alone,
            condition,
        )
    return table


def register(app: typer.Typer) -> None:
    @app.command("plan-lamps")
    def plan_lamps(
        lamp: Annotated[
            list[str],
            typer.Option(
                help="A lamp you have (repeatable): a spectrum CSV, a colour-science name "
                "(LED-B3, FL2, A) or a Gaussian LED gauss:CENTRE_NM:FWHM_NM."
            ),
        ],
        candidate: Annotated[
            list[str] | None,
            typer.Option(
                help="An extra lamp you could add (repeatable; default: blue, green and red "
                "narrow-band LEDs)."
            ),
        ] = None,
        noise: Annotated[
            float, typer.Option(help="Direct noise, fraction of the brightest channel.")
        ] = DEFAULT_NOISE_FRACTION,
        top: Annotated[int, typer.Option(min=1, help="Subsets to list.")] = 10,
        terms: Annotated[
            int, typer.Option(min=1, help="Fourier terms of the grating efficiency.")
        ] = DEFAULT_EFFICIENCY_TERMS,
        data_dir: DataDirOption = None,
        as_json: JsonOption = False,
        grating_model: Annotated[
            str,
            typer.Option(
                help="The grating model to plan for: fourier (free, η₀ flat), sinusoidal (a "
                "phase sheet) or blazed."
            ),
        ] = "fourier",
        grating_parameter: Annotated[
            float | None,
            typer.Option(
                help="The physical model's parameter: peak phase (rad at 550 nm) or blaze (nm); "
                "default 1.2 rad / 500 nm."
            ),
        ] = None,
        grating: Annotated[
            Path | None,
            typer.Option(
                help="A grating file from an earlier calibration: plan for the model it records."
            ),
        ] = None,
    ) -> None:
        """Rank lamp subsets by how well they determine the grating efficiency (multilamp)."""
        from calib.core.grating_file import read_grating_file
        from calib.core.lamp_specs import RGB_LEDS
        from calib.core.spectra import WavelengthGrid
        from calib.evaluation.lamp_planning import best_additions, rank_subsets, recorded_model
        from calib.model.bases import default_camera_basis

        if not math.isfinite(noise) or noise <= 0:
            raise InputError(f"must be a fraction > 0, got {noise}", source="--noise")
        model, parameter = grating_model, grating_parameter
        if grating is not None:
            model, parameter = recorded_model(read_grating_file(grating))
        owned = _lamps(lamp, "--lamp")
        extra = _lamps(list(candidate or RGB_LEDS), "--candidate")
        basis = default_camera_basis(WavelengthGrid(), data_dir=data_dir)
        for line in basis.warnings():
            warn("calib", line)
        prior = basis.prior()
        ranked = rank_subsets(
            owned,
            prior,
            noise_fraction=noise,
            efficiency_terms=terms,
            grating_model=model,
            grating_parameter=parameter,
        )
        additions = best_additions(
            owned,
            extra,
            prior,
            noise_fraction=noise,
            efficiency_terms=terms,
            grating_model=model,
            grating_parameter=parameter,
        )
        if as_json:
            typer.echo(
                json.dumps(
                    {
                        "subsets": [score.to_dict() for score in ranked[:top]],
                        "additions": [score.to_dict() for score in additions],
                    },
                    indent=2,
                )
            )
            return
        console = Console()
        console.print(_table("Your lamps: best subsets", ranked[:top]))
        if not additions:
            console.print("every candidate lamp is already among yours")
            return
        console.print(_table("All your lamps plus one more", additions))
        best = additions[0]
        console.print(
            f"adding {best.lamps[-1]} helps most: σ(η) {ranked[0].efficiency_sigma * 100:.2f} % → "
            f"{best.efficiency_sigma * 100:.2f} %"
        )
