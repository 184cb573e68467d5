"""Pose-space maps: SPEC §6 metrics over grids of reference poses, per controller.

For a grid of reference positions ``(x_r, y_r)`` at several headings ``θ_r``,
with the robot starting at the origin, every pose is run to the SPEC §6
horizon by ``wmr_jax.sweep``, which reduces each run to its metrics inside the
time loop (success, arrival time, path length, peak wheel speed, zig-zag
count) and feeds the poses in fixed-size chunks: no trajectory is stored,
memory grows with the number of poses only (a few numbers each), and one
compiled program serves any count. A million poses is an ordinary run.

``sweep`` draws heat maps (one figure per controller, metrics × headings),
a map of which controller arrives first, and a side-by-side summary table in
Markdown and JSON; ``summarize`` gives the same table for any set of poses
(the comparison over random SPEC §6 poses uses it).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from wmr_jax import baselines as _baselines  # noqa: F401  (registers the baselines by name)
from wmr_jax import controllers, metrics, simulation
from wmr_jax.io import atomic_write_json, atomic_write_text, save_figure
from wmr_jax.params import Robot
from wmr_jax.simulation import DEFAULT_DT
from wmr_jax.sweep import sweep as run_chunked

__all__ = [
    "DEFAULT_HEADINGS_DEG",
    "HORIZON_S",
    "PoseGrid",
    "PoseMetrics",
    "configure_parser",
    "evaluate_poses",
    "horizon_steps",
    "pose_grid",
    "run_cli",
    "spec_poses",
    "summarize",
    "sweep",
]

HORIZON_S = 6.0  # SPEC §6
DEFAULT_HEADINGS_DEG = (-90.0, 0.0, 90.0, 180.0)
R_MIN, R_MAX = 5.0, 80.0  # SPEC §6 evaluation set, cm
DEFAULT_CHUNK = 16384


class PoseMetrics(NamedTuple):
    """SPEC §6 metrics of ``N`` runs, each a NumPy ``(N,)`` array.

    Attributes:
        arrival: arrival time, s; ``inf`` where the robot is not arrived at
            the end of the horizon.
        path: distance travelled by the centre, cm.
        peak_wheel: largest rim speed ``|v ± L ω|`` over the run, cm/s.
        zigzag: sign changes of ``v`` plus those of ``ω`` beyond the dead bands.
        final_distance: distance to the reference at the end, cm.
        first_arrival: ``(k + 1) dt`` for the first sample ``k`` at which the
            robot is arrived, whether or not it stays, s; ``inf`` if never
            (``None`` where not computed: ``evaluate_poses`` does not).
    """

    arrival: np.ndarray
    path: np.ndarray
    peak_wheel: np.ndarray
    zigzag: np.ndarray
    final_distance: np.ndarray
    first_arrival: np.ndarray | None = None

    @property
    def success(self) -> np.ndarray:
        """Whether each run arrived (finite arrival time)."""
        return np.isfinite(self.arrival)


# ---------------------------------------------------------------- pose sets


def spec_poses(seed: int, n: int, *, r_min: float = R_MIN, r_max: float = R_MAX) -> np.ndarray:
    """Return ``n`` random SPEC §6 references ``(n, 3)``: distance, bearing, heading uniform.

    Args:
        seed: seed of the NumPy generator (same seed, same poses).
        n: number of poses.
        r_min: least distance from the origin, cm.
        r_max: largest distance, cm.
    """
    rng = np.random.default_rng(seed)
    dist = rng.uniform(r_min, r_max, n)
    bearing = rng.uniform(-math.pi, math.pi, n)
    heading = rng.uniform(-math.pi, math.pi, n)
    return np.stack([dist * np.cos(bearing), dist * np.sin(bearing), heading], axis=-1)


class PoseGrid(NamedTuple):
    """A grid of references: ``G × G`` positions at ``H`` headings, inside the SPEC annulus.

    Attributes:
        xs: ``(G,)`` x_r, cm (also the y_r values).
        headings: ``(H,)`` θ_r, rad.
        inside: ``(G, G)`` bool, ``[iy, ix]``: position within ``r_min..r_max``.
        refs: ``(H · n_inside, 3)`` the references run, heading-major.
    """

    xs: np.ndarray
    headings: np.ndarray
    inside: np.ndarray
    refs: np.ndarray


def pose_grid(
    n_poses: int,
    headings_deg: Sequence[float] = DEFAULT_HEADINGS_DEG,
    *,
    r_min: float = R_MIN,
    r_max: float = R_MAX,
) -> PoseGrid:
    """Return a square grid over ``[−r_max, r_max]²`` with about ``n_poses`` references.

    Only positions at distance ``r_min``–``r_max`` from the origin are run (the
    SPEC §6 set); the grid side is chosen so that their number times the number
    of headings is close to ``n_poses``.
    """
    headings = np.radians(np.asarray(headings_deg, dtype=float))
    annulus = math.pi * (r_max**2 - r_min**2) / (2 * r_max) ** 2
    side = max(2, round(math.sqrt(n_poses / (len(headings) * annulus))))
    xs = np.linspace(-r_max, r_max, side)
    gx, gy = np.meshgrid(xs, xs)  # [iy, ix]
    dist = np.hypot(gx, gy)
    inside = (dist >= r_min) & (dist <= r_max)
    pos = np.stack([gx[inside], gy[inside]], axis=-1)
    refs = np.concatenate(
        [np.concatenate([pos, np.full((len(pos), 1), h)], axis=-1) for h in headings]
    )
    return PoseGrid(xs, headings, inside, refs)


# ---------------------------------------------------------------- evaluation


def evaluate_poses(
    refs: Any,
    params: Any = None,
    *,
    controller: Any = controllers.SHIM_SUNG,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    steps: int | None = None,
    robot: Robot | None = None,
    velocity: str = "ideal",
    chunk: int = DEFAULT_CHUNK,
    progress: bool = False,
    x64: bool = True,
    cache: str | Path | None = None,
) -> PoseMetrics:
    """Return the SPEC §6 metrics of every reference, in bounded memory (``wmr_jax.sweep``).

    Args:
        refs: ``(N, 3)`` reference poses ``[x cm, y cm, θ rad]``.
        params: the controller's parameters (its defaults if ``None``); leaves
            scalar, or ``(N,)`` for one value per pose.
        controller: a ``Controller`` or its registered name.
        init: ``(3,)`` initial pose shared by every run.
        dt: control period, s.
        steps: control periods; default the SPEC §6 horizon of 6 s.
        robot: robot parameters; default ``Robot()``.
        velocity: ``"ideal"`` or ``"nonideal"``.
        chunk: poses per compiled call (the last chunk is padded to it).
        progress: show a progress bar (stderr).
        x64: compute in float64 (default), whatever JAX's default dtype.
            The polar-coordinate baselines are singular at their goal: in
            float32 the rounding of positions (about 4e-6 cm at 40 cm) makes
            their bearing ``α`` random once ``ρ`` gets that small, within the
            6 s horizon, and their heading drifts off again; ``False`` shows it.
        cache: a folder where each finished chunk is kept, so that a run
            interrupted and started again with the same arguments resumes
            (``wmr_jax.sweep``'s ``out``); ``None`` keeps nothing.

    Returns:
        ``PoseMetrics`` of ``(N,)`` NumPy arrays, in the order of ``refs``.

    Raises:
        ValueError: for misshapen or non-finite poses and bad options.
    """
    refs_host = np.asarray(simulation.as_poses("refs", refs, batch=True))
    chunk = _positive_int("chunk", chunk)
    if np.ndim(init) != 1:
        raise ValueError(f"init has shape {np.shape(init)}; allowed: (3,), shared by every run")
    with jax.enable_x64(bool(x64)):
        out = run_chunked(
            refs_host,
            params,
            init=init,
            dt=dt,
            steps=horizon_steps(dt) if steps is None else steps,
            robot=robot,
            velocity=velocity,
            controller=controller,
            chunk_size=chunk,
            progress=progress,
            out=cache,
        )
    final = np.stack([out["final_x"], out["final_y"]], axis=-1)
    return PoseMetrics(
        arrival=out["arrival_time"],
        path=out["path_length"],
        peak_wheel=out["peak_wheel_speed"],
        zigzag=out["zigzags"],
        final_distance=np.hypot(*(final - refs_host[:, :2]).T),
    )


def horizon_steps(dt: float) -> int:
    """Return the number of periods covering the SPEC §6 horizon of 6 s."""
    return math.ceil(HORIZON_S / simulation.check_dt(dt) - 1e-9)


def _positive_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: an integer >= 1")
    return int(value)


# ---------------------------------------------------------------- summaries


def summarize(
    results: dict[str, PoseMetrics], *, v_max: float = 125.0, reference: str | None = None
) -> list[dict[str, Any]]:
    """Return one row of summary statistics per controller, side by side.

    Args:
        results: controller name → its ``PoseMetrics`` over the same poses.
        v_max: wheel-speed limit for the "over V_max" column, cm/s.
        reference: the controller the others are compared with pose by pose
            (default: Shim–Sung if present).

    Returns:
        Rows with: poses, success rate, mean/median/90th-percentile arrival
        time of the successful runs, mean path length, mean and largest peak
        wheel speed, fraction of runs over ``v_max``, mean zig-zag count,
        fraction of runs with any zig-zag, and against ``reference``: the
        fraction of poses where this controller arrives strictly earlier.
    """
    if reference is None and controllers.SHIM_SUNG.name in results:
        reference = controllers.SHIM_SUNG.name
    rows = []
    for name, m in results.items():
        ok = m.success
        t = m.arrival[ok]
        row: dict[str, Any] = {
            "controller": name,
            "poses": int(len(m.arrival)),
            "success": float(ok.mean()),
            "mean arrival s": float(t.mean()) if t.size else math.inf,
            "median arrival s": float(np.median(t)) if t.size else math.inf,
            "p90 arrival s": float(np.percentile(t, 90)) if t.size else math.inf,
            "mean path cm": float(m.path.mean()),
            "mean peak wheel cm/s": float(m.peak_wheel.mean()),
            "max peak wheel cm/s": float(m.peak_wheel.max()),
            "over V_max": float((m.peak_wheel > v_max * (1 + 1e-9)).mean()),
            "mean zigzag": float(m.zigzag.mean()),
            "any zigzag": float((m.zigzag > 0).mean()),
        }
        if reference is not None and reference in results:
            ref_t = results[reference].arrival
            row[f"faster than {reference}"] = float((m.arrival < ref_t).mean())
        rows.append(row)
    return rows


# ---------------------------------------------------------------- figures


_MAP_FIELDS = (
    ("success", "success", "RdYlGn"),
    ("arrival", "arrival time [s]", "viridis"),
    ("path", "path length [cm]", "magma"),
    ("peak_wheel", "peak wheel speed [cm/s]", "plasma"),
    ("zigzag", "zig-zag count", "cividis"),
)


def _field_values(m: PoseMetrics, field: str) -> np.ndarray:
    if field == "success":
        return m.success.astype(float)
    values = np.asarray(getattr(m, field), dtype=float)
    return np.where(np.isfinite(values), values, np.nan)


def _to_image(grid: PoseGrid, values: np.ndarray, h: int) -> np.ndarray:
    """Return the ``[iy, ix]`` image of heading ``h`` (NaN outside the annulus)."""
    per_heading = int(grid.inside.sum())
    image = np.full(grid.inside.shape, np.nan)
    image[grid.inside] = values[h * per_heading : (h + 1) * per_heading]
    return image


def _ranges(results: dict[str, PoseMetrics]) -> dict[str, tuple[float, float]]:
    """Colour ranges shared by every controller, so that their maps compare."""
    out = {}
    for field, _, _ in _MAP_FIELDS:
        values = np.concatenate([_field_values(m, field) for m in results.values()])
        finite = values[np.isfinite(values)]
        if field == "success" or finite.size == 0:
            out[field] = (0.0, 1.0)
        else:
            hi = float(np.percentile(finite, 99.5)) if field != "zigzag" else float(finite.max())
            out[field] = (float(finite.min()) if field != "zigzag" else 0.0, max(hi, 1e-9))
    return out


def _map_figure(path, name, grid: PoseGrid, m: PoseMetrics, ranges, v_max: float, title: str):
    from wmr_jax.plotting import plt

    n_h = len(grid.headings)
    fig, axes = plt.subplots(
        len(_MAP_FIELDS), n_h, figsize=(2.6 * n_h + 1.2, 2.45 * len(_MAP_FIELDS)), squeeze=False
    )
    extent = (grid.xs[0], grid.xs[-1], grid.xs[0], grid.xs[-1])
    for row, (field, label, cmap_name) in enumerate(_MAP_FIELDS):
        cmap = plt.get_cmap(cmap_name).with_extremes(bad=(1, 1, 1, 0))
        values = _field_values(m, field)
        image = None
        for h in range(n_h):
            ax = axes[row, h]
            img = _to_image(grid, values, h)
            image = ax.imshow(
                img,
                origin="lower",
                extent=extent,
                cmap=cmap,
                vmin=ranges[field][0],
                vmax=ranges[field][1],
                interpolation="nearest",
            )
            if field == "arrival":
                failed = _to_image(grid, (~m.success).astype(float), h)
                overlay = np.zeros((*failed.shape, 4))  # transparent but where it failed
                overlay[failed == 1] = (0.85, 0.1, 0.1, 1.0)
                ax.imshow(overlay, origin="lower", extent=extent, interpolation="nearest")
            if field == "peak_wheel" and np.nanmax(img) > v_max:
                ax.contour(
                    grid.xs, grid.xs, np.nan_to_num(img), levels=[v_max], colors="w", linewidths=0.6
                )
            ax.plot(0, 0, marker=(3, 0, -90), color="k", ms=6)  # the robot at the origin, facing +x
            ax.set_xticks([-80, 0, 80] if grid.xs[-1] >= 80 else [])
            ax.set_yticks([-80, 0, 80] if grid.xs[-1] >= 80 else [])
            ax.tick_params(labelsize=7)
            if row == 0:
                ax.set_title(f"θ_r = {math.degrees(grid.headings[h]):g}°", fontsize=9)
        fig.colorbar(image, ax=axes[row, :].tolist(), shrink=0.85, pad=0.01).set_label(
            label, fontsize=8
        )
    fig.suptitle(title, fontsize=10)
    save_figure(fig, path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def _winner_figure(path, grid: PoseGrid, results: dict[str, PoseMetrics], title: str):
    """Map of the controller that arrives first (grey: none arrives)."""
    from matplotlib.colors import ListedColormap

    from wmr_jax.plotting import plt

    names = list(results)
    times = np.stack([results[n].arrival for n in names])  # (C, N)
    best = np.argmin(times, axis=0).astype(float)
    best[~np.isfinite(times.min(axis=0))] = len(names)
    colours = [plt.get_cmap("tab10")(i) for i in range(len(names))] + [(0.6, 0.6, 0.6, 1)]
    cmap = ListedColormap(colours).with_extremes(bad=(1, 1, 1, 0))
    n_h = len(grid.headings)
    fig, axes = plt.subplots(1, n_h, figsize=(2.8 * n_h, 3.2), squeeze=False)
    extent = (grid.xs[0], grid.xs[-1], grid.xs[0], grid.xs[-1])
    for h in range(n_h):
        ax = axes[0, h]
        ax.imshow(
            _to_image(grid, best, h),
            origin="lower",
            extent=extent,
            cmap=cmap,
            vmin=-0.5,
            vmax=len(names) + 0.5,
            interpolation="nearest",
        )
        ax.plot(0, 0, marker=(3, 0, -90), color="k", ms=6)
        ax.set_title(f"θ_r = {math.degrees(grid.headings[h]):g}°", fontsize=9)
        ax.tick_params(labelsize=7)
    handles = [
        plt.Line2D([], [], marker="s", ls="", color=c, label=lab)
        for c, lab in zip(colours, [*names, "none arrives"], strict=True)
    ]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    save_figure(fig, path, dpi=100)
    plt.close(fig)


# ---------------------------------------------------------------- the sweep


def sweep(
    out_dir: str | Path,
    *,
    n_poses: int = 20000,
    controller_names: Sequence[str] | None = None,
    velocity: str = "ideal",
    headings_deg: Sequence[float] = DEFAULT_HEADINGS_DEG,
    chunk: int = DEFAULT_CHUNK,
    progress: bool = True,
    x64: bool = True,
    resume: bool = False,
) -> dict[str, Any]:
    """Run the pose-space maps and write figures and the summary table.

    Writes into ``out_dir``: ``maps_<controller>.png`` (metrics × headings),
    ``winner.png`` (which controller arrives first), ``summary.md`` and
    ``summary.json``. Every file is written atomically.

    Args:
        out_dir: output folder (created if needed).
        n_poses: about how many reference poses in all (grid × headings).
        controller_names: controllers to run; default every registered one.
        velocity: ``"ideal"`` or ``"nonideal"``.
        headings_deg: the reference headings θ_r of the maps, degrees.
        chunk: poses per compiled call.
        progress: show a progress bar per controller.
        x64: compute in float64 (see ``evaluate_poses``).
        resume: keep each finished chunk under ``out_dir/chunks/<controller>``
            and reuse those already there (an interrupted run goes on).

    Returns:
        ``{"rows": summary rows, "grid_side": G, "poses": N, ...}``.
    """
    from wmr_jax.paper import markdown_table
    from wmr_jax.waypoints import registered_names

    out = Path(out_dir)
    n_poses = _positive_int("n_poses", n_poses)
    names = list(controller_names) if controller_names else registered_names()
    grid = pose_grid(n_poses, headings_deg)
    robot = Robot()
    results = {
        name: evaluate_poses(
            grid.refs,
            controller=name,
            velocity=velocity,
            chunk=chunk,
            progress=progress,
            x64=x64,
            cache=out / "chunks" / name if resume else None,
        )
        for name in names
    }
    rows = summarize(results, v_max=float(robot.v_max))
    ranges = _ranges(results)
    what = f"{len(grid.refs)} poses, {velocity} loop, horizon {HORIZON_S:g} s, start (0, 0, 0°)"
    what += "" if x64 else ", float32"
    for name, m in results.items():
        _map_figure(
            out / f"maps_{name}.png",
            name,
            grid,
            m,
            ranges,
            float(robot.v_max),
            f"{name}: {what} (red: not arrived)",
        )
    if len(names) > 1:
        _winner_figure(out / "winner.png", grid, results, f"First to arrive ({what})")
    summary = {
        "poses": int(len(grid.refs)),
        "grid_side": int(len(grid.xs)),
        "headings_deg": [float(h) for h in headings_deg],
        "velocity": velocity,
        "dtype": "float64" if x64 else "float32",
        "horizon_s": HORIZON_S,
        "dt_s": DEFAULT_DT,
        "tolerances": {"r_cm": metrics.DEFAULT_TOL_R, "theta_deg": 5.0},
        "rows": rows,
    }
    atomic_write_json(out / "summary.json", summary)
    atomic_write_text(
        out / "summary.md",
        f"Pose-space sweep: {what}; SPEC §6 metrics "
        "(arrival statistics over the successful runs)\n\n" + markdown_table(rows),
    )
    return summary


# ---------------------------------------------------------------- command line


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Add the flags of ``wmr-jax sweep`` to ``parser``."""
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument(
        "--poses", type=int, default=20000, help="about how many reference poses (default 20000)"
    )
    parser.add_argument(
        "--controller",
        nargs="+",
        action="extend",
        default=None,
        metavar="NAME",
        help="controllers to compare (repeatable; default: every registered one)",
    )
    parser.add_argument("--velocity", default="ideal", help="velocity loop: ideal or nonideal")
    parser.add_argument(
        "--headings",
        nargs="+",
        type=float,
        default=list(DEFAULT_HEADINGS_DEG),
        metavar="DEG",
        help="reference headings of the maps, degrees (default -90 0 90 180)",
    )
    parser.add_argument(
        "--chunk", type=int, default=DEFAULT_CHUNK, help=f"poses per call ({DEFAULT_CHUNK})"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--float32",
        action="store_true",
        help="compute in float32 (default float64; the polar baselines need it, see docs)",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="keep finished chunks under OUT/chunks and reuse them when run again",
    )
    parser.set_defaults(func=run_cli)


def run_cli(args: argparse.Namespace) -> int:
    """Run ``wmr-jax sweep``; return the exit status."""
    from wmr_jax.paper import markdown_table
    from wmr_jax.waypoints import check_controllers, check_velocity

    if args.poses < 1:
        raise ValueError(f"--poses = {args.poses} is not allowed; allowed: an integer >= 1")
    if args.chunk < 1:
        raise ValueError(f"--chunk = {args.chunk} is not allowed; allowed: an integer >= 1")
    bad = [h for h in args.headings if not math.isfinite(h)]
    if bad:
        raise ValueError(f"--headings = {bad[0]} is not allowed; allowed: finite degrees")
    names = check_controllers(args.controller)
    velocity = check_velocity(args.velocity)
    summary = sweep(
        args.out,
        n_poses=args.poses,
        controller_names=names,
        velocity=velocity,
        headings_deg=args.headings,
        chunk=args.chunk,
        progress=not args.no_progress,
        x64=not args.float32,
        resume=args.resume,
    )
    print(f"{summary['poses']} poses -> {Path(args.out)}/maps_*.png, summary.md, summary.json")
    print(markdown_table(summary["rows"]), end="")
    return 0
