"""The closed loop of one pose as a ``lax.scan``, and the one ``vmap`` that batches it.

``closed_loop_step`` samples the controller and moves the robot over one
control period (``docs/model.md §4``); ``scan_closed_loop`` runs it for a
number of periods, recording the run or folding it into streamed metrics;
``batched`` lifts any single-pose function to batches. The ideal velocity
loop takes a faster, equal route (``_ideal_loop``). Nothing here checks its
inputs: the entry points do that first (``wmr_jax._src.checks``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from wmr_jax._src import dynamics, velocity_loop
from wmr_jax._src.controllers import shim_sung as law
from wmr_jax._src.controllers.base import Controller
from wmr_jax._src.controllers.shim_sung import SHIM_SUNG
from wmr_jax._src.params import Robot

__all__ = [
    "COMPILER_OPTIONS",
    "DEFAULT_STEPS",
    "DEFAULT_SUBSTEPS",
    "EntryJit",
    "Options",
    "StepOutput",
    "VELOCITY_LOOPS",
    "WHEEL_LIMITS",
    "batched",
    "closed_loop_step",
    "initial_state",
    "jit_top_level",
    "scan_closed_loop",
]

VELOCITY_LOOPS = ("ideal", "nonideal")
WHEEL_LIMITS = ("clip", "scale")
DEFAULT_SUBSTEPS = velocity_loop.DEFAULT_SUBSTEPS
DEFAULT_STEPS = 150


# ---------------------------------------------------------------- single pose


@dataclasses.dataclass(frozen=True)
class Options:
    """Shape- and code-deciding options of a rollout: static under ``jit``.

    Attributes:
        steps: number of control periods.
        velocity: ``"ideal"`` or ``"nonideal"`` velocity loop (docs/model.md §4).
        controller: the pose controller (``wmr_jax.controllers.SHIM_SUNG``).
        temperature: ``None`` for the hard law, else its smooth relaxation.
        substeps: inner integration steps per period (non-ideal loop).
        wheel_limit: ``"clip"`` each wheel command at ``±v_max`` or ``"scale"``
            both by one factor, keeping the curvature (non-ideal loop).
    """

    steps: int = DEFAULT_STEPS
    velocity: str = "ideal"
    controller: Controller = SHIM_SUNG
    temperature: float | None = None
    substeps: int = DEFAULT_SUBSTEPS
    wheel_limit: str = "clip"


def initial_state(init: jax.Array) -> dynamics.RobotState:
    """Return the robot at rest at ``init`` ``(3,)``."""
    zeros = jnp.zeros((2,), init.dtype)
    return dynamics.RobotState(pose=init, velocity=zeros, integral=zeros)


class StepOutput(NamedTuple):
    """What one control period reports (one sample of a ``Trajectory``)."""

    v: jax.Array
    omega: jax.Array
    region: jax.Array
    wheel_speeds: jax.Array
    distance: jax.Array


def closed_loop_step(
    state: dynamics.RobotState,
    ref: jax.Array,
    params: Any,
    robot: Robot,
    dt: jax.Array,
    options: Options,
) -> tuple[dynamics.RobotState, StepOutput]:
    """Sample the controller at ``state`` and move the robot over one ``dt`` (docs/model.md §4).

    The single-pose building block of every rollout; scans of other kinds
    (streaming metrics, waypoints) are built from it.
    """
    control = options.controller
    v, omega = control.command(state.pose, ref, params, temperature=options.temperature)
    region = control.region_of(state.pose, ref, params)
    if options.velocity == "ideal":
        pose = dynamics.arc_step(state.pose, v, omega, dt)
        new_state = dynamics.RobotState(pose, jnp.stack([v, omega]), state.integral)
        distance = jnp.abs(v) * dt
    else:
        new_state, distance = velocity_loop.advance(
            state,
            jnp.stack([v, omega]),
            robot,
            dt,
            substeps=options.substeps,
            wheel_limit=options.wheel_limit,
        )
    rims = law.wheel_speeds(new_state.velocity[0], new_state.velocity[1], robot)
    return new_state, StepOutput(v, omega, region, rims, distance)


Fold = Callable[[Any, jax.Array, StepOutput], Any]


def scan_closed_loop(
    ref: jax.Array,
    params: Any,
    init: jax.Array,
    robot: Robot,
    dt: jax.Array,
    options: Options,
    *,
    fold: Fold | None = None,
    acc: Any = None,
    record: bool = False,
) -> tuple[jax.Array, Any, Any]:
    """Run ``options.steps`` control periods for one pose, streaming or recording.

    The same closed loop as scanning ``closed_loop_step``; the ideal velocity
    loop takes a faster route to it (see ``_ideal_loop``).

    Args:
        ref: ``(3,)`` reference pose.
        params: the controller's parameters.
        init: ``(3,)`` initial pose.
        robot: robot parameters.
        dt: control period, s.
        options: static rollout options.
        fold: ``fold(acc, pose, out) -> acc``, called after every period with
            the pose ``(3,)`` at its end and its ``StepOutput``: metrics that
            stream through the scan instead of storing the trajectory.
        acc: the initial value of the fold's accumulator (a pytree).
        record: also return every pose and ``StepOutput`` (stacked over steps).

    Returns:
        ``(final pose (3,), acc, (poses (steps, 3), StepOutput) or None)``.
    """
    if options.velocity == "ideal":
        return _ideal_loop(ref, params, init, robot, dt, options, fold, acc, record)
    return _generic_loop(ref, params, init, robot, dt, options, fold, acc, record)


def _remat(body: Callable) -> Callable:
    """Differentiate ``body`` by recomputing it, not by storing its intermediates.

    Reverse-mode through a scan otherwise keeps every intermediate of every
    step (some fifty arrays of ``N × steps`` for the ideal loop, gigabytes at
    ``N = 10⁵``); with this only the carry is kept per step and the backward
    pass recomputes the step, which is cheaper than writing it all to memory.
    No effect on evaluation without differentiation.
    """
    return jax.checkpoint(body, prevent_cse=False)


def _generic_loop(ref, params, init, robot, dt, options, fold, acc, record):
    def body(carry, _):
        (x, y, theta), velocity, integral, acc = carry
        state = dynamics.RobotState(jnp.stack([x, y, theta]), velocity, integral)
        new_state, out = closed_loop_step(state, ref, params, robot, dt, options)
        pose = new_state.pose
        if fold is not None:
            acc = fold(acc, pose, out)
        # The pose rides in the carry as three scalars: a batched (N, 3) carry
        # is rebuilt column by column every step, the law evaluated once per column.
        carry = ((pose[0], pose[1], pose[2]), new_state.velocity, new_state.integral, acc)
        return carry, ((pose, out) if record else None)

    start = initial_state(init)
    carry = ((init[0], init[1], init[2]), start.velocity, start.integral, acc)
    (final, _, _, acc), ys = jax.lax.scan(_remat(body), carry, None, length=options.steps)
    return jnp.stack(final), acc, ys


def _ideal_loop(ref, params, init, robot, dt, options, fold, acc, record):
    """The ideal velocity loop, arranged for speed; equal to scanning ``closed_loop_step``.

    Three things make it several times faster than the plain scan:

    * The position and heading ride as complex numbers ``x + i y`` and
      ``cos θ + i sin θ`` (``dynamics.arc_advance``), so no step recomputes
      the heading's cosine and sine for the law (``frame=`` of
      ``Controller.command``) or the arc. θ itself is carried too, for the pose.
    * The command of the next period is computed at the end of each period
      and carried as ``v + i ω``. XLA on the CPU compiles a step into one
      loop per output of the step and repeats in each whatever they share;
      carried this way, the law is evaluated in one loop only, and the
      step's outputs are four arrays, not nine.
    * The heading is renormalised every step by one Newton step towards
      ``|heading| = 1``, so rounding does not make it drift over long runs.
    """
    control = options.controller

    def frame(position, heading):
        return position.real, position.imag, heading.real, heading.imag

    def command(position, heading, theta):
        pose = jnp.stack([position.real, position.imag, theta])
        v, omega = control.command(
            pose, ref, params, temperature=options.temperature, frame=frame(position, heading)
        )
        return jax.lax.complex(v, omega)

    def region(position, heading, theta):
        pose = jnp.stack([position.real, position.imag, theta])
        return control.region_of(pose, ref, params, frame=frame(position, heading))

    def body(carry, _):
        position, heading, theta, cmd, acc = carry
        v, omega = cmd.real, cmd.imag
        if fold is not None or record:
            out = StepOutput(
                v,
                omega,
                region(position, heading, theta),
                law.wheel_speeds(v, omega, robot),
                jnp.abs(v) * dt,
            )
        position, heading = dynamics.arc_advance(position, heading, v, omega, dt)
        heading = heading * (1.5 - 0.5 * (heading.real**2 + heading.imag**2))
        theta = theta + omega * dt
        pose = jnp.stack([position.real, position.imag, theta])
        if fold is not None:
            acc = fold(acc, pose, out)
        carry = (position, heading, theta, command(position, heading, theta), acc)
        return carry, ((pose, out) if record else None)

    cos_0, sin_0 = dynamics.sin_cos(init[2])
    position = jax.lax.complex(init[0], init[1])
    heading = jax.lax.complex(cos_0, sin_0)
    carry = (position, heading, init[2], command(position, heading, init[2]), acc)
    (position, _, theta, _, acc), ys = jax.lax.scan(_remat(body), carry, None, length=options.steps)
    return jnp.stack([position.real, position.imag, theta]), acc, ys


# ---------------------------------------------------------------- batching


def _batch_axes(tree: Any, single_ndim: int) -> Any:
    """Map each leaf to 0 if it carries a leading batch axis, else ``None``."""
    return jax.tree.map(lambda leaf: 0 if jnp.ndim(leaf) > single_ndim else None, tree)


def batched(single: Callable) -> Callable:
    """Lift ``single(ref, params, init, robot, dt, options)`` to batched inputs.

    A leading axis on ``ref``/``init`` (beyond ``(3,)``) or on any leaf of
    ``params``/``robot`` (beyond a scalar) is mapped over; the others are
    shared. This is the one place where ``vmap`` is applied.
    """

    def run(ref, params, init, robot, dt, options):
        in_axes = (
            _batch_axes(ref, 1),
            _batch_axes(params, 0),
            _batch_axes(init, 1),
            _batch_axes(robot, 0),
            None,
        )
        return jax.vmap(lambda *a: single(*a, options), in_axes=in_axes)(
            ref, params, init, robot, dt
        )

    return run


# XLA:CPU targets 256-bit vectors unless told otherwise; on a CPU with AVX-512
# the rollouts run about 20 % faster with 512-bit ones (measured on AMD Zen 4).
# Other backends ignore the option, and a CPU without AVX-512 uses what it has.
COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": "512"}


def jit_top_level(fn: Callable, **kwargs: Any) -> Callable:
    """Return ``jax.jit(fn, **kwargs)`` compiled with ``COMPILER_OPTIONS``.

    For a function of the caller's that runs rollouts inside (a loss, its
    gradient): only the outermost ``jit`` can carry compiler options.
    """
    try:
        return jax.jit(fn, compiler_options=COMPILER_OPTIONS, **kwargs)
    except TypeError:  # a JAX without per-function compiler options
        return jax.jit(fn, **kwargs)


class EntryJit:
    """A jitted entry point, compiled with ``COMPILER_OPTIONS`` when called at top level.

    JAX accepts compiler options only on a top-level ``jit``; inside a
    caller's own ``jit``/``grad``/``vmap`` (traced arguments) the same
    function runs as a plain nested ``jit``.
    """

    def __init__(self, fn: Callable, **kwargs: Any):
        self.nested = jax.jit(fn, **kwargs)
        self.top = jit_top_level(fn, **kwargs)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        traced = any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(args))
        return (self.nested if traced else self.top)(*args, **kwargs)

    def lower(self, *args: Any, **kwargs: Any) -> Any:
        """Lower the top-level version (for inspecting the compiled program)."""
        return self.top.lower(*args, **kwargs)

    def _cache_size(self) -> int:
        return self.top._cache_size() + self.nested._cache_size()
