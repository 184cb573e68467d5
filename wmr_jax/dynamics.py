"""Robot motion over one control period: the ideal velocity loop (SPEC §4).

The controller is sampled: its command is held constant over each ``dt``
(zero-order hold). With the ideal velocity controller the robot moves at the
command at once, so the unicycle kinematics (Eq. 2) are integrated exactly over
the interval: a circular arc, or a straight segment when ``ω = 0``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["RobotState", "arc_step", "sinc"]

# Below this |u| the series 1 − u²/6 + u⁴/120 equals sin(u)/u to float64
# precision (the next term is u⁶/5040 < 1e-27), and sin(u)/u would lose digits.
_SINC_SERIES_BELOW = 1e-3


class RobotState(NamedTuple):
    """What the robot carries from one sample to the next.

    Attributes:
        pose: ``(3,)`` ``[x cm, y cm, θ rad]``; θ is not wrapped.
        velocity: ``(2,)`` body velocity ``[v cm/s, ω rad/s]`` at the sample.
        integral: ``(2,)`` integral of the wheel-speed loop's velocity error
            (non-ideal loop only; zero for the ideal one).
    """

    pose: jax.Array
    velocity: jax.Array
    integral: jax.Array


def sinc(u: jax.Array) -> jax.Array:
    """Return ``sin(u)/u`` (unnormalised), exact and with finite gradients at 0."""
    small = jnp.abs(u) < _SINC_SERIES_BELOW
    safe_u = jnp.where(small, 1.0, u)  # double-where: no 0/0 in the unused branch
    u2 = u * u
    return jnp.where(small, 1.0 - u2 / 6.0 * (1.0 - u2 / 20.0), jnp.sin(safe_u) / safe_u)


def arc_step(pose: jax.Array, v: jax.Array, omega: jax.Array, h: jax.Array) -> jax.Array:
    """Advance ``pose`` by ``h`` seconds at constant ``(v, ω)``, exactly (SPEC §4).

    The robot turns by ``ω h`` and moves along the chord of length
    ``v h sinc(ω h / 2)`` in the direction ``θ + ω h / 2``.

    Args:
        pose: ``(..., 3)`` ``[x cm, y cm, θ rad]``.
        v: linear velocity, cm/s.
        omega: angular velocity, rad/s.
        h: duration, s.

    Returns:
        The pose after ``h``, same shape as ``pose``.
    """
    half_turn = 0.5 * omega * h
    chord = v * h * sinc(half_turn)
    heading = pose[..., 2] + half_turn
    return jnp.stack(
        [
            pose[..., 0] + chord * jnp.cos(heading),
            pose[..., 1] + chord * jnp.sin(heading),
            pose[..., 2] + omega * h,
        ],
        axis=-1,
    )
