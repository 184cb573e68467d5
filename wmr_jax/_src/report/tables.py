"""Markdown tables of results, the one formatter every report and command uses."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["markdown_table"]


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
