"""What the two polar-coordinate baselines of Shim–Sung share (docs/model.md §3).

Both steer from ``ρ = r_e``, ``α`` (the bearing of the reference from the
direction of travel: ``φ_e``, or ``φ_e + π`` wrapped when driving backwards)
and ``θ_A = α − θ_e`` (wrapped; Astolfi's and Corke's ``β`` is ``−θ_A``).
Driving backwards, ``v`` changes sign and ``ω`` does not. choice: the
direction is decided afresh at every sample, backwards when ``cos φ_e < 0``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import check_bool, field_values
from wmr_jax._src.model.controllers import shim_sung as law
from wmr_jax._src.model.controllers.base import Controller, check_law_inputs, register_controller

# choice (docs/model.md §3): within this distance of the reference, cm, the
# polar laws only turn to the reference heading: their bearing α is undefined
# at ρ = 0, and rounding noise near it.
AT_GOAL = 1e-3

# choice: far from the origin positions are coarser than AT_GOAL, so the floor
# grows to this many machine epsilons of the largest coordinate, where a step
# of k ρ dt no longer rounds away (the world-frame loops; the rollouts compute
# such runs in the reference's frame).
GOAL_EPS = 16


def driving_error(
    pose: jax.Array, ref: jax.Array, *, backward: bool, frame: Any = None
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Return ``(ρ cm, α rad, θ_A rad, direction)`` of the polar laws (module docstring).

    Args:
        pose: ``(..., 3)`` current pose ``[x cm, y cm, θ rad]``.
        ref: ``(..., 3)`` reference pose.
        backward: static; drive backwards when the reference is behind.
        frame: the pose as ``(x, y, cos θ, sin θ)`` (see ``shim_sung.polar_error``).

    Returns:
        ``ρ ≥ 0``; ``α ∈ [−π, π]`` (within ``[−π/2, π/2]`` when ``backward``);
        ``θ_A ∈ [−π, π)``; ``direction`` ``+1`` forwards or ``−1`` backwards.
        Each has the broadcast leading shape of ``pose`` and ``ref``.
    """
    backward = check_bool("backward", backward)  # static: "no" would drive backwards
    err = law.polar_error(pose, ref, frame=frame)
    phi, theta_e = law.error_angles(err)
    if backward:
        behind = err.cos_phi < 0
        alpha = jnp.where(behind, law.wrap_angle(phi + jnp.pi), phi)
        direction = jnp.where(behind, -1.0, 1.0).astype(phi.dtype)
    else:
        alpha = phi
        direction = jnp.ones_like(phi)
    theta_a = law.wrap_angle(alpha - theta_e)
    return err.r, alpha, theta_a, direction


def gain_values(params: Any, cls: type) -> dict[str, np.ndarray | None]:
    """Check the fields of polar-law gains (finite numbers; ``backward`` a bool)."""
    if isinstance(params, cls):
        check_bool("gains.backward", params.backward)
    return field_values(params, cls, "gains", skip=("backward",))


def goal_floor(pose: Any, ref: jax.Array, *, frame: Any = None) -> jax.Array:
    """Return the distance in cm within which the polar laws only turn (``hold_at_goal``).

    ``max(AT_GOAL, GOAL_EPS · ε · m)`` for the machine epsilon ``ε`` and the
    largest ``m`` of ``|x|, |y|`` of pose and reference (see ``GOAL_EPS``).
    ``pose`` is not read when ``frame`` is given.
    """
    x, y = (frame[0], frame[1]) if frame is not None else (pose[..., 0], pose[..., 1])
    x, y, ref = jnp.asarray(x), jnp.asarray(y), jnp.asarray(ref)
    dtype = jnp.result_type(x, y, ref, float)
    magnitude = jnp.maximum(
        jnp.maximum(jnp.abs(x), jnp.abs(y)),
        jnp.maximum(jnp.abs(ref[..., 0]), jnp.abs(ref[..., 1])),
    ).astype(dtype)
    return jnp.maximum(jnp.asarray(AT_GOAL, dtype), GOAL_EPS * jnp.finfo(dtype).eps * magnitude)


def hold_at_goal(error: tuple, command: tuple, rate: Any, floor: Any = AT_GOAL) -> tuple:
    """Return ``command`` ``(v, ω)``, or ``(0, rate · θ_e)`` where ``ρ < floor`` cm.

    ``error`` is ``(ρ, α, θ_A)``: at the goal the robot holds its position and
    turns to the reference heading, ``θ_e = α − θ_A`` (wrapped).
    """
    rho, alpha, theta_a = error
    v, omega = command
    near = rho < floor
    theta_e = law.wrap_angle(alpha - theta_a)
    return jnp.where(near, 0.0, v), jnp.where(near, rate * theta_e, omega)


def polar_command(
    pose: Any, ref: Any, *, backward: bool, frame: Any, speeds: Callable
) -> tuple[jax.Array, jax.Array]:
    """Return ``(v cm/s, ω rad/s)`` of a polar law, held within ``goal_floor`` of ``ref``.

    ``speeds(ρ, α, θ_A, direction) -> (α, v, ω, rate)`` is the law; ``rate``
    is its heading rate at the goal, ``α`` the bearing it used.
    """
    rho, alpha, theta_a, direction = driving_error(pose, ref, backward=backward, frame=frame)
    alpha, v, omega, rate = speeds(rho, alpha, theta_a, direction)
    floor = goal_floor(pose, ref, frame=frame)
    return hold_at_goal((rho, alpha, theta_a), (v, omega), rate, floor)


def polar_controller(
    name: str, command: Callable, params_type: type, validate: Callable
) -> tuple[Controller, Callable]:
    """Register the polar law ``command`` as ``name``; return it and its public form.

    The public form checks poses and gains on the host and takes no ``temperature``.
    """
    controller = Controller(name=name, command=command, params_type=params_type, validate=validate)

    def checked(pose: Any, ref: Any, gains: Any, *, temperature: Any = None) -> Any:
        if temperature is not None:
            raise ValueError(
                f"temperature = {temperature!r} is not allowed; allowed: None (this law has "
                "no smooth relaxation)"
            )
        return command(*check_law_inputs(pose, ref, gains, params_type, validate))

    checked.__name__ = checked.__qualname__ = command.__name__.lstrip("_")
    checked.__module__, checked.__doc__ = command.__module__, command.__doc__
    return register_controller(controller), checked
