"""Tables of the validation protocol: per split, per method, per channel and per camera group.

Every table is headed by its split and the split's composition (:meth:`Split.describe`), so a
number is never read without knowing which cameras made it. Outputs: a Markdown report, the
summary as CSV (one line per table row) and every estimate as CSV (:func:`write_rows_csv`).

Statistics (over the estimates of a cell; failed estimates are counted, not averaged):

- RE ×10⁻²: mean and median of Eq. 16 (per channel: its term ``RMSE_c / max s_c``);
- ±2σ coverage: the mean share of the truth inside the stated band (a σ that is honest covers
  ~95 %); the share of estimates whose band covers at least 85 % (a mean can hide a few bands
  that miss); and the coverage of the method's own σ before the budget
  (:mod:`calib.methods.uncertainty`);
- σ ratio: the median over estimates of RMS(actual error) / RMS(stated σ) (1 when honest);
- mapping: mean and median of the mean ``|Δλ|`` over the profile (nm), the number of estimates
  off by more than 3 nm and how many of them carried no ambiguity warning, how many within 3 nm
  carried one (false alarms), mapping RE (%), coverage and σ ratio of the stated σ_λ — the
  ratio also over the estimates without and with an ambiguity warning apart: a warned mapping's
  σ spans its competing basins (:mod:`calib.wavelength.profile_search`), so where the chosen basin
  is the right one its ratio is small by design, and a split where many mappings are warned has a
  small median ratio whatever the unwarned σ does.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.core.markdown import table_row, table_rule
from calib.core.result import MAPPING_FAILURE_NM
from calib.evaluation.validation.protocol import (
    CHANNELS,
    ProtocolSettings,
    ValidationRow,
)
from calib.evaluation.validation.splits import Split

Statistics = tuple[tuple[str, float | None], ...]
ALL = "all"
#: An estimate whose ±2σ band holds at least this share of the truth counts as covered.
WELL_COVERED = 0.85


@dataclass(frozen=True)
class SummaryRow:
    """One row of a summary table."""

    split: str
    table: str
    variant: str
    method: str
    group: str
    channel: str
    estimates: int
    failures: int
    statistics: tuple[tuple[str, float | None], ...]


def _mean(values: Iterable[float | None]) -> float | None:
    kept = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(kept)) if kept else None


def _median(values: Iterable[float | None]) -> float | None:
    kept = [v for v in values if v is not None and not math.isnan(v)]
    return float(np.median(kept)) if kept else None


def _channel(value: tuple[float, float, float] | None, channel: str) -> float | None:
    if value is None:
        return None
    return float(np.mean(value)) if channel == ALL else value[CHANNELS.index(channel)]


def _sensitivity_statistics(
    rows: Sequence[ValidationRow], channel: str
) -> tuple[tuple[str, float | None], ...]:
    fine = [row for row in rows if row.failure is None]
    errors = [_channel(row.channel_re, channel) for row in fine]
    return (
        ("mean RE ×10⁻²", None if (m := _mean(errors)) is None else 100 * m),
        ("median RE ×10⁻²", None if (m := _median(errors)) is None else 100 * m),
        (
            "±2σ coverage %",
            None if (m := _mean(_channel(r.coverage, channel) for r in fine)) is None else 100 * m,
        ),
        (
            "estimates ≥ 85 % covered %",
            None
            if not (
                covered := [c for r in fine if (c := _channel(r.coverage, channel)) is not None]
            )
            else 100 * float(np.mean([c >= WELL_COVERED for c in covered])),
        ),
        (
            "method's own σ ±2σ cov. %",
            None
            if (m := _mean(_channel(r.method_coverage, channel) for r in fine)) is None
            else 100 * m,
        ),
        ("σ ratio (median)", _median(_channel(r.sigma_ratio, channel) for r in fine)),
    )


def _mapping_statistics(rows: Sequence[ValidationRow]) -> Statistics:
    mapped = [row for row in rows if row.failure is None and row.mapping_mean_abs_nm is not None]
    errors = [row.mapping_mean_abs_nm for row in mapped]
    off = [
        row
        for row in mapped
        if row.mapping_mean_abs_nm is not None and row.mapping_mean_abs_nm > MAPPING_FAILURE_NM
    ]
    silent = [row for row in off if not row.mapping_warned]
    alarms = [
        row
        for row in mapped
        if row.mapping_warned
        and row.mapping_mean_abs_nm is not None
        and row.mapping_mean_abs_nm <= MAPPING_FAILURE_NM
    ]
    return (
        ("mean |Δλ| nm", _mean(errors)),
        ("median |Δλ| nm", _median(errors)),
        (f"> {MAPPING_FAILURE_NM:g} nm", float(len(off)) if mapped else None),
        (f"> {MAPPING_FAILURE_NM:g} nm unwarned", float(len(silent)) if mapped else None),
        (f"≤ {MAPPING_FAILURE_NM:g} nm warned", float(len(alarms)) if mapped else None),
        ("mapping RE %", None if (m := _mean(r.mapping_re for r in mapped)) is None else 100 * m),
        (
            "±2σ coverage %",
            None if (m := _mean(r.mapping_coverage for r in mapped)) is None else 100 * m,
        ),
        ("σ ratio (median)", _median(r.mapping_sigma_ratio for r in mapped)),
        (
            "σ ratio unwarned (median)",
            _median(r.mapping_sigma_ratio for r in mapped if not r.mapping_warned),
        ),
        (
            "σ ratio warned (median)",
            _median(r.mapping_sigma_ratio for r in mapped if r.mapping_warned),
        ),
    )


def _summary_row(
    key: tuple[str, str, str, str, str, str], chosen: Sequence[ValidationRow], stats: Statistics
) -> SummaryRow:
    failures = sum(row.failure is not None for row in chosen)
    return SummaryRow(*key, len(chosen), failures, stats)


def summarise(rows: Sequence[ValidationRow]) -> list[SummaryRow]:
    """The summary tables' rows for every split in ``rows`` (see the module docstring)."""
    summary: list[SummaryRow] = []
    for split in dict.fromkeys(row.split for row in rows):
        in_split = [row for row in rows if row.split == split]
        groups = list(dict.fromkeys(row.group for row in in_split))
        by_group = [ALL, *groups] if len(groups) > 1 else [ALL]
        for variant, method in dict.fromkeys((row.variant, row.method) for row in in_split):
            selected = [row for row in in_split if row.variant == variant]
            for channel in (*CHANNELS, ALL):
                key = (split, "sensitivity by channel", variant, method, ALL, channel)
                summary.append(
                    _summary_row(key, selected, _sensitivity_statistics(selected, channel))
                )
            for group in by_group[1:]:
                chosen = [row for row in selected if row.group == group]
                key = (split, "sensitivity by group", variant, method, group, ALL)
                summary.append(_summary_row(key, chosen, _sensitivity_statistics(chosen, ALL)))
            for group in by_group:
                chosen = selected if group == ALL else [r for r in selected if r.group == group]
                key = (split, "mapping", variant, method, group, ALL)
                summary.append(_summary_row(key, chosen, _mapping_statistics(chosen)))
    return summary


def _cell(value: float | None, digits: int = 2) -> str:
    if value is None or not math.isfinite(value):
        return "—" if value is None or math.isnan(value) else "∞"
    return f"{value:.{digits}f}"


def _markdown_table(rows: Sequence[SummaryRow], key_columns: Sequence[str]) -> list[str]:
    names = [name for name, _ in rows[0].statistics]
    header = [*key_columns, "n", "failed", *names]
    lines = [table_row(header), table_rule(len(header))]
    for row in rows:
        keys = {
            "method": row.variant,
            "registry": row.method,
            "group": row.group,
            "channel": row.channel,
        }
        values = [_cell(v, 0 if name.startswith(">") else 2) for name, v in row.statistics]
        lines.append(
            table_row([*(keys[k] for k in key_columns), row.estimates, row.failures, *values])
        )
    return lines


def markdown_report(
    splits: Sequence[Split],
    rows: Sequence[ValidationRow],
    settings: ProtocolSettings,
    *,
    command: str = "",
) -> str:
    """The report: for each split in ``rows``, its composition (when ``splits`` has it), then the
    tables and the failures."""
    summary = summarise(rows)
    out = ["# Validation protocol", ""]
    if command:
        out += [f"Command: `{command}`", ""]
    out += [f"Settings: {settings.describe()}.", ""]
    out += [
        "Methods: "
        + "; ".join(
            f"{v.label} = `{v.method}` with {', '.join(v.lamps)}"
            + (f" ({v.options})" if v.options is not None else "")
            for v in settings.variants
        ),
        "",
    ]
    described = {split.role: split for split in splits}
    for role in dict.fromkeys(row.split for row in summary):
        in_split = [row for row in summary if row.split == role]
        out += [f"## Split: {role}", ""]
        if role in described:
            out += [*described[role].describe(), ""]
        for table, keys in (
            ("sensitivity by channel", ("method", "registry", "channel")),
            ("sensitivity by group", ("method", "group")),
            ("mapping", ("method", "group")),
        ):
            chosen = [row for row in in_split if row.table == table]
            if chosen:
                out += [f"### {role}: {table}", "", *_markdown_table(chosen, keys), ""]
        failures = [row for row in rows if row.split == role and row.failure is not None]
        if failures:
            out += [f"### {role}: failed estimates", ""]
            out += [
                f"- {row.variant} on {row.camera} (scene {row.scene}): {row.failure}"
                for row in failures
            ]
            out.append("")
    return "\n".join(out)


def write_summary_csv(path: Path, rows: Sequence[ValidationRow]) -> Path:
    """The summary tables, one line per table row (statistics as columns)."""
    summary = summarise(rows)
    names = list(dict.fromkeys(name for row in summary for name, _ in row.statistics))
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(
            [
                "split",
                "table",
                "variant",
                "method",
                "group",
                "channel",
                "estimates",
                "failures",
                *names,
            ]
        )
        for row in summary:
            values = dict(row.statistics)
            writer.writerow(
                [
                    row.split,
                    row.table,
                    row.variant,
                    row.method,
                    row.group,
                    row.channel,
                    row.estimates,
                    row.failures,
                ]
                + ["" if values.get(name) is None else f"{values[name]:.6g}" for name in names]
            )
    return path


def write_rows_csv(path: Path, rows: Sequence[ValidationRow]) -> Path:
    """Every estimate: split, camera, scene, variant, per-channel scores, mapping scores, time,
    failure, and the scene's drawn parameters (JSON)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    per_channel = ("re", "coverage", "sigma_ratio", "method_coverage")
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(
            [
                "split",
                "camera",
                "body",
                "group",
                "collection",
                "scene",
                "variant",
                "method",
                "relative_error",
            ]
            + [f"{name}_{c}" for name in per_channel for c in CHANNELS]
            + [
                "mapping_mean_abs_nm",
                "mapping_re",
                "mapping_coverage",
                "mapping_sigma_ratio",
                "mapping_warned",
                "time_s",
                "failure",
                "scene_record",
            ]
        )
        for row in rows:
            triples = (row.channel_re, row.coverage, row.sigma_ratio, row.method_coverage)
            writer.writerow(
                [
                    row.split,
                    row.camera,
                    row.body,
                    row.group,
                    row.collection,
                    row.scene,
                    row.variant,
                    row.method,
                ]
                + ["" if row.channel_re is None else f"{row.relative_error:.6g}"]
                + [
                    "" if t is None else f"{value:.6g}"
                    for t in triples
                    for value in (t or (0.0, 0.0, 0.0))
                ]
                + [
                    "" if v is None else f"{v:.6g}"
                    for v in (
                        row.mapping_mean_abs_nm,
                        row.mapping_re,
                        row.mapping_coverage,
                        row.mapping_sigma_ratio,
                    )
                ]
                + ["" if row.mapping_warned is None else str(int(row.mapping_warned))]
                + [f"{row.time_s:.3f}", row.failure or "", row.scene_record]
            )
    return path
