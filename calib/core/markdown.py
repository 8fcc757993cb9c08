"""Markdown tables, written one way: a cell's own ``|`` is escaped, so it stays one cell.

A heading such as ``mean |Δλ| nm`` would otherwise split into three cells and shift every column
after it.

Examples
--------
>>> print(table_row(["mean |Δλ| nm", 0.5]))
| mean \\|Δλ\\| nm | 0.5 |
>>> table_rule(3, right_aligned_from=1)
'|---|---:|---:|'
"""

from __future__ import annotations

from collections.abc import Iterable


def table_row(cells: Iterable[object]) -> str:
    """One row of a Markdown table, each cell's ``|`` escaped."""
    return "| " + " | ".join(str(cell).replace("|", "\\|") for cell in cells) + " |"


def table_rule(columns: int, *, right_aligned_from: int | None = None) -> str:
    """The rule under a table's heading row; columns from ``right_aligned_from`` on are
    right-aligned (numbers)."""
    return (
        "|"
        + "|".join(
            "---:" if right_aligned_from is not None and index >= right_aligned_from else "---"
            for index in range(columns)
        )
        + "|"
    )
