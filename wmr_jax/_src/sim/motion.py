"""The pose as the loops carry it, and its motion over one control period.

``SplitPose`` holds the position and heading as complex numbers, so that
the exact arc of the ideal robot (``ideal_move``, docs/model.md §4) is two
complex products; ``advance_period`` moves it under either velocity loop.
``HeldCommand`` and ``speed_limit`` are the ideal loop's speed limiter
(§4.2.2). Nothing here checks its inputs.
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

__all__ = [
    "ArcMove",
    "HeldCommand",
    "SplitPose",
    "advance_period",
    "ideal_arc",
    "ideal_move",
    "initial_wheel",
    "speed_limit",
    "split_command",
    "split_region",
]


class SplitPose(NamedTuple):
    """A pose as the fast loops carry it (leading batch axes allowed).

    Attributes:
        position: complex ``x + i y``, cm.
        heading: complex ``cos θ + i sin θ``.
        theta: θ, rad (not wrapped).
    """

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
    v, omega = options.controller.command(
        pose.stacked(), ref, params, temperature=options.temperature, frame=pose.frame()
    )
    return jax.lax.complex(v, omega)


def split_region(pose: SplitPose, ref, params, options: Options) -> jax.Array:
    """Return the controller's region label at ``pose`` (−1 if it has none)."""
    return options.controller.region_of(pose.stacked(), ref, params, frame=pose.frame())


class HeldCommand(NamedTuple):
    """The command the ideal loop's speed limiter last let through (docs/model.md §4.2.2).

    The ideal loop's state beside the pose when ``Options.accel_limit`` is
    on (leading batch axes allowed); the robot starts at rest, ``(0, 0)``.

    Attributes:
        v: linear velocity, cm/s.
        omega: angular velocity, rad/s.
    """

    v: jax.Array
    omega: jax.Array


def speed_limit(
    previous: HeldCommand, v: jax.Array, omega: jax.Array, robot: Robot, dt: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The command ``(v, ω)`` after the robot's speed limiter (docs/model.md §4.2.2).

    Each axis moves from ``previous`` by at most its acceleration limit
    times ``dt``; an axis whose limit is 0 (none) passes unchanged.
    """
    return (
        dynamics.rate_limit(v, previous.v, robot.accel_max, dt),
        dynamics.rate_limit(omega, previous.omega, robot.angular_accel_max, dt),
    )


def initial_wheel(
    init: jax.Array, options: Options
) -> velocity_loop.WheelState | HeldCommand | None:
    """The velocity loop at rest: the wheel loop's state, or the ideal loop's held command.

    ``None`` for the ideal loop without a speed limiter, which has no state.
    """
    zero = jnp.zeros((), init.dtype)
    if options.velocity == "ideal":
        return HeldCommand(zero, zero) if options.accel_limit else None
    return velocity_loop.WheelState(zero, zero, zero, zero)


class ArcMove(NamedTuple):
    """One period's motion at a held command, apart from the pose it moves (``ideal_move``).

    Attributes:
        turn: ``cos(ω dt/2) + i sin(ω dt/2)``.
        chord: ``v dt sinc(ω dt/2)``, cm.
        rotation: ``ω dt``, rad.
    """

    turn: jax.Array
    chord: jax.Array
    rotation: jax.Array

    @classmethod
    def of(cls, v: jax.Array, omega: jax.Array, dt: jax.Array) -> ArcMove:
        """The move of the held command ``(v, ω)`` over ``dt``."""
        turn, chord = dynamics.arc_factors(v, omega, dt)
        return cls(turn, chord, omega * dt)


def ideal_move(pose: SplitPose, move: ArcMove) -> SplitPose:
    """Move ``pose`` by ``move``: the exact arc of docs/model.md §4 (``ideal_arc``)."""
    position, heading = dynamics.arc_apply(pose.position, pose.heading, move.turn, move.chord)
    # One Newton step towards |heading| = 1, so that rounding does not drift.
    heading = heading * (1.5 - 0.5 * (heading.real**2 + heading.imag**2))
    return SplitPose(position, heading, pose.theta + move.rotation)


def ideal_arc(pose: SplitPose, v: jax.Array, omega: jax.Array, dt: jax.Array) -> SplitPose:
    """Move ``pose`` over ``dt`` at the held ``(v, ω)`` on the exact arc of docs/model.md §4.

    The ideal loop's motion, and the prediction of every estimator (whose
    model is the ideal robot, docs/model.md §9).
    """
    return ideal_move(pose, ArcMove.of(v, omega, dt))


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

    Args:
        pose: the pose at the sample.
        wheel: the velocity loop's state (``initial_wheel``): the wheel loop's,
            the ideal loop's last held command under a speed limiter, or
            ``None``.
        command: ``(v cm/s, ω rad/s)``, held over the period (after the speed
            limiter, which ``ClosedLoopStep`` applies).
        robot: the robot that moves.
        dt: control period, s.
        options: ``velocity``, ``substeps``, ``wheel_limit`` and the wheel
            loop's flags are used.
        model: the robot the wheel controller believes in (non-ideal loop;
            default ``robot``).

    Returns:
        ``(pose, wheel, rim speeds (2,) [v_L, v_R] cm/s, distance cm)`` at the
        end of the period.
    """
    v, omega = command
    if options.velocity == "ideal":
        new = ideal_arc(pose, v, omega, dt)
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
