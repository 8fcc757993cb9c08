"""What limits the first-order-alone set-up (the real D7000 pair's analog)? η, and what stands in for it.

The validation protocol's variant "A + FL unmeasured, no direct" (a halogen A with its measured
spectrum, an FL2 nobody measured for the mapping only, the first order alone, no grating file:
``auto`` goes through the known-grating solve with η assumed) on the protocol's own scenes
(``calib validate``'s plan per camera, so its flat and "physical" rows equal that command's), each
scene estimated with:

- ``flat`` — η = 1 (the default);
- ``physical`` — η₁ marginalised over the sinusoidal and blazed families and the flat candidate,
  weighed by the camera prior (``KnownGratingOptions(assumed_grating="physical")``, decisions
  0074 and 0088); ``physical, no flat`` — the families alone (decision 0074's population);
- ``… only sinusoidal`` / ``… only blazed`` — that family alone: on the scenes drawn from the
  family left out (and on the maker's curve, in no family) the population is judged on gratings it
  has never seen, which is what a default must hold on (decision 0074's amendment);
- ``η known`` — the scene's own η₁ given as the grating file: what the set-up gives when η is not
  the problem (the halogen's measured spectrum, the FL's mapping and the camera prior remain).

Printed per grating kind drawn: estimates, failures, mean / median RE ×10⁻², r / g / b mean,
±2σ coverage, share of estimates ≥ 85 % covered. Validation split only (tuning data); the rows go
to ``--out`` as ``calib validate`` writes them.

    python bench/assumed_eta.py --data-dir ../shared/data/camera_sensitivities --grating mix \\
        --catalogue ".../LHires III Grating Efficiency 150.csv" --predictions 40 [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from calib.core.errors import InputError
from calib.core.grating_file import GratingEfficiency
from calib.evaluation.validation.protocol import (
    NO_DIRECT_VARIANT,
    ProtocolSettings,
    ValidationRow,
    failed_row,
    protocol_gratings,
    render_task_scene,
    row_identity,
    scored_row,
    split_tasks,
    variant_arguments,
    variant_observations,
)
from calib.evaluation.validation.report import write_rows_csv
from calib.evaluation.validation.splits import load_splits, require_validation
from calib.methods import estimate
from calib.methods.known_grating import KnownGratingOptions

#: Label → the estimate's keywords besides the variant's own (``None``: the scene's own η₁).
CONFIGURATIONS: dict[str, dict[str, Any] | None] = {
    "flat": {},
    "physical": {"options": KnownGratingOptions(assumed_grating="physical")},
    "physical, no flat": {
        "options": KnownGratingOptions(
            assumed_grating="physical", assumed_families=("sinusoidal", "blazed")
        )
    },
    "physical, only sinusoidal": {
        "options": KnownGratingOptions(assumed_grating="physical", assumed_families=("sinusoidal",))
    },
    "physical, only blazed": {
        "options": KnownGratingOptions(assumed_grating="physical", assumed_families=("blazed",))
    },
    "η known": None,
}
#: The η known's table: the grid's range with a margin, 1 nm.
KNOWN_AXIS_NM = np.arange(370.0, 801.0, 1.0)


def scene_rows(task: Any, labels: Sequence[str]) -> list[ValidationRow]:
    """One scene rendered, every configuration of ``labels`` estimated and scored on it."""
    scene = render_task_scene(task)
    record = json.dumps(scene.plan.to_dict(), default=float)
    observations = variant_observations(scene, NO_DIRECT_VARIANT)
    rows = []
    for label in labels:
        extra = CONFIGURATIONS[label]
        if extra is None:
            grating = scene.plan.grating
            extra = {
                "grating": GratingEfficiency(
                    KNOWN_AXIS_NM,
                    grating.efficiency(1, KNOWN_AXIS_NM),
                    source=f"the scene's own {grating.kind} η₁",
                )
            }
        else:
            extra = {**variant_arguments(NO_DIRECT_VARIANT), **extra}
        identity = row_identity(task, replace(NO_DIRECT_VARIANT, label=label), record)
        started = time.perf_counter()
        try:
            result = estimate(
                observations,
                method=NO_DIRECT_VARIANT.method,
                grid=task.settings.grid,
                basis=task.basis,
                **extra,
            )
            rows.append(
                scored_row(
                    identity,
                    result,
                    scene.truth,
                    observations[0].pixel,
                    scene.true_wavelength_nm,
                    started,
                )
            )
        except Exception as exc:  # a failure is a result, as in the protocol
            rows.append(failed_row(identity, exc, started))
    return rows


def table(rows: Sequence[ValidationRow], labels: Sequence[str]) -> list[str]:
    """The per-kind table (module docstring)."""
    lines = [
        "| η | grating | n | failed | mean RE ×10⁻² | median | r / g / b mean | ±2σ cov. % "
        "| ≥ 85 % covered % |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label in labels:
        mine = [row for row in rows if row.variant == label]
        kinds = sorted({json.loads(row.scene_record)["grating"]["kind"] for row in mine})
        for kind in [*kinds, "all"]:
            group = [
                row
                for row in mine
                if kind == "all" or json.loads(row.scene_record)["grating"]["kind"] == kind
            ]
            done = [row for row in group if row.channel_re is not None]
            if not done:
                lines.append(f"| {label} | {kind} | {len(group)} | {len(group)} | | | | | |")
                continue
            errors = np.array([row.channel_re for row in done])
            covered = np.array([np.mean(row.coverage) for row in done if row.coverage is not None])
            lines.append(
                f"| {label} | {kind} | {len(group)} | {len(group) - len(done)} | "
                f"{100 * errors.mean():.2f} | {100 * np.median(errors.mean(axis=1)):.2f} | "
                + " / ".join(f"{100 * value:.2f}" for value in errors.mean(axis=0))
                + f" | {100 * covered.mean():.1f} | {100 * np.mean(covered >= 0.85):.0f} |"
            )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--grating", default="mix", help="sinusoidal, blazed, catalogue or mix")
    parser.add_argument("--catalogue", type=Path, default=None)
    parser.add_argument("--predictions", type=int, default=0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eta", action="append", choices=list(CONFIGURATIONS), default=None)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    try:
        kinds, curve = protocol_gratings(args.grating, args.catalogue)
    except InputError as exc:
        parser.error(str(exc))
    settings = ProtocolSettings(
        seed=args.seed, grating_kinds=kinds, catalogue=curve, variants=(NO_DIRECT_VARIANT,)
    )
    loaded, _ = load_splits(args.data_dir, predictions=args.predictions, seed=args.seed)
    split = require_validation(loaded.validation)
    labels = args.eta or list(CONFIGURATIONS)
    rows: list[ValidationRow] = []
    for task in split_tasks(split, settings):
        rows += scene_rows(task, labels)
    print(f"validation split, {len(split.cameras)} cameras, gratings {'/'.join(kinds)}")
    print("\n".join(table(rows, labels)))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        print(f"wrote {write_rows_csv(args.out / 'rows.csv', rows)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
