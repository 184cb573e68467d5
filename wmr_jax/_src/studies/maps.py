"""Pose-space maps: docs/model.md §6 metrics over grids of reference poses, per controller."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from wmr_jax._src import checks
from wmr_jax._src.model import controllers
from wmr_jax._src.model.params import Robot, validate_one_robot
from wmr_jax._src.model.robots import robot_json, robot_name
from wmr_jax._src.sim import metrics
from wmr_jax._src.sim.metrics import PoseMetrics
from wmr_jax._src.sim.poses import (
    EVAL_R_MAX,
    EVAL_R_MIN,
    HORIZON_S,
    MAX_SAMPLES,
    horizon_steps,
    sample_poses,
)
from wmr_jax._src.sim.rollout import DEFAULT_DT, make_options
from wmr_jax._src.studies.robustness import mean_median, robot_defaults, study_horizon
from wmr_jax._src.studies.sweep import sweep

DEFAULT_HEADINGS_DEG = (-90.0, 0.0, 90.0, 180.0)
DEFAULT_CHUNK = 16384


def robot_record(robot: Robot) -> dict[str, Any]:
    """The robot as a summary records it: its fields and a label (preset name or "custom")."""
    return {"robot": robot_json(robot), "robot_label": robot_name(robot) or "custom"}


class PoseGrid(NamedTuple):
    """A grid of references: ``G × G`` positions at ``H`` headings, inside the evaluation annulus.

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


_MAX_SIDE = 4097  # grid points per side at most: 16.8 million positions


def _grid(side: int, r_min: float, r_max: float) -> tuple:
    """The grid's axis, the mask of its points in the annulus, and their coordinates."""
    xs = np.linspace(-r_max, r_max, side)
    gx, gy = np.meshgrid(xs, xs)  # [iy, ix]
    dist = np.hypot(gx, gy)
    return xs, (dist >= r_min) & (dist <= r_max), gx, gy


def pose_grid(
    n_poses: int,
    headings_deg: Sequence[float] = DEFAULT_HEADINGS_DEG,
    *,
    r_min: float = EVAL_R_MIN,
    r_max: float = EVAL_R_MAX,
) -> PoseGrid:
    """About ``n_poses`` references on a grid over ``[−r_max, r_max]²``, ``r_min``–``r_max`` from 0.

    Args:
        n_poses: about how many references in all, ``>= 1``.
        headings_deg: the reference headings θ_r, degrees (at least one, finite).
        r_min: least distance from the origin, cm.
        r_max: largest distance, cm, ``> r_min``.
    """
    n_poses = checks.check_int("n_poses", n_poses, 1, MAX_SAMPLES)
    r_min = checks.check_number("r_min", r_min, closed=True, unit="cm")
    r_max = checks.check_number("r_max", r_max, low=r_min, unit="cm")
    degrees = checks.real_array(
        "headings_deg", headings_deg, "real numbers of degrees (at least one, finite)"
    ).reshape(-1)
    if degrees.size == 0:
        raise ValueError("headings_deg = () is not allowed; allowed: at least one heading")
    checks.require("headings_deg", degrees, np.isfinite(degrees), "finite degrees")
    within = np.abs(np.radians(degrees)) <= checks.MAX_HEADING
    limit = f"|heading| <= {math.degrees(checks.MAX_HEADING):.3g} degrees"
    checks.require("headings_deg", degrees, within, limit)
    turns = np.mod(degrees, 360.0)  # one heading, however many turns it is written with
    repeated = [float(d) for i, d in enumerate(degrees) if np.any(turns[:i] == turns[i])]
    if repeated:
        raise ValueError(
            f"headings_deg = {degrees.tolist()} is not allowed: {repeated[0]:g} repeats a "
            "heading (modulo 360); allowed: distinct headings"
        )
    headings = np.radians(degrees)
    annulus = math.pi * (1.0 - (r_min / r_max) ** 2) / 4  # its share of the square
    side = min(max(2, round(math.sqrt(n_poses / (len(headings) * annulus)))), _MAX_SIDE)
    xs, inside, gx, gy = _grid(side, r_min, r_max)
    if not inside.any():
        # An even grid can miss a thin annulus; an odd one has (r_max, 0) on it.
        xs, inside, gx, gy = _grid(side + 1, r_min, r_max)
    pos = np.stack([gx[inside], gy[inside]], axis=-1)
    refs = np.concatenate(
        [np.concatenate([pos, np.full((len(pos), 1), h)], axis=-1) for h in headings]
    )
    return PoseGrid(xs, headings, inside, refs)


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
    resume: bool = True,
    on_chunk: Callable[[int, int], None] | None = None,
) -> PoseMetrics:
    """The docs/model.md §6 metrics of every reference, in bounded memory.

    Args:
        refs, controller, dt, robot, velocity, on_chunk: as ``wmr_jax.sweep``.
        params: as ``sweep``'s ``gains``.
        init: ``(3,)`` initial pose shared by every run.
        steps: control periods; default the robot's study horizon
            (``study_horizon``: 6 s for the paper robot, longer for a slower
            one; 6 s for robots batched per run).
        chunk: poses per compiled call (the last chunk is padded to it).
        progress: show a progress bar (stderr).
        x64: compute in float64 (default), whatever JAX's default dtype: in
            float32 the polar baselines' bearing is rounding noise near their goal.
        cache: a folder where each finished chunk is kept (``wmr_jax.sweep``'s
            ``out``); ``None`` keeps nothing.
        resume: with ``cache``, reuse the chunks it holds of the same settings.

    Returns:
        ``PoseMetrics`` of ``(N,)`` NumPy arrays, in the order of ``refs``.
    """
    chunk, x64, progress = _run_flags(chunk, x64, progress)
    with jax.enable_x64(x64):  # checked, and kept for the distance below, in the run's dtype
        refs_host = np.asarray(checks.as_poses("refs", refs, batch=True))
    cache = None if cache is None else checks.check_folder("cache", cache)
    if np.ndim(init) != 1:
        raise ValueError(f"init has shape {np.shape(init)}; allowed: (3,), shared by every run")
    run = {"init": init, "dt": dt, "robot": robot, "velocity": velocity, "controller": controller}
    kept = {"out": cache, "resume": resume, "on_chunk": on_chunk, "progress": progress}
    if steps is None:
        one = robot is None or all(np.ndim(leaf) == 0 for leaf in jax.tree.leaves(robot))
        steps = horizon_steps(dt, study_horizon(robot) if one else HORIZON_S)
    with jax.enable_x64(x64):
        out = sweep(refs_host, params, steps=steps, chunk_size=chunk, **run, **kept)
    final = np.stack([out["final_x"], out["final_y"]], axis=-1)
    return PoseMetrics(
        arrival=out["arrival_time"],
        path=out["path_length"],
        peak_wheel=out["peak_wheel_speed"],
        zigzag=out["zigzags"],
        final_distance=np.hypot(*(final - refs_host[:, :2]).T),
    )


def summarize(
    results: dict[str, PoseMetrics], *, v_max: float = 125.0, reference: str | None = None
) -> list[dict[str, Any]]:
    """One row of summary statistics per controller, side by side.

    Args:
        results: controller name → its ``PoseMetrics`` over the same poses.
        v_max: wheel-speed limit for the "over V_max" column, cm/s.
        reference: the controller the others are compared with pose by pose
            (default: Shim–Sung if present).

    Returns:
        Rows with the poses, success rate, mean/median/90th-percentile arrival
        of the successes, mean path, mean and largest peak wheel speed, the
        fraction over ``v_max``, mean zig-zag count, the fraction with any
        zig-zag, and the fraction of poses arriving strictly before ``reference``.
    """
    v_max = checks.check_number("v_max", v_max, unit="cm/s")
    if not isinstance(results, Mapping) or not all(
        isinstance(m, PoseMetrics) for m in results.values()
    ):
        raise ValueError(
            f"results is a {type(results).__name__}; allowed: a dict of controller name -> "
            "PoseMetrics (evaluate_poses returns one)"
        )
    sizes = {name: len(m.arrival) for name, m in results.items()}
    if not results or min(sizes.values()) == 0 or len(set(sizes.values())) > 1:
        raise ValueError(
            f"results of {sizes} runs are not allowed; allowed: one or more controllers, each "
            "over the same poses (at least one)"
        )
    if reference is not None and reference not in results:
        raise ValueError(
            f"reference = {reference!r} is not allowed; allowed: one of {list(results)}"
        )
    if reference is None and controllers.SHIM_SUNG.name in results:
        reference = controllers.SHIM_SUNG.name
    rows = []
    for name, m in results.items():
        t = m.arrival[m.success]
        mean, median = mean_median(t)
        row: dict[str, Any] = {
            "controller": name,
            "poses": int(len(m.arrival)),
            "success": float(m.success.mean()),
            "mean arrival s": mean,
            "median arrival s": median,
            "p90 arrival s": float(np.percentile(t, 90)) if t.size else math.inf,
            "mean path cm": float(m.path.mean()),
            "mean peak wheel cm/s": float(m.peak_wheel.mean()),
            "max peak wheel cm/s": float(m.peak_wheel.max()),
            "over V_max": float((m.peak_wheel > v_max * (1 + 1e-9)).mean()),
            "mean zigzag": float(m.zigzag.mean()),
            "any zigzag": float((m.zigzag > 0).mean()),
        }
        if reference is not None:
            row[f"faster than {reference}"] = float((m.arrival < results[reference].arrival).mean())
        rows.append(row)
    return rows


class MapStudy(NamedTuple):
    """What ``map_study`` returns.

    Attributes:
        grid: the references run (``PoseGrid``).
        results: controller name → its ``PoseMetrics`` over ``grid.refs``.
        summary: JSON-ready settings of the run, the robot and its ``rows``
            (``summarize``).
    """

    grid: PoseGrid
    results: dict[str, PoseMetrics]
    summary: dict[str, Any]

    @property
    def rows(self) -> list[dict[str, Any]]:
        """The summary table, one row per controller."""
        return self.summary["rows"]


def map_study(
    n_poses: int = 20000,
    *,
    controller_names: Sequence[str] | None = None,
    velocity: str = "ideal",
    headings_deg: Sequence[float] = DEFAULT_HEADINGS_DEG,
    chunk: int = DEFAULT_CHUNK,
    progress: bool = False,
    x64: bool = True,
    cache: str | Path | None = None,
    resume: bool = True,
    robot: Robot | None = None,
    horizon: float | None = None,
    on_chunk: Callable[[str, int, int], None] | None = None,
    params: Mapping[str, Any] | None = None,
) -> MapStudy:
    """Run the pose-space maps of every controller: the same grid from ``(0, 0, 0)``.

    Args:
        n_poses: about how many reference poses in all (grid × headings).
        controller_names: controllers to run; default every registered one.
        velocity: ``"ideal"`` or ``"nonideal"``.
        headings_deg: the reference headings θ_r of the maps, degrees.
        chunk, progress, x64, resume: as ``evaluate_poses`` (a progress bar per controller).
        cache: a folder for each controller's finished chunks (``cache/<controller>``).
        robot: the robot (one, a number per field); default ``Robot()``.
        horizon: simulated time per run, s; default ``study_horizon(robot)``.
        on_chunk: called as ``on_chunk(controller, done, total)`` after every chunk.
        params: controller name → its parameters (tuned gains, say); a controller
            not named runs its defaults for ``robot`` (``robot_defaults``). The
            summary then lists the names given (``params_given``).

    Returns:
        A ``MapStudy``.
    """
    names = controllers.controller_names(controller_names)
    params = {} if params is None else params
    if not isinstance(params, Mapping) or not set(params) <= set(names):
        unknown = sorted(set(params) - set(names)) if isinstance(params, Mapping) else params
        raise ValueError(
            f"params = {unknown!r:.60} is not allowed; allowed: a dict of controller name -> "
            f"parameters, names among {', '.join(names)} (the controllers run)"
        )
    cache = None if cache is None else checks.check_folder("cache", cache)
    checks.check_callable("on_chunk", on_chunk)
    robot = validate_one_robot(robot, "map_study")
    horizon = _horizon(horizon, robot)
    grid = pose_grid(n_poses, headings_deg)

    def per_run(name: str) -> dict[str, Any]:
        told = None if on_chunk is None else (lambda done, total: on_chunk(name, done, total))
        cached = None if cache is None else cache / name
        return {"cache": cached, "resume": resume, "on_chunk": told}

    runs = {name: (name, params.get(name)) for name in names}
    results = _metrics(grid.refs, runs, robot, horizon, velocity, chunk, progress, x64, per_run)
    head = {
        "poses": int(len(grid.refs)),
        **({"params_given": sorted(params)} if params else {}),
        "grid_side": int(len(grid.xs)),
        # As given (pose_grid checked them: a number or a nested list works too).
        "headings_deg": np.asarray(headings_deg, dtype=float).reshape(-1).tolist(),
    }
    tolerances = {"r_cm": metrics.DEFAULT_TOL_R, "theta_deg": 5.0}
    summary = _summary(head, results, robot, horizon, velocity, x64, tolerances=tolerances)
    return MapStudy(grid, results, summary)


def _summary(head, results, robot, horizon, velocity, x64, **more) -> dict[str, Any]:
    """A study's JSON-ready record: ``head``, the run's settings, ``more``, the robot and rows."""
    return {
        **head,
        "velocity": velocity,
        "dtype": "float64" if x64 else "float32",
        "horizon_s": horizon,
        "dt_s": DEFAULT_DT,
        **more,
        **robot_record(robot),
        "rows": summarize(results, v_max=float(robot.v_max)),
    }


def _horizon(horizon: float | None, robot: Robot) -> float:
    """The horizon asked for, checked, or the robot's default (``study_horizon``)."""
    if horizon is None:
        return study_horizon(robot)
    horizon_steps(DEFAULT_DT, horizon)  # a number of s, at least a period, at most MAX_STEPS
    return float(horizon)


def _run_flags(chunk: Any, x64: Any, progress: Any) -> tuple[int, bool, bool]:
    """``evaluate_poses``' ``chunk``, ``x64`` and ``progress``, checked."""
    chunk = checks.check_int("chunk", chunk)
    return chunk, checks.check_bool("x64", x64), checks.check_bool("progress", progress)


def _metrics(refs, runs, robot, horizon, velocity, chunk, progress, x64, per_run=None):
    """Each run's metrics over ``refs``: ``runs`` maps a label to (controller, params or None)."""
    same = {"robot": robot, "velocity": velocity, "chunk": chunk, "progress": progress, "x64": x64}
    same["steps"] = horizon_steps(DEFAULT_DT, horizon)
    return {
        label: evaluate_poses(
            refs,
            robot_defaults(name, robot) if params is None else params,
            controller=name,
            **same,
            **({} if per_run is None else per_run(label)),
        )
        for label, (name, params) in runs.items()
    }


def _comparison_runs() -> dict[str, tuple[str, Any]]:
    """Label -> (controller name, parameters): each baseline also with its other driving mode."""
    from wmr_jax._src.model.controllers.aicardi import AicardiGains
    from wmr_jax._src.model.controllers.astolfi import AstolfiGains

    return {
        "shim-sung": ("shim-sung", None),
        "aicardi": ("aicardi", None),
        "aicardi, backward allowed": ("aicardi", AicardiGains(backward=True)),
        "astolfi-corke": ("astolfi-corke", None),
        "astolfi-corke, forward only": ("astolfi-corke", AstolfiGains(backward=False)),
    }


COMPARISON_RUNS = tuple(_comparison_runs())


def compare_controllers(
    n_poses: int = 200_000,
    *,
    seed: int = 0,
    velocity: str = "ideal",
    chunk: int = DEFAULT_CHUNK,
    progress: bool = False,
    x64: bool = True,
    robot: Robot | None = None,
    horizon: float | None = None,
    also: Sequence[Any] = (),
) -> dict[str, Any]:
    """Compare every controller over the same random docs/model.md §6 poses.

    The poses are ``wmr_jax.sample_poses(seed, n_poses)`` from ``(0, 0, 0)``;
    each run of ``COMPARISON_RUNS`` has its published defaults.

    Args:
        n_poses: number of random reference poses.
        seed: seed of ``sample_poses``.
        velocity, chunk, progress, x64, robot, horizon: as ``map_study``.
        also: registered controllers (names or values) to run after those,
            each with its default parameters (``robot_defaults``), labelled
            by name: a law of one's own beside the baselines.

    Returns:
        A JSON-ready dict of the settings, the robot and ``rows``
        (``summarize``, one per run).
    """
    n_poses = checks.check_int("n_poses", n_poses, 1, MAX_SAMPLES)
    seed = checks.check_int("seed", seed, minimum=0)
    robot = validate_one_robot(robot, "compare_controllers")
    horizon = _horizon(horizon, robot)
    runs = _comparison_runs()
    for name in [] if not also else controllers.controller_names(also):
        if name in runs:
            raise ValueError(
                f"also = {name!r} is not allowed: it is compared already; allowed: another "
                "registered controller"
            )
        runs[name] = (name, None)
    _run_flags(chunk, x64, progress)  # the runs' options, refused before the poses are drawn
    make_options(velocity=velocity)
    refs = np.asarray(sample_poses(seed, n_poses), dtype=float)
    results = _metrics(refs, runs, robot, horizon, velocity, chunk, progress, x64)
    return _summary({"poses": n_poses, "seed": seed}, results, robot, horizon, velocity, x64)
