"""Figures and files of a pose-space study: heat maps, the first-to-arrive map, the summary."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from wmr_jax._src.checks import check_number
from wmr_jax._src.io import atomic_write_text, json_text, save_figure
from wmr_jax._src.model.controllers import registered_names
from wmr_jax._src.model.params import Robot
from wmr_jax._src.model.robots import robot_from_values, same_robot
from wmr_jax._src.report.figures import ListedColormap, Patch, closed_after, plt
from wmr_jax._src.report.tables import (
    json_number,
    markdown_table,
    number,
    percent,
    require_rows,
    row_numbers,
)
from wmr_jax._src.studies.maps import MapStudy, PoseGrid, PoseMetrics

# metric (a PoseMetrics field, or "success"), colour-bar label, colour map
_MAP_FIELDS = (
    ("success", "success", "RdYlGn"),
    ("arrival", "arrival time [s]", "viridis"),
    ("path", "path length [cm]", "magma"),
    ("peak_wheel", "peak wheel speed [cm/s]", "plasma"),
    ("zigzag", "zig-zag count", "cividis"),
)


def _metric_values(m: PoseMetrics, field: str) -> np.ndarray:
    """The values of one metric as floats, NaN where not finite (drawn blank)."""
    if field == "success":
        return m.success.astype(float)
    values = np.asarray(getattr(m, field), dtype=float)
    return np.where(np.isfinite(values), values, np.nan)


def _to_image(grid: PoseGrid, values: np.ndarray, h: int) -> np.ndarray:
    """The ``[iy, ix]`` image of heading ``h`` (NaN outside the annulus)."""
    per_heading = int(grid.inside.sum())
    image = np.full(grid.inside.shape, np.nan)
    image[grid.inside] = values[h * per_heading : (h + 1) * per_heading]
    return image


def _ranges(results: dict[str, PoseMetrics]) -> dict[str, tuple[float, float]]:
    """Colour ranges shared by every controller, so that their maps compare."""
    out = {}
    for field, _, _ in _MAP_FIELDS:
        values = np.concatenate([_metric_values(m, field) for m in results.values()])
        finite = values[np.isfinite(values)]
        if field == "success" or finite.size == 0:
            out[field] = (0.0, 1.0)
        else:
            hi = float(np.percentile(finite, 99.5)) if field != "zigzag" else float(finite.max())
            out[field] = (float(finite.min()) if field != "zigzag" else 0.0, max(hi, 1e-9))
    return out


def comparison_table(rows: list[dict[str, Any]]) -> str:
    """The Markdown table of ``summarize`` rows (or their JSON) that docs/maps.md shows."""
    rows = require_rows("rows", rows)
    ahead = [k for k in rows[0] if k.startswith("faster than ")]
    table = []
    for i, raw in enumerate(rows):
        if "controller" not in raw:
            raise ValueError(f"rows[{i}] has no 'controller'; allowed: summarize rows")
        # Numbers as floats, also where the JSON file holds "inf" or null for them.
        r = row_numbers(f"rows[{i}]", raw, (*_SUMMARY_NUMBERS, *ahead))
        row = {
            "controller": raw["controller"],
            "success": percent(r["success"]),
            "mean / median / p90 arrival (s)": " / ".join(
                number(r[f"{k} arrival s"]) for k in ("mean", "median", "p90")
            ),
            "mean path (cm)": number(r["mean path cm"]),
            "mean / max peak wheel (cm/s)": (
                f"{r['mean peak wheel cm/s']:.0f} / {r['max peak wheel cm/s']:.0f}"
            ),
            "runs over V_max": percent(r["over V_max"]),
            "mean zig-zag": number(r["mean zigzag"]),
        }
        for key in ahead:
            row[f"arrives before {key.removeprefix('faster than ')}"] = percent(r[key])
        table.append(row)
    return markdown_table(table)


# The numbers of a ``summarize`` row that ``comparison_table`` shows.
_SUMMARY_NUMBERS = (
    "success",
    "mean arrival s",
    "median arrival s",
    "p90 arrival s",
    "mean path cm",
    "mean peak wheel cm/s",
    "max peak wheel cm/s",
    "over V_max",
    "mean zigzag",
)


def save_comparison(out_dir: str | Path, comparison: dict[str, Any]) -> list[Path]:
    """Write ``comparison.md`` and ``comparison.json`` of ``compare_controllers``; their paths."""
    out = Path(out_dir)
    keys = ("poses", "seed", "velocity", "horizon_s", "dtype", "rows")
    if not isinstance(comparison, dict) or any(k not in comparison for k in keys):
        raise ValueError(
            f"comparison = {comparison!r:.80} is not allowed; allowed: what "
            f"compare_controllers returned (a dict with {', '.join(keys)})"
        )
    horizon = json_number("comparison['horizon_s']", comparison["horizon_s"])
    head = (
        f"{comparison['poses']} random docs/model.md §6 poses (sample_poses seed "
        f"{comparison['seed']}), {comparison['velocity']} loop, horizon "
        f"{horizon:g} s, {comparison['dtype']}\n\n"
    )
    # Both texts are made (and the rows checked) before the first file is written.
    text = head + comparison_table(comparison["rows"])
    record = json_text(comparison, "comparison", indent=2, sort_keys=False) + "\n"
    return [
        atomic_write_text(out / "comparison.json", record),
        atomic_write_text(out / "comparison.md", text),
    ]


def _describe(summary: dict[str, Any]) -> str:
    """The run in words, for the titles and the summary's first line."""
    missing = [k for k in ("poses", "velocity", "horizon_s", "dtype") if k not in summary]
    if missing:
        raise ValueError(
            f"study.summary has no {missing[0]!r}; allowed: the summary map_study wrote"
        )
    what = (
        f"{summary['poses']:,} poses, {summary['velocity']} loop, "
        f"horizon {summary['horizon_s']:g} s, start (0, 0, 0°)"
    )
    # Another robot than the paper's is named (older summaries record none).
    robot, label = summary.get("robot"), summary.get("robot_label")
    if isinstance(robot, dict) and not same_robot(robot_from_values(robot, "robot"), Robot()):
        what += f", robot {label if isinstance(label, str) else 'custom'}"
    return what + ("" if summary["dtype"] == "float64" else ", float32")


def _decorate(ax: Any, grid: PoseGrid, h: int, *, top: bool, bottom: bool, left: bool) -> None:
    """Mark the robot at the origin (facing +x); heading ``h``, axis labels on outer panels only."""
    ax.plot(0, 0, marker=(3, 0, -90), color="k", ms=6)
    reach = float(grid.xs[-1])
    ticks = [-80, 0, 80] if reach >= 80 else [round(-reach), 0, round(reach)]
    ax.set_xticks(ticks)
    ax.set_yticks(ticks)
    ax.tick_params(labelsize=7, labelbottom=bottom, labelleft=left)
    if bottom:
        ax.set_xlabel("x_r [cm]", fontsize=8)
    if left:
        ax.set_ylabel("y_r [cm]", fontsize=8)
    if top:
        ax.set_title(f"θ_r = {math.degrees(grid.headings[h]):g}°", fontsize=9)


# Side of the square cells over which the V_max contour is drawn, cm: the peak
# wheel speed of neighbouring poses alternates across V_max in thin streaks
# (sampled-time switching), so the contour follows the share of poses over
# V_max per cell, not the poses themselves.
_CONTOUR_CELL_CM = 8.0


def _over_vmax_share(grid: PoseGrid, img: np.ndarray, v_max: float) -> tuple:
    """Cell centres ``(cx, cy)`` and the share of poses over ``v_max`` in each cell."""
    step = float(grid.xs[1] - grid.xs[0]) if len(grid.xs) > 1 else 1.0
    k = max(1, int(round(_CONTOUR_CELL_CM / step)))
    n = len(grid.xs) // k * k
    over = np.where(np.isfinite(img), img > v_max, np.nan)[:n, :n]
    cells = over.reshape(n // k, k, n // k, k)
    counted = np.isfinite(cells).sum(axis=(1, 3))
    with np.errstate(invalid="ignore"):
        share = np.nansum(cells, axis=(1, 3)) / counted
    share[counted < k * k / 2] = np.nan  # cells mostly outside the annulus
    centres = grid.xs[:n].reshape(-1, k).mean(axis=1)
    return centres, centres, share


def _show(ax: Any, grid: PoseGrid, img: np.ndarray, **style: Any) -> Any:
    """Draw ``img`` (``[iy, ix]``) over the grid's square, one cell per pose."""
    extent = (grid.xs[0], grid.xs[-1], grid.xs[0], grid.xs[-1])
    return ax.imshow(img, origin="lower", extent=extent, interpolation="nearest", **style)


def _draw_metric(ax, grid: PoseGrid, m: PoseMetrics, field: str, cmap, vrange, h, v_max):
    """Draw one metric at heading ``h``; failures in red on the arrival map."""
    img = _to_image(grid, _metric_values(m, field), h)
    image = _show(ax, grid, img, cmap=cmap, vmin=vrange[0], vmax=vrange[1])
    if field == "arrival":
        failed = _to_image(grid, (~m.success).astype(float), h)
        overlay = np.zeros((*failed.shape, 4))  # transparent but where it failed
        overlay[failed == 1] = (0.85, 0.1, 0.1, 1.0)
        _show(ax, grid, overlay)
    if field == "peak_wheel" and np.nanmax(img) > v_max:
        cx, cy, share = _over_vmax_share(grid, img, v_max)
        if np.nanmax(share) > 0.5:
            with plt.rc_context({"hatch.color": "w", "hatch.linewidth": 0.6}):
                ax.contourf(cx, cy, share, levels=[0.5, 1.01], colors="none", hatches=["////"])
            if np.nanmin(share) < 0.5:
                ax.contour(cx, cy, share, levels=[0.5], colors="w", linewidths=1.2)
    return image


def map_figure(
    path: str | Path,
    grid: PoseGrid,
    m: PoseMetrics,
    ranges: dict[str, tuple[float, float]] | None = None,
    *,
    v_max: float | None = None,
    title: str = "",
) -> Path:
    """Save the heat maps of one controller: a row per metric, a column per heading.

    Args:
        path: the image to write (atomically).
        grid: the references run.
        m: the controller's metrics over ``grid.refs``.
        ranges: metric → (low, high) colour range; default from ``m`` alone.
        v_max: wheel-speed limit drawn as a white contour, cm/s; default ``Robot().v_max``.
        title: text above the figure.

    Returns:
        The path written.
    """
    _check_sizes(grid, {None: m}, "m")
    ranges = _ranges({"": m}) if ranges is None else ranges
    missing = [field for field, _, _ in _MAP_FIELDS if field not in ranges]
    if missing:
        raise ValueError(
            f"ranges has no {missing[0]!r}; allowed: a (low, high) colour range for each of "
            f"{[field for field, _, _ in _MAP_FIELDS]}"
        )
    v_max = float(Robot().v_max) if v_max is None else check_number("v_max", v_max, unit="cm/s")
    n_h, n_rows = len(grid.headings), len(_MAP_FIELDS)
    size = {"figsize": (2.5 * n_h + 1.3, 2.4 * n_rows + 0.9), "squeeze": False}
    with closed_after(n_rows, n_h, layout="constrained", **size) as (fig, axes):
        for row, (field, label, cmap_name) in enumerate(_MAP_FIELDS):
            cmap = plt.get_cmap(cmap_name).with_extremes(bad=(1, 1, 1, 0))
            image = None
            for h in range(n_h):
                ax = axes[row, h]
                image = _draw_metric(ax, grid, m, field, cmap, ranges[field], h, v_max)
                _decorate(ax, grid, h, top=row == 0, bottom=row == n_rows - 1, left=h == 0)
            bar = fig.colorbar(image, ax=axes[row, :].tolist(), shrink=0.85, pad=0.01)
            bar.set_label(label, fontsize=8)
        cells = f"{_CONTOUR_CELL_CM:g} cm cells"
        over = f"peak wheel speed > V_max = {v_max:g} cm/s on most poses ({cells})"
        legend = [
            Patch(facecolor="0.55", edgecolor="w", hatch="////", label=over),
            plt.Line2D([], [], marker="s", ls="", color=(0.85, 0.1, 0.1), label="not arrived"),
            plt.Line2D([], [], marker=(3, 0, -90), ls="", color="k", label="robot at (0, 0, 0°)"),
        ]
        box = {"facecolor": "0.55", "labelcolor": "k", "framealpha": 1}
        fig.legend(handles=legend, loc="outside lower center", ncol=3, fontsize=7, **box)
        fig.suptitle(title, fontsize=10)
        save_figure(fig, path, dpi=100)
    return Path(path)


def _check_sizes(grid: PoseGrid, results: Any, name: str) -> None:
    """Raise unless ``results`` is a non-empty dict of metrics, each with one value per pose."""
    if not isinstance(results, dict) or not results:
        raise ValueError(
            f"{name} = {results!r:.80} is not allowed; allowed: a non-empty dict of "
            "controller name → PoseMetrics"
        )
    n_h, per_heading = len(grid.headings), int(np.asarray(grid.inside).sum())
    for key, m in results.items():
        label = name if key is None else f"{name}[{key!r}]"
        for field in ("arrival", "path", "peak_wheel", "zigzag"):
            size = np.size(getattr(m, field))
            if size != n_h * per_heading:
                raise ValueError(
                    f"{label}.{field} has {size} values; allowed: one per pose of grid, "
                    f"{n_h * per_heading} ({n_h} headings × {per_heading} positions)"
                )


def winner_figure(
    path: str | Path, grid: PoseGrid, results: dict[str, PoseMetrics], *, title: str = ""
) -> Path:
    """Save the map of the controller that arrives first at each pose (grey: none arrives)."""
    _check_sizes(grid, results, "results")
    names = list(results)
    times = np.stack([results[n].arrival for n in names])  # (C, N)
    best = np.argmin(times, axis=0).astype(float)
    best[~np.isfinite(times.min(axis=0))] = len(names)
    colours = [plt.get_cmap("tab10")(i) for i in range(len(names))] + [(0.6, 0.6, 0.6, 1)]
    cmap = ListedColormap(colours).with_extremes(bad=(1, 1, 1, 0))
    n_h = len(grid.headings)
    size = (2.9 * n_h, 3.8)
    with closed_after(1, n_h, figsize=size, squeeze=False, layout="constrained") as (fig, axes):
        for h in range(n_h):
            ax = axes[0, h]
            _show(ax, grid, _to_image(grid, best, h), cmap=cmap, vmin=-0.5, vmax=len(names) + 0.5)
            _decorate(ax, grid, h, top=True, bottom=True, left=h == 0)
        handles = [
            plt.Line2D([], [], marker="s", ls="", color=c, label=lab)
            for c, lab in zip(colours, [*names, "none arrives"], strict=True)
        ]
        fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=8)
        fig.suptitle(title, fontsize=10)
        save_figure(fig, path, dpi=100)
    return Path(path)


def save_map_study(out_dir: str | Path, study: MapStudy) -> list[Path]:
    """Write ``maps_<controller>.png``, ``winner.png``, ``summary.md`` and ``.json``.

    ``winner.png`` only with two controllers or more; the figures of an earlier
    study that this one does not draw are removed. Returns the paths written.
    """
    out = Path(out_dir)
    # Everything is checked, and the texts made, before the first file is written.
    _check_sizes(study.grid, study.results, "study.results")
    what = _describe(study.summary)
    given = study.summary.get("params_given", []) if isinstance(study.summary, dict) else []
    summary_json = json_text(study.summary, "study.summary", indent=2, sort_keys=False) + "\n"
    summary_md = (
        f"Pose-space sweep: {what}; docs/model.md §6 metrics "
        "(arrival statistics over the successful runs)\n\n" + comparison_table(study.rows)
    )
    if given:  # the rest ran their defaults for the robot
        summary_md += f"\nParameters given for {', '.join(given)}; the others ran their defaults.\n"
    ranges = _ranges(study.results)
    # The robot the study ran (older summaries record none: the paper robot).
    robot = study.summary.get("robot") if isinstance(study.summary, dict) else None
    v_max = float(robot["v_max"]) if isinstance(robot, dict) else float(Robot().v_max)
    # A figure of an earlier study in this folder would pass for this one's.
    earlier = {f"maps_{name}.png" for name in registered_names()} | {"winner.png"}
    drawn = {f"maps_{name}.png" for name in study.results}
    drawn |= {"winner.png"} if len(study.results) > 1 else set()
    for name in sorted(earlier - drawn):
        (out / name).unlink(missing_ok=True)
    written = []
    for name, m in study.results.items():
        title = f"{name}{' (parameters given)' * (name in given)}: {what} (red: not arrived)"
        path = out / f"maps_{name}.png"
        written.append(map_figure(path, study.grid, m, ranges, v_max=v_max, title=title))
    if len(study.results) > 1:
        title = f"First to arrive ({what})"
        written.append(winner_figure(out / "winner.png", study.grid, study.results, title=title))
    written.append(atomic_write_text(out / "summary.json", summary_json))
    written.append(atomic_write_text(out / "summary.md", summary_md))
    return written
