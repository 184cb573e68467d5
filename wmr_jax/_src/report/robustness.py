"""The robustness study's figures, tables and result files (``docs/model.md §7``).

Tables print fractions of runs as percentages; figures mark apart the runs
that count as arrived only because the horizon ends.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from wmr_jax._src.io import atomic_write_text, json_text
from wmr_jax._src.model.params import Robot
from wmr_jax._src.model.robots import describe_robot, robot_from_values, robot_json
from wmr_jax._src.report.figures import Patch, built, plt, save_closed
from wmr_jax._src.report.tables import markdown_table, percent, require_rows
from wmr_jax._src.sim.poses import HORIZON_S

# The columns of robustness.md, in order.
ROBUSTNESS_COLUMNS = [
    "condition",
    "controller",
    "noise xy cm",
    "noise theta deg",
    "success",
    "mean arrival s",
    "median arrival s",
    "reached",
    "median first arrival s",
    "mean final distance cm",
    "mean zigzag",
]

# The columns of standard_conditions.md, in order.
STANDARD_COLUMNS = [
    "condition",
    "gains",
    "feedback",
    "success",
    "mean arrival s",
    "median arrival s",
    "mean final distance cm",
    "mismatch",
    "runs",
]

# The columns of noise_curve.md, in order.
NOISE_CURVE_COLUMNS = [
    "gains",
    "feedback",
    "noise xy cm",
    "noise theta deg",
    "success",
    "mean arrival s",
    "mismatch",
    "runs",
]

_STYLES = ("-", "--", ":", "-.")

# Fractions of runs, printed as percentages in the tables.
_PERCENT_KEYS = ("success", "reached", "settled at horizon")
# The share of runs that only settle at the horizon (studies.settled_at_horizon),
# and the arrival of the others: shown where every row has them.
_LATE = "settled at horizon"
_ARRIVAL_COLUMNS = ("mean arrival s", "median arrival s")
# A point where at least this share of the successes only settles at the horizon
# is drawn as an x (line figures).
_LATE_MARK = 0.5


def robustness_table(rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    """A Markdown table of study rows, fractions of runs as percentages (``'99.8 %'``).

    ``"settled at horizon"`` is shown after the last arrival column where every row has it.
    """
    rows = require_rows("rows", rows)
    columns = list(columns)
    if all(_LATE in r for r in rows) and _LATE not in columns:
        after = [i for i, c in enumerate(columns) if c in _ARRIVAL_COLUMNS]
        columns.insert(after[-1] + 1 if after else len(columns), _LATE)
    markdown_table(rows, columns)  # names a row without a column, before formatting
    shown = [{c: _cell(r, c) for c in columns} for r in rows]
    return markdown_table(shown, columns)


def _cell(row: dict[str, Any], column: str) -> Any:
    """A cell as the table shows it: a percentage, ``none arrived`` for no arrival, or as is."""
    if column in _PERCENT_KEYS:
        with contextlib.suppress(TypeError, ValueError):  # a damaged cell is shown as it is
            return percent(float(row[column]))
    elif column.endswith(" s") and row[column] == math.inf:  # an arrival time of no run
        return "none before the horizon" if "not at horizon" in column else "none arrived"
    return row[column]


def _late_share(row: dict[str, Any]) -> float:
    """The fraction of a row's runs that only settle at the horizon (0 where not recorded)."""
    try:
        return min(max(float(row.get(_LATE, 0.0)), 0.0), float(row["success"]))
    except (TypeError, ValueError):
        return 0.0


def _arrived_time(row: dict[str, Any], key: str) -> float:
    """``key`` (a mean or median arrival) over the runs that arrive, NaN where none does."""
    if float(row["success"]) - _late_share(row) <= 0:
        return math.nan
    value = row.get(f"{key.removesuffix(' s')}, not at horizon s", row[key])
    try:
        value = float(value)
    except (TypeError, ValueError):
        return math.nan
    return value if math.isfinite(value) else math.nan


def _horizon_of(rows: Sequence[dict[str, Any]], default: float = HORIZON_S) -> float:
    """The runs' horizon, s, as the rows record it (else ``default``)."""
    try:
        return float(rows[0].get("horizon s", default))
    except (TypeError, ValueError):
        return default


def _robot_text(meta: dict[str, Any]) -> str:
    """``", on <robot>"`` for a meta that records a robot, else ``""``."""
    if not isinstance(meta.get("robot"), dict):
        return ""
    return f", on {describe_robot(robot_from_values(meta['robot'], 'meta robot'))}"


def write_robustness(
    out_dir: str | os.PathLike,
    rows: Sequence[dict[str, Any]],
    *,
    seed: int,
    velocity: str,
    n_runs: int,
    robot: Any = None,
    x64: bool | None = None,
) -> list[Path]:
    """Write ``robustness.png``, ``robustness.md`` and ``robustness.json`` into ``out_dir``.

    Args:
        out_dir: the folder (created if missing).
        rows: ``robustness_study`` rows.
        seed, velocity, n_runs: the study's seed, velocity loop and runs per level.
        robot: the study's ``Robot``; ``None``: the paper robot.
        x64: recorded as the ``dtype`` (float64 or float32); ``None`` records none.

    Returns:
        The paths written.
    """
    rows = require_rows("rows", rows)
    horizon = _horizon_of(rows)
    # The controllers' feedback, as the rows say it (raw, or the estimator's name).
    fed = sorted({str(row["feedback"]) for row in rows if "feedback" in row})
    named = {"raw": "raw feedback", "ekf": "the ekf", "observer": "the observer"}
    feedback = "".join(f"{named.get(f, f'estimator {f}')}, " for f in fed)
    meta = {"seed": seed, "velocity": velocity, "runs": n_runs, "horizon_s": horizon}
    if x64 is not None:
        meta["dtype"] = "float64" if x64 else "float32"
    meta["robot"] = robot_json(Robot() if robot is None else robot)

    def head(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
        return (
            f"Robustness Monte Carlo ({velocity} loop, {feedback}seed {seed}, {n_runs} runs "
            f"per row, horizon {horizon:g} s{_robot_text(meta)})\n\n"
        )

    title = (
        f"Robustness, {velocity} loop{_robot_text(meta)}: {n_runs} random poses "
        f"(docs/model.md §6) per point, seed {seed}, horizon {horizon:g} s; mismatch ±3 % "
        "wheel radius" + (", ±20 % mass" if velocity == "nonideal" else "") + "; latency one sample"
    )

    # "tight": the legend lies outside the axes.
    figure, save = functools.partial(robustness_figure, title=title), {"bbox_inches": "tight"}
    return _write_study(out_dir, "robustness", rows, meta, ROBUSTNESS_COLUMNS, head, figure, **save)


def robustness_figure(rows: Sequence[dict[str, Any]], *, title: str) -> Any:
    """Draw success and median arrival against noise, one line per controller and condition.

    The caller saves and closes the returned ``Figure``.
    """
    rows = require_rows("rows", rows)
    drawn = ["controller", "condition", "noise xy cm", "noise theta deg", "success"]
    markdown_table(rows, [*drawn, "median arrival s"])  # names a row without one of them
    names = list(dict.fromkeys(r["controller"] for r in rows))
    conditions = list(dict.fromkeys(r["condition"] for r in rows))
    first = [r for r in rows if (r["controller"], r["condition"]) == (names[0], conditions[0])]
    lines = []
    for c, name in enumerate(names):
        for i, label in enumerate(conditions):
            sel = [r for r in rows if r["controller"] == name and r["condition"] == label]
            style = {"linestyle": _STYLES[i % len(_STYLES)], "color": plt.get_cmap("tab10")(c)}
            lines.append((f"{name}, {label}", style, sel))
    degrees = ", ".join(f"{r['noise theta deg']:g}" for r in first)
    x_axis = f"measurement noise σ_xy [cm] (σ_θ = {degrees}°)"
    limits = ((-0.02, 1.02), (0.0, _horizon_of(rows)))
    return _lines_figure(rows, lines, "median arrival s", x_axis, limits, title, (0.75, 7), 4.2)


def _lines_figure(rows, lines, arrival, x_axis, limits, title, legend, height) -> Any:
    """Success and ``arrival`` against σ_xy, one line per ``(label, style, rows)`` of ``lines``.

    ``limits``: each panel's y range; ``legend``: ``(right, fontsize)``, the axes fitted
    left of ``right`` (a share of the width), the legend, x mark included, right of it.
    """

    def draw(fig, axes):
        for label, style, sel in lines:
            x = [r["noise xy cm"] for r in sel]
            late = _late_points(sel)
            _plot_marked(axes[0], x, [r["success"] for r in sel], late, label=label, **style)
            # Over the runs that arrive only; absent (not drawn) where none does.
            _plot_marked(axes[1], x, [_arrived_time(r, arrival) for r in sel], late, **style)
        shown = f"{arrival.removesuffix(' s')} of the runs that arrive [s]"
        for ax, label, (low, high) in zip(axes, ("success rate", shown), limits, strict=True):
            ax.set_xlabel(x_axis)
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
            ax.set_ylim(low, high)
        fig.suptitle(title, fontsize=9)
        right, fontsize = legend
        fig.tight_layout(rect=(0, 0, right, 1))
        handles, labels = axes[0].get_legend_handles_labels()
        if _late_points(rows):
            handles.append(plt.Line2D([], [], color="grey", marker="x", linestyle="none"))
            labels.append("x: half or more of the\nsuccesses only settle\nat the horizon")
        outside = {"loc": "center left", "bbox_to_anchor": (right, 0.5)}
        fig.legend(handles, labels, fontsize=fontsize, **outside)

    return built(draw, 1, 2, figsize=(11, height))


def _late_points(rows: Sequence[dict[str, Any]]) -> list[int]:
    """The indices of rows where at least half of the successes only settle at the horizon."""
    return [
        i
        for i, r in enumerate(rows)
        if float(r["success"]) > 0 and _late_share(r) >= _LATE_MARK * float(r["success"])
    ]


def _plot_marked(ax, x, y, late, **style) -> None:
    """A line with o markers, and x markers at the ``late`` indices."""
    others = [i for i in range(len(x)) if i not in late]
    ax.plot(x, y, marker="o", markevery=others, **style)
    if late:
        plain = {k: v for k, v in style.items() if k not in ("linestyle", "label")}
        ax.plot([x[i] for i in late], [y[i] for i in late], linestyle="none", marker="x",
                markersize=8, **plain)  # fmt: skip


def write_standard_conditions(
    out_dir: str | os.PathLike, rows: Sequence[dict[str, Any]], *, meta: dict[str, Any]
) -> list[Path]:
    """Write ``standard_conditions.png``, ``.md`` and ``.json``; return their paths.

    ``meta`` says what produced the rows; its ``"robot"`` is named in the text.
    """

    def head(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
        return (
            "Gain sets under the standard conditions of docs/model.md §7 (hard law, ideal loop"
            f"{_robot_text(meta)}, {rows[0]['runs']} held-out poses of docs/model.md §6, horizon "
            f"{_horizon_of(rows):g} s); every condition but the model robot's with each wheel's "
            "radius off by up to the mismatch column, drawn per run (docs/model.md §9)\n\n"
        )

    columns, figure = STANDARD_COLUMNS, standard_figure
    return _write_study(out_dir, "standard_conditions", rows, meta, columns, head, figure)


def standard_figure(rows: Sequence[dict[str, Any]]) -> Any:
    """Draw success and mean arrival per condition, one bar per gain set (legend outside).

    Success is hatched for the runs that only settle at the horizon.
    """
    rows = require_rows("rows", rows)
    markdown_table(rows, ["condition", "gains", "success", "mean arrival s"])  # names a gap
    conditions = list(dict.fromkeys(r["condition"] for r in rows))
    sets = list(dict.fromkeys(r["gains"] for r in rows))
    for name in sets:
        have = {r["condition"] for r in rows if r["gains"] == name}
        if len(have) < len(conditions):
            lacking = next(c for c in conditions if c not in have)
            raise ValueError(
                f"rows has no row of gains {name!r} under condition {lacking!r}; allowed: "
                "one row per gain set and condition"
            )
    return built(functools.partial(_draw_standard, rows, conditions, sets), 1, 2, figsize=(11, 4.0))


def _draw_standard(rows, conditions, sets, fig, axes) -> None:
    """Draw the bars, labels and legend of ``standard_figure``."""
    any_late, width = False, 0.8 / len(sets)
    for j, name in enumerate(sets):
        got = {r["condition"]: r for r in rows if r["gains"] == name}
        x = [i + (j - (len(sets) - 1) / 2) * width for i in range(len(conditions))]
        colour = plt.get_cmap("tab10")(j)
        late = [_late_share(got[c]) for c in conditions]
        arrived = [float(got[c]["success"]) - s for c, s in zip(conditions, late, strict=True)]
        axes[0].bar(x, arrived, width, color=colour, label=name)
        if any(late):  # no arrival time: hatched, on top of the runs that arrive
            any_late = True
            axes[0].bar(x, late, width, bottom=arrived, color="white", edgecolor=colour,
                        hatch="///", linewidth=0.8)  # fmt: skip
        # Mean arrival of the runs that arrive; no bar where none does.
        means = [_arrived_time(got[c], "mean arrival s") for c in conditions]
        axes[1].bar(x, [0.0 if math.isnan(m) else m for m in means], width, color=colour)
        for xi, mean, share in zip(x, means, late, strict=True):
            if math.isnan(mean) and share > 0:  # only settles at the horizon: said, not drawn
                axes[1].text(xi, 0.0, "settles at horizon only", rotation=90, fontsize=6,
                             ha="center", va="bottom", color=colour)  # fmt: skip
    labels = ("success rate", "mean arrival of the runs that arrive [s]")
    for ax, label in zip(axes, labels, strict=True):
        ax.set_xticks(range(len(conditions)), conditions)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, axis="y")
    axes[0].set_ylim(0, 1.05)
    fig.suptitle(
        "docs/model.md §7 standard conditions: latency = 1 sample; noise σ_xy = 0.5 cm, "
        "σ_θ = 1°; ±3 % wheel radius but on the model robot; hard law, ideal loop, horizon "
        f"{_horizon_of(rows):g} s",
        fontsize=9,
    )
    fig.tight_layout(rect=(0, 0, 0.82, 1))
    handles, labels = axes[0].get_legend_handles_labels()
    if any_late:
        handles.append(Patch(facecolor="white", edgecolor="grey", hatch="///"))
        labels.append("only settles at\nthe horizon")
    fig.legend(handles, labels, fontsize=8, loc="center left", bbox_to_anchor=(0.82, 0.5))


def write_noise_curve(
    out_dir: str | os.PathLike, rows: Sequence[dict[str, Any]], *, meta: dict[str, Any]
) -> list[Path]:
    """Write ``noise_curve.png``, ``.md`` and ``.json`` of ``noise_curve`` rows, as above."""

    def head(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
        return (
            "Success and mean arrival against pose noise (σ_θ = 2° per cm of σ_xy; hard law, "
            f"ideal loop{_robot_text(meta)}, {rows[0]['runs']} held-out poses, horizon "
            f"{_horizon_of(rows):g} s, each wheel's radius off by up to "
            f"{100 * float(rows[0]['mismatch']):g} % per run; docs/model.md §7, §9)\n\n"
        )

    columns, figure = NOISE_CURVE_COLUMNS, noise_curve_figure
    return _write_study(out_dir, "noise_curve", rows, meta, columns, head, figure)


def _write_study(out_dir, name, rows, meta, columns, head, figure, **save) -> list[Path]:
    """Write ``name``.png, ``.md`` (``head`` and the table) and ``.json``, all checked first."""
    out, rows = Path(out_dir), require_rows("rows", rows)
    if not isinstance(meta, dict):
        raise ValueError(f"meta = {meta!r:.80} is not allowed; allowed: a dict")
    table = robustness_table(rows, columns)
    text = head(rows, meta) + table
    record = json_text({**meta, "rows": rows}, "meta and rows", indent=2, sort_keys=False) + "\n"
    png = save_closed(figure(rows), out / f"{name}.png", dpi=110, **save)
    md = atomic_write_text(out / f"{name}.md", text)
    return [png, md, atomic_write_text(out / f"{name}.json", record)]


def noise_curve_figure(rows: Sequence[dict[str, Any]]) -> Any:
    """Draw success and mean arrival against σ_xy, one line per loop (legend outside)."""
    rows = require_rows("rows", rows)
    markdown_table(rows, ["gains", "feedback", "noise xy cm", "success", "mean arrival s"])
    lines = []
    for j, name in enumerate(dict.fromkeys(r["gains"] for r in rows)):
        mine = sorted((r for r in rows if r["gains"] == name), key=lambda r: r["noise xy cm"])
        style = {"linestyle": "--" if mine[0]["feedback"] == "raw" else "-"}
        style["color"] = plt.get_cmap("tab10")(j)
        lines.append((f"{name} ({mine[0]['feedback']})", style, mine))
    title = (
        f"Noise-level curve: ±{100 * float(rows[0]['mismatch']):g} % wheel radius per run, "
        "hard law, ideal loop; dashed: raw feedback, solid: estimator"
    )
    x_axis = "pose noise σ_xy [cm] (σ_θ = 2°/cm)"
    limits = ((0, 1.05), (0, None))
    return _lines_figure(rows, lines, "mean arrival s", x_axis, limits, title, (0.78, 8), 4.0)
