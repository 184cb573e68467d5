"""The robustness study's figure, tables and result file (``docs/model.md §7``)."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from wmr_jax._src.io import atomic_write_text, json_text, save_figure
from wmr_jax._src.poses import HORIZON_S
from wmr_jax._src.report.figures import plt
from wmr_jax._src.report.tables import markdown_table, require_rows

__all__ = [
    "NOISE_CURVE_COLUMNS",
    "ROBUSTNESS_COLUMNS",
    "STANDARD_COLUMNS",
    "robustness_figure",
    "standard_figure",
    "write_robustness",
    "write_noise_curve",
    "write_standard_conditions",
]

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

# The keys of a row that robustness_figure draws.
_FIGURE_KEYS = [
    "controller",
    "condition",
    "noise xy cm",
    "noise theta deg",
    "success",
    "median arrival s",
]


def write_robustness(
    out_dir: str | os.PathLike,
    rows: Sequence[dict[str, Any]],
    *,
    seed: int,
    velocity: str,
    n_runs: int,
) -> list[Path]:
    """Write ``robustness.png``, ``robustness.md`` and ``robustness.json`` into ``out_dir``.

    Args:
        out_dir: the folder (created if missing).
        rows: ``robustness_study`` rows.
        seed: the study's seed.
        velocity: its velocity loop.
        n_runs: its runs per noise level.

    Returns:
        The paths written.
    """
    out, rows = Path(out_dir), require_rows("rows", rows)
    head = f"Robustness Monte Carlo ({velocity} loop, seed {seed}, {n_runs} runs per row)\n\n"
    # Everything is checked and drawn before the first file is written.
    text = head + markdown_table(rows, ROBUSTNESS_COLUMNS)
    meta = {"seed": seed, "velocity": velocity, "runs": n_runs, "horizon_s": HORIZON_S}
    record = (
        json_text(
            {**meta, "rows": rows}, "seed, velocity, n_runs and rows", indent=2, sort_keys=False
        )
        + "\n"
    )
    title = (
        f"Robustness, {velocity} loop: {n_runs} random poses (docs/model.md §6) per point, "
        f"seed {seed}; mismatch ±3 % wheel radius"
        + (", ±20 % mass" if velocity == "nonideal" else "")
        + "; latency one sample"
    )
    fig = robustness_figure(rows, title=title)
    try:  # "tight": the legend lies outside the axes
        png = save_figure(fig, out / "robustness.png", dpi=110, bbox_inches="tight")
    finally:
        plt.close(fig)
    md = atomic_write_text(out / "robustness.md", text)
    return [png, md, atomic_write_text(out / "robustness.json", record)]


def robustness_figure(rows: Sequence[dict[str, Any]], *, title: str) -> Any:
    """Draw success rate and median arrival against noise level, one line per row group.

    Args:
        rows: ``robustness_study`` rows: one colour per controller, one line
            style per condition.
        title: the figure's title.

    Returns:
        The matplotlib ``Figure`` (the caller saves and closes it).
    """
    rows = require_rows("rows", rows)
    markdown_table(rows, _FIGURE_KEYS)  # names a row without one of them
    names = list(dict.fromkeys(r["controller"] for r in rows))
    conditions = list(dict.fromkeys(r["condition"] for r in rows))
    first = [r for r in rows if (r["controller"], r["condition"]) == (names[0], conditions[0])]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    try:
        _draw_robustness(fig, axes, rows, names, conditions, first, title)
    except BaseException:
        plt.close(fig)
        raise
    return fig


def _draw_robustness(fig, axes, rows, names, conditions, first, title) -> None:
    """Draw the lines, labels and legend of ``robustness_figure``."""
    for c, name in enumerate(names):
        colour = plt.get_cmap("tab10")(c)
        for i, label in enumerate(conditions):
            sel = [r for r in rows if r["controller"] == name and r["condition"] == label]
            x = [r["noise xy cm"] for r in sel]
            style = dict(linestyle=_STYLES[i % len(_STYLES)], marker="o", color=colour)
            axes[0].plot(x, [r["success"] for r in sel], label=f"{name}, {label}", **style)
            # Over the successful runs only; absent (not drawn) where none succeeds.
            medians = [r["median arrival s"] if r["success"] > 0 else math.nan for r in sel]
            axes[1].plot(x, medians, **style)
    axes[0].set_ylabel("success rate")
    axes[1].set_ylabel("median arrival time of successes [s]")
    degrees = ", ".join(f"{r['noise theta deg']:g}" for r in first)
    for ax in axes:
        ax.set_xlabel(f"measurement noise σ_xy [cm] (σ_θ = {degrees}°)")
        ax.grid(alpha=0.3)
    axes[0].set_ylim(-0.02, 1.02)
    axes[1].set_ylim(0.0, HORIZON_S)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0, 0, 0.75, 1))
    # Outside the axes, so that it never hides a line.
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="center left", bbox_to_anchor=(0.75, 0.5))


def write_standard_conditions(
    out_dir: str | os.PathLike, rows: Sequence[dict[str, Any]], *, meta: dict[str, Any]
) -> list[Path]:
    """Write ``standard_conditions.png``, ``.md`` and ``.json`` (``docs/model.md §7``).

    Args:
        out_dir: the folder (created if missing).
        rows: ``standard_conditions`` rows.
        meta: what produced them (seed, runs, where the gains came from).

    Returns:
        The paths written.
    """
    out, rows = Path(out_dir), require_rows("rows", rows)
    if not isinstance(meta, dict):
        raise ValueError(f"meta = {meta!r:.80} is not allowed; allowed: a dict")
    # Everything is checked and drawn before the first file is written.
    table = markdown_table(rows, STANDARD_COLUMNS)
    head = (
        "Gain sets under the standard conditions of docs/model.md §7 (hard law, ideal loop, "
        f"{rows[0]['runs']} held-out poses of docs/model.md §6, horizon {HORIZON_S:g} s); "
        "every condition but the model robot's with each wheel's radius off by up to the "
        "mismatch column, drawn per run (docs/model.md §9)\n\n"
    )
    record = json_text({**meta, "rows": rows}, "meta and rows", indent=2, sort_keys=False) + "\n"
    fig = standard_figure(rows)
    try:
        png = save_figure(fig, out / "standard_conditions.png", dpi=110)
    finally:
        plt.close(fig)
    md = atomic_write_text(out / "standard_conditions.md", head + table)
    return [png, md, atomic_write_text(out / "standard_conditions.json", record)]


def standard_figure(rows: Sequence[dict[str, Any]]) -> Any:
    """Draw success and mean arrival per condition, one bar per gain set (legend outside)."""
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
    width = 0.8 / len(sets)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.0))
    try:
        _draw_standard(fig, axes, rows, conditions, sets, width)
    except BaseException:
        plt.close(fig)
        raise
    return fig


def _draw_standard(fig, axes, rows, conditions, sets, width) -> None:
    """Draw the bars, labels and legend of ``standard_figure``."""
    for j, name in enumerate(sets):
        got = {r["condition"]: r for r in rows if r["gains"] == name}
        x = [i + (j - (len(sets) - 1) / 2) * width for i in range(len(conditions))]
        colour = plt.get_cmap("tab10")(j)
        axes[0].bar(x, [got[c]["success"] for c in conditions], width, color=colour, label=name)
        # Mean arrival of the successful runs; no bar where none succeeds.
        means = [got[c]["mean arrival s"] if got[c]["success"] > 0 else 0.0 for c in conditions]
        axes[1].bar(x, means, width, color=colour)
    for ax, label in zip(axes, ("success rate", "mean arrival of successes [s]"), strict=True):
        ax.set_xticks(range(len(conditions)), conditions)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, axis="y")
    axes[0].set_ylim(0, 1.05)
    fig.suptitle(
        "docs/model.md §7 standard conditions: latency = 1 sample; noise σ_xy = 0.5 cm, "
        "σ_θ = 1°; ±3 % wheel radius but on the model robot; hard law, ideal loop",
        fontsize=9,
    )
    fig.tight_layout(rect=(0, 0, 0.82, 1))
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="center left", bbox_to_anchor=(0.82, 0.5))


def write_noise_curve(
    out_dir: str | os.PathLike, rows: Sequence[dict[str, Any]], *, meta: dict[str, Any]
) -> list[Path]:
    """Write ``noise_curve.png``, ``.md`` and ``.json`` (``noise_curve`` rows).

    Args:
        out_dir: the folder (created if missing).
        rows: ``noise_curve`` rows.
        meta: what produced them (seed, where the gains came from).

    Returns:
        The paths written.
    """
    out, rows = Path(out_dir), require_rows("rows", rows)
    if not isinstance(meta, dict):
        raise ValueError(f"meta = {meta!r:.80} is not allowed; allowed: a dict")
    table = markdown_table(rows, NOISE_CURVE_COLUMNS)
    head = (
        "Success and mean arrival against pose noise (σ_θ = 2° per cm of σ_xy; hard law, "
        f"ideal loop, {rows[0]['runs']} held-out poses, each wheel's radius off by up to "
        f"{100 * float(rows[0]['mismatch']):g} % per run; docs/model.md §7, §9)\n\n"
    )
    record = json_text({**meta, "rows": rows}, "meta and rows", indent=2, sort_keys=False) + "\n"
    fig = noise_curve_figure(rows)
    try:
        png = save_figure(fig, out / "noise_curve.png", dpi=110)
    finally:
        plt.close(fig)
    md = atomic_write_text(out / "noise_curve.md", head + table)
    return [png, md, atomic_write_text(out / "noise_curve.json", record)]


def noise_curve_figure(rows: Sequence[dict[str, Any]]) -> Any:
    """Draw success and mean arrival against σ_xy, one line per loop (legend outside).

    A level where no run of a loop arrived has no arrival point (not a value
    at the horizon); its success point at 0 says why.
    """
    rows = require_rows("rows", rows)
    markdown_table(rows, ["gains", "feedback", "noise xy cm", "success", "mean arrival s"])
    names = list(dict.fromkeys(r["gains"] for r in rows))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.0))
    try:
        for j, name in enumerate(names):
            mine = sorted((r for r in rows if r["gains"] == name), key=lambda r: r["noise xy cm"])
            x = [r["noise xy cm"] for r in mine]
            colour = plt.get_cmap("tab10")(j)
            style = "--" if mine[0]["feedback"] == "raw" else "-"
            label = f"{name} ({mine[0]['feedback']})"
            axes[0].plot(x, [r["success"] for r in mine], style, marker="o", color=colour,
                         label=label)  # fmt: skip
            arrival = [r["mean arrival s"] if r["success"] > 0 else math.nan for r in mine]
            axes[1].plot(x, arrival, style, marker="o", color=colour)
        labels = ("success rate", "mean arrival of successes [s]")
        for ax, label in zip(axes, labels, strict=True):
            ax.set_xlabel("pose noise σ_xy [cm] (σ_θ = 2°/cm)")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
        axes[0].set_ylim(0, 1.05)
        axes[1].set_ylim(bottom=0)
        fig.suptitle(
            f"Noise-level curve: ±{100 * float(rows[0]['mismatch']):g} % wheel radius per run, "
            "hard law, ideal loop; dashed: raw feedback, solid: estimator",
            fontsize=9,
        )
        fig.tight_layout(rect=(0, 0, 0.78, 1))
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, fontsize=8, loc="center left", bbox_to_anchor=(0.78, 0.5))
    except BaseException:
        plt.close(fig)
        raise
    return fig
