"""Robot motion over one control period: the ideal velocity loop (docs/model.md §4).

The controller is sampled: its command is held constant over each ``dt``
(zero-order hold). With the ideal velocity controller the robot moves at the
command at once, so the unicycle kinematics (Eq. 2) are integrated exactly over
the interval: a circular arc, or a straight segment when ``ω = 0``.

The arc has one home, ``arc_advance``, which works on the position as the
complex number ``x + i y`` and the heading as the unit complex number
``cos θ + i sin θ``: turning by an angle is then one complex product, and a
rollout can carry the heading without a trigonometric call per step.
``arc_step`` is the same arc on a pose ``[x, y, θ]``.

``sin_cos`` is the cosine and sine used by the rollouts. XLA on the CPU
evaluates ``jnp.sin``/``jnp.cos`` about ten times slower than a polynomial of
the same accuracy (they do not vectorise well), and they were the largest
single cost of a rollout step.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

__all__ = [
    "RobotState",
    "arc_advance",
    "arc_apply",
    "arc_factors",
    "arc_step",
    "initial_state",
    "rate_limit",
    "sin_cos",
    "sin_small",
    "sinc",
]

_NEAREST_EVEN = lax.RoundingMethod.TO_NEAREST_EVEN  # what jnp.round does

# Below this |u| the series 1 − u²/6 + u⁴/120 equals sin(u)/u to float64
# precision (the next term is u⁶/5040 < 1e-27), and sin(u)/u would lose digits.
_SINC_SERIES_BELOW = 1e-3

# π/2 split in three (Cody–Waite): the leading parts have enough trailing zero
# bits that k·part is exact for |k| < 2^20 (float64) or 2^16 (float32), so the
# reduced argument keeps full precision for |angle| up to about 1e6 rad
# (float64) or 1e5 rad (float32). Rollout angles stay far below that.
_PIO2 = {
    np.dtype(np.float64): (
        1.57079632673412561417e00,
        6.07710050630396597660e-11,
        2.02226624879595063154e-21,
    ),
    np.dtype(np.float32): (1.5703125, 4.837512969970703125e-4, 7.54978995489188216e-8),
}
# Minimax polynomials on [−π/4, π/4] (fdlibm's __kernel_sin/__kernel_cos for
# float64, Cephes' sinf/cosf for float32): sin r = r + r³ S(r²),
# cos r = 1 − r²/2 + r⁴ C(r²), both within one ulp.
_SIN = {
    np.dtype(np.float64): (
        -1.66666666666666324348e-01,
        8.33333333332248946124e-03,
        -1.98412698298579493134e-04,
        2.75573137070700676789e-06,
        -2.50507602534068634195e-08,
        1.58969099521155010221e-10,
    ),
    np.dtype(np.float32): (-1.6666654611e-1, 8.3321608736e-3, -1.9515295891e-4),
}
_COS = {
    np.dtype(np.float64): (
        4.16666666666666019037e-02,
        -1.38888888888741095749e-03,
        2.48015872894767294178e-05,
        -2.75573143513906633035e-07,
        2.08757232129817482790e-09,
        -1.13596475577881948265e-11,
    ),
    np.dtype(np.float32): (4.166664568298827e-2, -1.388731625493765e-3, 2.443315711809948e-5),
}


class RobotState(NamedTuple):
    """What the robot carries from one sample to the next.

    Attributes:
        pose: ``(3,)`` ``[x cm, y cm, θ rad]``; θ is not wrapped.
        velocity: ``(2,)`` body velocity ``[v cm/s, ω rad/s]`` at the sample
            (ideal loop: the command it last followed, after any speed limiter).
        integral: ``(2,)`` integral of the wheel-speed loop's velocity error
            (non-ideal loop only; zero for the ideal one).
    """

    pose: jax.Array
    velocity: jax.Array
    integral: jax.Array


def initial_state(init: jax.Array) -> RobotState:
    """Return the robot at rest at ``init``, a ``(3,)`` pose ``[x cm, y cm, θ rad]``."""
    init = jnp.asarray(init)
    init = init.astype(jnp.result_type(init, float))  # integers as the float dtype
    zeros = jnp.zeros((2,), init.dtype)
    return RobotState(pose=init, velocity=zeros, integral=zeros)


def rate_limit(value: jax.Array, previous: jax.Array, rate: jax.Array, dt: jax.Array) -> jax.Array:
    """``value`` moved from ``previous`` by at most ``rate · dt`` (docs/model.md §4.2.2).

    One axis of a speed limiter's acceleration limit. A ``rate`` of 0 means
    no limit: ``value`` passes unchanged, bit for bit. Differentiable in all
    four arguments: where the limit binds the result is ``previous ± rate dt``,
    elsewhere ``value``.
    """
    step = jnp.where(rate > 0, rate * dt, jnp.inf)
    return jnp.clip(value, previous - step, previous + step)


def _polynomial(z: jax.Array, coefficients: tuple[float, ...]) -> jax.Array:
    """Return ``Σ c_k z^k`` by Horner's rule (in ``lax``: see ``sin_cos``)."""
    const = _constants(z)
    acc = lax.full_like(z, coefficients[-1])
    for c in coefficients[-2::-1]:
        acc = lax.add(lax.mul(acc, z), const(c))
    return acc


def _constants(x: jax.Array) -> Callable:
    """Scalar constants in ``x``'s dtype, weakly typed as ``x`` is.

    Mixed with ``x`` in ``lax`` they act as Python numbers do in ``jnp``: a
    result is weakly typed (takes a caller's dtype) only if ``x`` was.
    """
    if x.weak_type:
        return lambda c: lax.full_like(x, c, shape=())
    return lambda c: np.asarray(c, x.dtype)


@jax.custom_jvp
def sin_cos(angle: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Return ``(cos angle, sin angle)`` within an ulp or two, elementwise.

    Cody–Waite reduction to ``r ∈ [−π/4, π/4]`` and ``angle = r + k π/2``,
    minimax polynomials for ``cos r`` and ``sin r``, then the quadrant ``k``
    permutes and negates them. Only float32 and float64 have coefficients;
    other dtypes fall back to ``jnp.cos``/``jnp.sin``.

    Args:
        angle: angle in rad, any shape; accurate for ``|angle|`` up to about
            1e6 (float64) or 1e5 (float32).

    Returns:
        ``(cos, sin)``, each the shape and dtype of ``angle``.
    """
    angle = jnp.asarray(angle)
    dtype = np.dtype(angle.dtype)
    if dtype not in _PIO2:
        return jnp.cos(angle), jnp.sin(angle)
    # Written in lax, each constant in the angle's dtype: the same operations
    # as the jnp spelling, bit for bit, at half its cost to trace (the
    # rollouts call this a dozen times per step they trace).
    const = _constants(angle)
    p1, p2, p3 = (const(p) for p in _PIO2[dtype])
    k = lax.round(lax.mul(angle, const(2 / np.pi)), _NEAREST_EVEN)
    r = lax.sub(lax.sub(lax.sub(angle, lax.mul(k, p1)), lax.mul(k, p2)), lax.mul(k, p3))
    z = lax.mul(r, r)
    sin_r = lax.add(r, lax.mul(lax.mul(r, z), _polynomial(z, _SIN[dtype])))
    cos_r = lax.sub(const(1), lax.mul(const(0.5), z))
    cos_r = lax.add(cos_r, lax.mul(lax.mul(z, z), _polynomial(z, _COS[dtype])))
    # The quadrant as an integer: k mod 4 from its two low bits.
    quadrant = lax.convert_element_type(k, np.int32)
    one, two = np.int32(1), np.int32(2)
    odd = lax.eq(lax.bitwise_and(quadrant, one), one)
    cos_k = lax.select(odd, sin_r, cos_r)
    sin_k = lax.select(odd, cos_r, sin_r)
    cos_flip = lax.eq(lax.bitwise_and(lax.add(quadrant, one), two), two)
    sin_flip = lax.eq(lax.bitwise_and(quadrant, two), two)
    return lax.select(cos_flip, lax.neg(cos_k), cos_k), lax.select(sin_flip, lax.neg(sin_k), sin_k)


@sin_cos.defjvp
def _sin_cos_jvp(primals, tangents):
    (angle,), (d_angle,) = primals, tangents
    cos, sin = sin_cos(angle)
    # The derivative of a rotation is the rotation turned by π/2: exact, and
    # cheaper than differentiating the polynomials.
    return (cos, sin), (-sin * d_angle, cos * d_angle)


# Taylor coefficients (−1)^k / (2k + 1)! of sin x / x; on |x| ≤ π/2 the first
# omitted term is below 1e-20 (float64, 12 terms) or 1e-9 (float32, 7 terms).
_SIN_TAYLOR = {
    np.dtype(np.float64): tuple((-1) ** k / math.factorial(2 * k + 1) for k in range(12)),
    np.dtype(np.float32): tuple((-1) ** k / math.factorial(2 * k + 1) for k in range(7)),
}


def sin_small(angle: jax.Array) -> jax.Array:
    """Return ``sin angle`` for ``|angle| ≤ π/2``, by its Taylor series.

    No range reduction, so cheaper than ``sin_cos``; outside ``[−π/2, π/2]``
    the result is wrong. The law uses it for the saturated distance
    ``r̄_e ∈ [0, π/2]`` (Eq. 6).
    """
    angle = jnp.asarray(angle)
    dtype = np.dtype(angle.dtype)
    if dtype not in _SIN_TAYLOR:
        return jnp.sin(angle)
    return angle * _polynomial(angle * angle, _SIN_TAYLOR[dtype])


def _sinc_of(u: jax.Array, sin_u: jax.Array) -> jax.Array:
    """Return ``sin(u)/u`` given ``sin u``, by its series where it would cancel."""
    small = jnp.abs(u) < _SINC_SERIES_BELOW
    safe_u = jnp.where(small, 1.0, u)  # double-where: no 0/0 in the unused branch
    u2 = u * u
    return jnp.where(small, 1.0 - u2 / 6.0 * (1.0 - u2 / 20.0), sin_u / safe_u)


def sinc(u: jax.Array) -> jax.Array:
    """Return ``sin(u)/u`` (unnormalised), exact and with finite gradients at 0."""
    return _sinc_of(u, sin_cos(u)[1])


def _half_turn_small(u: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Return ``(cos u, sin u, sin(u)/u)`` for ``|u| ≤ π/4``: ``sin_cos`` without its reduction.

    On ``[−π/4, π/4]`` the kernels of ``sin_cos`` apply directly, and
    ``sin(u)/u = 1 + u² S(u²)`` needs neither a division nor a branch at 0.
    """
    dtype = np.dtype(u.dtype)
    if dtype not in _SIN:
        cos_u, sin_u = sin_cos(u)
        return cos_u, sin_u, _sinc_of(u, sin_u)
    z = u * u
    sinc_u = 1 + z * _polynomial(z, _SIN[dtype])
    cos_u = (1 - 0.5 * z) + z * z * _polynomial(z, _COS[dtype])
    return cos_u, u * sinc_u, sinc_u


def arc_advance(
    position: jax.Array,
    heading: jax.Array,
    v: jax.Array,
    omega: jax.Array,
    h: jax.Array,
    *,
    small_turn: bool = False,
) -> tuple[jax.Array, jax.Array]:
    """Advance the robot by ``h`` seconds at constant ``(v, ω)``, exactly (docs/model.md §4).

    The robot turns by ``ω h`` and moves along the chord of length
    ``v h sinc(ω h / 2)`` in the direction ``θ + ω h / 2``. With ``u = ω h / 2``
    and ``e = cos u + i sin u``: ``position += chord · heading · e`` and
    ``heading ← heading · e²``.

    Args:
        position: complex ``x + i y``, cm.
        heading: complex ``cos θ + i sin θ``.
        v: linear velocity, cm/s.
        omega: angular velocity, rad/s.
        h: duration, s.
        small_turn: the caller guarantees ``|ω h| ≤ π/2`` (static): the
            turn's cosine and sine then need no range reduction.

    Returns:
        ``(position, heading)`` after ``h``, complex, broadcast shape.
    """
    turn, chord = arc_factors(v, omega, h, small_turn=small_turn)
    return arc_apply(position, heading, turn, chord)


def arc_factors(
    v: jax.Array, omega: jax.Array, h: jax.Array, *, small_turn: bool = False
) -> tuple[jax.Array, jax.Array]:
    """The parts of ``arc_advance`` that depend on the motion only: ``(e, chord)``.

    ``e = cos(ω h / 2) + i sin(ω h / 2)`` (complex) and ``chord = v h sinc(ω h / 2)``
    (cm). Computed once, they move any pose by the same arc (``arc_apply``):
    an estimator and its latency compensation share them.
    """
    half_turn = 0.5 * omega * h
    if small_turn:
        cos_half, sin_half, sinc_half = _half_turn_small(half_turn)
    else:
        cos_half, sin_half = sin_cos(half_turn)
        sinc_half = _sinc_of(half_turn, sin_half)
    return jax.lax.complex(cos_half, sin_half), v * h * sinc_half


def arc_apply(
    position: jax.Array, heading: jax.Array, turn: jax.Array, chord: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Move ``(position, heading)`` along the arc of ``arc_factors``; returns both, complex."""
    mid_heading = heading * turn
    # As one complex expression: written on the real and imaginary parts, the
    # ideal loop ran 1.6x slower on XLA:CPU (2.2e8 against 3.5e8 robot-steps/s
    # at N = 10^5), and the non-ideal loop no faster.
    return position + chord * mid_heading, mid_heading * turn


def arc_step(pose: jax.Array, v: jax.Array, omega: jax.Array, h: jax.Array) -> jax.Array:
    """Advance ``pose`` by ``h`` seconds at constant ``(v, ω)``, exactly (docs/model.md §4).

    The same arc as ``arc_advance``, on a pose.

    Args:
        pose: ``(..., 3)`` ``[x cm, y cm, θ rad]``.
        v: linear velocity, cm/s.
        omega: angular velocity, rad/s.
        h: duration, s.

    Returns:
        The pose after ``h``, same shape as ``pose``.
    """
    x, y, theta = pose[..., 0], pose[..., 1], pose[..., 2]
    cos_theta, sin_theta = sin_cos(theta)
    position, _ = arc_advance(
        jax.lax.complex(x, y), jax.lax.complex(cos_theta, sin_theta), v, omega, h
    )
    return jnp.stack([position.real, position.imag, theta + omega * h], axis=-1)
