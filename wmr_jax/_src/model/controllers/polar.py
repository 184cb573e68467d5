"""Two classic polar-coordinate pose controllers, as baselines for Shim–Sung.

Both steer a unicycle to a pose from the same three error coordinates, which
are restated here in the terms of docs/model.md §2 (robot-frame bearing ``φ_e`` of the
reference and heading error ``θ_e = θ_r − θ_c``):

* ``ρ = r_e``, the distance to the reference, cm;
* ``α``, the bearing of the reference from the direction of travel: ``φ_e``
  when driving forwards, ``φ_e + π`` (wrapped) when driving backwards;
* ``θ_A = α − θ_e`` (wrapped), the bearing of the line robot→reference
  measured from the reference's own heading (Aicardi's ``θ``); Astolfi's and
  Corke's ``β`` is ``−θ_A`` (``β = −θ − α`` with the reference at the origin,
  plus the reference heading).

Backward driving follows one rule for both laws: a robot driving backwards is
a robot turned by ``π`` whose reference is turned by ``π`` too. Its ``α`` is
then ``φ_e + π`` (the bearing from its rear), ``θ_e`` is unchanged, ``v``
changes sign and ``ω`` does not. choice: the direction is decided afresh at
every sample, backwards when the reference lies in the rear half-plane
(``cos φ_e < 0``). Corke's block diagram decides once, at the start; for the
default gains both rules agree, since Astolfi (1999) shows ``α`` then stays
within ``(−π/2, π/2]`` once it starts there (``k_α + 5/3 k_β − 2/π k_ρ > 0``).

The laws are pure and elementwise, like the Shim–Sung law; the ``backward`` flag
is a static field, so it picks code, not values. At ``ρ = 0`` (robot on the
reference) ``polar_error`` sets ``φ_e = 0`` with finite gradients, the only
division (``sin α / α``) goes through the NaN-safe ``dynamics.sinc``, and the
commands and their gradients are finite.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import check_bool, field_values
from wmr_jax._src.model.controllers import shim_sung as law
from wmr_jax._src.model.controllers.base import check_law_inputs

__all__ = [
    "AT_GOAL",
    "GOAL_EPS",
    "entry_point",
    "driving_error",
    "gain_values",
    "goal_floor",
    "hold_at_goal",
]

# choice (docs/model.md §3): within this distance of the reference, cm, the
# polar laws stop driving and only turn to the reference heading. Their
# bearing α is undefined at ρ = 0, and once ρ is down to rounding it is noise
# that ω would follow (PythonRobotics' move_to_pose stops at 0.001 too).
AT_GOAL = 1e-3

# choice: far from the origin the positions themselves are coarser than
# AT_GOAL (float32 spaces them 1e-3 cm apart near 1e4 cm), so the floor grows
# to this many machine epsilons ε of the largest coordinate magnitude. Within
# a few spacings of the goal a step of v dt = k ρ dt rounds away (k dt ≈ 0.1
# at the default gains and period: below ρ ≈ 5 spacings the robot no longer
# moves), ρ stalls above a fixed floor and ω chases the bearing of a rounding
# error instead of the reference heading, 90° off. 16 ε m is 16 to 32
# spacings, enough for k dt down to 1/32; it changes nothing while the largest
# coordinate is below AT_GOAL / (16 ε), 524 cm in float32 and 3e11 cm in
# float64. The rollout entry points compute such runs in the reference's
# frame instead (rollout.GOAL_FRAME_SPACING), where the floor is AT_GOAL
# again; loops that run in the world frame (sweeps, studies) use this one.
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
    backward = getattr(params, "backward", None) if isinstance(params, cls) else None
    if isinstance(params, cls) and not isinstance(backward, (bool, np.bool_)):
        raise ValueError(f"gains.backward = {backward!r} is not allowed; allowed: True or False")
    return field_values(params, cls, "gains", skip=("backward",))


def goal_floor(pose: Any, ref: jax.Array, *, frame: Any = None) -> jax.Array:
    """Return the distance in cm within which the polar laws only turn (``hold_at_goal``).

    ``max(AT_GOAL, GOAL_EPS · ε · m)`` for the machine epsilon ``ε`` of the
    compute dtype and the largest of ``|x|, |y|`` of the pose and of the
    reference, ``m`` in cm: ``AT_GOAL`` at ordinary coordinates, and a few
    spacings of the representable positions far from the origin, so that the
    floor lies above the distances that rounding leaves (see ``GOAL_EPS``).

    Args:
        pose: ``(..., 3)`` current pose ``[x cm, y cm, θ rad]``; not read when
            ``frame`` is given.
        ref: ``(..., 3)`` reference pose.
        frame: the pose as ``(x, y, cos θ, sin θ)`` (see ``shim_sung.polar_error``).

    Returns:
        The broadcast leading shape of ``pose`` (or ``frame``) and ``ref``.
    """
    x, y = (frame[0], frame[1]) if frame is not None else (pose[..., 0], pose[..., 1])
    x, y, ref = jnp.asarray(x), jnp.asarray(y), jnp.asarray(ref)
    dtype = jnp.result_type(x, y, ref, float)
    magnitude = jnp.maximum(
        jnp.maximum(jnp.abs(x), jnp.abs(y)),
        jnp.maximum(jnp.abs(ref[..., 0]), jnp.abs(ref[..., 1])),
    ).astype(dtype)
    return jnp.maximum(jnp.asarray(AT_GOAL, dtype), GOAL_EPS * jnp.finfo(dtype).eps * magnitude)


def hold_at_goal(
    rho: jax.Array,
    alpha: jax.Array,
    theta_a: jax.Array,
    v: jax.Array,
    omega: jax.Array,
    rate: jax.Array,
    floor: Any = AT_GOAL,
) -> tuple[jax.Array, jax.Array]:
    """Return ``(v, ω)``, or ``(0, rate · θ_e)`` where ``ρ < floor``.

    At the goal the robot holds its position and turns to the reference
    heading, ``θ_e = α − θ_A`` (wrapped), at the law's own heading rate.
    ``floor``, cm: ``AT_GOAL``, or ``goal_floor`` of the pose (the laws pass it).
    """
    near = rho < floor
    theta_e = law.wrap_angle(alpha - theta_a)
    return jnp.where(near, 0.0, v), jnp.where(near, rate * theta_e, omega)


def entry_point(law: Callable, params_type: type, validate: Callable) -> Callable:
    """The public form of a polar law: its arguments checked on the host, then the law.

    ``law`` is the pure ``Controller.command`` the loops call (with ``frame``);
    the returned function takes poses, refuses a ``temperature`` (these laws
    have no smooth relaxation) and checks the poses and gains as ``control``
    does, naming the argument.
    """

    def checked(pose: Any, ref: Any, gains: Any, *, temperature: Any = None) -> Any:
        if temperature is not None:
            raise ValueError(
                f"temperature = {temperature!r} is not allowed; allowed: None (this law has "
                "no smooth relaxation)"
            )
        return law(*check_law_inputs(pose, ref, gains, params_type, validate))

    checked.__name__ = checked.__qualname__ = law.__name__.lstrip("_")
    checked.__module__, checked.__doc__ = law.__module__, law.__doc__
    return checked
