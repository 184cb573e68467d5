"""Reports of a tuning run: the tuning curve and the before/after table."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax._src.checks import real_array, require
from wmr_jax._src.io import save_figure
from wmr_jax._src.model.controllers.schedule import SHAPE_FIELDS, knot_radii
from wmr_jax._src.report.tables import json_number, markdown_table, require_rows
from wmr_jax._src.studies.optimal import bound_ratios
from wmr_jax._src.tuning.parametrisation import (
    GAIN_FIELDS,
    PAPER_FEASIBLE_GAINS,
    gains_as_dict,
    paper_feasible_gains,
)
from wmr_jax._src.tuning.problems import MAX_TUNED_KNOTS, PROBLEMS, get_problem, schedule_problem
from wmr_jax._src.tuning.robust import condition_score

# Each parameter's symbol and the unit a person types it in (Φ_m in degrees, as
# simulate's --phi-m takes it; the files hold radians).
SYMBOLS = {
    "kr": ("k_r", "cm/s"),
    "k_theta": ("k_θ", "rad/s"),
    "k_turn": ("k_turn", "rad/s"),
    "phi_m": ("Φ_m", "°"),
    "r_m": ("R_m", "cm"),
    "r_a": ("R_a", "cm"),
    "r_e": ("R_e", "cm"),
    "alpha": ("α", ""),
    "v_max": ("V_max", "cm/s"),
    "half_track": ("L", "cm"),
}
_GAIN_LABELS = {k: f"{s} ({u.replace('°', 'deg')})" if u else s for k, (s, u) in SYMBOLS.items()}

# The columns of the yardstick ratios -> their bound_ratios keys.
_BOUND_COLUMNS = {"vs turn–drive–turn": "vs_turn_drive_turn", "vs lower bound": "vs_lower_bound"}
_NONE_ARRIVED = "none arrived"


def _right_aligned(rows: list[dict[str, str]]) -> str:
    """The table of ``rows``, whose first has every column; the numeric ones right-aligned."""
    columns = list(rows[0])
    rows = [{**dict.fromkeys(columns, ""), **row} for row in rows]
    lines = markdown_table(rows, columns).splitlines()
    lines[1] = "|---|" + "---:|" * (len(columns) - 1)
    return "\n".join(lines) + "\n"


def evaluation_table(evaluation: dict[str, Any], bounds: Any = None) -> str:
    """Return the before/after table as Markdown (mean arrival, success, peak wheel speed).

    Args:
        evaluation: ``Evaluation`` rows keyed by name; ``"paper_feasible"``
            is the reference of the "vs paper" column.
        bounds: ``time_bounds`` of the same poses (docs/model.md §8): adds the
            ratio of each mean arrival to the mean turn–drive–turn time and
            to the mean lower bound, and a row for each yardstick.
    """
    if not isinstance(evaluation, dict) or "paper_feasible" not in evaluation:
        raise ValueError(
            f"evaluation = {evaluation!r:.80} is not allowed; allowed: a dict of Evaluation "
            "rows with 'paper_feasible' (the reference of the 'vs paper' column)"
        )
    for name, ev in evaluation.items():
        for field, ok, allowed in (
            ("success_rate", lambda x: 0 <= x <= 1, "a fraction in [0, 1]"),
            ("mean_arrival", lambda x: x > 0, "a time > 0 s (inf if no run arrives)"),
        ):
            value = getattr(ev, field, None)
            try:
                good = not isinstance(value, (bool, str)) and ok(float(value))
            except (TypeError, ValueError):
                good = False
            if not good:
                raise ValueError(
                    f"evaluation[{name!r}].{field} = {value!r} is not allowed; allowed: {allowed}"
                )
    paper = float(evaluation["paper_feasible"].mean_arrival)
    rows = []
    for name, ev in evaluation.items():
        mean = float(ev.mean_arrival)
        # A ratio that needs a run that never arrived says so (never nan×, inf× or 0.00×).
        if not math.isfinite(mean):
            vs_paper = _NONE_ARRIVED
        elif not math.isfinite(paper):
            vs_paper = "paper: none arrived"
        else:
            vs_paper = f"{paper / mean:.2f}×"
        row = {
            "gains": name.replace("_", " "),
            "mean arrival (s)": f"{mean:.3f}" if math.isfinite(mean) else _NONE_ARRIVED,
            "vs paper": vs_paper,
            "success": f"{100 * ev.success_rate:.2f} %",
            "peak wheel speed (cm/s)": f"{ev.peak_wheel_speed:.1f}",
        }
        if bounds is not None:
            ratios = bound_ratios(mean, bounds)
            for column, key in _BOUND_COLUMNS.items():
                row[column] = f"{ratios[key]:.3f}×" if math.isfinite(mean) else _NONE_ARRIVED
        rows.append(row)
    if bounds is not None:
        for label, values in (
            ("turn–drive–turn (§8)", bounds.turn_drive_turn),
            ("lower bound (§8)", bounds.lower_bound),
        ):
            rows.append({"gains": label, "mean arrival (s)": f"{float(np.mean(values)):.3f}"})
    return _right_aligned(rows)


# The numbers comparison_table reads from each row, and what each may be.
_COMPARE_NUMBERS = {
    "mean_arrival": (lambda x: x > 0, "a time > 0 s, or inf (none arrived)"),
    "success_rate": (lambda x: 0 <= x <= 1, "a fraction in [0, 1]"),
    "wall_s": (lambda x: 0 <= x < math.inf, "a finite time >= 0 s"),
    "lower_bound_s": (lambda x: 0 < x < math.inf, "a finite time > 0 s"),
    "turn_drive_turn_s": (lambda x: 0 < x < math.inf, "a finite time > 0 s"),
}


def _compare_numbers(i: int, row: dict[str, Any]) -> dict[str, float]:
    """The numbers of ``rows[i]`` that the table shows, read back as ``atomic_write_json`` wrote."""
    out = {}
    for key, (ok, allowed) in _COMPARE_NUMBERS.items():
        if key not in row:
            raise ValueError(f"rows[{i}] has no {key!r}; allowed: rows of compare")
        try:
            value = json_number(f"rows[{i}][{key!r}]", row[key])
        except ValueError:
            value = math.nan
        if not ok(value):  # NaN is never allowed
            raise ValueError(
                f"rows[{i}][{key!r}] = {row[key]!r:.60} is not allowed; allowed: {allowed}"
            )
        out[key] = value
    for key in ("problem", "method"):
        if not isinstance(row.get(key), str):
            raise ValueError(
                f"rows[{i}][{key!r}] = {row.get(key)!r:.60} is not allowed; allowed: a string"
            )
    return out


def _arrived_mean(values: list[float], fmt: str) -> str:
    """The mean of ``values`` as ``fmt``, or which of them never arrived (``inf``)."""
    missed = sum(not math.isfinite(v) for v in values)
    if missed == len(values):
        return _NONE_ARRIVED
    if missed:
        return f"{_NONE_ARRIVED} in {missed} of {len(values)}"
    return fmt.format(float(np.mean(values)))


def _maybe(value: Any, fmt: str) -> str:
    """``value`` as ``fmt``, or "—" where a row has none (a rate over 0 s)."""
    return "—" if value is None else fmt.format(float(value))


def _minimised_notes(rows: list[dict[str, Any]]) -> str:
    """One line per method: what it minimises (the rows' ``minimises``), under a table."""
    said = {}
    for row in rows:
        if isinstance(row.get("minimises"), str):
            said.setdefault(str(row["method"]), row["minimises"])
    if not said:
        return ""
    return "\n" + "".join(f"- {method} minimises: {text}\n" for method, text in said.items())


def comparison_table(rows: list[dict[str, Any]]) -> str:
    """Return gradient vs CMA-ES vs random search as Markdown, one line per problem and method.

    A seed that never arrives (``inf``, or ``"inf"`` read back from JSON) reads
    "none arrived", as do the means and ratios that need it; under the table,
    what each method minimises.

    Args:
        rows: the rows of ``wmr_jax.tuning.compare`` (one per problem, seed and method).

    Raises:
        ValueError: naming the row and key of a missing or non-numeric number.
    """
    rows = require_rows("rows", rows)
    numbers = [_compare_numbers(i, row) for i, row in enumerate(rows)]
    # Each row with its numbers read back as floats, grouped by problem and method.
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row, values in zip(rows, numbers, strict=True):
        # A row without a parameter count has the default problem's.
        default = PROBLEMS.get(row["problem"])
        size = row.get("parameters", None if default is None else default.dim)
        problem = row["problem"] if size is None else f"{row['problem']} ({size})"
        groups.setdefault((problem, row["method"]), []).append({**row, **values})
    lines = []
    for (problem, method), group in groups.items():
        arrival = [r["mean_arrival"] for r in group]
        gap = [r["mean_arrival"] - r["lower_bound_s"] for r in group]
        ratio = [r["mean_arrival"] / r["turn_drive_turn_s"] for r in group]
        lines.append(
            {
                "problem (parameters)": problem,
                "method": method,
                "mean arrival (s), seeds 0/1/2": " / ".join(
                    f"{a:.3f}" if math.isfinite(a) else _NONE_ARRIVED for a in arrival
                ),
                "success": f"{100 * min(r['success_rate'] for r in group):.1f} %",
                "mean − lower bound (s)": _arrived_mean(gap, "{:.3f}"),
                "vs turn–drive–turn": _arrived_mean(ratio, "{:.3f}×"),
                "CPU time (s)": " / ".join(_maybe(r.get("cpu_s"), "{:.0f}") for r in group),
                "wall time (s)": " / ".join(f"{r['wall_s']:.0f}" for r in group),
                "candidates per CPU-s": " / ".join(
                    _maybe(r.get("per_cpu_s"), "{:.3g}") for r in group
                ),
            }
        )
    first = numbers[0]
    lines.append(
        {
            "problem (parameters)": "—",
            "method": "turn–drive–turn / lower bound (§8)",
            "mean arrival (s), seeds 0/1/2": (
                f"{first['turn_drive_turn_s']:.3f} / {first['lower_bound_s']:.3f}"
            ),
        }
    )
    return _right_aligned(lines) + _minimised_notes(rows)


def tuning_curve(
    path: str | os.PathLike,
    history: dict[str, np.ndarray],
    *,
    velocity: str = "ideal",
    problem: str = "fixed",
    robot: Any = None,
) -> Path:
    """Save the loss (with the temperature) and the parameters against the iteration.

    A schedule's tables are drawn against ``r_e`` (first and last iteration);
    fixed gains beside ``paper_feasible_gains(robot)``, the run's baseline.
    Non-finite values are marked × along the panel's top and counted in its title.

    Args:
        path: the image file to write (atomically).
        history: ``TuneResult.history``: ``loss`` (s), ``temperature`` and
            ``gains`` ``(iters, columns)`` (``Problem.columns``).
        velocity: the velocity loop tuned for, for the title.
        problem: ``"fixed"`` or ``"schedule"``.
        robot: the robot tuned for; ``None`` is the paper robot.

    Returns:
        ``path``.
    """
    from wmr_jax._src.report.figures import closed_after

    if not isinstance(history, dict) or any(k not in history for k in _HISTORY_KEYS):
        raise ValueError(
            f"history = {history!r:.80} is not allowed; allowed: TuneResult.history, a dict "
            f"with {', '.join(_HISTORY_KEYS)}"
        )
    if problem not in ("fixed", "schedule"):
        raise ValueError(f"problem = {problem!r} is not allowed; allowed: 'fixed', 'schedule'")
    loss, temperature = _history_curves(history)
    gains = real_array("history['gains']", history["gains"], "real numbers")
    columns = len(get_problem(problem).columns)
    # A schedule of K knots has 3K + 7 columns (tables, shape gains, robot).
    knots = (gains.shape[-1] - 7) // 3 if gains.ndim == 2 else 0
    if problem == "schedule" and 2 <= knots <= MAX_TUNED_KNOTS:
        columns = len(schedule_problem(knots).columns)
    if gains.shape != (len(loss), columns):
        raise ValueError(
            f"history['gains'] has shape {gains.shape}; allowed: ({len(loss)}, "
            f"{columns}), one row of the {problem!r} problem's columns per iteration"
        )
    baseline = paper_feasible_gains(robot)
    steps = np.arange(1, len(loss) + 1)
    # A panel for the loss and one for each parameter tuned: 7 gains, or a
    # schedule's 3 tables and 5 shape gains.
    grid, size = ((3, 3), (12, 9)) if problem == "schedule" else ((2, 4), (14, 6))
    with closed_after(*grid, figsize=size, constrained_layout=True) as (fig, axes):
        ax = axes[0, 0]
        # The loss axis is logarithmic: a loss <= 0 has no place on it either.
        finite = _plot_marked(ax, steps, loss, np.isfinite(loss) & (loss > 0), lw=0.8, color="C0")
        ax.set_yscale("log")
        ax.set_xlabel("iteration")
        ax.set_ylabel("loss (s)", color="C0")
        twin = ax.twinx()
        twin.plot(steps, temperature, lw=1.0, color="C3")
        twin.set_yscale("log")
        twin.set_ylabel("temperature", color="C3")
        what = "non-finite or non-positive, marked ×"
        _marked_title(ax, f"loss ({velocity} loop)", finite, what)
        if problem == "schedule":
            _schedule_panels(axes, steps, gains, knots)
        else:
            _gain_panels(axes, steps, gains, baseline)
        return save_figure(fig, path, dpi=110)


def _plot_marked(ax: Any, steps: np.ndarray, values: np.ndarray, drawn: Any, **style: Any) -> Any:
    """Plot ``values`` where ``drawn``, mark the rest × along the top; return ``drawn``."""
    drawn = np.asarray(drawn, dtype=bool)
    ax.plot(steps[drawn], values[drawn], **style)
    if not drawn.all():
        top = ax.get_xaxis_transform()  # x in data, y in axes fraction
        ax.plot(steps[~drawn], np.full((~drawn).sum(), 0.97), "x", color="C3", transform=top)
    return drawn


def _marked_title(ax: Any, title: str, drawn: Any, what: str = "non-finite, marked ×") -> None:
    """``title``, with the count of the values not drawn (``what`` they are) where there are any."""
    missing = int((~np.asarray(drawn, dtype=bool)).sum())
    if missing:
        title += f"; {missing} {what}"
    ax.set_title(title, fontsize=9 if missing else None)


_HISTORY_KEYS = ("loss", "temperature", "gains")


def _history_curves(history: dict) -> tuple[np.ndarray, np.ndarray]:
    """``history``'s loss and temperature, checked: one number of each per iteration."""
    curves = []
    for key in ("loss", "temperature"):
        name = f"history[{key!r}]"
        values = real_array(name, history[key], "real numbers, one per iteration")
        if values.ndim != 1 or values.size == 0:
            raise ValueError(
                f"{name} has shape {values.shape}; allowed: (iterations,) with iterations >= 1"
            )
        if key == "temperature":  # annealed from a positive start; drawn on a log axis
            require(name, values, np.isfinite(values) & (values > 0), "finite numbers > 0")
        curves.append(values)
    if len(curves[0]) != len(curves[1]):
        raise ValueError(
            f"history['loss'] has {len(curves[0])} iterations and history['temperature'] "
            f"{len(curves[1])}; allowed: one of each per iteration"
        )
    return curves[0], curves[1]


def _gain_panels(axes: Any, steps: np.ndarray, gains: np.ndarray, baseline: Any) -> None:
    start_values = gains_as_dict(baseline)
    # The dashed baseline: the gains the table compares with.
    label = "paper (feasible)"
    if baseline is not PAPER_FEASIBLE_GAINS:
        label = (
            f"paper's, scaled into the wheel budget (k_r = {float(baseline.kr):.3g}, "
            f"k_θ = {float(baseline.k_theta):.3g})"
        )
    for k, name in enumerate(GAIN_FIELDS):
        ax = axes.flat[k + 1]
        values = gains[:, k]
        start = start_values[name]
        if name == "phi_m":
            values, start = np.degrees(values), math.degrees(start)
        drawn = _plot_marked(ax, steps, values, np.isfinite(values), lw=1.0)
        ax.axhline(start, ls="--", lw=0.8, color="gray", label=label)
        _marked_title(ax, _GAIN_LABELS[name], drawn)
        ax.set_xlabel("iteration")
    axes.flat[1].legend(fontsize=8)


def _schedule_panels(axes: Any, steps: np.ndarray, rows: np.ndarray, knots: int) -> None:
    radii = knot_radii(knots)
    titles = (
        "k_r(r_e) (cm/s)",
        "k_θ(r_e), d ≠ 0 (rad/s)",
        "k_turn(r_e), turning in place, d = 0 (rad/s)",
    )
    for k, title in enumerate(titles):
        ax = axes.flat[k + 1]
        table = rows[:, k * knots : (k + 1) * knots]
        ax.plot(radii, table[0], "o--", ms=3, lw=0.8, color="gray", label="iteration 1")
        ax.plot(radii, table[-1], "o-", ms=3, lw=1.2, label="tuned")
        ax.set_xscale("symlog", linthresh=1.0)
        ax.set_xlabel("r_e (cm)")
        _marked_title(ax, title, np.isfinite(table[[0, -1]]), "knot values non-finite, not drawn")
    axes.flat[1].legend(fontsize=8)
    for k, name in enumerate(SHAPE_FIELDS):  # Φ_m, the radii and α
        ax = axes.flat[k + 4]
        values = rows[:, 3 * knots + SHAPE_FIELDS.index(name)]
        values = np.degrees(values) if name == "phi_m" else values
        drawn = _plot_marked(ax, steps, values, np.isfinite(values), lw=1.0)
        _marked_title(ax, _GAIN_LABELS[name], drawn)
        ax.set_xlabel("iteration")


# The order of a robust comparison's conditions (standard_conditions' rows).
_ROBUST_CONDITIONS = ("model robot", "nominal", "latency", "noise", "both")


def robust_comparison_table(rows: list[dict[str, Any]]) -> str:
    """Markdown table of ``tune --robust --compare``: each method and seed under each condition.

    A cell is the success rate and the mean arrival of the successful runs;
    ``score`` is what the searches minimise (``condition_score``, failures at
    twice each row's horizon), ``gradient CPU`` the gradient's CPU time,
    ``price`` the candidates one of its iterations costs (a given price
    with the price measured beside it) and ``budget`` the
    candidates each search scored for it. The last rows are each method's
    mean over the seeds.
    """
    rows = require_rows("rows", rows)
    cells: dict[tuple[str, int], dict[str, Any]] = {}
    for row in rows:
        entry = cells.setdefault((str(row["method"]), int(row["seed"])), {"row": row})
        ok, mean = float(row["success"]), float(row["mean arrival s"])
        entry[row["condition"]] = (ok, mean, condition_score(row))
    table, scores = [], {}
    for (method, seed), entry in sorted(cells.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        conditions = [c for c in _ROBUST_CONDITIONS if c in entry]
        score = np.mean([entry[c][2] for c in conditions])
        scores.setdefault(method, []).append(score)
        line = {"method": method, "seed": str(seed), "score (s)": f"{score:.3f}"}
        for c in conditions:
            ok, mean, _ = entry[c]
            line[c] = f"{100 * ok:.1f} %, " + (f"{mean:.3f} s" if ok > 0 else "none arrived")
        first = entry["row"]
        price, measured = first["price"], first["measured_price"]
        given = f" (measured {measured:.3g})" if measured != price else ""  # a price given
        line["gradient CPU (s)"] = f"{first['budget_s']:.0f}"
        line["price"], line["budget"] = f"{price:.3g}{given}", str(first["budget_candidates"])
        line["candidates"] = str(first["candidates"])
        line["CPU (s)"] = _maybe(first["cpu_s"], "{:.0f}")
        line["wall (s)"] = _maybe(first["wall_s"], "{:.0f}")
        line["per CPU-s"] = _maybe(first["per_cpu_s"], "{:.3g}")
        table.append(line)
    for method, values in scores.items():
        table.append({"method": method, "seed": "mean", "score (s)": f"{np.mean(values):.3f}"})
    columns = ["method", "seed", "score (s)", *_ROBUST_CONDITIONS, "gradient CPU (s)", "price"]
    columns += ["budget", "candidates", "CPU (s)", "wall (s)", "per CPU-s"]
    columns = [c for c in columns if any(c in r for r in table)]
    table = markdown_table([{c: r.get(c, "") for c in columns} for r in table], columns)
    return table + _minimised_notes(rows)
