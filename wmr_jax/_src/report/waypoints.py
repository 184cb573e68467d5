"""The soccer-like waypoint sequence: its figure, table and result file."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax._src.io import atomic_write_text, json_text, save_figure
from wmr_jax._src.report.figures import plot_paths, plt
from wmr_jax._src.report.tables import markdown_table
from wmr_jax._src.sim.rollout import DEFAULT_DT
from wmr_jax._src.studies.waypoints import (
    SOCCER_WAYPOINTS_DEG,
    SoccerRun,
    SoccerStudy,
    soccer_waypoints,
)

__all__ = ["soccer_figure", "write_soccer"]


def soccer_figure(runs: Sequence[SoccerRun], *, title: str) -> Any:
    """Draw the path of every run through the soccer waypoints, one column per controller.

    Args:
        runs: ``soccer_study`` runs, a stopping and a passing run per
            controller, in that order (top and bottom row).
        title: the figure's title.

    Returns:
        The matplotlib ``Figure`` (the caller saves and closes it).
    """
    wp = soccer_waypoints()
    cols = max(1, len(runs) // 2)
    if len(runs) != 2 * cols:
        raise ValueError(
            f"runs has {len(runs)} runs; allowed: a stopping and a passing run per "
            "controller (an even number >= 2)"
        )
    fig, axes = plt.subplots(2, cols, figsize=(4.2 * cols, 8.0), squeeze=False)
    try:
        for (name, mode, run), ax in zip(runs, axes.T.flat, strict=True):
            plot_paths(ax, [np.asarray(run.trajectory.poses)], wp, color="tab:blue")
            for i, (x, y, _) in enumerate(wp):
                ax.annotate(str(i + 1), (x, y), textcoords="offset points", xytext=(6, 6))
            done = np.isfinite(np.asarray(run.arrival)).sum()
            ax.set_title(f"{name}, {mode} ({done}/{len(wp)} reached)", fontsize=9)
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()
    except BaseException:
        plt.close(fig)
        raise
    return fig


def write_soccer(out_dir: str | os.PathLike, study: SoccerStudy) -> list[Path]:
    """Write ``soccer.png`` (paths), ``soccer.md`` and ``soccer.json`` into ``out_dir``.

    Args:
        out_dir: the folder (created if missing).
        study: what ``soccer_study`` returned.

    Returns:
        The paths written.
    """
    out, degrees = Path(out_dir), math.degrees(study.pass_tol_theta)
    meta = {
        "waypoints_deg": [list(p) for p in SOCCER_WAYPOINTS_DEG],
        "velocity": study.velocity,
        "dt_s": DEFAULT_DT,
        "steps": study.steps,
        "pass_tol_r_cm": study.pass_tol_r,
        "pass_tol_theta_deg": degrees,
        "rows": study.rows,
    }
    # The texts are made (and checked) before the first file is written.
    head = "Arrival time at each waypoint (s from the start; inf: not reached)\n\n"
    text = head + markdown_table(study.rows)
    record = json_text(meta, "study", indent=2, sort_keys=False) + "\n"
    fig = soccer_figure(
        study.runs,
        title=f"Soccer-like sequence ({study.velocity} loop): stop at each waypoint (top), "
        f"pass through within {study.pass_tol_r:g} cm / {degrees:g}° (bottom)",
    )
    try:
        png = save_figure(fig, out / "soccer.png", dpi=110)
    finally:
        plt.close(fig)
    md = atomic_write_text(out / "soccer.md", text)
    return [png, atomic_write_text(out / "soccer.json", record), md]
