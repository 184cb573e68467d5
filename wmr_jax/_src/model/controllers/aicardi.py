"""The Aicardi et al. (1995) pose controller, a baseline (``docs/model.md §3``)."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from wmr_jax._src.checks import Parameters, require
from wmr_jax._src.model.controllers import polar
from wmr_jax._src.model.dynamics import sinc


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class AicardiGains(Parameters):
    """Gains of the Aicardi et al. (1995) controller.

    Defaults are the gains of the paper's simulations (M. Aicardi, G. Casalino,
    A. Bicchi, A. Balestrino, "Closed loop steering of unicycle-like vehicles
    via Lyapunov techniques", IEEE Robotics & Automation Magazine 2(1), 1995).

    Attributes:
        gamma: ``γ > 0``, 1/s: ``v = γ ρ cos α``.
        k: ``k > 0``, 1/s: the proportional term ``k α`` of ``ω``.
        h: ``h > 0``, dimensionless: weight of ``θ_A`` in the Lyapunov function.
        backward: static; drive in reverse to a reference in the rear half-plane.
            Off (the paper's law), ``ω`` turns the robot to face the reference.
    """

    gamma: Any = 3.0
    k: Any = 6.0
    h: Any = 1.0
    backward: bool = dataclasses.field(default=False, metadata={"static": True})


def _aicardi_control(pose, ref, gains, *, temperature=None, frame=None):
    """Return ``(v cm/s, ω rad/s)`` of Aicardi et al. (1995) (``polar.polar_command``).

    With ``V = (λ ρ² + α² + h θ_A²)/2``: ``v = γ ρ cos α`` and
    ``ω = k α + γ (cos α sin α / α)(α + h θ_A)``, so ``V̇ ≤ 0``; at the goal
    it turns at ``k``. ``temperature``: ``None`` only (no smooth relaxation).
    """

    def speeds(rho, alpha, theta_a, direction):
        cos_alpha = jnp.cos(alpha)
        v = direction * gains.gamma * rho * cos_alpha
        omega = gains.k * alpha + gains.gamma * cos_alpha * sinc(alpha) * (
            alpha + gains.h * theta_a
        )
        return alpha, v, omega, gains.k

    return polar.polar_command(pose, ref, backward=gains.backward, frame=frame, speeds=speeds)


def validate_aicardi_gains(gains: AicardiGains) -> AicardiGains:
    """Check Aicardi gains (``γ, k, h > 0``, ``backward`` a bool); return them."""
    g = polar.gain_values(gains, AicardiGains)
    for name, unit in (("gamma", " 1/s"), ("k", " 1/s"), ("h", "")):
        if g[name] is not None:
            require(f"gains.{name}", g[name], g[name] > 0, f"{name} > 0{unit}")
    return gains


AICARDI, aicardi_control = polar.polar_controller(
    "aicardi", _aicardi_control, AicardiGains, validate_aicardi_gains
)
