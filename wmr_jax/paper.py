"""Reproductions of the paper's figures and the numbers behind them (SPEC §5)."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax import metrics
from wmr_jax.io import atomic_write_json, atomic_write_text, save_figure
from wmr_jax.law import wheel_speeds
from wmr_jax.params import Gains, Robot, WheelSpeedWarning
from wmr_jax.simulation import DEFAULT_DT, batch_rollout

__all__ = [
    "PAPER_REFS_DEG",
    "figure_6",
    "figure_7",
    "markdown_table",
    "paper_figures",
    "paper_refs",
    "residual_bound",
    "run_table",
]

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
    peak = np.abs(np.asarray(traj.wheel_speeds)).max(axis=(-1, -2))
    # Saturated: the wheel command v_m ± L ω_m asks for more than V_max (the
    # non-ideal loop clips it; the ideal loop obeys it regardless).
    commanded = np.abs(np.asarray(wheel_speeds(traj.v, traj.omega, robot)))
    saturated = (commanded > float(robot.v_max)).any(axis=-1).mean(axis=-1)
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


def _gains_dict(gains: Gains) -> dict[str, float]:
    return {k: float(v) for k, v in vars(gains).items()}


def residual_bound(phi_m: Any) -> Any:
    """Return the paper's residual distance bound ``sqrt(sin Φ_m tan Φ_m)`` (Fig. 6)."""
    return np.sqrt(np.sin(phi_m) * np.tan(phi_m))


def _paths_figure(path, title, refs, runs):
    """Draw several sets of paths (label, trajectory, line style) on one plot."""
    from wmr_jax.plotting import plot_paths, plt

    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    for i, (label, traj, style, color) in enumerate(runs):
        plot_paths(
            ax,
            np.asarray(traj.poses),
            refs,
            label=label,
            linestyle=style,
            color=color,
            mark_refs=i == len(runs) - 1,
        )
    ax.plot([0], [0], "ko", ms=5)
    ax.set_title(title, fontsize=10)
    ax.legend(loc="lower left", fontsize=8)
    save_figure(fig, path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def _wheels_figure(path, title, refs, ideal, nonideal, robot):
    from wmr_jax.plotting import plot_wheel_speeds, plt

    n = len(refs)
    fig, axes = plt.subplots(2, (n + 1) // 2, figsize=(3.2 * ((n + 1) // 2), 5.6), sharey=True)
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.axis("off")
            continue
        plot_wheel_speeds(
            ax,
            np.asarray(nonideal.wheel_speeds[i]),
            dt=DEFAULT_DT,
            v_max=float(robot.v_max),
            labels=("left (non-ideal)", "right (non-ideal)"),
        )
        ax.set_prop_cycle(None)
        plot_wheel_speeds(
            ax,
            np.asarray(ideal.wheel_speeds[i]),
            dt=DEFAULT_DT,
            labels=("left (ideal)", "right (ideal)"),
            linestyle=":",
        )
        x, y, th = refs[i]
        ax.set_title(f"ref ({x:g}, {y:g}, {math.degrees(th):g}°)", fontsize=9)
        if i:
            ax.set_ylabel("")
    axes.flat[0].legend(fontsize=6, loc="lower right")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def figure_6(out_dir: str | Path) -> dict[str, Any]:
    """Fig. 6: the residual error bound ``sqrt(sin Φ_m tan Φ_m)`` against ``Φ_m``."""
    from wmr_jax.plotting import plt

    phi_deg = np.linspace(1.0, 89.0, 400)
    bound = residual_bound(np.radians(phi_deg))
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogy(phi_deg, bound)
    at_70 = float(residual_bound(math.radians(70.0)))
    ax.plot([70.0], [at_70], "ro")
    ax.annotate(
        f"Φ_m = 70°: {at_70:.2f} cm", (70.0, at_70), textcoords="offset points", xytext=(-110, 10)
    )
    ax.set_xlabel("Φ_m [deg]")
    ax.set_ylabel("residual distance bound [cm]")
    ax.set_title("Fig. 6: bound sqrt(sin Φ_m tan Φ_m) on the non-convergent error")
    ax.grid(alpha=0.3, which="both")
    save_figure(fig, Path(out_dir) / "fig6.png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    return {"phi_m_deg": 70.0, "bound_cm": at_70}


def paper_figures(out_dir: str | Path, *, robot: Robot | None = None) -> dict[str, Any]:
    """Reproduce Figs. 6–10 and their numbers into ``out_dir`` (SPEC §5).

    Writes ``fig6.png`` … ``fig10.png``, ``wheels_k120.png``, ``wheels_k60.png``
    and ``paper_table.md`` / ``paper_table.json``: one row per reference and
    case (k_r = 120 and 60, ideal and non-ideal) with arrival time, path
    length, peak wheel speed, fraction of samples saturated, zig-zag count and
    the largest distance between the ideal and non-ideal paths. Every file is
    written atomically.

    Returns:
        The table and a per-case summary, as written to ``paper_table.json``.
    """
    robot = Robot() if robot is None else robot
    out_dir = Path(out_dir)
    with warnings.catch_warnings():
        # k_r = 120 violates the wheel-speed condition on purpose (Figs. 7–9).
        warnings.simplefilter("ignore", WheelSpeedWarning)
        return _paper_figures(out_dir, robot)


def _paper_figures(out_dir: Path, robot: Robot) -> dict[str, Any]:
    refs = paper_refs()
    summary: dict[str, Any] = {"fig6": figure_6(out_dir)}
    rows: list[dict[str, Any]] = []
    for kr, fig_pair in ((120.0, (7, 8, 9)), (60.0, (None, None, 10))):
        gains = Gains(kr=kr)
        ideal = batch_rollout(refs, gains, steps=PAPER_STEPS, robot=robot)
        nonideal = batch_rollout(refs, gains, steps=PAPER_STEPS, robot=robot, velocity="nonideal")
        gap = np.hypot(*np.moveaxis(np.asarray(ideal.poses - nonideal.poses)[..., :2], -1, 0))
        deviation = gap.max(axis=-1)
        bound = float(kr + float(robot.half_track) * float(gains.k_theta))
        held = "holds" if bound <= float(robot.v_max) else "violated"
        case_rows = {}
        for loop, traj in (("ideal", ideal), ("nonideal", nonideal)):
            case_rows[loop] = run_table(traj, refs, dt=DEFAULT_DT, robot=robot)
            for row, dev in zip(case_rows[loop], deviation, strict=True):
                row.update(kr=kr, loop=loop, condition=held, max_deviation_cm=float(dev))
                rows.append(row)
        summary[f"kr={kr:g}"] = {
            "k_r + L k_theta": bound,
            "condition": held,
            "max_deviation_cm": float(deviation.max()),
            "mean_deviation_cm": float(deviation.mean()),
            **{
                f"{loop}_{key}": float(np.mean([r[key] for r in case_rows[loop]]))
                for loop in ("ideal", "nonideal")
                for key in ("arrival_s", "path_cm", "zigzag", "saturated_fraction")
            },
        }
        cond = f"k_r + L k_θ = {bound:g} cm/s, V_max = {float(robot.v_max):g}: condition {held}"
        fig_ideal, fig_nonideal, fig_compare = fig_pair
        if fig_ideal:
            _paths_figure(
                out_dir / f"fig{fig_ideal}.png",
                f"Fig. {fig_ideal}: ideal velocity loop, k_r = {kr:g}",
                refs,
                [("ideal loop", ideal, "-", None)],
            )
        if fig_nonideal:
            _paths_figure(
                out_dir / f"fig{fig_nonideal}.png",
                f"Fig. {fig_nonideal}: non-ideal loop, wheels ≤ {float(robot.v_max):g} "
                f"cm/s, k_r = {kr:g}",
                refs,
                [("non-ideal loop", nonideal, "-", None)],
            )
        _paths_figure(
            out_dir / f"fig{fig_compare}.png",
            f"Fig. {fig_compare}: ideal (dashed) vs non-ideal (solid), k_r = {kr:g}\n{cond}",
            refs,
            [("ideal", ideal, "--", "tab:blue"), ("non-ideal", nonideal, "-", "tab:red")],
        )
        _wheels_figure(
            out_dir / f"wheels_k{kr:g}.png",
            f"Rim speeds, k_r = {kr:g} ({cond})",
            refs,
            ideal,
            nonideal,
            robot,
        )
    columns = [
        "kr",
        "loop",
        "ref",
        "arrival_s",
        "path_cm",
        "peak_wheel_cm_s",
        "saturated_fraction",
        "zigzag",
        "max_deviation_cm",
    ]
    text = "# Paper runs (SPEC §5): seven references, two gains, two velocity loops\n\n"
    text += markdown_table(rows, columns)
    text += "\n## Summary per gain (means over the seven references)\n\n"
    text += markdown_table([{"case": k, **v} for k, v in summary.items() if k.startswith("kr=")])
    atomic_write_text(out_dir / "paper_table.md", text)
    result = {
        "robot": {k: float(v) for k, v in vars(robot).items()},
        "summary": summary,
        "runs": rows,
    }
    atomic_write_json(out_dir / "paper_table.json", result)
    return result


def figure_7(out_dir: str | Path, *, gains: Gains | None = None) -> list[dict[str, Any]]:
    """Fig. 7: the seven runs from (0, 0, 0) with the ideal velocity loop, k_r = 120.

    Writes ``fig7.png``, ``fig7.md`` and ``fig7.json`` to ``out_dir``; returns the rows.
    """
    from wmr_jax.plotting import plot_paths, plt

    gains = Gains() if gains is None else gains
    out_dir = Path(out_dir)
    refs = paper_refs()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", WheelSpeedWarning)  # the paper's own gains
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
