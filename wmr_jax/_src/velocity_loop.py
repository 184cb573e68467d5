"""The non-ideal velocity loop: wheel-speed control of the Eq. 5 dynamics (docs/model.md §4).

Between the pose controller and the robot sits a wheel-speed controller that
can only do so much. Over each control period ``dt``:

1. The command ``(v_m, ω_m)`` becomes rim-speed set points
   ``v_R* = v_m + L ω_m``, ``v_L* = v_m − L ω_m``, limited to ``±V_max``:
   choice (docs/model.md §4) per-wheel clipping by default, as the paper's uneven
   trajectories suggest; ``wheel_limit="scale"`` divides both by one factor
   instead, which keeps the commanded curvature.
2. choice (docs/model.md §4): the wheel-speed controller is a model-based
   (computed-torque) loop with proportional and optional integral action on
   the body velocity ``q = (v, ω)``:
   ``B τ = H (k_p (q* − q) + k_i z) + G(q)``, ``ż = q* − q``, each wheel's
   torque then clipped at ``±τ_max``. Computed torque was chosen over a plain
   PI on each wheel because, with an exact model and unsaturated torques, it
   makes every component of ``q`` a first-order lag ``1/k_p``, so one number
   states how stiff the loop is, and the limit ``k_p → ∞`` is the ideal loop.
   The paper used an adaptive controller (its ref. [14]), whose details it
   does not give.
3. The robot obeys the Euler–Lagrange dynamics of Eq. 5, ``H q̇ + G(q) = B τ``
   with ``τ = (τ_L, τ_R)``:
   ``m₁₁ v̇ − M a ω² = (τ_L + τ_R)/r`` and ``m₂₂ ω̇ + M a v ω = L (τ_R − τ_L)/r``,
   where ``a`` is the centre-of-mass offset ahead of the axle,
   ``m₁₁ = M + 2m + 2 I_w/r²`` and ``m₂₂ = I_b + M a² + 2 m L² + 2 I_d + 2 I_w L²/r²``,
   with the body a uniform disc of diameter ``D`` (``I_b = M D²/8``) and each
   wheel a uniform disc of radius ``r`` (``I_w = m r²/2`` about its axle,
   ``I_d = m r²/4`` about a diameter). Under zero torque the kinetic energy
   ``(m₁₁ v² + m₂₂ ω²)/2`` is conserved.
4. Integration: ``substeps`` inner steps of ``h = dt/substeps``. Velocity and
   integral advance by classical RK4 (torque clipping included in the
   right-hand side); the pose advances by the exact arc (``dynamics.arc_step``)
   at the mean of the sub-step's start and end velocities, which is second
   order and exact once the velocity has settled. After each sub-step each
   wheel's rim speed is held within ``±V_max`` (the motors cannot go faster).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src import dynamics
from wmr_jax._src.params import Robot

__all__ = [
    "DEFAULT_SUBSTEPS",
    "advance",
    "body_acceleration",
    "check_stability",
    "inertia",
    "kinetic_energy",
    "limit_wheels",
    "wheel_torques",
]

DEFAULT_SUBSTEPS = 10

# RK4 is stable on ẏ = −k y for k h < 2.785; keep a margin, the loop is
# nonlinear once torques saturate.
_MAX_STIFFNESS = 2.5


def inertia(robot: Robot) -> tuple[jax.Array, jax.Array]:
    """Return the diagonal of ``H``: ``(m₁₁ kg, m₂₂ kg·cm²)`` (Eq. 5)."""
    M, m, r, L, a = (
        robot.body_mass,
        robot.wheel_mass,
        robot.wheel_radius,
        robot.half_track,
        robot.com_offset,
    )
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
    L, v_max = robot.half_track, robot.v_max
    v, w = velocity[..., 0], velocity[..., 1]
    left, right = v - L * w, v + L * w
    if mode == "clip":
        left, right = jnp.clip(left, -v_max, v_max), jnp.clip(right, -v_max, v_max)
    else:
        excess = jnp.maximum(jnp.maximum(jnp.abs(left), jnp.abs(right)) / v_max, 1.0)
        left, right = left / excess, right / excess
    return jnp.stack([0.5 * (left + right), 0.5 * (right - left) / L], axis=-1)


def _rk4(f, y, h):
    k1 = f(y)
    k2 = f(jax.tree.map(lambda a, b: a + 0.5 * h * b, y, k1))
    k3 = f(jax.tree.map(lambda a, b: a + 0.5 * h * b, y, k2))
    k4 = f(jax.tree.map(lambda a, b: a + h * b, y, k3))
    return jax.tree.map(
        lambda a, b1, b2, b3, b4: a + h / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4), y, k1, k2, k3, k4
    )


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
    model = robot if model is None else model
    target = limit_wheels(command, model, mode=wheel_limit)
    h = dt / substeps

    def loop_rates(y):
        velocity, integral = y
        torques = wheel_torques(velocity, target, integral, model)
        return body_acceleration(velocity, torques, robot), target - velocity

    def substep(carry, _):
        pose, velocity, integral, travelled = carry
        new_velocity, integral = _rk4(loop_rates, (velocity, integral), h)
        new_velocity = limit_wheels(new_velocity, robot, mode="clip")
        mean = 0.5 * (velocity + new_velocity)
        pose = dynamics.arc_step(pose, mean[0], mean[1], h)
        return (pose, new_velocity, integral, travelled + jnp.abs(mean[0]) * h), None

    zero = jnp.zeros((), state.pose.dtype)
    (pose, velocity, integral, travelled), _ = jax.lax.scan(
        substep, (state.pose, state.velocity, state.integral, zero), None, length=substeps
    )
    return dynamics.RobotState(pose, velocity, integral), travelled


def check_stability(robot: Robot, dt: float, substeps: int) -> None:
    """Raise ``ValueError`` if the inner sub-step is too long for the loop's stiffness.

    RK4 on the wheel loop needs ``speed_gain · dt / substeps ≤ 2.5``.
    """
    gain = robot.speed_gain
    if isinstance(gain, jax.core.Tracer) or isinstance(dt, jax.core.Tracer):
        return
    stiffness = float(np.max(np.asarray(gain, dtype=float))) * float(dt) / substeps
    if stiffness > _MAX_STIFFNESS:
        need = math.ceil(float(np.max(np.asarray(gain))) * float(dt) / _MAX_STIFFNESS)
        raise ValueError(
            f"substeps = {substeps} is not allowed for robot.speed_gain = "
            f"{float(np.max(np.asarray(gain))):g} 1/s and dt = {float(dt):g} s; allowed: "
            f"substeps >= {need} (speed_gain * dt / substeps <= {_MAX_STIFFNESS})"
        )
