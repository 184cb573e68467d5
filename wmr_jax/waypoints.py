"""Consecutive motions: a chain of waypoints, and references that move.

Two closed loops built from ``simulation.closed_loop_step``, each a
``lax.scan`` over one robot, batched by ``simulation.batched``:

* **Waypoint chain.** The robot is given waypoint 0 and, when it has arrived
  there, waypoint 1, and so on. Arrived means the SPEC §6 test
  (``r_e ≤ tol_r`` and ``|θ̄_e| ≤ tol_theta``) after a control period; the
  intermediate waypoints may use a looser *pass-through* tolerance, so that
  the robot runs through them instead of settling on each. The arrival time
  of an intermediate waypoint is the end of the period at which it was
  reached (when the chain moved on); that of the last one is the SPEC §6
  arrival time, counted over the samples spent on the last leg.
* **Moving reference.** One reference per control period, ``(steps, 3)``: the
  command of period ``k`` is computed for ``refs[k]``. The tracking error and
  the arrival test after period ``k`` are taken against ``refs[k]``; with a
  constant reference this is exactly a ``rollout`` and its SPEC §6 metrics.

``soccer_demo`` runs a soccer-like sequence for each controller and writes a
figure and a table of the arrival time per leg.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax import baselines as _baselines  # noqa: F401  (registers the baselines by name)
from wmr_jax import controllers, metrics, simulation
from wmr_jax.io import atomic_write_json, atomic_write_text, save_figure
from wmr_jax.params import Robot
from wmr_jax.simulation import DEFAULT_DT, Options, Trajectory

__all__ = [
    "SOCCER_WAYPOINTS_DEG",
    "ChainRun",
    "TrackRun",
    "batch_chain_rollout",
    "batch_track_rollout",
    "chain_rollout",
    "configure_parser",
    "run_cli",
    "soccer_demo",
    "track_rollout",
]

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


class ChainRun(NamedTuple):
    """A run through a chain of ``K`` waypoints (leading batch axes first).

    Attributes:
        trajectory: the ``Trajectory`` of the run (``steps + 1`` poses).
        leg: ``(steps,)`` int32 index of the waypoint the command of each
            period was computed for.
        arrival: ``(K,)`` arrival time at each waypoint, s; ``inf`` if never.
    """

    trajectory: Trajectory
    leg: jax.Array
    arrival: jax.Array


class TrackRun(NamedTuple):
    """A run after a moving reference (leading batch axes first).

    Attributes:
        trajectory: the ``Trajectory`` of the run (``steps + 1`` poses).
        error: ``(steps,)`` distance ``r_e`` after each period to the
            reference of that period, cm.
        arrival: ``()`` SPEC §6 arrival time against the moving reference, s.
    """

    trajectory: Trajectory
    error: jax.Array
    arrival: jax.Array


# ---------------------------------------------------------------- single robot


def _chain_single(spec, params, init, robot, dt, options: Options) -> ChainRun:
    """Scan one robot through its waypoints; ``spec = (waypoints (K, 3), tolerances (4,))``."""
    waypoints, tolerances = spec
    n_legs = waypoints.shape[0]
    pass_r, pass_theta, final_r, final_theta = (tolerances[i] for i in range(4))
    dtype = waypoints.dtype

    def body(carry, k):
        state, leg, arrival, run_start = carry
        target = waypoints[leg]
        state, out = simulation.closed_loop_step(state, target, params, robot, dt, options)
        last = leg == n_legs - 1
        tol_r = jnp.where(last, final_r, pass_r)
        tol_theta = jnp.where(last, final_theta, pass_theta)
        ok = metrics.arrived(state.pose, target, tol_r=tol_r, tol_theta=tol_theta)
        reached = ok & ~last
        arrival = jnp.where(
            reached & (jnp.arange(n_legs) == leg), (k + 1).astype(dtype) * dt, arrival
        )
        # On the last leg, remember where the current run of arrived samples began.
        run_start = jnp.where(last & ok, jnp.where(run_start < 0, k, run_start), -1)
        record = (state.pose, out, leg)
        return (state, leg + reached.astype(leg.dtype), arrival, run_start), record

    carry = (
        simulation.initial_state(init),
        jnp.zeros((), jnp.int32),
        jnp.full((n_legs,), jnp.inf, dtype),
        jnp.full((), -1, jnp.int32),
    )
    steps = jnp.arange(options.steps, dtype=jnp.int32)
    (_, _, arrival, run_start), (poses, out, leg) = jax.lax.scan(body, carry, steps)
    settled = jnp.where(run_start >= 0, (run_start + 1).astype(dtype) * dt, jnp.inf)
    arrival = arrival.at[-1].set(settled)
    traj = _as_trajectory(init, poses, out)
    return ChainRun(traj, leg, arrival)


def _track_single(refs, params, init, robot, dt, options: Options) -> TrackRun:
    """Scan one robot after a reference per period, ``refs (steps, 3)``."""
    dtype = refs.dtype

    def body(carry, xs):
        state, run_start = carry
        k, ref = xs
        state, out = simulation.closed_loop_step(state, ref, params, robot, dt, options)
        ok = metrics.arrived(state.pose, ref)
        run_start = jnp.where(ok, jnp.where(run_start < 0, k, run_start), -1)
        error = _distance(state.pose, ref)
        return (state, run_start), (state.pose, out, error)

    carry = (simulation.initial_state(init), jnp.full((), -1, jnp.int32))
    xs = (jnp.arange(options.steps, dtype=jnp.int32), refs)
    (_, run_start), (poses, out, error) = jax.lax.scan(body, carry, xs)
    arrival = jnp.where(run_start >= 0, (run_start + 1).astype(dtype) * dt, jnp.inf)
    return TrackRun(_as_trajectory(init, poses, out), error, arrival)


def _distance(pose: jax.Array, ref: jax.Array) -> jax.Array:
    """Return the distance between the positions of two poses, cm (NaN-safe at 0)."""
    d_sq = (ref[..., 0] - pose[..., 0]) ** 2 + (ref[..., 1] - pose[..., 1]) ** 2
    positive = d_sq > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, d_sq, 1.0)), 0.0)


def _as_trajectory(init, poses, out) -> Trajectory:
    poses = jnp.concatenate([init[None], poses], axis=0)
    return Trajectory(poses, out.v, out.omega, out.region, out.wheel_speeds, out.distance)


_chain_jit = simulation.EntryJit(_chain_single, static_argnames=("options",))
_batch_chain_jit = simulation.EntryJit(
    simulation.batched(_chain_single), static_argnames=("options",)
)
_track_jit = simulation.EntryJit(_track_single, static_argnames=("options",))
_batch_track_jit = simulation.EntryJit(
    simulation.batched(_track_single), static_argnames=("options",)
)


# ---------------------------------------------------------------- boundary checks


def _pose_array(name: str, value: Any, ndim: int, what: str) -> np.ndarray:
    """Return ``value`` as float poses of ``ndim`` dims, last axis 3, finite."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be numbers [x cm, y cm, theta rad]: {err}") from err
    if arr.ndim != ndim or arr.shape[-1] != 3 or 0 in arr.shape:
        raise ValueError(f"{name} has shape {arr.shape}; allowed: {what} [x cm, y cm, theta rad]")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} has a non-finite value; allowed: finite numbers")
    return arr


def check_tolerance(name: str, value: Any, *, upper: float, inclusive: bool) -> float:
    """Return a tolerance as a float after checking its range (rad or cm)."""
    try:
        tol = float(value)
    except (TypeError, ValueError):
        tol = float("nan")
    below = tol <= upper if inclusive else tol < upper
    if not (math.isfinite(tol) and tol > 0 and below):
        bound = ("<= " if inclusive else "< ") + (f"{upper:g}" if upper != math.pi / 2 else "pi/2")
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: 0 < {name} {bound}")
    return tol


def _tolerances(tol_r, tol_theta, pass_tol_r, pass_tol_theta) -> np.ndarray:
    tol_r = check_tolerance("tol_r", tol_r, upper=math.inf, inclusive=False)
    tol_theta = check_tolerance("tol_theta", tol_theta, upper=math.pi / 2, inclusive=False)
    pass_r = tol_r if pass_tol_r is None else pass_tol_r
    pass_theta = tol_theta if pass_tol_theta is None else pass_tol_theta
    # π/2 is allowed for passing through: |θ̄_e| ≤ π/2 always holds, heading ignored.
    pass_r = check_tolerance("pass_tol_r", pass_r, upper=math.inf, inclusive=False)
    pass_theta = check_tolerance("pass_tol_theta", pass_theta, upper=math.pi / 2, inclusive=True)
    return np.array([pass_r, pass_theta, tol_r, tol_theta])


def _options(steps, velocity, controller, substeps, wheel_limit) -> Options:
    return simulation.make_options(
        steps=steps,
        velocity=velocity,
        controller=controller,
        substeps=substeps,
        wheel_limit=wheel_limit,
    )


def _prepared(params, init, robot, dt, options, n: int | None):
    """Check params, init, robot and dt as ``simulation.prepare`` does; ``n`` for a batch."""
    if n is not None and np.ndim(init) == 2 and np.shape(init)[0] != n:
        raise ValueError(f"init has {np.shape(init)[0]} rows; allowed: {n}, one per run")
    # A stand-in reference: the real ones are checked by the caller, and its
    # batch size is the one every batched argument must share.
    dummy = np.zeros((3,) if n is None else (n, 3))
    _, params, init, robot, dt = simulation.prepare(
        dummy, params, init, robot, dt, options, batch=False if n is None else None
    )
    return params, init, robot, dt


# ---------------------------------------------------------------- entry points


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
    substeps: int = simulation.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> ChainRun:
    """Drive one robot through ``waypoints`` in order, switching on arrival.

    Args:
        waypoints: ``(K, 3)`` poses ``[x cm, y cm, θ rad]``, visited in order.
        params: the controller's parameters (its defaults if ``None``).
        init: ``(3,)`` initial pose.
        dt: control period, s.
        steps: control periods in all (static).
        robot: robot parameters; default ``Robot()``.
        velocity: ``"ideal"`` or ``"nonideal"`` (static).
        controller: a ``Controller`` or its registered name (static).
        tol_r: arrival distance at the last waypoint, cm (SPEC §6: 1).
        tol_theta: arrival folded-heading error at the last waypoint, rad,
            ``< π/2`` (SPEC §6: 5°).
        pass_tol_r: distance at which an intermediate waypoint counts as
            reached, cm; default ``tol_r``.
        pass_tol_theta: heading tolerance there, rad, ``≤ π/2`` (``π/2``
            ignores the heading); default ``tol_theta``.
        substeps: inner steps of the non-ideal loop (static).
        wheel_limit: ``"clip"`` or ``"scale"``, non-ideal loop (static).

    Returns:
        A ``ChainRun``; ``arrival`` has one entry per waypoint.

    Raises:
        ValueError: for misshapen or non-finite poses, bad tolerances, or any
            bad option or parameter (as ``rollout``).
    """
    wp = _pose_array("waypoints", waypoints, 2, "(K, 3)")
    tol = _tolerances(tol_r, tol_theta, pass_tol_r, pass_tol_theta)
    options = _options(steps, velocity, controller, substeps, wheel_limit)
    params, init, robot, dt = _prepared(params, init, robot, dt, options, None)
    dtype = simulation.float_dtype()
    spec = (jnp.asarray(wp, dtype), jnp.asarray(tol, dtype))
    return _chain_jit(spec, params, init, robot, dt, options=options)


def batch_chain_rollout(
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
    substeps: int = simulation.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> ChainRun:
    """Run ``chain_rollout`` for a batch of ``N`` robots in one call.

    Args:
        waypoints: ``(N, K, 3)`` one chain per robot, or ``(K, 3)`` shared when
            ``init`` is ``(N, 3)``.
        init: ``(3,)`` shared or ``(N, 3)`` initial poses.
        (the rest as ``chain_rollout``; ``params`` leaves may have shape ``(N,)``.)

    Returns:
        A ``ChainRun`` whose fields have a leading axis ``N``.
    """
    if np.ndim(waypoints) == 2:
        wp = _pose_array("waypoints", waypoints, 2, "(K, 3)")
        if np.ndim(init) != 2:
            raise ValueError(
                f"waypoints has shape {wp.shape} and init has shape {np.shape(init)}; "
                "allowed: waypoints (N, K, 3), or (K, 3) with init (N, 3)"
            )
        wp = np.broadcast_to(wp, (np.shape(init)[0], *wp.shape))
    wp = _pose_array("waypoints", wp, 3, "(N, K, 3)")
    tol = _tolerances(tol_r, tol_theta, pass_tol_r, pass_tol_theta)
    options = _options(steps, velocity, controller, substeps, wheel_limit)
    params, init, robot, dt = _prepared(params, init, robot, dt, options, wp.shape[0])
    dtype = simulation.float_dtype()
    spec = (jnp.asarray(wp, dtype), jnp.asarray(tol, dtype))
    return _batch_chain_jit(spec, params, init, robot, dt, options=options)


def track_rollout(
    refs: Any,
    params: Any = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    robot: Robot | None = None,
    velocity: str = "ideal",
    controller: Any = controllers.SHIM_SUNG,
    substeps: int = simulation.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> TrackRun:
    """Drive one robot after a moving reference, one reference per period.

    Args:
        refs: ``(steps, 3)`` reference of each control period; ``steps`` is
            its length.
        (the rest as ``chain_rollout``.)

    Returns:
        A ``TrackRun``.
    """
    arr = _pose_array("refs", refs, 2, "(steps, 3)")
    options = _options(arr.shape[0], velocity, controller, substeps, wheel_limit)
    params, init, robot, dt = _prepared(params, init, robot, dt, options, None)
    return _track_jit(jnp.asarray(arr, init.dtype), params, init, robot, dt, options=options)


def batch_track_rollout(
    refs: Any,
    params: Any = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    robot: Robot | None = None,
    velocity: str = "ideal",
    controller: Any = controllers.SHIM_SUNG,
    substeps: int = simulation.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
) -> TrackRun:
    """Run ``track_rollout`` for ``N`` robots: ``refs (N, steps, 3)``, ``init (3,)`` or ``(N, 3)``.

    Returns:
        A ``TrackRun`` whose fields have a leading axis ``N``.
    """
    arr = _pose_array("refs", refs, 3, "(N, steps, 3)")
    options = _options(arr.shape[1], velocity, controller, substeps, wheel_limit)
    params, init, robot, dt = _prepared(params, init, robot, dt, options, arr.shape[0])
    return _batch_track_jit(jnp.asarray(arr, init.dtype), params, init, robot, dt, options=options)


# ---------------------------------------------------------------- demo


def soccer_waypoints() -> np.ndarray:
    """Return ``SOCCER_WAYPOINTS_DEG`` as ``(K, 3)`` in cm, cm, rad."""
    wp = np.array(SOCCER_WAYPOINTS_DEG)
    wp[:, 2] = np.radians(wp[:, 2])
    return wp


def soccer_demo(
    out_dir: str | Path,
    *,
    controller_names: Sequence[str] | None = None,
    velocity: str = "ideal",
    steps: int = 450,
    pass_tol_r: float = 5.0,
    pass_tol_theta: float = math.radians(30.0),
) -> list[dict[str, Any]]:
    """Run the soccer-like sequence for each controller; write a figure and tables.

    Each controller runs the chain twice: stopping at every waypoint (SPEC §6
    tolerances throughout) and passing through the intermediate ones
    (``pass_tol_r``, ``pass_tol_theta``). Writes ``soccer.png`` (paths),
    ``soccer.md`` and ``soccer.json`` (arrival time per leg) into ``out_dir``.
    Computed in float64 (see ``maps.evaluate_poses`` why).

    Returns:
        One row per controller and mode: arrival time at each waypoint, s, and
        the path length and zig-zag count of the run.
    """
    with jax.enable_x64(True):
        return _soccer_demo(out_dir, controller_names, velocity, steps, pass_tol_r, pass_tol_theta)


def _soccer_demo(out_dir, controller_names, velocity, steps, pass_tol_r, pass_tol_theta):
    from wmr_jax.paper import markdown_table
    from wmr_jax.plotting import plot_paths, plt

    out = Path(out_dir)
    names = list(controller_names) if controller_names else registered_names()
    wp = soccer_waypoints()
    rows: list[dict[str, Any]] = []
    runs = []
    for name in names:
        for mode, p_r, p_theta in (
            ("stop", None, None),
            ("pass", pass_tol_r, pass_tol_theta),
        ):
            run = chain_rollout(
                wp,
                controller=name,
                velocity=velocity,
                steps=steps,
                pass_tol_r=p_r,
                pass_tol_theta=p_theta,
            )
            arrival = np.asarray(run.arrival, dtype=float)
            row = {"controller": name, "mode": mode}
            row.update({f"leg {i + 1} s": float(t) for i, t in enumerate(arrival)})
            legs = np.diff(np.concatenate([[0.0], arrival]))
            row["slowest leg s"] = float(np.max(legs))
            row["path cm"] = float(np.sum(np.asarray(run.trajectory.distance)))
            row["zigzag"] = int(metrics.zigzag_count(run.trajectory))
            rows.append(row)
            runs.append((name, mode, run))

    cols = len(names)
    fig, axes = plt.subplots(2, cols, figsize=(4.2 * cols, 8.0), squeeze=False)
    for (name, mode, run), ax in zip(runs, axes.T.flat, strict=True):
        plot_paths(ax, [np.asarray(run.trajectory.poses)], wp, color="tab:blue")
        for i, (x, y, _) in enumerate(wp):
            ax.annotate(str(i + 1), (x, y), textcoords="offset points", xytext=(6, 6))
        done = np.isfinite(np.asarray(run.arrival)).sum()
        ax.set_title(f"{name}, {mode} ({done}/{len(wp)} reached)", fontsize=9)
    fig.suptitle(
        f"Soccer-like sequence ({velocity} loop): stop at each waypoint (top), "
        f"pass through within {pass_tol_r:g} cm / {math.degrees(pass_tol_theta):g}° (bottom)",
        fontsize=10,
    )
    fig.tight_layout()
    save_figure(fig, out / "soccer.png", dpi=110)
    plt.close(fig)
    meta = {
        "waypoints_deg": [list(p) for p in SOCCER_WAYPOINTS_DEG],
        "velocity": velocity,
        "dt_s": DEFAULT_DT,
        "steps": steps,
        "pass_tol_r_cm": pass_tol_r,
        "pass_tol_theta_deg": math.degrees(pass_tol_theta),
        "rows": rows,
    }
    atomic_write_json(out / "soccer.json", meta)
    atomic_write_text(
        out / "soccer.md",
        "Arrival time at each waypoint (s from the start; inf: not reached)\n\n"
        + markdown_table(rows),
    )
    return rows


def registered_names() -> list[str]:
    """Return the names of every registered controller, Shim–Sung first."""
    # The registry has no public listing; reading it keeps this in step with
    # every controller registered at import time.
    names = sorted(controllers._REGISTRY)
    names.remove(controllers.SHIM_SUNG.name)
    return [controllers.SHIM_SUNG.name, *names]


# ---------------------------------------------------------------- command line


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Add the flags of ``wmr-jax waypoints`` to ``parser``."""
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument(
        "--controller",
        nargs="+",
        action="extend",
        default=None,
        metavar="NAME",
        help="controllers to run (repeatable; default: every registered one)",
    )
    parser.add_argument("--velocity", default="ideal", help="velocity loop: ideal or nonideal")
    parser.add_argument("--steps", type=int, default=450, help="control periods (default 450)")
    parser.add_argument(
        "--pass-tol", type=float, default=5.0, help="pass-through distance, cm (default 5)"
    )
    parser.add_argument(
        "--pass-tol-deg",
        type=float,
        default=30.0,
        help="pass-through heading tolerance, degrees, <= 90 (default 30)",
    )
    parser.set_defaults(func=run_cli)


def check_controllers(names: Sequence[str] | None) -> list[str]:
    """Return the controller names to run, checking each is registered."""
    if not names:
        return registered_names()
    known = registered_names()
    for name in names:
        if name not in known:
            raise ValueError(f"--controller = {name!r} is not known; allowed: {known}")
    return list(dict.fromkeys(names))


def check_velocity(value: str) -> str:
    """Return ``value`` if it names a velocity loop."""
    if value not in simulation.VELOCITY_LOOPS:
        raise ValueError(
            f"--velocity = {value!r} is not allowed; allowed: {list(simulation.VELOCITY_LOOPS)}"
        )
    return value


def run_cli(args: argparse.Namespace) -> int:
    """Run ``wmr-jax waypoints``; return the exit status."""
    names = check_controllers(args.controller)
    velocity = check_velocity(args.velocity)
    if args.steps < 1:
        raise ValueError(f"--steps = {args.steps} is not allowed; allowed: an integer >= 1")
    if not (math.isfinite(args.pass_tol) and args.pass_tol > 0):
        raise ValueError(f"--pass-tol = {args.pass_tol} is not allowed; allowed: a number > 0 cm")
    if not (math.isfinite(args.pass_tol_deg) and 0 < args.pass_tol_deg <= 90):
        raise ValueError(
            f"--pass-tol-deg = {args.pass_tol_deg} is not allowed; allowed: 0 < degrees <= 90"
        )
    rows = soccer_demo(
        args.out,
        controller_names=names,
        velocity=velocity,
        steps=args.steps,
        pass_tol_r=args.pass_tol,
        pass_tol_theta=math.radians(args.pass_tol_deg),
    )
    from wmr_jax.paper import markdown_table

    print(f"soccer-like sequence -> {Path(args.out)}/soccer.png, soccer.md, soccer.json")
    print(markdown_table(rows), end="")
    return 0
