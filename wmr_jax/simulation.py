"""Closed-loop rollouts: one pose in a ``lax.scan``, batches by one ``vmap``.

The public functions check their inputs in plain Python (SPEC §3 ranges,
shapes, finiteness, options) and then call a jitted core whose static
arguments are the shape-deciding options. Calling them again with the same
shapes and options reuses the compiled code.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax import dynamics, law
from wmr_jax.params import Gains, Robot, check_feasible, validate_gains, validate_robot

__all__ = [
    "VELOCITY_LOOPS",
    "Trajectory",
    "batch_rollout",
    "final_poses",
    "rollout",
]

VELOCITY_LOOPS = ("ideal",)

DEFAULT_DT = 0.033
DEFAULT_STEPS = 150


class Trajectory(NamedTuple):
    """A closed-loop run, sampled once per control period.

    Leading batch axes, if any, come first in every field.

    Attributes:
        poses: ``(steps + 1, 3)`` poses ``[x cm, y cm, θ rad]``, the initial one first.
        v: ``(steps,)`` linear-velocity command applied over each period, cm/s.
        omega: ``(steps,)`` angular-velocity command, rad/s.
        region: ``(steps,)`` int32 region label 0–3 of the command (SPEC §3).
        wheel_speeds: ``(steps, 2)`` rim speeds ``[v_L, v_R]`` of the robot
            at the end of each period, cm/s.
        distance: ``(steps,)`` distance the centre travelled over each period, cm.
    """

    poses: jax.Array
    v: jax.Array
    omega: jax.Array
    region: jax.Array
    wheel_speeds: jax.Array
    distance: jax.Array


# ---------------------------------------------------------------- single pose


def _initial_state(init: jax.Array) -> dynamics.RobotState:
    zeros = jnp.zeros((2,), init.dtype)
    return dynamics.RobotState(pose=init, velocity=zeros, integral=zeros)


def _closed_loop_step(
    state: dynamics.RobotState,
    ref: jax.Array,
    gains: Gains,
    robot: Robot,
    dt: jax.Array,
    *,
    velocity: str,
    temperature: float | None,
):
    """Sample the controller at ``state`` and move the robot over one ``dt``."""
    err = law.polar_error(state.pose, ref)
    v, omega = law.commands(err, gains, temperature=temperature)
    if velocity == "ideal":
        pose = dynamics.arc_step(state.pose, v, omega, dt)
        new_state = dynamics.RobotState(pose, jnp.stack([v, omega]), state.integral)
        distance = jnp.abs(v) * dt
    else:  # pragma: no cover - the option is checked at the boundary
        raise ValueError(velocity)
    rims = law.wheel_speeds(new_state.velocity[0], new_state.velocity[1], robot)
    return new_state, (v, omega, law.region_label(err, gains), rims, distance)


def _simulate(
    ref, gains, init, robot, dt, *, steps, velocity, temperature, record
) -> tuple[dynamics.RobotState, Any]:
    def body(state, _):
        new_state, outputs = _closed_loop_step(
            state, ref, gains, robot, dt, velocity=velocity, temperature=temperature
        )
        if record:
            return new_state, (new_state.pose, *outputs)
        return new_state, None

    return jax.lax.scan(body, _initial_state(init), None, length=steps)


def _trajectory(ref, gains, init, robot, dt, *, steps, velocity, temperature) -> Trajectory:
    _, (poses, v, omega, region, rims, distance) = _simulate(
        ref,
        gains,
        init,
        robot,
        dt,
        steps=steps,
        velocity=velocity,
        temperature=temperature,
        record=True,
    )
    poses = jnp.concatenate([init[None], poses], axis=0)
    return Trajectory(poses, v, omega, region, rims, distance)


def _final_pose(ref, gains, init, robot, dt, *, steps, velocity, temperature) -> jax.Array:
    final, _ = _simulate(
        ref,
        gains,
        init,
        robot,
        dt,
        steps=steps,
        velocity=velocity,
        temperature=temperature,
        record=False,
    )
    return final.pose


# ---------------------------------------------------------------- batching


def _batch_axes(tree: Any, single_ndim: int) -> Any:
    """Map each leaf to 0 if it carries a leading batch axis, else ``None``."""
    return jax.tree.map(lambda leaf: 0 if jnp.ndim(leaf) > single_ndim else None, tree)


def batched(single: Callable) -> Callable:
    """Lift ``single(ref, gains, init, robot, dt, **options)`` to batched inputs.

    A leading axis on ``ref``/``init`` (beyond ``(3,)``) or on any leaf of
    ``gains``/``robot`` (beyond a scalar) is mapped over; the others are
    shared. This is the one place where ``vmap`` is applied.
    """

    def run(ref, gains, init, robot, dt, **options):
        in_axes = (
            _batch_axes(ref, 1),
            _batch_axes(gains, 0),
            _batch_axes(init, 1),
            _batch_axes(robot, 0),
            None,
        )
        return jax.vmap(lambda *a: single(*a, **options), in_axes=in_axes)(
            ref, gains, init, robot, dt
        )

    return run


_STATIC = ("steps", "velocity", "temperature")
_rollout_jit = jax.jit(_trajectory, static_argnames=_STATIC)
_batch_rollout_jit = jax.jit(batched(_trajectory), static_argnames=_STATIC)
_final_poses_jit = jax.jit(batched(_final_pose), static_argnames=_STATIC)


# ---------------------------------------------------------------- boundary checks


def float_dtype() -> Any:
    """Return JAX's default float dtype (float64 when ``jax_enable_x64`` is on)."""
    return jnp.result_type(float)


def as_poses(name: str, value: Any, *, batch: bool | None) -> jax.Array:
    """Return ``value`` as a float pose array after checking shape and finiteness.

    Args:
        name: the argument's name, for error messages.
        value: a pose ``(3,)`` or, where ``batch`` allows, a batch ``(N, 3)``.
        batch: ``False`` for a single pose, ``True`` for ``(N, 3)``, ``None`` for either.

    Raises:
        ValueError: naming the argument, its shape or bad value, and what is allowed.
    """
    if isinstance(value, jax.core.Tracer):
        return value
    if isinstance(value, jax.Array):
        arr = value.astype(float_dtype()) if value.dtype != float_dtype() else value
        host = None
    else:
        try:
            host = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{name} must be numbers [x cm, y cm, theta rad]: {err}") from err
        arr = None
    shape = tuple((arr if arr is not None else host).shape)
    allowed = {False: "(3,)", True: "(N, 3) with N >= 1", None: "(3,) or (N, 3)"}[batch]
    ok_ndim = {False: (1,), True: (2,), None: (1, 2)}[batch]
    if len(shape) not in ok_ndim or shape[-1] != 3 or (len(shape) == 2 and shape[0] == 0):
        raise ValueError(f"{name} has shape {shape}; allowed: {allowed} [x cm, y cm, theta rad]")
    finite = bool(jnp.all(jnp.isfinite(arr))) if arr is not None else bool(np.isfinite(host).all())
    if not finite:
        flat = np.asarray(arr if arr is not None else host).reshape(-1, 3)
        row = int(np.flatnonzero(~np.isfinite(flat).all(axis=1))[0])
        where = f"{name}[{row}]" if len(shape) == 2 else name
        raise ValueError(f"{where} = {flat[row].tolist()} is not finite; allowed: finite numbers")
    return arr if arr is not None else jnp.asarray(host, dtype=float_dtype())


def _check_options(dt: Any, steps: Any, velocity: Any) -> float:
    if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool) or steps < 1:
        raise ValueError(f"steps = {steps!r} is not allowed; allowed: an integer >= 1")
    if velocity not in VELOCITY_LOOPS:
        raise ValueError(f"velocity = {velocity!r} is not allowed; allowed: {VELOCITY_LOOPS}")
    try:
        dt_value = float(dt)
    except (TypeError, ValueError) as err:
        raise ValueError(f"dt = {dt!r} is not allowed; allowed: a number > 0 s") from err
    if not (math.isfinite(dt_value) and dt_value > 0):
        raise ValueError(f"dt = {dt!r} is not allowed; allowed: a finite number > 0 s")
    return dt_value


def _check_temperature(temperature: Any) -> float | None:
    if temperature is None:
        return None
    value = float(temperature)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(
            f"temperature = {temperature!r} is not allowed; allowed: None or a number > 0"
        )
    return value


def _batch_size(refs: jax.Array, gains: Gains, init: jax.Array, robot: Robot) -> int:
    sizes = {}
    if refs.ndim == 2:
        sizes["refs"] = refs.shape[0]
    if init.ndim == 2:
        sizes["init"] = init.shape[0]
    for prefix, tree in (("gains", gains), ("robot", robot)):
        for key, leaf in jax.tree_util.tree_leaves_with_path(tree):
            if jnp.ndim(leaf) == 1:
                sizes[f"{prefix}{jax.tree_util.keystr(key)}"] = jnp.shape(leaf)[0]
    if not sizes:
        raise ValueError(
            "refs has shape (3,) and nothing else is batched; allowed: refs (N, 3), "
            "init (N, 3) or gains/robot fields of shape (N,)"
        )
    if len(set(sizes.values())) > 1:
        listed = ", ".join(f"{k}: {v}" for k, v in sizes.items())
        raise ValueError(f"batch sizes differ ({listed}); allowed: one common N")
    return next(iter(sizes.values()))


def as_float_tree(tree: Any) -> Any:
    """Convert every concrete leaf to an array of the default float dtype.

    Python floats, NumPy scalars and arrays then all reach ``jit`` with one
    signature, so changing a gain's type does not recompile.
    """
    dtype = float_dtype()
    return jax.tree.map(
        lambda leaf: leaf if isinstance(leaf, jax.core.Tracer) else jnp.asarray(leaf, dtype), tree
    )


def prepare(refs, gains, init, robot, dt, steps, velocity, *, batch: bool | None):
    """Check and convert every argument of a rollout entry point (before tracing)."""
    gains = as_float_tree(validate_gains(Gains() if gains is None else gains))
    robot = as_float_tree(validate_robot(Robot() if robot is None else robot))
    dt = _check_options(dt, steps, velocity)
    refs = as_poses("refs" if batch is not False else "ref", refs, batch=batch)
    init = as_poses("init", init, batch=None if batch is not False else False)
    if batch is not False:
        _batch_size(refs, gains, init, robot)
    leaves = jax.tree.leaves((gains, robot))
    if not any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
        check_feasible(gains, robot, warn=True, stacklevel=4)  # legal, but warned (SPEC §3, Fig. 8)
    return refs, gains, init, robot, jnp.asarray(dt, dtype=float_dtype())


# ---------------------------------------------------------------- entry points


def rollout(
    ref: Any,
    gains: Gains | None = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    steps: int = DEFAULT_STEPS,
    robot: Robot | None = None,
    velocity: str = "ideal",
    temperature: float | None = None,
) -> Trajectory:
    """Drive the robot from ``init`` towards ``ref`` and record the whole run.

    Args:
        ref: ``(3,)`` reference pose ``[x cm, y cm, θ rad]``.
        gains: controller gains; default ``Gains()`` (the paper's Fig. 7).
        init: ``(3,)`` initial pose.
        dt: control period in s; commands are held over it (SPEC §4).
        steps: number of control periods (static).
        robot: robot parameters; default ``Robot()``.
        velocity: velocity loop between command and robot (static): ``"ideal"``.
        temperature: ``None`` for the paper's law, or a smooth relaxation
            (see ``wmr_jax.law``).

    Returns:
        A ``Trajectory`` with ``steps + 1`` poses.

    Raises:
        ValueError: for out-of-range gains, non-finite or misshapen poses,
            ``steps < 1``, ``dt ≤ 0`` or an unknown ``velocity``.
    """
    ref, gains, init, robot, dt = prepare(ref, gains, init, robot, dt, steps, velocity, batch=False)
    temperature = _check_temperature(temperature)
    return _rollout_jit(
        ref, gains, init, robot, dt, steps=steps, velocity=velocity, temperature=temperature
    )


def batch_rollout(
    refs: Any,
    gains: Gains | None = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    steps: int = DEFAULT_STEPS,
    robot: Robot | None = None,
    velocity: str = "ideal",
    temperature: float | None = None,
) -> Trajectory:
    """Run ``rollout`` for a batch, in one call.

    Any of ``refs (N, 3)``, ``init (N, 3)`` and the leaves of ``gains`` or
    ``robot`` with shape ``(N,)`` are mapped over together; the rest are
    shared by every run. Options as for ``rollout``.

    Returns:
        A ``Trajectory`` whose fields have a leading axis ``N``.
    """
    refs, gains, init, robot, dt = prepare(
        refs, gains, init, robot, dt, steps, velocity, batch=None
    )
    temperature = _check_temperature(temperature)
    return _batch_rollout_jit(
        refs, gains, init, robot, dt, steps=steps, velocity=velocity, temperature=temperature
    )


def final_poses(
    refs: Any,
    gains: Gains | None = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = DEFAULT_DT,
    steps: int = DEFAULT_STEPS,
    robot: Robot | None = None,
    velocity: str = "ideal",
    temperature: float | None = None,
) -> jax.Array:
    """Return only the last pose of each run, ``(N, 3)``; memory O(N), not O(N·steps).

    Batching and options as for ``batch_rollout``.
    """
    refs, gains, init, robot, dt = prepare(
        refs, gains, init, robot, dt, steps, velocity, batch=None
    )
    temperature = _check_temperature(temperature)
    return _final_poses_jit(
        refs, gains, init, robot, dt, steps=steps, velocity=velocity, temperature=temperature
    )
