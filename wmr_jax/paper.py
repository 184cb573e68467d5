"""Reproductions of the paper's figures and the numbers behind them (SPEC §5)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax import metrics
from wmr_jax.io import atomic_write_json, atomic_write_text, save_figure
from wmr_jax.params import Gains, Robot
from wmr_jax.simulation import DEFAULT_DT, batch_rollout

__all__ = ["PAPER_REFS_DEG", "paper_refs", "run_table", "markdown_table", "figure_7"]

# Fig. 7 references, (cm, cm, deg), counter-clockwise as in the paper.
PAPER_REFS_DEG = (
    (40.0, 0.0, -45.0),
    (30.0, 30.0, 0.0),
    (0.0, 40.0, 90.0),
    (-30.0, 30.0, 135.0),
    (-30.0, -30.0, 0.0),
    (0.0, -40.0, 0.0),
    (30.0, -30.0, 90.0),
)
PAPER_STEPS = 91  # 3 s at 33 ms: every paper run has settled by then


def paper_refs() -> np.ndarray:
    """Return the seven references of Fig. 7 as ``(7, 3)`` in cm, cm, rad."""
    refs = np.array(PAPER_REFS_DEG)
    refs[:, 2] = np.radians(refs[:, 2])
    return refs


def run_table(
    traj: Any, refs: np.ndarray, *, dt: float, robot: Robot | None = None
) -> list[dict[str, Any]]:
    """Return one row of SPEC §6 metrics per run of a batched trajectory."""
    robot = Robot() if robot is None else robot
    times = np.asarray(metrics.arrival_time(traj, refs, dt=dt))
    lengths = np.asarray(metrics.path_length(traj))
    zigzag = np.asarray(metrics.zigzag_count(traj))
    rims = np.abs(np.asarray(traj.wheel_speeds))
    peak = rims.max(axis=(-1, -2))
    saturated = (rims >= float(robot.v_max) * (1 - 1e-9)).any(axis=-1).mean(axis=-1)
    final = np.asarray(traj.poses[:, -1])
    rows = []
    for i, ref in enumerate(np.asarray(refs)):
        rows.append(
            {
                "ref": [float(ref[0]), float(ref[1]), round(math.degrees(float(ref[2])), 6)],
                "arrival_s": float(times[i]),
                "path_cm": float(lengths[i]),
                "peak_wheel_cm_s": float(peak[i]),
                "saturated_fraction": float(saturated[i]),
                "zigzag": int(zigzag[i]),
                "final_distance_cm": float(np.hypot(*(final[i, :2] - ref[:2]))),
            }
        )
    return rows


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


def figure_7(out_dir: str | Path, *, gains: Gains | None = None) -> list[dict[str, Any]]:
    """Fig. 7: the seven runs from (0, 0, 0) with the ideal velocity loop, k_r = 120.

    Writes ``fig7.png``, ``fig7.md`` and ``fig7.json`` to ``out_dir``; returns the rows.
    """
    from wmr_jax.plotting import plot_paths, plt

    gains = Gains() if gains is None else gains
    out_dir = Path(out_dir)
    refs = paper_refs()
    traj = batch_rollout(refs, gains, steps=PAPER_STEPS, dt=DEFAULT_DT)
    rows = run_table(traj, refs, dt=DEFAULT_DT)
    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    plot_paths(ax, np.asarray(traj.poses), refs, label="robot path (ideal loop)")
    ax.plot([0], [0], "ko", ms=5)
    ax.set_title(
        f"Fig. 7: ideal velocity loop, k_r = {float(gains.kr):g}, k_θ = {float(gains.k_theta):g}, "
        f"Φ_m = {math.degrees(float(gains.phi_m)):g}°"
    )
    ax.legend(loc="lower left", fontsize=8)
    save_figure(fig, out_dir / "fig7.png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    atomic_write_text(out_dir / "fig7.md", markdown_table(rows))
    atomic_write_json(out_dir / "fig7.json", {"gains": _gains_dict(gains), "runs": rows})
    return rows


def _gains_dict(gains: Gains) -> dict[str, float]:
    return {k: float(v) for k, v in vars(gains).items()}
