"""``calib validate``'s scenes with the HDR merge's frame gains on (the rig's merge) or off.

The protocol's captures go through the rig's merge (:mod:`calib.evaluation.validation.capture`),
which estimates each frame's gain (decision 0089). ``--merge-gains off`` trusts the recorded times
instead, as the merge did before that decision: the rows then show what a per-frame shutter error
does to the estimates when nothing removes it (decision 0098). Everything else is
``calib validate``'s run with its defaults (seed 0, one scene per camera, sinusoidal gratings, the
rig's errors, profiles measured from the direct spot), so ``--merge-gains on`` prints the same
rows as ``calib validate`` with the same split and variants.

    python bench/validate_hdr_gains.py --split validation --data-dir DIR --merge-gains off \\
        [--variant 'LED+FL' ...] [--jobs 1] [--cameras N] [--out DIR]
"""

from __future__ import annotations

import argparse
import shlex
import sys
from dataclasses import replace
from pathlib import Path

from calib.evaluation.validation.protocol import (
    DEFAULT_VARIANTS,
    EXTRA_VARIANTS,
    ProtocolSettings,
    ValidationRow,
    evaluate_task,
    run_split,
    spread_tasks,
)
from calib.evaluation.validation.report import (
    markdown_report,
    write_rows_csv,
    write_summary_csv,
)
from calib.evaluation.validation.rig_errors import RigErrors
from calib.evaluation.validation.splits import load_splits


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--split", choices=("validation", "test"), default="validation")
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--merge-gains", choices=("on", "off", "base"), default="off")
    parser.add_argument("--variant", action="append", default=None)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument(
        "--cameras",
        type=int,
        default=0,
        help="at most this many cameras of the split, spread over its order (0: all)",
    )
    parser.add_argument("--out", type=Path, default=Path("validation-hdr-gains"))
    args = parser.parse_args(argv)
    known = {v.label: v for v in (*DEFAULT_VARIANTS, *EXTRA_VARIANTS)}
    labels = args.variant or [v.label for v in DEFAULT_VARIANTS]
    unknown = [label for label in labels if label not in known]
    if unknown:
        parser.error(f"unknown variant {'; '.join(unknown)}; choose from {'; '.join(known)}")
    errors = RigErrors()
    if args.merge_gains != "base":  # base: a tree before decision 0098 (no such switch)
        photons = replace(errors.photons, merge_gains=args.merge_gains == "on")
        errors = replace(errors, photons=photons)
    settings = ProtocolSettings(errors=errors, variants=tuple(known[label] for label in labels))
    loaded, _ = load_splits(args.data_dir)
    split = loaded.validation if args.split == "validation" else loaded.test
    if args.cameras:
        tasks = spread_tasks(args.data_dir, args.split, settings, args.cameras)
        rows: list[ValidationRow] = [row for task in tasks for row in evaluate_task(task)]
    else:
        rows = run_split(split, settings, jobs=args.jobs)
    command = "python bench/validate_hdr_gains.py " + shlex.join(
        sys.argv[1:] if argv is None else argv
    )
    report = markdown_report([split], rows, settings, command=command)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "report.md").write_text(report + "\n", encoding="utf-8")
    write_summary_csv(args.out / "summary.csv", rows)
    write_rows_csv(args.out / "rows.csv", rows)
    print(report)


if __name__ == "__main__":
    main()
