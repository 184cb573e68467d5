"""Markdown tables of results, the one formatter every report and command uses."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np


def markdown_table(rows: list[dict[str, Any]], columns: list[str] | None = None) -> str:
    """Format rows of scalars (lists shown compactly) as a Markdown table, ``|`` escaped."""
    rows = require_rows("rows", rows)
    columns = list(rows[0]) if columns is None else list(columns)
    for i, row in enumerate(rows):
        missing = [c for c in columns if c not in row]
        if missing:
            raise ValueError(
                f"rows[{i}] has no column {missing[0]!r}; allowed: rows with every one of "
                f"columns = {columns!r}"
            )

    def fmt(value: Any) -> str:
        if _is_float_scalar(value):
            value = float(value)
            return f"{value:.4g}" if math.isfinite(value) and abs(value) >= 1e4 else number(value)
        if isinstance(value, list):
            return "(" + ", ".join(f"{v:g}" for v in value) + ")"
        return str(value)

    def cell(text: Any) -> str:
        return " ".join(str(text).replace("|", r"\|").splitlines())

    lines = ["| " + " | ".join(cell(c) for c in columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(fmt(row[c])) for c in columns) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def require_rows(name: str, rows: Any) -> list[Any]:
    """``rows`` as a list, or refused unless it is a non-empty sequence of dicts."""
    if isinstance(rows, Iterable) and not isinstance(rows, (str, bytes, Mapping)):
        rows = list(rows)
    if not isinstance(rows, list) or not rows:
        raise ValueError(
            f"{name} = {rows!r:.80} is not allowed; allowed: a non-empty list of dicts"
        )
    for i, row in enumerate(rows):
        if not isinstance(row, Mapping):
            raise ValueError(f"{name}[{i}] = {row!r:.80} is not allowed; allowed: a dict")
    return list(rows)


# What ``wmr_jax.io.atomic_write_json`` writes for the floats JSON has no literal for.
_JSON_FLOATS = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan, None: math.nan}


def json_number(name: str, value: Any) -> float:
    """``value`` as a float, reading back what ``atomic_write_json`` wrote for inf or NaN."""
    if value is None or isinstance(value, str):
        if value in _JSON_FLOATS:
            return _JSON_FLOATS[value]
    elif not isinstance(value, (bool, np.bool_)):
        with contextlib.suppress(TypeError, ValueError):
            if np.ndim(value) == 0 and not np.iscomplexobj(value):
                return float(value)
    raise ValueError(
        f'{name} = {value!r:.80} is not allowed; allowed: a number, or "inf", "-inf", "nan" '
        "or None (as atomic_write_json writes them)"
    )


def row_numbers(name: str, row: Mapping[str, Any], keys: Any) -> dict[str, float]:
    """``{key: json_number(row[key])}`` for ``keys``, naming a missing key."""
    missing = [k for k in keys if k not in row]
    if missing:
        raise ValueError(
            f"{name} has no {missing[0]!r}; allowed: a dict with {', '.join(map(repr, keys))}"
        )
    return {k: json_number(f"{name}[{k!r}]", row[k]) for k in keys}


def _is_float_scalar(value: Any) -> bool:
    """Whether ``value`` is a float: Python, NumPy (``float32`` too) or a 0-d NumPy/JAX array."""
    if isinstance(value, (float, np.floating)):
        return True
    dtype = getattr(value, "dtype", None)
    return dtype is not None and np.ndim(value) == 0 and np.dtype(dtype).kind == "f"


def number(value: float) -> str:
    """A float with three significant digits, as every table prints it (``inf`` for no value)."""
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return f"{value:.3g}"


def percent(fraction: float) -> str:
    """A fraction in ``[0, 1]`` as a percentage with three significant digits (``'99.9 %'``)."""
    value = 100.0 * float(fraction)
    return f"{value:.0f} %" if value in (0.0, 100.0) else f"{value:.3g} %"
