"""The soccer-like waypoint sequence: its figure, table and result file."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax._src.io import atomic_write_text, json_text
from wmr_jax._src.report.figures import built, plot_paths, save_closed
from wmr_jax._src.report.tables import markdown_table
from wmr_jax._src.sim.rollout import DEFAULT_DT
from wmr_jax._src.studies.waypoints import (
    SOCCER_WAYPOINTS_DEG,
    SoccerRun,
    SoccerStudy,
    soccer_waypoints,
)


def soccer_figure(runs: Sequence[SoccerRun], *, title: str) -> Any:
    """Draw the path of every run through the soccer waypoints, one column per controller.

    ``runs`` are ``soccer_study``'s, a stopping and a passing run per
    controller (top and bottom row); the caller saves and closes the figure.
    """
    wp = soccer_waypoints()
    cols = max(1, len(runs) // 2)
    if len(runs) != 2 * cols:
        raise ValueError(
            f"runs has {len(runs)} runs; allowed: a stopping and a passing run per "
            "controller (an even number >= 2)"
        )

    def draw(fig, axes):
        for (name, mode, run), ax in zip(runs, axes.T.flat, strict=True):
            plot_paths(ax, [np.asarray(run.trajectory.poses)], wp, color="tab:blue")
            for i, (x, y, _) in enumerate(wp):
                ax.annotate(str(i + 1), (x, y), textcoords="offset points", xytext=(6, 6))
            done = np.isfinite(np.asarray(run.arrival)).sum()
            ax.set_title(f"{name}, {mode} ({done}/{len(wp)} reached)", fontsize=9)
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()

    return built(draw, 2, cols, figsize=(4.2 * cols, 8.0), squeeze=False)


def write_soccer(
    out_dir: str | os.PathLike, study: SoccerStudy, *, extra: dict[str, Any] | None = None
) -> list[Path]:
    """Write ``soccer.png`` (paths), ``soccer.md`` and ``soccer.json`` of a ``soccer_study``.

    ``extra``: more fields for ``soccer.json``, after the rows (a command's robot).
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
        **(extra or {}),
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
    png = save_closed(fig, out / "soccer.png", dpi=110)
    md = atomic_write_text(out / "soccer.md", text)
    return [png, atomic_write_text(out / "soccer.json", record), md]
