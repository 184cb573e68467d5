"""Robot motion over one control period: the ideal velocity loop (docs/model.md §4).

The ideal robot follows the held command at once, so the unicycle kinematics
(Eq. 2) integrate exactly to an arc (``arc_factors``, ``arc_apply``) of the
position ``x + i y`` and heading ``cos θ + i sin θ``, complex numbers. ``sin_cos``
is a polynomial cosine and sine, which XLA:CPU vectorises, unlike ``jnp.sin``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

# Below this |u| the series 1 − u²/6 + u⁴/120 equals sin(u)/u to float64
# precision (the next term is u⁶/5040 < 1e-27), and sin(u)/u would lose digits.
_SINC_SERIES_BELOW = 1e-3

# π/2 split in three (Cody–Waite): k·part is exact for |k| < 2^20 (float64) or
# 2^16 (float32), so the reduction is precise for |angle| up to 1e6 or 1e5 rad.
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

    One axis of a speed limiter; a ``rate`` of 0 is no limit (``value`` passes bit for bit).
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
    """Scalar constants in ``x``'s dtype, weakly typed as ``x`` is (as numbers in ``jnp``)."""
    if x.weak_type:
        return lambda c: lax.full_like(x, c, shape=())
    return lambda c: np.asarray(c, x.dtype)


@jax.custom_jvp
def sin_cos(angle: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Return ``(cos angle, sin angle)`` within an ulp or two, elementwise.

    Cody–Waite reduction to ``r ∈ [−π/4, π/4]``, minimax polynomials, then
    the quadrant; dtypes other than float32/float64 use ``jnp.cos``/``jnp.sin``.

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
    # In lax: the jnp spelling's operations bit for bit, at half its cost to trace.
    const = _constants(angle)
    p1, p2, p3 = (const(p) for p in _PIO2[dtype])
    k = lax.round(lax.mul(angle, const(2 / np.pi)), lax.RoundingMethod.TO_NEAREST_EVEN)
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

    No range reduction, so cheaper than ``sin_cos``; for ``r̄_e ∈ [0, π/2]`` (Eq. 6).
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
    """Return ``(cos u, sin u, sin(u)/u)`` for ``|u| ≤ π/4``: ``sin_cos`` without its reduction."""
    dtype = np.dtype(u.dtype)
    if dtype not in _SIN:
        cos_u, sin_u = sin_cos(u)
        return cos_u, sin_u, _sinc_of(u, sin_u)
    z = u * u
    sinc_u = 1 + z * _polynomial(z, _SIN[dtype])
    cos_u = (1 - 0.5 * z) + z * z * _polynomial(z, _COS[dtype])
    return cos_u, u * sinc_u, sinc_u


def arc_factors(
    v: jax.Array, omega: jax.Array, h: jax.Array, *, small_turn: bool = False
) -> tuple[jax.Array, jax.Array]:
    """The exact arc of ``(v, ω)`` held for ``h`` s, apart from the pose it moves (§4).

    The robot turns by ``ω h`` and moves along the chord ``v h sinc(ω h / 2)``
    in the direction ``θ + ω h / 2``. Returns ``(e, chord)``, ``e = cos(ω h / 2)
    + i sin(ω h / 2)`` and the chord in cm: computed once, they move any pose by
    the same arc (``arc_apply``). ``small_turn``: the caller guarantees
    ``|ω h| ≤ π/2`` (static).
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
    """Move ``position`` (``x + i y`` cm) and ``heading`` (``cos θ + i sin θ``) by the arc."""
    mid_heading = heading * turn
    # One complex expression: on the real and imaginary parts XLA:CPU is slower.
    return position + chord * mid_heading, mid_heading * turn


def arc_step(pose: jax.Array, v: jax.Array, omega: jax.Array, h: jax.Array) -> jax.Array:
    """Advance ``pose`` by ``h`` seconds at constant ``(v, ω)``, exactly (docs/model.md §4).

    ``pose``: ``(..., 3)`` ``[x cm, y cm, θ rad]``; ``v`` cm/s, ``omega`` rad/s, ``h`` s.
    """
    x, y, theta = pose[..., 0], pose[..., 1], pose[..., 2]
    cos_theta, sin_theta = sin_cos(theta)
    turn, chord = arc_factors(v, omega, h)
    position, _ = arc_apply(
        jax.lax.complex(x, y), jax.lax.complex(cos_theta, sin_theta), turn, chord
    )
    return jnp.stack([position.real, position.imag, theta + omega * h], axis=-1)
