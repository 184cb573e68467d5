"""The closed loop of one pose as a ``lax.scan`` (docs/model.md §4, §7, §9), and its ``vmap``.

Nothing here checks its inputs: the entry points do that first.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import is_traced
from wmr_jax._src.model import velocity_loop
from wmr_jax._src.model.controllers.base import Controller
from wmr_jax._src.model.controllers.shim_sung import SHIM_SUNG
from wmr_jax._src.model.params import Robot
from wmr_jax._src.sim.motion import (
    ArcMove,
    HeldCommand,
    SplitPose,
    advance_period,
    ideal_move,
    initial_wheel,
    speed_limit,
    split_command,
)

VELOCITY_LOOPS = ("ideal", "nonideal")
LAW_DERIVATIVES = ("traced", "jacobian")
WHEEL_LIMITS = ("clip", "scale")
DEFAULT_SUBSTEPS = velocity_loop.DEFAULT_SUBSTEPS
DEFAULT_STEPS = 150


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
        wheel_integral: integrate the wheel loop's velocity error (non-ideal loop).
        wheel_coriolis: include the Coriolis terms ``G(q)`` (non-ideal loop).
        small_turn: no sub-step turns beyond ``π/2``: no range reduction (non-ideal loop).
        estimator: the ``Estimator`` between measurement and law (disturbed loop), or ``None``.
        remat: recompute each step in the backward pass instead of storing it.
        accel_limit: the robot's speed limiter (ideal loop; docs/model.md §4.2.2).
        max_delay: the longest latency of a disturbed run, samples (docs/model.md §7).
        law_derivative: ``"traced"`` (JAX differentiates the law's operations) or
            ``"jacobian"`` (the law's Jacobian in pose and reference, formed once per
            step: a faster gradient with the EKF, slower without; docs/robustness.md).
    """

    steps: int = DEFAULT_STEPS
    velocity: str = "ideal"
    controller: Controller = SHIM_SUNG
    temperature: float | None = None
    substeps: int = DEFAULT_SUBSTEPS
    wheel_limit: str = "clip"
    wheel_integral: bool = True
    wheel_coriolis: bool = True
    small_turn: bool = False
    estimator: Any = None
    remat: bool = True
    accel_limit: bool = False
    max_delay: int = 1
    law_derivative: str = "traced"


def for_robot(options: Options, robot: Robot, dt: Any) -> Options:
    """Return ``options`` fitted to ``robot``: its speed limiter on, vanishing terms left out.

    Ideal loop: the limiter where the robot has an acceleration limit
    (docs/model.md §4.2.2). Non-ideal loop: no integral state, Coriolis terms
    or range reduction where they vanish. Traced values keep the general loop.
    """

    def concrete(value: Any) -> np.ndarray | None:
        return None if is_traced(value) else np.asarray(value, dtype=float)

    def vanishes(value: Any) -> bool:
        value = concrete(value)
        return value is not None and not np.any(value != 0)

    if options.velocity == "ideal":
        limits = [concrete(robot.accel_max), concrete(robot.angular_accel_max)]
        limited = any(x is None or np.any(x > 0) for x in limits)
        return dataclasses.replace(options, accel_limit=options.accel_limit or limited)
    if options.velocity != "nonideal":
        return options
    v_max, half_track, period = (concrete(x) for x in (robot.v_max, robot.half_track, dt))
    small = not any(x is None for x in (v_max, half_track, period)) and bool(
        np.all(v_max * period / (half_track * options.substeps) <= np.pi / 2)
    )
    return dataclasses.replace(
        options,
        wheel_integral=options.wheel_integral and not vanishes(robot.integral_gain),
        wheel_coriolis=options.wheel_coriolis and not vanishes(robot.com_offset),
        small_turn=options.small_turn or small,
    )


class StepOutput(NamedTuple):
    """One period's sample of a ``Trajectory``; ``v``, ``ω`` before limiter and mismatch."""

    v: jax.Array
    omega: jax.Array
    region: jax.Array
    wheel_speeds: jax.Array
    distance: jax.Array


Fold = Callable[[Any, "SplitPose", StepOutput], Any]


class LoopCarry(NamedTuple):
    """The scan's carry: ``command`` is ``v + i ω``; ``in_flight``/``moves`` newest first."""

    pose: Any
    wheel: Any
    command: jax.Array
    in_flight: tuple
    moves: tuple
    estimate: Any
    ref: jax.Array
    acc: Any


@dataclasses.dataclass(frozen=True)
class ClosedLoopStep:
    """One control period of the closed loop: law → commands in flight → velocity loop → robot.

    Optional parts are ``None`` where a run has none: ``disturbance``,
    ``estimate`` (the estimator's parameters), and ``aim(acc) -> ref``, the
    next command's reference from the fold's accumulator (waypoint chains).
    """

    ref: jax.Array
    params: Any
    robot: Robot
    dt: jax.Array
    options: Options
    disturbance: Any = None
    estimate: Any = None
    aim: Callable[[Any], jax.Array] | None = None
    fold: Fold | None = None
    record: bool = False

    @property
    def limiter(self) -> bool:
        return self.options.velocity == "ideal" and self.options.accel_limit

    @property
    def estimator(self) -> Any:
        return None if self.disturbance is None else self.options.estimator

    @property
    def slots(self) -> int:
        return 0 if self.disturbance is None else max(1, self.options.max_delay)

    def law(self, pose: SplitPose, ref: jax.Array) -> jax.Array:
        return split_command(pose, ref, self.params, self.options)

    def delayed(self, fresh: jax.Array, queue: tuple) -> Any:
        """Of ``fresh`` and the older ``queue``, the one computed ``delay`` samples ago."""
        applied = fresh
        for j, held in enumerate(queue):
            applied = _select(self.disturbance.delay == j + 1, held, applied)
        return applied

    def followed(self, wheel: Any, command: jax.Array) -> tuple[jax.Array, Any]:
        """``command`` after the speed limiter, if any, in state ``wheel``."""
        if not self.limiter:
            return command, wheel
        v, omega = speed_limit(wheel, command.real, command.imag, self.robot, self.dt)
        return jax.lax.complex(v, omega), HeldCommand(v, omega)

    def law_input(self, estimate: SplitPose, queue: tuple, moves: tuple, wheel: Any) -> SplitPose:
        """The estimate rolled over the commands in flight, oldest first (compensation)."""
        if not self.estimate.compensate:
            return estimate
        for j in reversed(range(self.slots)):
            late = self.disturbance.delay > j
            if moves:
                move = moves[j]
            else:
                followed, next_wheel = self.followed(wheel, queue[j])
                move = ArcMove.of(followed.real, followed.imag, self.dt)
                wheel = _select(late, next_wheel, wheel)
            estimate = _select(late, ideal_move(estimate, move), estimate)
        return estimate

    def start(self, ref: jax.Array, init: jax.Array, acc: Any) -> LoopCarry:
        """The carry at the first sample: the robot at rest at ``init`` (3,)."""
        pose = SplitPose.of(init)
        wheel = initial_wheel(init, self.options)
        spec, estimator = self.disturbance, self.estimator
        state, queue, moves = None, (), ()
        if spec is None:
            first = self.law(pose, ref)
        else:
            sensed = spec.measurement(pose, spec.noise[0]).pose()
            if estimator is None:
                first = self.law(sensed, ref)
            else:
                state = estimator.start(sensed, self.estimate, self.robot)
                zero = jnp.zeros((), init.dtype)
                still = (ArcMove.of(zero, zero, self.dt),) * self.slots
                first = self.law(self.law_input(state.pose, (), still, wheel), ref)
                moves = () if self.limiter else still
            queue = (jnp.zeros_like(first),) * self.slots
        carried = None if self.aim is None else ref
        return LoopCarry(pose, wheel, first, queue, moves, state, carried, acc)

    def move(
        self, pose: SplitPose, wheel: Any, applied: jax.Array, ref: jax.Array, acc: Any
    ) -> tuple[SplitPose, Any, jax.Array, StepOutput, Any]:
        """The plant's half of a period under ``applied``; the command side is the caller's.

        Returns ``(pose, wheel, followed, out, acc)``; ``followed``: what the limiter let through.
        """
        spec = self.disturbance
        if spec is not None:
            region = jnp.int32(-1)
        elif self.fold or self.record:
            control = self.options.controller
            region = control.region_of(pose.stacked(), ref, self.params, frame=pose.frame())
        else:
            region = None
        followed, wheel = self.followed(wheel, applied)
        v, omega = applied.real, applied.imag
        target = (v, omega) if followed is applied else (followed.real, followed.imag)
        robot = self.robot
        if spec is not None:
            target, robot = spec.realised(followed, robot), spec.true_robot(robot)
        pose, wheel, rims, distance = advance_period(
            pose, wheel, target, robot, self.dt, self.options, model=self.robot
        )
        out = StepOutput(v, omega, region, rims, distance)
        if self.fold is not None:
            acc = self.fold(acc, pose, out)
        return pose, wheel, followed, out, acc

    def __call__(self, carry: LoopCarry, noise_next: Any) -> tuple[LoopCarry, Any]:
        """Move over one period; compute the next command from the measurement ``noise_next``."""
        pose, wheel, fresh, queue, moves, state, ref, acc = carry
        ref = self.ref if self.aim is None else ref
        spec, estimator, dt = self.disturbance, self.estimator, self.dt
        applied = fresh if spec is None else self.delayed(fresh, queue)
        if estimator is not None and moves:
            # The arc is computed here, not where the law returns it: XLA would
            # fuse the law into each of the arc's parts.
            fresh_move = ArcMove.of(fresh.real, fresh.imag, dt)
            move = self.delayed(fresh_move, moves)
            moves = (fresh_move, *moves[:-1])
        pose, wheel, followed, out, acc = self.move(pose, wheel, applied, ref, acc)
        if estimator is not None and not moves:
            move = ArcMove.of(followed.real, followed.imag, dt)
        queue = (fresh, *queue[:-1]) if queue else ()
        if spec is None:
            seen = pose
        else:
            sensed = spec.measurement(pose, noise_next)
            if estimator is None:
                seen = sensed.pose()
            else:
                predicted = ideal_move(state.pose, move)
                state = estimator.update(
                    state, predicted, followed, sensed, ref, self.estimate, self.robot, dt
                )
                seen = state.pose
        next_ref = ref if self.aim is None else self.aim(acc)
        law_pose = seen if estimator is None else self.law_input(seen, queue, moves, wheel)
        command = self.law(law_pose, next_ref)
        next_ref = None if self.aim is None else next_ref
        recorded = None
        if self.record:
            recorded = (pose.stacked(), out) + (() if spec is None else (seen.stacked(),))
        return LoopCarry(pose, wheel, command, queue, moves, state, next_ref, acc), recorded


def _select(flag: jax.Array, on_true: Any, on_false: Any) -> Any:
    return jax.tree.map(lambda a, b: jnp.where(flag, a, b), on_true, on_false)


def scan_closed_loop(
    ref: jax.Array,
    params: Any,
    init: jax.Array,
    robot: Robot,
    dt: jax.Array,
    options: Options,
    *,
    disturbance: Any = None,
    estimate: Any = None,
    aim: Callable[[Any], jax.Array] | None = None,
    fold: Fold | None = None,
    acc: Any = None,
    record: bool = False,
) -> tuple[jax.Array, Any, Any]:
    """Run the closed loop of one pose: the one ``lax.scan`` of ``ClosedLoopStep``.

    ``ref``, ``init``: ``(3,)``; ``robot``: the nominal one. A ``disturbance``
    sets the number of periods by its noise; ``fold(acc, pose, out) -> acc``
    streams metrics; ``record`` also returns every pose and ``StepOutput``
    (disturbed: and the estimate). Returns ``(final pose (3,), acc, records)``.
    """
    step = ClosedLoopStep(ref, params, robot, dt, options, disturbance, estimate, aim, fold, record)
    carry = step.start(ref, init, acc)
    if disturbance is None:
        xs, length = None, options.steps
    else:
        # The measurement at sample k + 1 is taken at the end of period k; the
        # last period's is never used.
        noise = disturbance.noise
        xs, length = jnp.concatenate([noise[1:], jnp.zeros_like(noise[:1])]), None

    def body(carry, noise_next):
        return step(carry, noise_next)

    body = remat(body) if options.remat else body
    carry, ys = jax.lax.scan(body, carry, xs, length=length)
    return carry.pose.stacked(), carry.acc, ys


def remat(body: Callable) -> Callable:
    """Recompute ``body`` in the backward pass instead of storing its intermediates."""
    return jax.checkpoint(body, prevent_cse=False)


def batch_axes(tree: Any, single_ndim: int) -> Any:
    """Map each leaf to 0 if it carries a leading batch axis, else ``None``."""
    return jax.tree.map(lambda leaf: 0 if jnp.ndim(leaf) > single_ndim else None, tree)


def batched(single: Callable) -> Callable:
    """Lift ``single(ref, params, init, robot, dt, options)`` to batched inputs.

    A leading axis on ``ref``/``init`` or any leaf of ``params``/``robot`` is
    mapped over; the others are shared. ``single`` is traced once per run's
    shapes and options, not again for each batch size.
    """

    one = jax.jit(single, static_argnums=5)

    def run(ref, params, init, robot, dt, options):
        in_axes = (
            batch_axes(ref, 1),
            batch_axes(params, 0),
            batch_axes(init, 1),
            batch_axes(robot, 0),
            None,
        )
        return jax.vmap(lambda *a: one(*a, options), in_axes=in_axes)(ref, params, init, robot, dt)

    return run


# XLA:CPU targets 256-bit vectors unless told otherwise; a CPU with AVX-512
# runs the rollouts faster with 512-bit ones. Other backends ignore it.
COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": "512"}


def jit_top_level(fn: Callable, **kwargs: Any) -> Callable:
    """Return ``jax.jit(fn, **kwargs)`` compiled with ``COMPILER_OPTIONS`` (top level only)."""
    try:
        return jax.jit(fn, compiler_options=COMPILER_OPTIONS, **kwargs)
    except TypeError:  # a JAX without per-function compiler options
        return jax.jit(fn, **kwargs)


class EntryJit:
    """A jitted entry point: ``COMPILER_OPTIONS`` at top level, a nested ``jit`` when traced."""

    def __init__(self, fn: Callable, **kwargs: Any):
        self.nested = jax.jit(fn, **kwargs)
        self.top = jit_top_level(fn, **kwargs)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if is_traced(args):
            return self.nested(*args, **kwargs)
        # Concrete arguments: nothing differentiates, so no remat.
        options = kwargs.get("options")
        if isinstance(options, Options) and options.remat:
            kwargs = {**kwargs, "options": dataclasses.replace(options, remat=False)}
        return self.top(*args, **kwargs)
