"""The Aicardi et al. (1995) pose controller, a baseline (``docs/model.md §3``).

Its error coordinates and backward-driving rule are those of ``polar.py``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from wmr_jax._src.checks import Parameters, require
from wmr_jax._src.model.controllers.base import Controller, register_controller
from wmr_jax._src.model.controllers.polar import (
    driving_error,
    entry_point,
    gain_values,
    goal_floor,
    hold_at_goal,
)
from wmr_jax._src.model.dynamics import sinc

__all__ = ["AICARDI", "AicardiGains", "aicardi_control", "validate_aicardi_gains"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class AicardiGains(Parameters):
    """Gains of the Aicardi et al. (1995) controller.

    Defaults are the gains of the paper's simulations, ``γ = 3``, ``h = 1``,
    ``k = 6`` (M. Aicardi, G. Casalino, A. Bicchi, A. Balestrino, "Closed loop
    steering of unicycle-like vehicles via Lyapunov techniques", IEEE Robotics
    & Automation Magazine 2(1), 1995, 27–35).

    Attributes:
        gamma: ``γ > 0``, 1/s: ``v = γ ρ cos α``.
        k: ``k > 0``, 1/s: the proportional term ``k α`` of ``ω``.
        h: ``h > 0``, dimensionless: weight of ``θ_A`` in the Lyapunov function.
        backward: static; drive in reverse to a reference in the rear half-plane.
            Off (the paper's law), ``v = γ ρ cos α`` still reverses briefly
            while ``|α| > π/2``, but ``ω`` turns the robot to face the reference.
    """

    gamma: Any = 3.0
    k: Any = 6.0
    h: Any = 1.0
    backward: bool = dataclasses.field(default=False, metadata={"static": True})


def _aicardi_control(
    pose: jax.Array,
    ref: jax.Array,
    gains: AicardiGains,
    *,
    temperature: float | None = None,
    frame: Any = None,
) -> tuple[jax.Array, jax.Array]:
    """Return ``(v cm/s, ω rad/s)`` of Aicardi et al. (1995).

    With ``V = (λ ρ² + α² + h θ_A²)/2`` the paper chooses
    ``v = γ ρ cos α`` and ``ω = k α + γ (cos α sin α / α)(α + h θ_A)``, so that
    ``V̇ = −λ γ ρ² cos² α − k α² ≤ 0``; ``v`` changes sign when driving backwards.
    Within ``goal_floor`` of the reference (``AT_GOAL`` = 1e-3 cm, more far from
    the origin) it only turns, ``ω = k θ_e`` (``polar.py``).

    Args:
        pose: ``(..., 3)`` current pose ``[x cm, y cm, θ rad]``.
        ref: ``(..., 3)`` reference pose.
        gains: ``AicardiGains``.
        temperature: ``None``: the law has no smooth relaxation (``aicardi_control``
            refuses any other value).
        frame: the pose as ``(x, y, cos θ, sin θ)``, as the rollouts hand it to
            the registered law (see ``shim_sung.polar_error``).
    """
    rho, alpha, theta_a, direction = driving_error(pose, ref, backward=gains.backward, frame=frame)
    cos_alpha = jnp.cos(alpha)
    v = direction * gains.gamma * rho * cos_alpha
    omega = gains.k * alpha + gains.gamma * cos_alpha * sinc(alpha) * (alpha + gains.h * theta_a)
    floor = goal_floor(pose, ref, frame=frame)
    return hold_at_goal(rho, alpha, theta_a, v, omega, gains.k, floor)


def validate_aicardi_gains(gains: AicardiGains) -> AicardiGains:
    """Check Aicardi gains (``γ, k, h > 0``, finite; ``backward`` a bool); return them.

    Raises:
        ValueError: naming the field, its value and the allowed range.
    """
    g = gain_values(gains, AicardiGains)
    for name, unit in (("gamma", " 1/s"), ("k", " 1/s"), ("h", "")):
        if g[name] is not None:
            require(f"gains.{name}", g[name], g[name] > 0, f"{name} > 0{unit}")
    return gains


AICARDI = register_controller(
    Controller(
        name="aicardi",
        command=_aicardi_control,
        params_type=AicardiGains,
        validate=validate_aicardi_gains,
    )
)

aicardi_control = entry_point(_aicardi_control, AicardiGains, validate_aicardi_gains)
"""The law called by hand: poses and gains checked first, no ``temperature``."""
