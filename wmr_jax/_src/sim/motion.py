"""The pose as the loops carry it, and its motion over one control period.

``SplitPose`` holds position and heading as complex numbers, so that the ideal
robot's exact arc is two complex products. Nothing here checks its inputs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp

from wmr_jax._src.model import dynamics, velocity_loop
from wmr_jax._src.model.controllers import shim_sung as law
from wmr_jax._src.model.params import Robot

if TYPE_CHECKING:
    from wmr_jax._src.sim.loops import Options


class SplitPose(NamedTuple):
    """A pose as the loops carry it: complex ``x + i y`` cm, ``cos θ + i sin θ``, θ rad."""

    position: jax.Array
    heading: jax.Array
    theta: jax.Array

    @classmethod
    def of(cls, pose: jax.Array) -> SplitPose:
        """Split a ``(3,)`` pose ``[x, y, θ]``."""
        cos_theta, sin_theta = dynamics.sin_cos(pose[2])
        return cls(
            jax.lax.complex(pose[0], pose[1]), jax.lax.complex(cos_theta, sin_theta), pose[2]
        )

    def stacked(self) -> jax.Array:
        """Return the pose as ``(3,)`` ``[x, y, θ]``."""
        return jnp.stack([self.position.real, self.position.imag, self.theta])

    def frame(self) -> tuple[jax.Array, ...]:
        """The pose as ``(x, y, cos θ, sin θ)``, the ``frame=`` of ``Controller.command``."""
        return self.position.real, self.position.imag, self.heading.real, self.heading.imag


def split_command(pose: SplitPose, ref, params, options: Options) -> jax.Array:
    """Return the controller's command at ``pose`` as the complex ``v + i ω``."""
    if options.law_derivative == "jacobian":
        return _jacobian_command(pose, ref, params, options)
    v, omega = options.controller.command(
        pose.stacked(), ref, params, temperature=options.temperature, frame=pose.frame()
    )
    return jax.lax.complex(v, omega)


def _jacobian_command(pose: SplitPose, ref, params, options: Options) -> jax.Array:
    """``split_command`` whose derivative in the pose and reference is their Jacobian.

    XLA:CPU repeats JAX's own derivative of the law in every kernel of a backward
    step that reads it; here the Jacobian of ``(v, ω)`` is formed once per step
    (one reverse pass per component). The parameters and temperature keep JAX's
    derivative; the values are ``split_command``'s.
    """
    dtype = pose.theta.dtype
    hard = options.temperature is None

    def law(state, rest):
        x, y, cos_theta, sin_theta, theta, reference = state
        temperature, gains = rest
        split = SplitPose(jax.lax.complex(x, y), jax.lax.complex(cos_theta, sin_theta), theta)
        v, omega = options.controller.command(
            split.stacked(),
            reference,
            gains,
            temperature=None if hard else temperature,
            frame=split.frame(),
        )
        return jnp.stack([v, omega])

    @jax.custom_jvp
    def jacobian_command(state, rest):
        return law(state, rest)

    @jacobian_command.defjvp
    def _(primals, tangents):
        state, rest = primals
        out, pullback = jax.vjp(lambda s: law(s, rest), state)
        (jacobian,) = jax.vmap(pullback)(jnp.eye(2, dtype=out.dtype))
        in_state = jax.tree.map(lambda j, t: j @ t if t.ndim else j * t, jacobian, tangents[0])
        _, in_rest = jax.jvp(lambda r: law(state, r), (rest,), (tangents[1],))
        return out, sum(jax.tree.leaves(in_state)) + in_rest

    temperature = jnp.zeros((), dtype) if hard else jnp.asarray(options.temperature, dtype)
    position, heading = pose.position, pose.heading
    state = (position.real, position.imag, heading.real, heading.imag, pose.theta, ref)
    vw = jacobian_command(state, (temperature, params))
    return jax.lax.complex(vw[0], vw[1])


class HeldCommand(NamedTuple):
    """The command ``(v cm/s, ω rad/s)`` the speed limiter let through (docs/model.md §4.2.2)."""

    v: jax.Array
    omega: jax.Array


def speed_limit(
    previous: HeldCommand, v: jax.Array, omega: jax.Array, robot: Robot, dt: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The command ``(v, ω)`` after the robot's speed limiter (docs/model.md §4.2.2)."""
    return (
        dynamics.rate_limit(v, previous.v, robot.accel_max, dt),
        dynamics.rate_limit(omega, previous.omega, robot.angular_accel_max, dt),
    )


def initial_wheel(
    init: jax.Array, options: Options
) -> velocity_loop.WheelState | HeldCommand | None:
    """The velocity loop at rest: the wheel loop's state, the held command, or ``None``."""
    zero = jnp.zeros((), init.dtype)
    if options.velocity == "ideal":
        return HeldCommand(zero, zero) if options.accel_limit else None
    return velocity_loop.WheelState(zero, zero, zero, zero)


class ArcMove(NamedTuple):
    """One period's arc at a held command, apart from the pose it moves (``ideal_move``)."""

    turn: jax.Array
    chord: jax.Array
    rotation: jax.Array

    @classmethod
    def of(cls, v: jax.Array, omega: jax.Array, dt: jax.Array) -> ArcMove:
        """The move of the held command ``(v, ω)`` over ``dt``."""
        turn, chord = dynamics.arc_factors(v, omega, dt)
        return cls(turn, chord, omega * dt)


def ideal_move(pose: SplitPose, move: ArcMove) -> SplitPose:
    """Move ``pose`` by ``move``: the exact arc of docs/model.md §4 (estimators predict so)."""
    position, heading = dynamics.arc_apply(pose.position, pose.heading, move.turn, move.chord)
    # One Newton step towards |heading| = 1, so that rounding does not drift.
    heading = heading * (1.5 - 0.5 * (heading.real**2 + heading.imag**2))
    return SplitPose(position, heading, pose.theta + move.rotation)


def advance_period(
    pose: SplitPose,
    wheel: Any,
    command: tuple[jax.Array, jax.Array],
    robot: Robot,
    dt: jax.Array,
    options: Options,
    *,
    model: Robot | None = None,
) -> tuple[SplitPose, Any, jax.Array, jax.Array]:
    """Move the robot over one period under the held ``command = (v, ω)`` (docs/model.md §4).

    ``model``: the robot the wheel controller believes in. Returns ``(pose,
    wheel, rim speeds (2,) cm/s, distance cm)`` at the end of the period.
    """
    v, omega = command
    if options.velocity == "ideal":
        new = ideal_move(pose, ArcMove.of(v, omega, dt))
        return new, wheel, law.wheel_speeds(v, omega, robot), jnp.abs(v) * dt
    position, heading, theta, wheel, distance = velocity_loop.advance_split(
        pose.position,
        pose.heading,
        pose.theta,
        wheel,
        command,
        robot,
        dt,
        substeps=options.substeps,
        wheel_limit=options.wheel_limit,
        model=model,
        integral=options.wheel_integral,
        coriolis=options.wheel_coriolis,
        small_turn=options.small_turn,
    )
    rims = law.wheel_speeds(wheel.v, wheel.omega, robot)
    return SplitPose(position, heading, theta), wheel, rims, distance
