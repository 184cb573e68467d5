"""Consecutive motions: a chain of waypoints, and references that move.

A chain gives the robot waypoint 0 and, once arrived there (docs/model.md §6),
waypoint 1, and so on; intermediate waypoints may use a looser pass-through
tolerance. A moving reference is one reference per control period: the error
after period ``k`` is taken against ``refs[k]``, and a constant reference
gives exactly a ``rollout``.
"""

from __future__ import annotations

import inspect
import math
import types
from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import checks
from wmr_jax._src.model import controllers
from wmr_jax._src.model.params import Robot, validate_one_robot
from wmr_jax._src.sim import loops, metrics
from wmr_jax._src.sim import rollout as simulation
from wmr_jax._src.sim.loops import Options
from wmr_jax._src.sim.poses import HORIZON_S
from wmr_jax._src.sim.rollout import DEFAULT_DT, Trajectory
from wmr_jax._src.studies.robustness import robot_defaults, study_horizon

# A soccer-like sequence on a 160 cm × 120 cm pitch, (x cm, y cm, θ deg): run to
# the ball, turn it upfield, dribble, cut back, return to defend, face the goal.
SOCCER_WAYPOINTS_DEG = (
    (40.0, 10.0, 0.0),
    (70.0, 40.0, 90.0),
    (30.0, 60.0, 180.0),
    (-20.0, 30.0, -90.0),
    (-40.0, -30.0, 0.0),
    (20.0, -40.0, 45.0),
)
# Control periods of each soccer run for the paper robot (14.85 s at dt = 0.033 s).
SOCCER_STEPS = 450


class ChainRun(NamedTuple):
    """A run through a chain of ``K`` waypoints (leading batch axes first).

    Attributes:
        trajectory: the ``Trajectory`` of the run (``steps + 1`` poses).
        leg: ``(steps,)`` int32 index of the waypoint each period aimed at.
        arrival: ``(K,)`` arrival time at each waypoint, s; ``inf`` if never: the
            end of the period it was reached at, the last one's that of docs/model.md §6.
    """

    trajectory: Trajectory
    leg: jax.Array
    arrival: jax.Array


class TrackRun(NamedTuple):
    """A run after a moving reference (leading batch axes first).

    Attributes:
        trajectory: the ``Trajectory`` of the run (``steps + 1`` poses).
        error: ``(steps,)`` distance ``r_e`` after each period to its reference, cm.
        arrival: ``()`` docs/model.md §6 arrival time against the moving reference, s.
    """

    trajectory: Trajectory
    error: jax.Array
    arrival: jax.Array


def _chain_single(spec, params, init, robot, dt, options: Options) -> ChainRun:
    """Run one robot through its waypoints; ``spec = (waypoints (K, 3), tolerances (4,))``."""
    waypoints, tolerances = spec
    n_legs = waypoints.shape[0]
    pass_r, pass_theta, final_r, final_theta = (tolerances[i] for i in range(4))

    def fold(acc, pose, out):
        k, leg, reached_at, run_start = acc
        last = leg == n_legs - 1
        tol_r = jnp.where(last, final_r, pass_r)
        tol_theta = jnp.where(last, final_theta, pass_theta)
        ok = metrics.arrived(pose.stacked(), waypoints[leg], tol_r=tol_r, tol_theta=tol_theta)
        reached = ok & ~last
        reached_at = jnp.where(reached & (jnp.arange(n_legs) == leg), k, reached_at)
        # On the last leg, remember where the current run of arrived samples began.
        run_start = jnp.where(last & ok, jnp.where(run_start < 0, k, run_start), -1)
        return k + 1, leg + reached.astype(leg.dtype), reached_at, run_start

    def aim(acc):
        return waypoints[acc[1]]

    zero, never = jnp.zeros((), jnp.int32), jnp.full((), -1, jnp.int32)
    start = (zero, zero, jnp.full((n_legs,), -1, jnp.int32), never)
    _, (_, _, reached_at, run_start), (poses, out) = loops.scan_closed_loop(
        waypoints[0], params, init, robot, dt, options, aim=aim, fold=fold, acc=start, record=True
    )
    arrival = _period_end(reached_at.at[-1].set(run_start), dt, waypoints.dtype)
    # The leg of period k: the waypoints reached before it.
    periods = jnp.arange(options.steps, dtype=jnp.int32)[:, None]
    passed = (reached_at[None, :-1] >= 0) & (reached_at[None, :-1] < periods)
    leg = jnp.sum(passed, axis=1, dtype=jnp.int32)
    return ChainRun(_as_trajectory(init, poses, out), leg, arrival)


def _track_single(refs, params, init, robot, dt, options: Options) -> TrackRun:
    """Run one robot after a reference per period, ``refs (steps, 3)``."""
    last = refs.shape[0] - 1
    _, _, (poses, out) = loops.scan_closed_loop(
        refs[0],
        params,
        init,
        robot,
        dt,
        options,
        aim=lambda k: refs[jnp.minimum(k, last)],
        fold=lambda k, pose, out: k + 1,
        acc=jnp.zeros((), jnp.int32),
        record=True,
    )
    ok = metrics.arrived(poses, refs)
    # The samples from which every later one is arrived: the last run of them.
    settled = jnp.cumprod(ok[::-1].astype(jnp.int32))[::-1]
    run_start = jnp.where(ok[-1], settled.shape[0] - jnp.sum(settled), -1)
    arrival = _period_end(run_start, dt, refs.dtype)
    # The distance r_e to each period's reference, cm, NaN-safe at 0.
    d_sq = (refs[..., 0] - poses[..., 0]) ** 2 + (refs[..., 1] - poses[..., 1]) ** 2
    error = jnp.where(d_sq > 0, jnp.sqrt(jnp.where(d_sq > 0, d_sq, 1.0)), 0.0)
    return TrackRun(_as_trajectory(init, poses, out), error, arrival)


def _period_end(period: jax.Array, dt: jax.Array, dtype: Any) -> jax.Array:
    """The time at the end of ``period`` (int32, ``-1`` for never: ``inf``), s."""
    return jnp.where(period >= 0, (period + 1).astype(dtype) * dt, jnp.inf)


def _as_trajectory(init, poses, out) -> Trajectory:
    poses = jnp.concatenate([init[None], poses], axis=0)
    return Trajectory(poses, out.v, out.omega, out.region, out.wheel_speeds, out.distance)


_chain_jit = loops.EntryJit(_chain_single, static_argnames=("options",))
_batch_chain_jit = loops.EntryJit(loops.batched(_chain_single), static_argnames=("options",))
_track_jit = loops.EntryJit(_track_single, static_argnames=("options",))
_batch_track_jit = loops.EntryJit(loops.batched(_track_single), static_argnames=("options",))


def _pose_stack(name: str, value: Any, ndim: int, allowed: str) -> jax.Array:
    """``value`` as checked poses of ``ndim`` dims, the last of length 3."""
    shape = np.shape(value)
    if len(shape) != ndim or shape[-1] != 3 or 0 in shape:
        raise ValueError(f"{name} has shape {shape}; allowed: {allowed} [x cm, y cm, theta rad]")
    flat = checks.as_poses(name, np.reshape(value, (-1, 3)), batch=True)
    if checks.is_traced(flat):  # inside a caller's jit or grad
        return flat.reshape(shape)
    return jax.device_put(np.asarray(flat).reshape(shape))  # shaped on the host: no program


def _tolerances(tol_r, tol_theta, pass_tol_r, pass_tol_theta) -> jax.Array:
    """``[pass r, pass θ, final r, final θ]``, each checked (cm, rad)."""
    tol_r = checks.check_number("tol_r", tol_r, unit="cm")
    tol_theta = checks.check_number("tol_theta", tol_theta, high=math.pi / 2, unit="rad")
    pass_r = tol_r if pass_tol_r is None else pass_tol_r
    pass_r = checks.check_number("pass_tol_r", pass_r, unit="cm")
    pass_theta = tol_theta if pass_tol_theta is None else pass_tol_theta
    pass_theta = checks.check_number("pass_tol_theta", pass_theta, unit="rad")
    # π/2 is allowed for passing through: |θ̄_e| ≤ π/2 always holds, heading ignored.
    checks.require(
        "pass_tol_theta", np.asarray(pass_theta), pass_theta <= math.pi / 2, "<= pi/2 rad"
    )
    return jnp.asarray([pass_r, pass_theta, tol_r, tol_theta], checks.float_dtype())


# What each loop keeps per run and period, (floats, int32s): a Trajectory
# (8 floats and the region) and the leg of a chain, or the error of a track.
_CHAIN_RECORD, _TRACK_RECORD = (8, 2), (9, 1)


def _shared_by_every_run(
    poses: jax.Array, params: Any, robot: Any, init: Any, steps: int, record: tuple[int, int]
) -> jax.Array:
    """``poses (1, ...)`` repeated for each run of batched params, robot or init."""
    runs = checks.common_batch_size({"gains": params, "robot": robot}, {"init": init})
    simulation.require_memory(max(poses.shape[0], runs), steps, record)
    if poses.shape[0] == 1 and runs > 1:
        return jnp.broadcast_to(poses, (runs, *poses.shape[1:]))
    return poses


def _options(steps, velocity, controller, substeps, wheel_limit) -> Options:
    return simulation.make_options(**locals())  # each by its name, as the rollouts do


# The batched entry point beside each single-run one, for the message that
# refuses batched parameters in the latter.
_BATCHED = {"chain_rollout": "batch_chain_rollout", "track_rollout": "batch_track_rollout"}


def _run(jitted, spec, params, init, robot, dt, options: Options, n: int | None, entry=""):
    """Check params, init, robot and dt as ``rollout`` does (``n`` runs, or one), then run."""
    if n is not None and np.ndim(init) == 2 and np.shape(init)[0] != n:
        raise ValueError(f"init has {np.shape(init)[0]} rows; allowed: {n}, one per run")
    # A stand-in reference: the caller checked the real ones.
    dummy, names = np.zeros((3,) if n is None else (n, 3)), (entry, _BATCHED.get(entry, ""))
    batch = False if n is None else None
    _, params, init, robot, dt = simulation.prepare(
        dummy, params, init, robot, dt, options, batch=batch, entry=names
    )
    # The robot's speed limiter, as in the rollouts (docs/model.md §4.2.2).
    options = loops.for_robot(options, robot, dt)
    return jitted(spec, params, init, robot, dt, options=options)


def _bound(single: Any, first: Any, params: Any, keywords: dict[str, Any]) -> Any:
    """Every argument of ``single`` as given to its batched twin, defaults filled in."""
    bound = inspect.signature(single).bind(first, params, **keywords)
    bound.apply_defaults()
    return types.SimpleNamespace(**bound.arguments)


def chain_rollout(
    waypoints: Any,
    params: Any = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    steps: int = 450,
    robot: Robot | None = None,
    velocity: str = "ideal",
    controller: Any = controllers.SHIM_SUNG,
    tol_r: float = metrics.DEFAULT_TOL_R,
    tol_theta: float = metrics.DEFAULT_TOL_THETA,
    pass_tol_r: float | None = None,
    pass_tol_theta: float | None = None,
    substeps: int = loops.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> ChainRun:
    """Drive one robot through ``waypoints`` in order, switching on arrival.

    Args:
        waypoints: ``(K, 3)`` poses ``[x cm, y cm, θ rad]``, visited in order.
        params: the controller's parameters (its defaults if ``None``).
        init: ``(3,)`` initial pose.
        steps: control periods in all (static).
        dt, robot, velocity, controller, substeps, wheel_limit: as ``wmr_jax.rollout``.
        tol_r: arrival distance at the last waypoint, cm.
        tol_theta: arrival folded-heading error at the last waypoint, rad, ``< π/2``.
        pass_tol_r: distance at which an intermediate waypoint counts as
            reached, cm; default ``tol_r``.
        pass_tol_theta: heading tolerance there, rad, ``≤ π/2`` (``π/2``
            ignores the heading); default ``tol_theta``.

    Returns:
        A ``ChainRun``; ``arrival`` has one entry per waypoint.
    """
    wp = _pose_stack("waypoints", waypoints, 2, "(K, 3)")
    tol = _tolerances(tol_r, tol_theta, pass_tol_r, pass_tol_theta)
    options = _options(steps, velocity, controller, substeps, wheel_limit)
    simulation.require_memory(1, options.steps, _CHAIN_RECORD)
    return _run(_chain_jit, (wp, tol), params, init, robot, dt, options, None, "chain_rollout")


def batch_chain_rollout(waypoints: Any, params: Any = None, **keywords: Any) -> ChainRun:
    """Run ``chain_rollout`` for a batch of ``N`` robots in one call.

    Args:
        waypoints: ``(N, K, 3)`` one chain per robot, or ``(K, 3)`` shared when
            ``init`` is ``(N, 3)``.
        init: ``(3,)`` shared or ``(N, 3)`` initial poses.
        (the rest as ``chain_rollout``; ``params`` leaves may have shape ``(N,)``.)

    Returns:
        A ``ChainRun`` whose fields have a leading axis ``N``.
    """
    a = _bound(chain_rollout, waypoints, params, keywords)
    if np.ndim(waypoints) == 2:
        wp = _pose_stack("waypoints", waypoints, 2, "(K, 3)")
        if np.ndim(a.init) != 2:
            raise ValueError(
                f"waypoints has shape {wp.shape} and init has shape {np.shape(a.init)}; "
                "allowed: waypoints (N, K, 3), or (K, 3) with init (N, 3)"
            )
        wp = jnp.broadcast_to(wp, (np.shape(a.init)[0], *wp.shape))
    else:
        wp = _pose_stack("waypoints", waypoints, 3, "(N, K, 3)")
    tol = _tolerances(a.tol_r, a.tol_theta, a.pass_tol_r, a.pass_tol_theta)
    options = _options(a.steps, a.velocity, a.controller, a.substeps, a.wheel_limit)
    wp = _shared_by_every_run(wp, params, a.robot, a.init, options.steps, _CHAIN_RECORD)
    return _run(_batch_chain_jit, (wp, tol), params, a.init, a.robot, a.dt, options, wp.shape[0])


batch_chain_rollout.__signature__ = inspect.signature(chain_rollout)  # for help()


def track_rollout(
    refs: Any,
    params: Any = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    robot: Robot | None = None,
    velocity: str = "ideal",
    controller: Any = controllers.SHIM_SUNG,
    substeps: int = loops.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> TrackRun:
    """Drive one robot after a moving reference, one reference per period.

    Args:
        refs: ``(steps, 3)`` reference of each control period.
        (the rest as ``chain_rollout``.)

    Returns:
        A ``TrackRun``.
    """
    arr = _pose_stack("refs", refs, 2, "(steps, 3)")
    options = _options(arr.shape[0], velocity, controller, substeps, wheel_limit)
    simulation.require_memory(1, options.steps, _TRACK_RECORD)
    return _run(_track_jit, arr, params, init, robot, dt, options, None, "track_rollout")


def batch_track_rollout(refs: Any, params: Any = None, **keywords: Any) -> TrackRun:
    """Run ``track_rollout`` for ``N`` robots: ``refs (N, steps, 3)``, ``init (3,)`` or ``(N, 3)``.

    Returns:
        A ``TrackRun`` whose fields have a leading axis ``N``.
    """
    a = _bound(track_rollout, refs, params, keywords)
    arr = _pose_stack("refs", refs, 3, "(N, steps, 3)")
    options = _options(arr.shape[1], a.velocity, a.controller, a.substeps, a.wheel_limit)
    arr = _shared_by_every_run(arr, params, a.robot, a.init, options.steps, _TRACK_RECORD)
    return _run(_batch_track_jit, arr, params, a.init, a.robot, a.dt, options, arr.shape[0])


batch_track_rollout.__signature__ = inspect.signature(track_rollout)  # for help()


def soccer_waypoints() -> np.ndarray:
    """``SOCCER_WAYPOINTS_DEG`` as ``(K, 3)`` in cm, cm, rad."""
    wp = np.array(SOCCER_WAYPOINTS_DEG)
    wp[:, 2] = np.radians(wp[:, 2])
    return wp


class SoccerRun(NamedTuple):
    """A soccer run: controller, mode (``"stop"`` or ``"pass"``) and its ``ChainRun``."""

    controller: str
    mode: str
    run: ChainRun


class SoccerStudy(NamedTuple):
    """What ``soccer_study`` ran and found.

    Attributes:
        rows: one per controller and mode: the time since the start at which
            each waypoint was reached (``"leg i s"``, ``inf`` if never), the
            slowest leg (``"slowest leg s"``), ``"path cm"`` and ``"zigzag"``.
        runs: the ``SoccerRun`` of each row, in the same order.
        velocity, steps, pass_tol_r (cm), pass_tol_theta (rad): the settings.
        robot: the robot run; ``None`` stands for ``Robot()``.
    """

    rows: list[dict[str, Any]]
    runs: list[SoccerRun]
    velocity: str
    steps: int
    pass_tol_r: float
    pass_tol_theta: float
    robot: Robot | None = None


def soccer_study(
    *,
    controller_names: Sequence[str] | None = None,
    velocity: str = "ideal",
    steps: int = SOCCER_STEPS,
    pass_tol_r: float = 5.0,
    pass_tol_theta: float = math.radians(30.0),
    robot: Robot | None = None,
) -> SoccerStudy:
    """Run the soccer-like sequence (``SOCCER_WAYPOINTS_DEG``) for each controller.

    Each controller runs the chain twice: stopping at every waypoint and
    passing through the intermediate ones. Computed in float64, where the
    polar baselines' bearing near a goal is not rounding noise.

    Args:
        controller_names: registered controllers; default every one.
        velocity: ``"ideal"`` or ``"nonideal"``.
        steps: control periods of each run (``soccer_steps(robot)`` suits a
            slower robot).
        pass_tol_r: pass-through distance, cm.
        pass_tol_theta: pass-through heading tolerance, rad, ``≤ π/2``.
        robot: the robot; default ``Robot()``. Shim–Sung runs
            ``robustness.robot_defaults`` there.

    Returns:
        A ``SoccerStudy``.
    """
    names = controllers.controller_names(controller_names)
    robot = validate_one_robot(robot, "soccer_study")
    # Every setting is checked before the first controller runs (and compiles).
    _tolerances(metrics.DEFAULT_TOL_R, metrics.DEFAULT_TOL_THETA, pass_tol_r, pass_tol_theta)
    for name in names:
        _options(steps, velocity, name, loops.DEFAULT_SUBSTEPS, "clip")
    wp = soccer_waypoints()
    modes = (("stop", None, None), ("pass", pass_tol_r, pass_tol_theta))
    rows, runs = [], []
    with jax.enable_x64(True):
        for name in names:
            same = {"controller": name, "velocity": velocity, "steps": steps, "robot": robot}
            same["params"] = robot_defaults(name, robot)
            for mode, p_r, p_theta in modes:
                run = chain_rollout(wp, pass_tol_r=p_r, pass_tol_theta=p_theta, **same)
                rows.append({"controller": name, "mode": mode, **_leg_summary(run)})
                runs.append(SoccerRun(name, mode, run))
    return SoccerStudy(rows, runs, velocity, steps, pass_tol_r, pass_tol_theta, robot)


def soccer_steps(robot: Robot | None = None, steps: int = SOCCER_STEPS) -> int:
    """The paper robot's ``steps`` of the soccer route, stretched as ``study_horizon(robot)``."""
    steps = checks.check_int("steps", steps)
    return math.ceil(steps * study_horizon(robot) / HORIZON_S - 1e-9)


def _leg_summary(run: ChainRun) -> dict[str, Any]:
    """The arrival at each waypoint, the slowest leg, path and zig-zag of a run."""
    arrival = np.asarray(run.arrival, dtype=float)
    row: dict[str, Any] = {f"leg {i + 1} s": float(t) for i, t in enumerate(arrival)}
    # A waypoint never reached makes its leg, and every later one, infinite.
    with np.errstate(invalid="ignore"):
        legs = np.diff(np.concatenate([[0.0], arrival]))
    legs[~np.isfinite(arrival)] = np.inf
    row["slowest leg s"] = float(np.max(legs))
    row["path cm"] = float(np.sum(np.asarray(run.trajectory.distance)))
    row["zigzag"] = int(metrics.zigzag_count(run.trajectory))
    return row
