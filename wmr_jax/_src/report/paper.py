"""The paper's figures and tables (``docs/model.md §5``) from ``wmr_jax.studies.paper_runs``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax._src.checks import check_number
from wmr_jax._src.io import atomic_write_text, json_text, save_figure
from wmr_jax._src.model.params import Gains
from wmr_jax._src.report.figures import closed_after, plot_paths, plot_wheel_speeds
from wmr_jax._src.report.tables import markdown_table, number, percent, row_numbers
from wmr_jax._src.sim.rollout import DEFAULT_DT

# k_r (cm/s) -> numbers of its figures: ideal paths, non-ideal paths, the two compared.
_FIGURES = {120.0: (7, 8, 9), 60.0: (None, None, 10)}
_TABLE_COLUMNS = [
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


def _fig6(path: Path, curve: dict[str, Any], r_e: float = 1.0) -> None:
    """Fig. 6: the least ``R_e`` the proof covers against ``Φ_m``, log scale, 70° marked."""
    with closed_after(figsize=(6, 4)) as (fig, ax):
        ax.semilogy(curve["phi_m_deg"], curve["bound_cm"])
        mark_deg, mark_cm = curve["mark_deg"], curve["mark_cm"]
        ax.plot([mark_deg], [mark_cm], "ro")
        text = f"Φ_m = {mark_deg:g}°: {mark_cm:.2f} cm"
        ax.annotate(text, (mark_deg, mark_cm), textcoords="offset points", xytext=(-110, 10))
        ax.axhline(r_e, color="0.4", ls="--", lw=1, label=f"default R_e = {r_e:g} cm (a choice)")
        ax.legend(loc="lower right", fontsize=8)
        ax.set_xlabel("Φ_m [deg]")
        ax.set_ylabel("least R_e = √(sin Φ_m tan Φ_m) [cm]")
        # A Region 0 of radius R_e above the curve covers every distance the proof leaves out.
        ax.set_title(
            "Fig. 6: error range of R_e: R_e ≥ √(sin Φ_m tan Φ_m) cm\n"
            "(V̇ ≤ 0 is proven only for r_e above the curve, docs/model.md §3.6)",
            fontsize=10,
        )
        ax.grid(alpha=0.3, which="both")
        save_figure(fig, path, dpi=120, bbox_inches="tight")


def _paths_figure(path: Path, title: str, refs: np.ndarray, runs: list[tuple]) -> None:
    """Draw several sets of paths ``(label, trajectory, line style, colour)`` on one plot."""
    with closed_after(figsize=(6.5, 6.5)) as (fig, ax):
        for i, (label, traj, style, color) in enumerate(runs):
            paths, last = np.asarray(traj.poses), i == len(runs) - 1
            plot_paths(ax, paths, refs, label=label, linestyle=style, color=color, mark_refs=last)
        ax.plot([0], [0], "ko", ms=5)
        ax.set_title(title, fontsize=10)
        # Under the axes, covering no path. One colour per path: the entries name the
        # references, the title the loop.
        legend = runs[0][0] if len(runs) == 1 and runs[0][3] is None else None
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=8,
                  title=legend, title_fontsize=8)  # fmt: skip
        save_figure(fig, path, dpi=120, bbox_inches="tight")


def _wheels_figure(path: Path, title: str, refs: np.ndarray, case: Any, v_max: float) -> None:
    """Rim speeds against time per reference, non-ideal (solid) and ideal (dotted)."""
    n = len(refs)
    cols = (n + 1) // 2
    loops = ((case.nonideal, "non-ideal", "-", v_max), (case.ideal, "ideal", ":", None))
    with closed_after(2, cols, figsize=(3.2 * cols, 5.6), sharey=True) as (fig, axes):
        for i, ax in enumerate(axes.flat):
            if i >= n:
                ax.axis("off")
                continue
            for traj, loop, style, limit in loops:
                ax.set_prop_cycle(None)  # the same colour per wheel in both loops
                speeds = np.asarray(traj.wheel_speeds[i])
                names = (f"left ({loop})", f"right ({loop})")
                plot_wheel_speeds(
                    ax, speeds, dt=DEFAULT_DT, v_max=limit, labels=names, linestyle=style
                )
            x, y, th = refs[i]
            ax.set_title(f"ref ({x:g}, {y:g}, {math.degrees(th):g}°)", fontsize=9)
            if i:
                ax.set_ylabel("")
        handles, labels = axes.flat[0].get_legend_handles_labels()
        if n < axes.size:  # one shared legend, readable, in the first empty panel
            axes.flat[n].legend(handles, labels, loc="center", fontsize=9, title="rim speed")
        else:
            fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=9)
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        save_figure(fig, path, dpi=110)


def _case_figures(out_dir: Path, refs: np.ndarray, case: Any, v_max: float) -> None:
    """Figs. 7–10 and the wheel speeds of one gain (``PaperCase``)."""
    kr = case.kr
    cond = f"k_r + L k_θ = {case.speed_bound:g} cm/s, V_max = {v_max:g}: condition {case.condition}"
    fig_ideal, fig_nonideal, fig_compare = _FIGURES[kr]
    ideal = ("ideal loop", case.ideal, "-", None)
    nonideal = ("non-ideal loop", case.nonideal, "-", None)
    both = [("ideal", case.ideal, "--", "tab:blue"), ("non-ideal", case.nonideal, "-", "tab:red")]
    figures = (
        (fig_ideal, f"ideal velocity loop, k_r = {kr:g}", [ideal]),
        (fig_nonideal, f"non-ideal loop, wheels ≤ {v_max:g} cm/s, k_r = {kr:g}", [nonideal]),
        (fig_compare, f"ideal (dashed) vs non-ideal (solid), k_r = {kr:g}\n{cond}", both),
    )
    for fig_number, title, runs in figures:
        if fig_number is not None:
            path = out_dir / f"fig{fig_number}.png"
            _paths_figure(path, f"Fig. {fig_number}: {title}", refs, runs)
    _wheels_figure(
        out_dir / f"wheels_k{kr:g}.png", f"Rim speeds, k_r = {kr:g} ({cond})", refs, case, v_max
    )


def paper_summary_table(summary: dict[str, Any], v_max: float) -> str:
    """The table of the paper runs in docs/paper.md: one line per gain, means over the references.

    Args:
        summary: ``PaperRuns.summary`` (or ``paper_table.json``'s ``"summary"``).
        v_max: the wheel-speed limit, cm/s.
    """
    v_max = check_number("v_max", v_max, unit="cm/s")
    if not isinstance(summary, dict):
        raise ValueError(f"summary = {summary!r:.80} is not allowed; allowed: a dict")
    rows = []
    for case, raw in summary.items():
        if not case.startswith("kr="):
            continue
        if not isinstance(raw, dict) or "condition" not in raw:
            raise ValueError(
                f"summary[{case!r}] = {raw!r:.80} is not allowed; allowed: a dict with "
                "'condition' and the numbers of PaperRuns.summary"
            )
        # Numbers as floats, also where the JSON file holds "inf" or null for them.
        s = row_numbers(f"summary[{case!r}]", raw, _SUMMARY_NUMBERS)
        rows.append(
            {
                "k_r": case.removeprefix("kr="),
                "k_r + L k_θ (cm/s)": f"{s['k_r + L k_theta']:g}",
                "condition": raw["condition"],
                "ideal vs non-ideal path gap, max / mean (cm)": (
                    f"{number(s['max_deviation_cm'])} / {number(s['mean_deviation_cm'])}"
                ),
                "arrival ideal / non-ideal (s)": _pair(s, "arrival_s"),
                "zig-zag ideal / non-ideal": _pair(s, "zigzag"),
                f"samples with a wheel command > {v_max:g} cm/s": _pair(
                    s, "saturated_fraction", percent
                ),
            }
        )
    if not rows:
        raise ValueError(
            f"summary has no gain (no key starting 'kr=', keys: {list(summary)}); allowed: "
            "PaperRuns.summary, or paper_table.json's 'summary'"
        )
    return markdown_table(rows)


def _pair(s: dict[str, float], key: str, fmt: Any = number) -> str:
    """``ideal_<key> / nonideal_<key>`` of a summary entry's numbers, each as ``fmt``."""
    return f"{fmt(s['ideal_' + key])} / {fmt(s['nonideal_' + key])}"


# The numbers of a ``PaperRuns.summary`` entry that ``paper_summary_table`` shows.
_SUMMARY_NUMBERS = ("k_r + L k_theta", "max_deviation_cm", "mean_deviation_cm") + tuple(
    f"{loop}_{key}"
    for key in ("arrival_s", "zigzag", "saturated_fraction")
    for loop in ("ideal", "nonideal")
)


def save_paper(out_dir: str | Path, runs: Any) -> dict[str, Any]:
    """Write ``fig6.png`` … ``fig10.png``, the wheel speeds and ``paper_table.md``/``.json``.

    Returns the table as written to ``paper_table.json``.
    """
    out_dir = Path(out_dir)
    v_max = float(runs.robot.v_max)
    # The tables are made (and checked) before the first file is written.
    text = "# Paper runs (docs/model.md §5): seven references, two gains, two velocity loops\n\n"
    text += markdown_table(runs.runs, _TABLE_COLUMNS)
    text += "\n## Summary per gain (means over the seven references)\n\n"
    text += paper_summary_table(runs.summary, v_max) + "\n"
    summary = [{"case": k, **v} for k, v in runs.summary.items() if k.startswith("kr=")]
    text += markdown_table(summary)
    table = runs.table()
    record = json_text(table, "runs.table()", indent=2, sort_keys=False) + "\n"
    _fig6(out_dir / "fig6.png", runs.fig6, float(Gains().r_e))
    for case in runs.cases:
        _case_figures(out_dir, runs.refs, case, v_max)
    atomic_write_text(out_dir / "paper_table.md", text)
    atomic_write_text(out_dir / "paper_table.json", record)
    return table


def save_fig7(out_dir: str | Path, fig7: Any) -> None:
    """Write ``fig7.png``, ``fig7.md`` and ``fig7.json`` of ``wmr_jax.studies.fig7_runs``."""
    out_dir = Path(out_dir)
    gains = fig7.gains
    # The table is made (and checked) before the first file is written.
    text = markdown_table(fig7.rows)
    record = json_text(fig7.table(), "fig7.table()", indent=2, sort_keys=False) + "\n"
    title = (
        f"Fig. 7: ideal velocity loop, k_r = {float(gains.kr):g}, "
        f"k_θ = {float(gains.k_theta):g}, Φ_m = {math.degrees(float(gains.phi_m)):g}°"
    )
    runs = [("robot paths (ideal loop)", fig7.trajectory, "-", None)]
    _paths_figure(out_dir / "fig7.png", title, fig7.refs, runs)
    atomic_write_text(out_dir / "fig7.md", text)
    atomic_write_text(out_dir / "fig7.json", record)
