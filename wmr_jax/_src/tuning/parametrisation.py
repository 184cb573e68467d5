"""The feasible set that tuning and random search share: gains as an image of the unit cube.

Every point ``u ∈ [0, 1]^7`` maps to gains that meet ``k_r + L k_θ ≤ V_max``
and every range of ``docs/model.md §3``, so every iterate is feasible. Adam
works on the logits ``z`` (``u = σ(z)``); random search samples ``u``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import is_traced, real_array, require, require_unbatched
from wmr_jax._src.model.params import Gains, Robot, validate_gains, validate_one_robot
from wmr_jax._src.sim.poses import EVAL_R_MAX

GAIN_FIELDS = tuple(f.name for f in dataclasses.fields(Gains))

# The paper's Fig. 10 gains, the ones that meet k_r + L k_θ ≤ V_max
# (60 + 1.85 · 10 = 78.5 cm/s); every other field at its default.
PAPER_FEASIBLE_GAINS = Gains(kr=60.0)


def paper_feasible_gains(robot: Robot | None = None) -> Gains:
    """The paper's feasible gains for ``robot``: its shape ``k_r : k_θ = 60 : 10``, within budget.

    ``PAPER_FEASIBLE_GAINS`` where ``60 + 10 L ≤ V_max``; on a slower or wider
    robot both scaled by one factor to ``k_r + L k_θ ≤ V_max``, so that every
    tuning report's baseline is one the robot can follow.

    Raises:
        ValueError: for a robot that is not one valid robot (a number per field).
    """
    robot = validate_one_robot(robot, "the paper's feasible gains")
    kr, k_theta = float(PAPER_FEASIBLE_GAINS.kr), float(PAPER_FEASIBLE_GAINS.k_theta)
    v_max, half_track = float(robot.v_max), float(robot.half_track)
    if kr + half_track * k_theta <= v_max:
        return PAPER_FEASIBLE_GAINS
    scale = v_max / (kr + half_track * k_theta)
    # Rounding may put the sum an ulp over the budget: step the scale down until it is not.
    while kr * scale + half_track * (k_theta * scale) > v_max:
        scale = math.nextafter(scale, 0.0)
    return PAPER_FEASIBLE_GAINS.replace(kr=kr * scale, k_theta=k_theta * scale)


# choice: the box that tuning and random search share. The wheel budget
# k_r + L k_θ, the share of it given to k_r, Φ_m and α are linear in u; the
# radii are log-uniform (R_m over 0.5–200 cm, R_a/R_m and R_e/R_a over
# 0.01–1), since their effect is on a log scale. The margins keep strict
# inequalities strict after float32 rounding: k_r + L k_θ ≤ (1 − 1e-4) V_max.
_BUDGET = (1e-3, 1.0 - 1e-4)  # fraction of V_max spent on k_r + L k_θ
_SHARE = (1e-3, 1.0 - 1e-3)  # fraction of that budget given to k_r
_PHI_M = (1e-3, math.pi / 2 - 1e-3)  # rad
_ALPHA = (1e-3, 0.5 - 1e-3)
_LOG_R_M = (math.log(0.5), math.log(200.0))  # log cm
_LOG_RATIO = (math.log(0.01), 0.0)  # log of R_a/R_m and of R_e/R_a
# The evaluation radius the length box above is chosen for (docs/model.md §6):
# the radii scale with the poses' reach, EVAL_R_MAX, by EVAL_R_MAX / this.
_BOX_RADIUS = 80.0  # cm
# How close to a face of the cube a starting point may sit: the logit of a
# point on a face is infinite (the paper's R_a = R_m is one).
_UNIT_CLIP = 1e-3


def _log_r_m() -> tuple[float, float]:
    """The box of ``log R_m`` (log cm), scaled by the evaluation radius (``EVAL_R_MAX``)."""
    shift = math.log(EVAL_R_MAX / _BOX_RADIUS)
    return (_LOG_R_M[0] + shift, _LOG_R_M[1] + shift)


def _lerp(u: Any, bounds: tuple[float, float]) -> Any:
    lo, hi = bounds
    return lo + (hi - lo) * u


def _unlerp(x: float, bounds: tuple[float, float]) -> float:
    lo, hi = bounds
    return (x - lo) / (hi - lo)


def checked_point(name: str, value: Any, dim: int, *, unit: bool) -> jax.Array:
    """``value`` as an array ``(..., dim)`` of the cube (``unit``) or of logits, or say why not.

    Traced values pass unchecked (they were checked where they were made).
    """
    if is_traced(value):
        return jnp.asarray(value)
    arr = real_array(name, value, f"real numbers of shape (..., {dim})")
    if arr.ndim == 0 or arr.shape[-1] != dim:
        raise ValueError(f"{name} has shape {arr.shape}; allowed: (..., {dim})")
    if unit:
        require(name, arr, (arr >= 0) & (arr <= 1), "numbers in [0, 1]")
    else:
        require(name, arr, ~np.isnan(arr), "real numbers (not NaN)")
    return jnp.asarray(value)


def gains_from_unit(u: jax.Array, robot: Robot | None = None) -> Gains:
    """Map a point of the unit cube to feasible gains (``docs/model.md §3``).

    Every ``u ∈ [0, 1]^7`` gives ``k_r + L k_θ < V_max`` with ``k_r, k_θ > 0``,
    ``0 < Φ_m < π/2``, ``0 < α < 0.5`` and ``0 < R_e ≤ R_a ≤ R_m``.

    Args:
        u: ``(..., 7)`` ``[budget, k_r share, Φ_m, α, R_m, R_a/R_m, R_e/R_a]``,
            each in ``[0, 1]``.
        robot: gives ``L`` (cm) and ``V_max`` (cm/s); default ``Robot()``.

    Returns:
        ``Gains`` whose fields have the leading shape of ``u``.

    Raises:
        ValueError: for ``u`` outside the cube, or a robot that is not one
            valid ``Robot`` (a traced one is not checked).
    """
    if not is_traced(robot):
        robot = validate_one_robot(robot, "gains_from_unit")
    u = checked_point("u", u, len(GAIN_FIELDS), unit=True)
    budget = robot.v_max * _lerp(u[..., 0], _BUDGET)  # cm/s
    share = _lerp(u[..., 1], _SHARE)
    r_m = jnp.exp(_lerp(u[..., 4], _log_r_m()))
    # exp(·) ≤ 1 here, so the products keep R_e ≤ R_a ≤ R_m after rounding.
    r_a = r_m * jnp.exp(_lerp(u[..., 5], _LOG_RATIO))
    r_e = r_a * jnp.exp(_lerp(u[..., 6], _LOG_RATIO))
    return Gains(
        kr=budget * share,
        k_theta=budget * (1.0 - share) / robot.half_track,
        phi_m=_lerp(u[..., 2], _PHI_M),
        r_m=r_m,
        r_a=r_a,
        r_e=r_e,
        alpha=_lerp(u[..., 3], _ALPHA),
    )


def unit_from_gains(gains: Gains, robot: Robot | None = None) -> np.ndarray:
    """Return the point of the unit cube that ``gains_from_unit`` maps to ``gains``.

    Gains outside the cube's box, or on its faces (the paper's ``R_a = R_m``
    is one), are moved just inside, ``1e-3`` from the faces, so that their
    logits are finite.

    Args:
        gains: feasible gains with scalar fields.
        robot: gives ``L`` (cm) and ``V_max`` (cm/s); default ``Robot()``.

    Returns:
        ``(7,)`` float64 array in ``[1e-3, 1 − 1e-3]``.

    Raises:
        ValueError: for gains outside the ranges of ``docs/model.md §3``, or
            a robot that is not one valid ``Robot``.
    """
    robot = validate_one_robot(robot, "unit_from_gains")
    g = gains_as_dict(gains)
    budget = g["kr"] + float(robot.half_track) * g["k_theta"]
    u = [
        _unlerp(budget / float(robot.v_max), _BUDGET),
        _unlerp(g["kr"] / budget, _SHARE),
        _unlerp(g["phi_m"], _PHI_M),
        _unlerp(g["alpha"], _ALPHA),
        _unlerp(math.log(g["r_m"]), _log_r_m()),
        _unlerp(math.log(g["r_a"] / g["r_m"]), _LOG_RATIO),
        _unlerp(math.log(g["r_e"] / g["r_a"]), _LOG_RATIO),
    ]
    return np.clip(np.asarray(u, dtype=float), _UNIT_CLIP, 1.0 - _UNIT_CLIP)


def gains_as_dict(gains: Gains) -> dict[str, float]:
    """Return scalar gains as ``{field: float}`` in ``GAIN_FIELDS`` order (JSON-ready).

    Raises:
        ValueError: for gains outside the ranges of ``docs/model.md §3``, or
            with a batch axis, naming the field.
    """
    validate_gains(gains)
    require_unbatched(gains, "gains", "a scalar (one set of gains)")
    return {name: float(getattr(gains, name)) for name in GAIN_FIELDS}


def gains_from_logits(z: jax.Array, robot: Robot | None = None) -> Gains:
    """Map logits ``z`` (``u = σ(z)``, any real ``(..., 7)``) to feasible gains.

    Args:
        z: ``(..., 7)`` logits of a point of the unit cube.
        robot: gives ``L`` (cm) and ``V_max`` (cm/s); default ``Robot()``.
    """
    if not is_traced(robot):  # refused before z is converted
        robot = validate_one_robot(robot, "gains_from_logits")
    z = checked_point("z", z, len(GAIN_FIELDS), unit=False)
    return gains_from_unit(jax.nn.sigmoid(z), robot)


def logits_from_gains(gains: Gains, robot: Robot | None = None) -> np.ndarray:
    """Return the logits of ``unit_from_gains(gains, robot)``: ``(7,)`` float64, finite."""
    u = unit_from_gains(gains, robot)
    return np.log(u) - np.log1p(-u)
