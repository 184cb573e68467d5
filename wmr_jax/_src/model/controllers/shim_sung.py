"""The Shim–Sung asymptotic pose controller, one equation per function (docs/model.md §2–3).

All but ``control`` and ``control_diagnostics`` are pure elementwise building
blocks that check nothing. ``φ_e`` and ``θ_e`` travel as cosine and sine: no
``atan2`` in a rollout, and values and gradients stay finite at ``r_e = 0``.
A positive ``temperature`` replaces each switch by a smooth one that tends to
the hard law (``None``) as it goes to 0.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from wmr_jax._src.checks import check_temperature, is_traced
from wmr_jax._src.model.controllers.base import Controller, check_law_inputs, register_controller
from wmr_jax._src.model.dynamics import sin_cos, sin_small
from wmr_jax._src.model.params import Gains, Robot, feasible, sampled, validate_gains


class PolarError(NamedTuple):
    """Error coordinates of docs/model.md §2 (Eq. 3), angles as cosine and sine.

    Attributes:
        r: ``r_e ≥ 0``, distance to the reference, cm.
        cos_phi: ``cos φ_e``; 1 when ``r_e = 0`` (choice: ``φ_e = 0`` there).
        sin_phi: ``sin φ_e``; 0 when ``r_e = 0``.
        cos_theta: ``cos θ_e`` with ``θ_e = θ_r − θ_c``.
        sin_theta: ``sin θ_e``.
    """

    r: jax.Array
    cos_phi: jax.Array
    sin_phi: jax.Array
    cos_theta: jax.Array
    sin_theta: jax.Array


class Diagnostics(NamedTuple):
    """Everything the law computes for one pose (see ``control_diagnostics``)."""

    v: jax.Array
    omega: jax.Array
    region: jax.Array
    d: jax.Array
    eps: jax.Array
    lyapunov: jax.Array
    r_e: jax.Array
    phi_e: jax.Array
    theta_e: jax.Array


def wrap_angle(angle: jax.Array) -> jax.Array:
    """Wrap an angle in rad to ``[−π, π)``."""
    return jnp.mod(jnp.asarray(angle) + jnp.pi, 2 * jnp.pi) - jnp.pi


def polar_error(
    pose: jax.Array,
    ref: jax.Array,
    *,
    frame: tuple[jax.Array, jax.Array, jax.Array, jax.Array] | None = None,
) -> PolarError:
    """Return the error of ``pose`` with respect to ``ref`` in the robot frame (Eq. 3).

    Args:
        pose: ``(..., 3)`` current pose ``[x cm, y cm, θ rad]``; not read
            (may be ``None``) when ``frame`` is given.
        ref: ``(..., 3)`` reference pose, broadcastable against ``pose``.
        frame: the same pose as ``(x, y, cos θ, sin θ)``, when the caller
            carries it that way (the rollouts do).

    Returns:
        A ``PolarError`` whose fields have the broadcast leading shape.
    """
    ref = jnp.asarray(ref)
    if frame is None:
        pose = jnp.asarray(pose)
        x, y = pose[..., 0], pose[..., 1]
        cos_c, sin_c = sin_cos(pose[..., 2])
    else:
        x, y, cos_c, sin_c = frame
    cos_r, sin_r = sin_cos(ref[..., 2])
    dx, dy = ref[..., 0] - x, ref[..., 1] - y
    # e_x + i e_y = (cos θ_c − i sin θ_c)(Δx + i Δy), one complex product.
    dtype = jnp.result_type(cos_c, sin_c, dx, dy, float)
    e = jax.lax.complex(jnp.asarray(cos_c, dtype), -jnp.asarray(sin_c, dtype)) * jax.lax.complex(
        jnp.asarray(dx, dtype), jnp.asarray(dy, dtype)
    )
    e_x, e_y = e.real, e.imag
    # Double-where keeps value and gradient finite at r_e = 0; where r_e²
    # underflows the robot is on the reference (φ_e = 0), in Region 0 either way.
    r_sq = e_x * e_x + e_y * e_y
    positive = r_sq > 0
    safe_r = jnp.sqrt(jnp.where(positive, r_sq, 1.0))
    inv_r = 1.0 / safe_r  # one division shared by cos φ_e and sin φ_e
    r = jnp.where(positive, safe_r, 0.0)
    cos_phi = jnp.where(positive, e_x * inv_r, 1.0)
    sin_phi = e_y * inv_r  # 0 where r_e = 0
    # θ_e = θ_r − θ_c by the angle-difference identities; its 2π wrap is implicit.
    cos_theta = cos_r * cos_c + sin_r * sin_c
    sin_theta = sin_r * cos_c - cos_r * sin_c
    return PolarError(r, cos_phi, sin_phi, cos_theta, sin_theta)


def error_angles(err: PolarError) -> tuple[jax.Array, jax.Array]:
    """Return ``(φ_e, θ_e)`` in rad, ``φ_e ∈ (−π, π]`` and ``θ_e ∈ [−π, π)`` (diagnostics)."""
    phi = jnp.arctan2(err.sin_phi, err.cos_phi)
    theta = wrap_angle(jnp.arctan2(err.sin_theta, err.cos_theta))
    return phi, theta


def _step(
    x: jax.Array, *, strict: bool, temperature: float | None, scale: jax.Array = 1.0
) -> jax.Array:
    """Return the indicator of ``x > 0`` (strict) or ``x ≥ 0``, or ``sigmoid(x / (scale T))``."""
    x = jnp.asarray(x)
    if temperature is None:
        return jnp.where(x > 0 if strict else x >= 0, 1.0, 0.0).astype(x.dtype)
    tie = _tie_break(temperature)
    return jax.nn.sigmoid(x / (scale * temperature) + (-tie if strict else tie))


def _tie_break(temperature: float) -> float:
    """The offset ``log(1 + 1/T)`` that makes a relaxed switch decide a tie as the hard one."""
    return jnp.log1p(1.0 / temperature)


def sgn(x: jax.Array, *, temperature: float | None = None) -> jax.Array:
    """Return the paper's ``Sgn(x)``: 1 if ``x > 0``, else −1 (so ``Sgn(0) = −1``) (Eq. 8).

    NaN in gives NaN out, as NumPy's ``sign`` does, not to hide where a run diverged.
    """
    x = jnp.asarray(x)
    if temperature is None:
        return jnp.where(x > 0, 1.0, jnp.where(x <= 0, -1.0, x)).astype(x.dtype)
    return jnp.tanh(x / temperature - _tie_break(temperature))  # Sgn(0) = −1


def saturated_distance(r: jax.Array, r_m: jax.Array, *, temperature: float | None = None):
    """Return ``r̄_e = min(π r_e / (2 R_m), π/2)`` in rad (docs/model.md §3, before Eq. 6).

    The relaxed form is the soft minimum ``ℓ − T softplus((ℓ − π/2)/T)`` for
    ``ℓ = π r_e / (2 R_m)``, evaluated as ``min(ℓ, π/2) − T log(1 +
    e^{−|ℓ − π/2|/T})``, which never subtracts two large numbers.
    """
    linear = r * ((jnp.pi / 2) / jnp.asarray(r_m))  # the factor is per gain set, not per step
    if temperature is None:
        return jnp.minimum(linear, jnp.pi / 2)
    excess = linear - jnp.pi / 2
    above = excess > 0
    nearest = jnp.where(above, jnp.pi / 2, linear)
    gap = jnp.where(above, -excess, excess)  # −|excess|
    return nearest - temperature * jnp.log(1.0 + jnp.exp(gap / temperature))


def direction_flag(err: PolarError, phi_m: jax.Array, *, temperature: float | None = None):
    """Return the direction ``d`` (docs/model.md §3): 1 ahead, −1 behind, 0 turn in place.

    ``d = 1`` if ``|φ_e| ≤ Φ_m``; ``d = −1`` if ``|φ_e| > π − Φ_m``; else 0.
    """
    cos_m = jnp.cos(phi_m)
    ahead = _step(err.cos_phi - cos_m, strict=False, temperature=temperature)
    behind = _step(-cos_m - err.cos_phi, strict=True, temperature=temperature)
    return ahead - behind


def fold(cos_a: jax.Array, sin_a: jax.Array, *, temperature: float | None = None):
    """Return ``(cos ā, sin ā)`` of ``ā = fold(a)``, front and back alike (docs/model.md §3).

    ``cos ā = |cos a|`` and ``sin ā = sign(cos a) sin a`` (no flip at
    ``cos a = 0``, in the relaxed form too).
    """
    cos_a, sin_a = jnp.asarray(cos_a), jnp.asarray(sin_a)
    if temperature is None:
        # A NaN cosine flips by NaN: no folded angle is made up for it.
        flip = jnp.where(cos_a < 0, -1.0, jnp.where(jnp.isnan(cos_a), jnp.nan, 1.0))
        flip = flip.astype(cos_a.dtype)
    else:
        flip = jnp.tanh(cos_a / temperature + _tie_break(temperature))  # no flip at 0
    return flip * cos_a, flip * sin_a


def blend(
    err: PolarError,
    d: jax.Array,
    gains: Gains,
    *,
    temperature: float | None = None,
) -> jax.Array:
    """Return the blend ``ε`` of Eq. 8, with the region tests in docs/model.md §3 order.

    1. ``r_e ≤ R_e`` (Region 0): ``ε = 0``.
    2. ``d = 0`` (Region 3): ``ε = 1``, as the paper's proof (Case 1) has it
       (choice, docs/model.md §3).
    3. ``r_e < R_a`` (Region 1): ``ε = 0.5 − α Sgn(sin θ̄_e) Sgn(sin θ̄_e + sin φ̄_e)``.
    4. otherwise (Region 2): ``ε = 1``.

    Written as ``ε = (1 − [0]) (1 − d² [1] (1 − ε₁))`` with ``[k]`` the
    region indicators: exact for ``d ∈ {−1, 0, 1}``, smooth when relaxed.
    """
    _, sin_phi_bar = fold(err.cos_phi, err.sin_phi, temperature=temperature)
    _, sin_theta_bar = fold(err.cos_theta, err.sin_theta, temperature=temperature)
    in_region_0 = _step(gains.r_e - err.r, strict=False, temperature=temperature, scale=gains.r_e)
    inside_r_a = _step(gains.r_a - err.r, strict=True, temperature=temperature, scale=gains.r_a)
    eps_1 = 0.5 - gains.alpha * sgn(sin_theta_bar, temperature=temperature) * sgn(
        sin_theta_bar + sin_phi_bar, temperature=temperature
    )
    return (1 - in_region_0) * (1 - d * d * inside_r_a * (1 - eps_1))


def commands(
    err: PolarError, gains: Gains, *, temperature: float | None = None
) -> tuple[jax.Array, jax.Array]:
    """Return the velocity command ``(v_m cm/s, ω_m rad/s)`` of Eq. 6 and 7.

    ``v_m = k_r d sin(r̄_e) cos φ̄_e`` and
    ``ω_m = k_θ (ε sin φ̄_e + (1 − ε) sin θ̄_e)``.
    """
    d = direction_flag(err, gains.phi_m, temperature=temperature)
    eps = blend(err, d, gains, temperature=temperature)
    r_bar = saturated_distance(err.r, gains.r_m, temperature=temperature)
    cos_phi_bar, sin_phi_bar = fold(err.cos_phi, err.sin_phi, temperature=temperature)
    _, sin_theta_bar = fold(err.cos_theta, err.sin_theta, temperature=temperature)
    # The hard r̄_e lies in [0, π/2]; the relaxed one can leave it slightly.
    sin_r_bar = sin_small(r_bar) if temperature is None else sin_cos(r_bar)[1]
    v = gains.kr * d * sin_r_bar * cos_phi_bar
    omega = gains.k_theta * (eps * sin_phi_bar + (1 - eps) * sin_theta_bar)
    return v, omega


def region_label(err: PolarError, gains: Gains) -> jax.Array:
    """Return the region 0–3 of docs/model.md §3, by the same order of tests as ``blend``."""
    d = direction_flag(err, gains.phi_m)
    return jnp.where(
        err.r <= gains.r_e, 0, jnp.where(d == 0, 3, jnp.where(err.r < gains.r_a, 1, 2))
    ).astype(jnp.int32)


def lyapunov(err: PolarError) -> jax.Array:
    """Return ``V = r_e²/2 + (1 − cos φ̄_e) + (1 − cos θ̄_e)`` (proof of Theorem 1)."""
    cos_phi_bar, _ = fold(err.cos_phi, err.sin_phi)
    cos_theta_bar, _ = fold(err.cos_theta, err.sin_theta)
    return 0.5 * err.r**2 + (1 - cos_phi_bar) + (1 - cos_theta_bar)


def wheel_speeds(v: jax.Array, omega: jax.Array, robot: Robot) -> jax.Array:
    """Return rim speeds ``[v_L, v_R] = [v − L ω, v + L ω]`` in cm/s, shape ``(..., 2)``.

    ``v``, ``omega`` and ``robot.half_track`` broadcast against each other.
    """
    v, omega = jnp.asarray(v), jnp.asarray(omega)
    return jnp.stack([v - robot.half_track * omega, v + robot.half_track * omega], axis=-1)


def control(
    pose: jax.Array, ref: jax.Array, gains: Gains, *, temperature: float | None = None
) -> tuple[jax.Array, jax.Array]:
    """Return the command ``(v cm/s, ω rad/s)`` of the asymptotic controller (checked, jitted).

    Args:
        pose: ``(..., 3)`` current pose ``[x cm, y cm, θ rad]``.
        ref: ``(..., 3)`` reference pose, broadcastable against ``pose``.
        gains: controller gains (scalars, or arrays that broadcast against the poses).
        temperature: ``None`` for the paper's law; positive for its smooth relaxation.
    """
    if temperature is not None and not is_traced(temperature):  # a tuner's traced one passes
        temperature = check_temperature("temperature", temperature)
    pose, ref, gains = check_law_inputs(pose, ref, gains, Gains, validate_gains)
    return _control_jit(pose, ref, gains, temperature=temperature)


def _law(pose, ref, gains, *, temperature=None, frame=None):
    """The law as the loops call it (``Controller.command``)."""
    return commands(polar_error(pose, ref, frame=frame), gains, temperature=temperature)


_control_jit = jax.jit(_law)  # the temperature an argument: a new value does not recompile


def control_diagnostics(pose: jax.Array, ref: jax.Array, gains: Gains) -> Diagnostics:
    """Return the command with the region, ``d``, ``ε``, ``V`` and error coordinates."""
    return _diagnostics_jit(*check_law_inputs(pose, ref, gains, Gains, validate_gains))


@jax.jit
def _diagnostics_jit(pose: jax.Array, ref: jax.Array, gains: Gains) -> Diagnostics:
    err = polar_error(pose, ref)
    d = direction_flag(err, gains.phi_m)
    v, omega = commands(err, gains)
    phi, theta = error_angles(err)
    return Diagnostics(
        v=v,
        omega=omega,
        region=region_label(err, gains),
        d=d,
        eps=blend(err, d, gains),
        lyapunov=lyapunov(err),
        r_e=err.r,
        phi_e=phi,
        theta_e=theta,
    )


def pose_region(pose: jax.Array, ref: jax.Array, gains: Any, *, frame=None) -> jax.Array:
    """``region_label`` of a pose (``Controller.region``); any gains with the shape fields."""
    return region_label(polar_error(pose, ref, frame=frame), gains)


SHIM_SUNG = register_controller(
    Controller(
        name="shim-sung",
        command=_law,
        params_type=Gains,
        validate=validate_gains,
        region=pose_region,
        smooth=True,
        # The rollout checked their arguments; the warnings name its caller.
        check_robot=functools.partial(feasible, warn=True, stacklevel=4),
        check_sampling=functools.partial(sampled, stacklevel=4),
    )
)
"""The Shim–Sung asymptotic controller of the paper, the default everywhere."""
