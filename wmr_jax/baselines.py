"""Two classic polar-coordinate pose controllers, as baselines for Shim–Sung.

Both steer a unicycle to a pose from the same three error coordinates, which
are restated here in the terms of SPEC §2 (robot-frame bearing ``φ_e`` of the
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

The laws are pure and elementwise, like ``wmr_jax.law``; the ``backward`` flag
is a static field, so it picks code, not values. At ``ρ = 0`` (robot on the
reference) ``law.polar_error`` sets ``φ_e = 0`` with finite gradients, the only
division (``sin α / α``) goes through the NaN-safe ``dynamics.sinc``, and the
commands and their gradients are finite.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax import law
from wmr_jax.controllers import Controller, register_controller
from wmr_jax.dynamics import sinc

__all__ = [
    "AICARDI",
    "ASTOLFI",
    "AicardiGains",
    "AstolfiGains",
    "aicardi_control",
    "astolfi_control",
    "driving_error",
    "validate_aicardi_gains",
    "validate_astolfi_gains",
]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class AicardiGains:
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

    def replace(self, **changes: Any) -> AicardiGains:
        """Return a copy with the given fields changed."""
        return dataclasses.replace(self, **changes)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class AstolfiGains:
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

    def replace(self, **changes: Any) -> AstolfiGains:
        """Return a copy with the given fields changed."""
        return dataclasses.replace(self, **changes)


def driving_error(
    pose: jax.Array, ref: jax.Array, *, backward: bool
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Return ``(ρ cm, α rad, θ_A rad, direction)`` of the polar laws (module docstring).

    Args:
        pose: ``(..., 3)`` current pose ``[x cm, y cm, θ rad]``.
        ref: ``(..., 3)`` reference pose.
        backward: static; drive backwards when the reference is behind.

    Returns:
        ``ρ ≥ 0``; ``α ∈ [−π, π]`` (within ``[−π/2, π/2]`` when ``backward``);
        ``θ_A ∈ [−π, π)``; ``direction`` ``+1`` forwards or ``−1`` backwards.
        Each has the broadcast leading shape of ``pose`` and ``ref``.
    """
    err = law.polar_error(pose, ref)
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


def aicardi_control(
    pose: jax.Array,
    ref: jax.Array,
    gains: AicardiGains,
    *,
    temperature: float | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Return ``(v cm/s, ω rad/s)`` of Aicardi et al. (1995).

    With ``V = (λ ρ² + α² + h θ_A²)/2`` the paper chooses
    ``v = γ ρ cos α`` and ``ω = k α + γ (cos α sin α / α)(α + h θ_A)``, so that
    ``V̇ = −λ γ ρ² cos² α − k α² ≤ 0``; ``v`` changes sign when driving backwards.

    Args:
        pose: ``(..., 3)`` current pose ``[x cm, y cm, θ rad]``.
        ref: ``(..., 3)`` reference pose.
        gains: ``AicardiGains``.
        temperature: must be ``None``; the law has no smooth relaxation.
    """
    del temperature  # no smooth relaxation: Controller.smooth is False
    rho, alpha, theta_a, direction = driving_error(pose, ref, backward=gains.backward)
    cos_alpha = jnp.cos(alpha)
    v = direction * gains.gamma * rho * cos_alpha
    omega = gains.k * alpha + gains.gamma * cos_alpha * sinc(alpha) * (alpha + gains.h * theta_a)
    return v, omega


def astolfi_control(
    pose: jax.Array,
    ref: jax.Array,
    gains: AstolfiGains,
    *,
    temperature: float | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Return ``(v cm/s, ω rad/s)`` of the Astolfi polar law in Corke's form.

    ``v = k_ρ ρ`` and ``ω = k_α α + k_β β`` with ``β = −θ_A`` (Corke's "moving to
    a pose"); ``v`` changes sign when driving backwards. choice: ``α`` is held
    within ``[−π/2, π/2]`` as the Toolbox's polar-coordinate block does, which
    matters only when backward driving is off.

    Args:
        pose: ``(..., 3)`` current pose ``[x cm, y cm, θ rad]``.
        ref: ``(..., 3)`` reference pose.
        gains: ``AstolfiGains``.
        temperature: must be ``None``; the law has no smooth relaxation.
    """
    del temperature  # no smooth relaxation: Controller.smooth is False
    rho, alpha, theta_a, direction = driving_error(pose, ref, backward=gains.backward)
    alpha = jnp.clip(alpha, -jnp.pi / 2, jnp.pi / 2)
    v = direction * gains.k_rho * rho
    omega = gains.k_alpha * alpha - gains.k_beta * theta_a
    return v, omega


# ---------------------------------------------------------------- boundary checks


def _values(params: Any, cls: type, prefix: str) -> dict[str, np.ndarray | None]:
    """Return each numeric field as a NumPy array (``None`` for a tracer), checked finite."""
    if not isinstance(params, cls):
        raise ValueError(
            f"{prefix} is a {type(params).__name__}; allowed: a wmr_jax.baselines.{cls.__name__}"
        )
    backward = params.backward
    if not isinstance(backward, (bool, np.bool_)):
        raise ValueError(f"{prefix}.backward = {backward!r} is not allowed; allowed: True or False")
    out = {}
    for field in dataclasses.fields(cls):
        if field.name == "backward":
            continue
        value = getattr(params, field.name)
        if isinstance(value, jax.core.Tracer):
            out[field.name] = None
            continue
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(
                f"{prefix}.{field.name} = {value!r} is not allowed; allowed: a finite number"
            ) from None
        if arr.ndim > 1:
            raise ValueError(
                f"{prefix}.{field.name} has shape {arr.shape}; "
                "allowed: a scalar or one leading batch axis"
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError(
                f"{prefix}.{field.name} = {_shown(arr, ~np.isfinite(arr))} is not allowed; "
                "allowed: a finite number"
            )
        out[field.name] = arr
    return out


def _shown(arr: np.ndarray, bad: np.ndarray) -> str:
    if arr.ndim == 0:
        return repr(float(arr))
    return f"array of shape {arr.shape} (e.g. {float(arr[bad].reshape(-1)[0])!r})"


def _require(name: str, arr: np.ndarray | None, ok: Any, allowed: str) -> None:
    if arr is None:
        return
    ok = np.asarray(ok)
    if not np.all(ok):
        raise ValueError(f"{name} = {_shown(arr, ~ok)} is not allowed; allowed: {allowed}")


def validate_aicardi_gains(gains: AicardiGains) -> AicardiGains:
    """Check Aicardi gains (``γ, k, h > 0``, finite; ``backward`` a bool); return them.

    Raises:
        ValueError: naming the field, its value and the allowed range.
    """
    g = _values(gains, AicardiGains, "gains")
    for name, unit in (("gamma", " 1/s"), ("k", " 1/s"), ("h", "")):
        if g[name] is not None:
            _require(f"gains.{name}", g[name], g[name] > 0, f"{name} > 0{unit}")
    return gains


def validate_astolfi_gains(gains: AstolfiGains) -> AstolfiGains:
    """Check the Astolfi/Corke stability conditions; return the gains.

    ``k_ρ > 0``, ``k_β < 0`` and ``k_α − k_ρ > 0`` (Corke, after Astolfi 1999).

    Raises:
        ValueError: naming the field, its value and the allowed range.
    """
    g = _values(gains, AstolfiGains, "gains")
    if g["k_rho"] is not None:
        _require("gains.k_rho", g["k_rho"], g["k_rho"] > 0, "k_rho > 0 1/s")
    if g["k_beta"] is not None:
        _require("gains.k_beta", g["k_beta"], g["k_beta"] < 0, "k_beta < 0 1/s")
    if g["k_alpha"] is not None and g["k_rho"] is not None:
        k_rho = g["k_rho"]
        _require(
            "gains.k_alpha",
            g["k_alpha"],
            g["k_alpha"] > k_rho,
            f"k_alpha > k_rho (k_rho = {float(np.max(k_rho)) if k_rho.ndim else float(k_rho)})",
        )
    return gains


AICARDI = register_controller(
    Controller(
        name="aicardi",
        command=aicardi_control,
        params_type=AicardiGains,
        validate=validate_aicardi_gains,
    )
)

ASTOLFI = register_controller(
    Controller(
        name="astolfi-corke",
        command=astolfi_control,
        params_type=AstolfiGains,
        validate=validate_astolfi_gains,
    )
)
