"""The Astolfi polar law in Corke's form, a baseline (``docs/model.md §3``)."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import Parameters, require
from wmr_jax._src.model.controllers import polar


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class AstolfiGains(Parameters):
    """Gains of the Astolfi polar law as given by Corke, *Robotics, Vision and Control*.

    Defaults are the book's "moving to a pose" example (P. Corke, Springer
    2011, §4.2.4; 2nd ed. 2017, §4.1.1.4, the ``sl_drivepose`` model). The law
    is A. Astolfi, "Exponential stabilization of a wheeled mobile robot via
    discontinuous control", J. Dyn. Sys., Meas., Control 121(1), 1999.

    Attributes:
        k_rho: ``k_ρ > 0``, 1/s: ``v = k_ρ ρ``.
        k_alpha: ``k_α > k_ρ``, 1/s.
        k_beta: ``k_β < 0``, 1/s.
        backward: static; drive in reverse to a reference in the rear half-plane
            (the book's model does); off, the robot always drives forwards.
    """

    k_rho: Any = 3.0
    k_alpha: Any = 8.0
    k_beta: Any = -3.0
    backward: bool = dataclasses.field(default=True, metadata={"static": True})


def _astolfi_control(pose, ref, gains, *, temperature=None, frame=None):
    """Return ``(v cm/s, ω rad/s)`` of the Astolfi law in Corke's form (``polar.polar_command``).

    ``v = k_ρ ρ`` and ``ω = k_α α + k_β β`` with ``β = −θ_A``. choice: ``α``
    is held within ``[−π/2, π/2]`` as the Toolbox's block does. At the goal
    it turns at ``k_α``. ``temperature``: ``None`` only.
    """

    def speeds(rho, alpha, theta_a, direction):
        alpha = jnp.clip(alpha, -jnp.pi / 2, jnp.pi / 2)
        v = direction * gains.k_rho * rho
        omega = gains.k_alpha * alpha - gains.k_beta * theta_a
        return alpha, v, omega, gains.k_alpha

    return polar.polar_command(pose, ref, backward=gains.backward, frame=frame, speeds=speeds)


def validate_astolfi_gains(gains: AstolfiGains) -> AstolfiGains:
    """Check ``k_ρ > 0``, ``k_β < 0``, ``k_α > k_ρ`` (Corke, after Astolfi 1999); return them."""
    g = polar.gain_values(gains, AstolfiGains)
    if g["k_rho"] is not None:
        require("gains.k_rho", g["k_rho"], g["k_rho"] > 0, "k_rho > 0 1/s")
    if g["k_beta"] is not None:
        require("gains.k_beta", g["k_beta"], g["k_beta"] < 0, "k_beta < 0 1/s")
    if g["k_alpha"] is not None and g["k_rho"] is not None:
        k_rho = g["k_rho"]
        require(
            "gains.k_alpha",
            g["k_alpha"],
            g["k_alpha"] > k_rho,
            f"k_alpha > k_rho (k_rho = {float(np.max(k_rho)) if k_rho.ndim else float(k_rho)})",
        )
    return gains


ASTOLFI, astolfi_control = polar.polar_controller(
    "astolfi-corke", _astolfi_control, AstolfiGains, validate_astolfi_gains
)
