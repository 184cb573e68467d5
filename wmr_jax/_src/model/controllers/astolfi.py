"""The Astolfi polar law in Corke's form, a baseline (``docs/model.md §3``).

Its error coordinates and backward-driving rule are those of ``polar.py``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import Parameters, require
from wmr_jax._src.model.controllers.base import Controller, register_controller
from wmr_jax._src.model.controllers.polar import (
    driving_error,
    entry_point,
    gain_values,
    goal_floor,
    hold_at_goal,
)

__all__ = ["ASTOLFI", "AstolfiGains", "astolfi_control", "validate_astolfi_gains"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class AstolfiGains(Parameters):
    """Gains of the Astolfi polar law as given by Corke, *Robotics, Vision and Control*.

    Defaults ``k_ρ = 3``, ``k_α = 8``, ``k_β = −3`` are the gains of the book's
    "moving to a pose" example (P. Corke, *Robotics, Vision and Control*,
    Springer 2011, §4.2.4; 2nd ed. 2017, §4.1.1.4), as set in the
    ``sl_drivepose`` model of the Robotics Toolbox for MATLAB that goes with it.
    The law is A. Astolfi, "Exponential stabilization of a wheeled mobile robot
    via discontinuous control", J. Dyn. Sys., Meas., Control 121(1), 1999.

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


def _astolfi_control(
    pose: jax.Array,
    ref: jax.Array,
    gains: AstolfiGains,
    *,
    temperature: float | None = None,
    frame: Any = None,
) -> tuple[jax.Array, jax.Array]:
    """Return ``(v cm/s, ω rad/s)`` of the Astolfi polar law in Corke's form.

    ``v = k_ρ ρ`` and ``ω = k_α α + k_β β`` with ``β = −θ_A`` (Corke's "moving to
    a pose"); ``v`` changes sign when driving backwards. choice: ``α`` is held
    within ``[−π/2, π/2]`` as the Toolbox's polar-coordinate block does, which
    matters only when backward driving is off. Within ``goal_floor`` of the
    reference (``AT_GOAL`` = 1e-3 cm, more far from the origin) it only turns,
    ``ω = k_α θ_e`` (``polar.py``).

    Args:
        pose: ``(..., 3)`` current pose ``[x cm, y cm, θ rad]``.
        ref: ``(..., 3)`` reference pose.
        gains: ``AstolfiGains``.
        temperature: ``None``: the law has no smooth relaxation (``astolfi_control``
            refuses any other value).
        frame: the pose as ``(x, y, cos θ, sin θ)``, as the rollouts hand it to
            the registered law (see ``shim_sung.polar_error``).
    """
    rho, alpha, theta_a, direction = driving_error(pose, ref, backward=gains.backward, frame=frame)
    alpha = jnp.clip(alpha, -jnp.pi / 2, jnp.pi / 2)
    v = direction * gains.k_rho * rho
    omega = gains.k_alpha * alpha - gains.k_beta * theta_a
    floor = goal_floor(pose, ref, frame=frame)
    return hold_at_goal(rho, alpha, theta_a, v, omega, gains.k_alpha, floor)


# ---------------------------------------------------------------- boundary checks


def validate_astolfi_gains(gains: AstolfiGains) -> AstolfiGains:
    """Check the Astolfi/Corke stability conditions; return the gains.

    ``k_ρ > 0``, ``k_β < 0`` and ``k_α − k_ρ > 0`` (Corke, after Astolfi 1999).

    Raises:
        ValueError: naming the field, its value and the allowed range.
    """
    g = gain_values(gains, AstolfiGains)
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


ASTOLFI = register_controller(
    Controller(
        name="astolfi-corke",
        command=_astolfi_control,
        params_type=AstolfiGains,
        validate=validate_astolfi_gains,
    )
)

astolfi_control = entry_point(_astolfi_control, AstolfiGains, validate_astolfi_gains)
"""The law called by hand: poses and gains checked first, no ``temperature``."""
