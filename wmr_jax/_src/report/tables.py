"""Markdown tables of results, the one formatter every report and command uses."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["markdown_table", "number", "percent"]


def markdown_table(rows: list[dict[str, Any]], columns: list[str] | None = None) -> str:
    """Format rows of scalars (lists shown compactly) as a Markdown table."""
    columns = columns or list(rows[0])

    def fmt(value: Any) -> str:
        if isinstance(value, float):
            if math.isinf(value):
                return "inf"
            return f"{value:.3g}" if abs(value) < 1e4 else f"{value:.4g}"
        if isinstance(value, list):
            return "(" + ", ".join(f"{v:g}" for v in value) + ")"
        return str(value)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(row[c]) for c in columns) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def number(value: float) -> str:
    """A float with three significant digits, as every table prints it (``inf`` for no value)."""
    return "inf" if math.isinf(value) else f"{value:.3g}"


def percent(fraction: float) -> str:
    """A fraction in ``[0, 1]`` as a percentage with three significant digits (``'99.9 %'``)."""
    value = 100.0 * float(fraction)
    return f"{value:.0f} %" if value in (0.0, 100.0) else f"{value:.3g} %"
