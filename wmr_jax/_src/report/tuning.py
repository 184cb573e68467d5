"""Reports of a tuning run: the tuning curve and the before/after table."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax._src.io import save_figure
from wmr_jax._src.report.tables import markdown_table
from wmr_jax._src.tuning.parametrisation import GAIN_FIELDS, PAPER_FEASIBLE_GAINS, gains_as_dict

__all__ = ["evaluation_table", "tuning_curve"]

_GAIN_LABELS = {
    "kr": "k_r (cm/s)",
    "k_theta": "k_θ (rad/s)",
    "phi_m": "Φ_m (deg)",
    "r_m": "R_m (cm)",
    "r_a": "R_a (cm)",
    "r_e": "R_e (cm)",
    "alpha": "α",
}

_TABLE_COLUMNS = ["gains", "mean arrival (s)", "vs paper", "success", "peak wheel speed (cm/s)"]


def evaluation_table(evaluation: dict[str, Any]) -> str:
    """Return the before/after table as Markdown (mean arrival, success, peak wheel speed).

    Args:
        evaluation: ``Evaluation`` rows keyed by name; ``"paper_feasible"``
            is the reference of the "vs paper" column.
    """
    paper = evaluation["paper_feasible"].mean_arrival
    rows = [
        {
            "gains": name.replace("_", " "),
            "mean arrival (s)": f"{ev.mean_arrival:.3f}",
            "vs paper": f"{paper / ev.mean_arrival:.2f}×",
            "success": f"{100 * ev.success_rate:.2f} %",
            "peak wheel speed (cm/s)": f"{ev.peak_wheel_speed:.1f}",
        }
        for name, ev in evaluation.items()
    ]
    lines = markdown_table(rows, _TABLE_COLUMNS).splitlines()
    # The numeric columns are right-aligned.
    lines[1] = "|---|" + "---:|" * (len(_TABLE_COLUMNS) - 1)
    return "\n".join(lines) + "\n"


def tuning_curve(
    path: str | os.PathLike, history: dict[str, np.ndarray], *, velocity: str = "ideal"
) -> Path:
    """Save the loss (with the temperature) and each gain against the iteration.

    Args:
        path: the image file to write (atomically).
        history: ``TuneResult.history``: ``loss`` (s), ``temperature`` and
            ``gains`` ``(iters, 7)`` in ``GAIN_FIELDS`` order.
        velocity: the velocity loop tuned for, for the title.

    Returns:
        ``path``.
    """
    from wmr_jax._src.report.figures import plt

    steps = np.arange(1, len(history["loss"]) + 1)
    fig, axes = plt.subplots(2, 4, figsize=(14, 6), constrained_layout=True)
    ax = axes[0, 0]
    ax.plot(steps, history["loss"], lw=0.8, color="C0")
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss (s)", color="C0")
    twin = ax.twinx()
    twin.plot(steps, history["temperature"], lw=1.0, color="C3")
    twin.set_yscale("log")
    twin.set_ylabel("temperature", color="C3")
    ax.set_title(f"loss ({velocity} loop)")
    paper = gains_as_dict(PAPER_FEASIBLE_GAINS)
    for k, name in enumerate(GAIN_FIELDS):
        ax = axes.flat[k + 1]
        values = history["gains"][:, k]
        start = paper[name]
        if name == "phi_m":
            values, start = np.degrees(values), math.degrees(start)
        ax.plot(steps, values, lw=1.0)
        ax.axhline(start, ls="--", lw=0.8, color="gray", label="paper (feasible)")
        ax.set_title(_GAIN_LABELS[name])
        ax.set_xlabel("iteration")
    axes.flat[1].legend(fontsize=8)
    try:
        return save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
