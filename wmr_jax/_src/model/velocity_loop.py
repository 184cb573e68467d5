"""The non-ideal velocity loop: wheel-speed control of the Eq. 5 dynamics (docs/model.md §4).

Over each control period the command becomes rim-speed set points within
``±V_max``; a computed-torque loop with torques clipped at ``±τ_max`` drives
the dynamics ``H q̇ + G(q) = B τ``; ``substeps`` RK4 steps advance the
velocity, and the exact arc at the mean velocity the pose.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import MAX_STEPS, is_traced
from wmr_jax._src.model import dynamics
from wmr_jax._src.model.params import Robot

DEFAULT_SUBSTEPS = 10
# RK4 is stable on ẏ = −k y for k h < 2.785; keep a margin, the loop is
# nonlinear once torques saturate.
_MAX_STIFFNESS = 2.5


def inertia(robot: Robot) -> tuple[jax.Array, jax.Array]:
    """Return the diagonal of ``H``: ``(m₁₁ kg, m₂₂ kg·cm²)`` (Eq. 5)."""
    M, m, r = robot.body_mass, robot.wheel_mass, robot.wheel_radius
    L, a = robot.half_track, robot.com_offset
    spin = 0.5 * m * r**2  # each wheel about its axle
    across = 0.25 * m * r**2  # each wheel about a vertical diameter
    body = M * robot.body_diameter**2 / 8.0
    m11 = M + 2 * m + 2 * spin / r**2
    m22 = body + M * a**2 + 2 * m * L**2 + 2 * across + 2 * spin * L**2 / r**2
    return m11, m22


def kinetic_energy(velocity: jax.Array, robot: Robot) -> jax.Array:
    """Return ``(m₁₁ v² + m₂₂ ω²)/2`` in kg·cm²/s² for ``velocity (..., 2)``."""
    m11, m22 = inertia(robot)
    return 0.5 * (m11 * velocity[..., 0] ** 2 + m22 * velocity[..., 1] ** 2)


def _coriolis(velocity: jax.Array, robot: Robot) -> jax.Array:
    """``G(q) = (−M a ω², M a v ω)`` of Eq. 5."""
    v, w = velocity[..., 0], velocity[..., 1]
    ma = robot.body_mass * robot.com_offset
    return jnp.stack([-ma * w * w, ma * v * w], axis=-1)


def body_acceleration(velocity: jax.Array, torques: jax.Array, robot: Robot) -> jax.Array:
    """Return ``q̇ = H⁻¹ (B τ − G(q))`` for wheel torques ``τ = (τ_L, τ_R)`` (Eq. 5).

    Args:
        velocity: ``(..., 2)`` ``[v cm/s, ω rad/s]``.
        torques: ``(..., 2)`` ``[τ_L, τ_R]`` in kg·cm²/s².
        robot: the robot's parameters.

    Returns:
        ``(..., 2)`` ``[v̇ cm/s², ω̇ rad/s²]``.
    """
    m11, m22 = inertia(robot)
    r, L = robot.wheel_radius, robot.half_track
    tau_l, tau_r = torques[..., 0], torques[..., 1]
    drive = jnp.stack([(tau_l + tau_r) / r, L * (tau_r - tau_l) / r], axis=-1)
    rhs = drive - _coriolis(velocity, robot)
    return jnp.stack([rhs[..., 0] / m11, rhs[..., 1] / m22], axis=-1)


def wheel_torques(
    velocity: jax.Array, target: jax.Array, integral: jax.Array, model: Robot
) -> jax.Array:
    """Return the clipped computed-torque command ``[τ_L, τ_R]`` of the wheel loop.

    ``B τ = H (k_p (q* − q) + k_i z) + G(q)`` with the model's ``H``, ``G``,
    ``B``; each torque then within ``±τ_max``.
    """
    m11, m22 = inertia(model)
    desired = model.speed_gain * (target - velocity) + model.integral_gain * integral
    coriolis = _coriolis(velocity, model)
    force = m11 * desired[..., 0] + coriolis[..., 0]
    moment = m22 * desired[..., 1] + coriolis[..., 1]
    r, L = model.wheel_radius, model.half_track
    tau_r = 0.5 * r * (force + moment / L)
    tau_l = 0.5 * r * (force - moment / L)
    torques = jnp.stack([tau_l, tau_r], axis=-1)
    return jnp.clip(torques, -model.torque_max, model.torque_max)


def limit_wheels(velocity: jax.Array, robot: Robot, *, mode: str = "clip") -> jax.Array:
    """Return the body velocity whose rim speeds lie within ``±V_max``.

    Args:
        velocity: ``(..., 2)`` ``[v, ω]``.
        robot: gives ``L`` and ``V_max``.
        mode: ``"clip"`` each rim speed on its own, or ``"scale"`` both by
            the same factor (keeps ``ω/v``).
    """
    v, w = _limit_split(velocity[..., 0], velocity[..., 1], robot, mode)
    return jnp.stack([v, w], axis=-1)


class WheelState(NamedTuple):
    """The wheel loop's state: ``v`` cm/s, ``omega`` rad/s, error integrals ``z_v``, ``z_omega``."""

    v: jax.Array
    omega: jax.Array
    z_v: jax.Array
    z_omega: jax.Array


def _limit_split(v, w, robot: Robot, mode: str):
    """``limit_wheels`` on separate ``v``, ``ω``."""
    L, v_max = robot.half_track, robot.v_max
    left, right = v - L * w, v + L * w
    if mode == "clip":
        left, right = jnp.clip(left, -v_max, v_max), jnp.clip(right, -v_max, v_max)
    elif mode != "scale":
        raise ValueError(f"mode = {mode!r} is not allowed; allowed: 'clip' or 'scale'")
    else:
        excess = jnp.maximum(jnp.maximum(jnp.abs(left), jnp.abs(right)) / v_max, 1.0)
        left, right = left / excess, right / excess
    return 0.5 * (left + right), 0.5 * (right - left) / L


def _loop_rates(target, robot: Robot, model: Robot, with_integral: bool, with_coriolis: bool):
    """Return ``f(wheel) -> d wheel/dt``: ``wheel_torques`` then ``body_acceleration``, unstacked.

    ``wheel`` is ``v + i ω``, with ``z_v + i z_ω`` if ``with_integral``.
    """
    target_v, target_w = target
    m11, m22 = inertia(model)
    true_m11, true_m22 = inertia(robot)
    model_ma = model.body_mass * model.com_offset
    true_ma = robot.body_mass * robot.com_offset
    r, limit = model.wheel_radius, model.torque_max
    # Reciprocals once per period: XLA stores a division instead of fusing it.
    inv_l = 1.0 / model.half_track
    to_v, to_w = (
        1.0 / (robot.wheel_radius * true_m11),
        robot.half_track / (robot.wheel_radius * true_m22),
    )
    inv_m11, inv_m22 = 1.0 / true_m11, 1.0 / true_m22

    def rates(y):
        # Complex pairs, so that XLA computes both parts of each in one loop.
        velocity, integral = y if with_integral else (y, None)
        v, w = velocity.real, velocity.imag
        error_v, error_w = target_v - v, target_w - w
        demand_v, demand_w = model.speed_gain * error_v, model.speed_gain * error_w
        if with_integral:
            demand_v = demand_v + model.integral_gain * integral.real
            demand_w = demand_w + model.integral_gain * integral.imag
        force, moment = m11 * demand_v, m22 * demand_w
        if with_coriolis:
            force, moment = force - model_ma * w * w, moment + model_ma * v * w
        tau_r = jnp.clip(0.5 * r * (force + moment * inv_l), -limit, limit)
        tau_l = jnp.clip(0.5 * r * (force - moment * inv_l), -limit, limit)
        accel_v, accel_w = to_v * (tau_l + tau_r), to_w * (tau_r - tau_l)
        if with_coriolis:
            accel_v = accel_v + inv_m11 * true_ma * w * w
            accel_w = accel_w - inv_m22 * true_ma * v * w
        accel = jax.lax.complex(accel_v, accel_w)
        return (accel, jax.lax.complex(error_v, error_w)) if with_integral else accel

    return rates


def _rk4(f, y, h):
    """One classical RK4 step of ``ẏ = f(y)``, ``y`` a pytree of complex arrays."""

    def along(c, k):
        # y + c k for a real c, without a complex product.
        def step(a, b):
            return jax.lax.complex(a.real + c * b.real, a.imag + c * b.imag)

        return jax.tree.map(step, y, k)

    k1 = f(y)
    k2 = f(along(0.5 * h, k1))
    k3 = f(along(0.5 * h, k2))
    k4 = f(along(h, k3))
    total = jax.tree.map(lambda b1, b2, b3, b4: (b1 + b4) + 2 * (b2 + b3), k1, k2, k3, k4)
    return along(h / 6.0, total)


def advance_split(
    position: jax.Array,
    heading: jax.Array,
    theta: jax.Array,
    wheel: WheelState,
    command: tuple[jax.Array, jax.Array],
    robot: Robot,
    dt: jax.Array,
    *,
    substeps: int = DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
    model: Robot | None = None,
    integral: bool = True,
    coriolis: bool = True,
    small_turn: bool = False,
) -> tuple[jax.Array, jax.Array, jax.Array, WheelState, jax.Array]:
    """Return ``advance`` of a split pose: ``(position, heading, theta, wheel, distance cm)``.

    ``integral=False`` is exact only for ``integral_gain = 0``, ``coriolis=False``
    for ``com_offset = 0``, ``small_turn`` if ``V_max dt / (L substeps) ≤ π/2``.
    """
    model = robot if model is None else model
    target = _limit_split(command[0], command[1], model, wheel_limit)
    rates = _loop_rates(target, robot, model, integral, coriolis)
    h = dt / substeps

    def substep(carry, _):
        position, heading, wheel, covered = carry
        velocity = wheel[0] if integral else wheel
        wheel = _rk4(rates, wheel, h)
        new = wheel[0] if integral else wheel
        new_v, new_w = _limit_split(new.real, new.imag, robot, "clip")
        new = jax.lax.complex(new_v, new_w)
        wheel = (new, wheel[1]) if integral else new
        # Stored once, or XLA:CPU repeats the RK4 step in each output's loop.
        wheel = jax.lax.optimization_barrier(wheel)
        new = wheel[0] if integral else wheel  # the stored one (not new_v, new_w)
        mean_v, mean_w = 0.5 * (velocity.real + new.real), 0.5 * (velocity.imag + new.imag)
        turn, chord = dynamics.arc_factors(mean_v, mean_w, h, small_turn=small_turn)
        position, heading = dynamics.arc_apply(position, heading, turn, chord)
        # Distance and turn in one accumulator |v| h + i ω h: one loop, not two.
        covered = jax.lax.complex(covered.real + jnp.abs(mean_v) * h, covered.imag + mean_w * h)
        return (position, heading, wheel, covered), None

    velocity = jax.lax.complex(wheel.v, wheel.omega)
    z = jax.lax.complex(wheel.z_v, wheel.z_omega)
    start = (velocity, z) if integral else velocity
    carry = (position, heading, start, jnp.zeros_like(position))
    # An inner scan: unrolled, XLA fuses consecutive sub-steps and repeats their work.
    (position, heading, state, covered), _ = jax.lax.scan(substep, carry, None, length=substeps)
    velocity, z = state if integral else (state, z)
    wheel = WheelState(velocity.real, velocity.imag, z.real, z.imag)
    # One Newton step towards |heading| = 1, so that rounding does not drift.
    heading = heading * (1.5 - 0.5 * (heading.real**2 + heading.imag**2))
    return position, heading, theta + covered.imag, wheel, covered.real


def advance(
    state: dynamics.RobotState,
    command: jax.Array,
    robot: Robot,
    dt: jax.Array,
    *,
    substeps: int = DEFAULT_SUBSTEPS,
    wheel_limit: str = "clip",
    model: Robot | None = None,
) -> tuple[dynamics.RobotState, jax.Array]:
    """Move the robot over one control period under the non-ideal loop (docs/model.md §4).

    Args:
        state: pose, body velocity and loop integral at the sample.
        command: ``(2,)`` held command ``[v_m cm/s, ω_m rad/s]``.
        robot: the robot that moves.
        dt: control period, s.
        substeps: inner steps (static).
        wheel_limit: ``"clip"`` or ``"scale"`` the rim-speed set points (static).
        model: the robot the wheel controller believes in (default ``robot``);
            differs from ``robot`` to study model mismatch.

    Returns:
        The state at the next sample and the distance the centre travelled, cm.
    """
    x, y, theta = state.pose[0], state.pose[1], state.pose[2]
    cos_theta, sin_theta = dynamics.sin_cos(theta)
    wheel = WheelState(state.velocity[0], state.velocity[1], state.integral[0], state.integral[1])
    position, _, theta, wheel, travelled = advance_split(
        jax.lax.complex(x, y),
        jax.lax.complex(cos_theta, sin_theta),
        theta,
        wheel,
        (command[0], command[1]),
        robot,
        dt,
        substeps=substeps,
        wheel_limit=wheel_limit,
        model=model,
    )
    pose = jnp.stack([position.real, position.imag, theta])
    velocity = jnp.stack([wheel.v, wheel.omega])
    return dynamics.RobotState(pose, velocity, jnp.stack([wheel.z_v, wheel.z_omega])), travelled


def check_stability(robot: Robot, dt: float, substeps: int) -> None:
    """Raise ``ValueError`` if the inner sub-step is too long for the loop's stiffness.

    The wheel loop's error obeys ``ë + k_p ė + k_i e = 0``; its fastest mode
    has ``|λ| = max((k_p + √(k_p² − 4 k_i)) / 2, √k_i)`` (``k_p`` when
    ``k_i = 0``), and RK4 needs ``|λ| dt / substeps ≤ 2.5``.
    """
    gain, integral = robot.speed_gain, robot.integral_gain
    if is_traced((gain, integral, dt)):
        return
    k_p = np.asarray(gain, dtype=float)
    k_i = np.asarray(integral, dtype=float)
    with np.errstate(over="ignore"):  # k_p² of a huge gain: inf, then refused below
        discriminant = np.maximum(k_p**2 - 4 * k_i, 0.0)
    fastest = float(np.max(np.maximum((k_p + np.sqrt(discriminant)) / 2, np.sqrt(k_i))))
    if not fastest * float(dt) / substeps <= _MAX_STIFFNESS:
        need = fastest * float(dt) / _MAX_STIFFNESS
        need = math.ceil(need) if math.isfinite(need) else math.inf
        allowed = (
            f"substeps >= {need}"
            if need <= MAX_STEPS
            else f"a smaller speed_gain or integral_gain ({need:.3g} substeps, beyond 2^31 - 1)"
        )
        raise ValueError(
            f"substeps = {substeps} is not allowed for robot.speed_gain = "
            f"{float(np.max(k_p)):g} 1/s, robot.integral_gain = {float(np.max(k_i)):g} 1/s² "
            f"and dt = {float(dt):g} s (fastest wheel-loop mode {fastest:.4g} 1/s); allowed: "
            f"{allowed} (|lambda| * dt / substeps <= {_MAX_STIFFNESS})"
        )
