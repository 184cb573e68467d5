"""The ``wmr_jax.dynamics`` functions as users call them: inputs checked first.

The rollouts call the functions of ``dynamics`` and ``velocity_loop``
directly, inside their own traces, on values the entry points have already
checked. Called by hand with concrete values, the same functions would read a
``(2,)`` pose as ``(3,)`` (JAX clamps an index past the end), run a negative
period or an unstable wheel loop, or give the fast sine of ``3e9`` rad as
``9.7e11``. The versions here check their concrete arguments (naming the
argument, its value and what is allowed) and then call the same function;
traced arguments pass unchecked, as everywhere in the package.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import dynamics, loops, velocity_loop
from wmr_jax._src.checks import (
    as_poses,
    check_dt,
    check_substeps,
    float_dtype,
    is_traced,
    position_limit,
    real_array,
    require,
    require_unbatched,
)
from wmr_jax._src.params import Robot, validate_robot

__all__ = [
    "advance",
    "arc_step",
    "body_acceleration",
    "check_stability",
    "initial_state",
    "inertia",
    "kinetic_energy",
    "limit_wheels",
    "sin_cos",
    "sinc",
    "wheel_torques",
]

# The fast sine and cosine are accurate up to about this many radians
# (docstring of ``dynamics.sin_cos``); angles beyond are reduced on the host.
_REDUCE_ABOVE = 1e4


def _real(name: str, value: Any, *, finite: bool = True, last: int | None = None) -> Any:
    """Check that ``value`` holds real numbers, optionally ``(..., last)``; tracers pass.

    Returns a NumPy array in the value's own float dtype (bfloat16 and float16
    included), or in the compute dtype for integers; a tracer as it is.
    """
    if is_traced(value):
        return value
    dtype = getattr(value, "dtype", None)
    own_float = dtype is not None and jnp.issubdtype(dtype, jnp.floating)
    if own_float:
        arr = np.asarray(value, dtype=dtype)
    else:
        shape = "" if last is None else f" of shape (..., {last})"
        arr = real_array(name, value, f"real numbers{shape}").astype(float_dtype())
    if last is not None and (arr.ndim == 0 or arr.shape[-1] != last):
        raise ValueError(f"{name} has shape {arr.shape}; allowed: (..., {last})")
    if finite:
        require(name, arr, np.isfinite(arr.astype(np.float64)), "finite numbers")
    if isinstance(value, (int, float)):
        return value  # a Python number stays weakly typed: it does not widen float32 arrays
    return arr


def _robot(robot: Any, name: str = "robot") -> Robot:
    """Check a robot's concrete fields (traced ones pass)."""
    if not isinstance(robot, Robot):
        raise ValueError(f"{name} = {robot!r} is not allowed; allowed: a wmr_jax.Robot")
    return validate_robot(robot)


def _batch_with_robot(robot: Robot, name: str, batch: tuple[int, ...], what: str) -> None:
    """Check that a batched robot's fields broadcast against ``what``'s batch shape."""
    if is_traced(robot):
        return
    fields = {
        f"{name}.{field}": _shape(value)
        for field, value in vars(robot).items()
        if _shape(value) and not is_traced(value)
    }
    if fields:
        _broadcast({f"{what}[..., 0]": batch, **fields})


def _array(value: Any) -> np.ndarray:
    """A checked value as a NumPy array (a Python number in the compute dtype)."""
    return value if isinstance(value, np.ndarray) else np.asarray(value, float_dtype())


def _shape(value: Any) -> tuple[int, ...]:
    return tuple(np.shape(value))


def _broadcast(shapes: dict[str, tuple[int, ...]]) -> None:
    try:
        np.broadcast_shapes(*shapes.values())
    except ValueError:
        listed = ", ".join(f"{name} {shape}" for name, shape in shapes.items())
        raise ValueError(f"shapes that do not broadcast: {listed}; allowed: ones that do") from None


def _reduced(angle: np.ndarray) -> jax.Array:
    """Angles beyond ``_REDUCE_ABOVE`` rad reduced to ``[−π, π]`` on the host.

    Through NumPy's own sine and cosine, which reduce any float64 angle
    accurately (tested up to 1e20 rad): a remainder by the float64 nearest
    2π would be off by about ``angle · 4e-17`` rad.
    """
    wide = angle.astype(np.float64)
    with np.errstate(invalid="ignore"):  # ±inf gives NaN, as sin and cos of it do
        wrapped = np.arctan2(np.sin(wide), np.cos(wide))
    return jnp.asarray(np.where(np.abs(wide) > _REDUCE_ABOVE, wrapped, wide), angle.dtype)


def _wraps(raw: Callable) -> Callable[[Callable], Callable]:
    """Give a checked version the name and docstring of the function it checks."""

    def decorate(checked: Callable) -> Callable:
        checked = functools.wraps(raw)(checked)
        checked.__doc__ = (raw.__doc__ or "") + (
            "\n\n    Concrete arguments are checked first (``ValueError`` naming the "
            "argument); traced ones are not.\n"
        )
        del checked.__wrapped__  # inspect.signature: the checked one's
        return checked

    return decorate


@_wraps(dynamics.sin_cos)
def sin_cos(angle: Any) -> tuple[jax.Array, jax.Array]:
    if is_traced(angle):
        return dynamics.sin_cos(angle)
    return dynamics.sin_cos(_reduced(_array(_real("angle", angle, finite=False))))


@_wraps(dynamics.sinc)
def sinc(u: Any) -> jax.Array:
    if is_traced(u):
        return dynamics.sinc(u)
    u = _array(_real("u", u, finite=False))
    return dynamics._sinc_of(jnp.asarray(u), dynamics.sin_cos(_reduced(u))[1])


@_wraps(dynamics.arc_step)
def arc_step(pose: Any, v: Any, omega: Any, h: Any) -> jax.Array:
    if not is_traced(pose):
        arr = _real("pose", pose, finite=False, last=3)
        if arr.size:  # finite, within range, huge headings reduced; in its own dtype
            checked = as_poses("pose", arr.reshape(-1, 3), batch=True)
            pose = np.asarray(checked, dtype=arr.dtype).reshape(arr.shape)
        else:
            pose = arr
    v, omega, h = _real("v", v), _real("omega", omega), _real("h", h)
    for name, value in (("pose", pose), ("v", v), ("omega", omega), ("h", h)):
        dtype = getattr(value, "dtype", None)  # the step rotates by a complex product
        if dtype is not None and np.dtype(dtype) in (np.float16, jnp.bfloat16):
            raise ValueError(
                f"{name} is an array of {np.dtype(dtype).name}; allowed: float32 or float64"
            )
    if not is_traced(h):
        require("h", np.asarray(h), np.asarray(h) >= 0, "a duration >= 0 s")
    if not is_traced((pose, v, omega, h)):
        shapes = {"pose[..., 0]": _shape(pose)[:-1], "v": _shape(v), "omega": _shape(omega)}
        _broadcast({**shapes, "h": _shape(h)})
        turn = np.abs(np.asarray(omega, np.float64) * np.asarray(h, np.float64))
        require(
            "omega * h", turn, turn <= _REDUCE_ABOVE, f"a turn of at most {_REDUCE_ABOVE:g} rad"
        )
        move, limit = (
            np.abs(np.asarray(v, np.float64) * np.asarray(h, np.float64)),
            position_limit(),
        )
        require("v * h", move, move <= limit, f"a move of at most {limit:.0e} cm")
    return dynamics.arc_step(pose, v, omega, h)


@_wraps(loops.initial_state)
def initial_state(init: Any) -> dynamics.RobotState:
    if is_traced(init):
        return loops.initial_state(init)
    return loops.initial_state(as_poses("init", init, batch=False))


@_wraps(velocity_loop.limit_wheels)
def limit_wheels(velocity: Any, robot: Robot, *, mode: str = "clip") -> jax.Array:
    _check_mode("mode", mode)
    velocity, robot = _real("velocity", velocity, last=2), _robot(robot)
    _batch_with_robot(robot, "robot", _shape(velocity)[:-1], "velocity")
    return velocity_loop.limit_wheels(velocity, robot, mode=mode)


@_wraps(velocity_loop.inertia)
def inertia(robot: Robot) -> tuple[jax.Array, jax.Array]:
    return velocity_loop.inertia(_robot(robot))


@_wraps(velocity_loop.kinetic_energy)
def kinetic_energy(velocity: Any, robot: Robot) -> jax.Array:
    velocity, robot = _real("velocity", velocity, last=2), _robot(robot)
    _batch_with_robot(robot, "robot", _shape(velocity)[:-1], "velocity")
    return velocity_loop.kinetic_energy(velocity, robot)


@_wraps(velocity_loop.body_acceleration)
def body_acceleration(velocity: Any, torques: Any, robot: Robot) -> jax.Array:
    velocity, torques = _real("velocity", velocity, last=2), _real("torques", torques, last=2)
    if not is_traced((velocity, torques)):
        _broadcast({"velocity": _shape(velocity), "torques": _shape(torques)})
    robot = _robot(robot)
    _batch_with_robot(robot, "robot", _shape(velocity)[:-1], "velocity")
    return velocity_loop.body_acceleration(velocity, torques, robot)


@_wraps(velocity_loop.wheel_torques)
def wheel_torques(velocity: Any, target: Any, integral: Any, model: Robot) -> jax.Array:
    arrays = {
        name: _real(name, value, last=2)
        for name, value in (("velocity", velocity), ("target", target), ("integral", integral))
    }
    if not is_traced(tuple(arrays.values())):
        _broadcast({name: _shape(arr) for name, arr in arrays.items()})
    velocity, target, integral = arrays.values()
    model = _robot(model, "model")
    _batch_with_robot(model, "model", _shape(velocity)[:-1], "velocity")
    return velocity_loop.wheel_torques(velocity, target, integral, model)


@_wraps(velocity_loop.check_stability)
def check_stability(robot: Robot, dt: Any, substeps: int) -> None:
    robot = _robot(robot)
    substeps = check_substeps(substeps)
    dt = check_dt(dt)  # a tracer passes, and the check below then skips
    return velocity_loop.check_stability(robot, dt, substeps)


@_wraps(velocity_loop.advance)
def advance(
    state: dynamics.RobotState,
    command: Any,
    robot: Robot,
    dt: Any,
    *,
    substeps: int = velocity_loop.DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
    model: Robot | None = None,
) -> tuple[dynamics.RobotState, jax.Array]:
    _check_mode("wheel_limit", wheel_limit)
    substeps = check_substeps(substeps)
    if not isinstance(state, dynamics.RobotState):
        raise ValueError(
            f"state = {state!r} is not allowed; allowed: a wmr_jax.dynamics.RobotState "
            "(e.g. from initial_state)"
        )
    pose = state.pose if is_traced(state.pose) else as_poses("state.pose", state.pose, batch=False)
    velocity = _real("state.velocity", state.velocity)
    integral = _real("state.integral", state.integral)
    command = _real("command", command)
    limit = position_limit()
    for name, arr, allowed, values in (
        ("state.velocity", velocity, "(2,) [v cm/s, omega rad/s]", "speeds"),
        ("state.integral", integral, "(2,)", "integrals"),
        ("command", command, "(2,) [v cm/s, omega rad/s]", "speeds"),
    ):
        if _shape(arr) != (2,) and not is_traced(arr):
            raise ValueError(f"{name} has shape {_shape(arr)}; allowed: {allowed}")
        if not is_traced(arr):  # far beyond any wheel; their squares would overflow
            wide = np.asarray(arr, np.float64)
            require(name, wide, np.abs(wide) <= limit, f"{values} of magnitude <= {limit:.0e}")
    state = dynamics.RobotState(pose, jnp.asarray(velocity), jnp.asarray(integral))
    one = "one robot (a number per field): advance moves one robot"
    robot = _robot(robot)
    require_unbatched(robot, "robot", one)
    if model is not None:
        model = _robot(model, "model")
        require_unbatched(model, "model", one)
    dt = check_dt(dt)
    velocity_loop.check_stability(robot if model is None else model, dt, substeps)
    return velocity_loop.advance(
        state, command, robot, dt, substeps=substeps, wheel_limit=wheel_limit, model=model
    )


def _check_mode(name: str, mode: Any) -> None:
    if not isinstance(mode, str) or mode not in loops.WHEEL_LIMITS:
        raise ValueError(f"{name} = {mode!r} is not allowed; allowed: {loops.WHEEL_LIMITS}")
