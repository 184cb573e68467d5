"""Metrics of SPEC §6, so that every experiment measures the same thing.

All functions broadcast over leading batch axes of the trajectory: a
``Trajectory`` from ``rollout`` or one from ``batch_rollout`` alike.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax import law

__all__ = [
    "DEFAULT_TOL_R",
    "DEFAULT_TOL_THETA",
    "arrival_time",
    "arrived",
    "path_length",
    "region_time",
    "success_rate",
    "zigzag_count",
]

DEFAULT_TOL_R = 1.0  # cm
DEFAULT_TOL_THETA = math.radians(5.0)


def _check_tolerances(tol_r: Any, tol_theta: Any) -> None:
    if isinstance(tol_r, jax.core.Tracer) or isinstance(tol_theta, jax.core.Tracer):
        return
    if not (np.isfinite(tol_r) and tol_r > 0):
        raise ValueError(f"tol_r = {tol_r!r} is not allowed; allowed: a number > 0 cm")
    if not (np.isfinite(tol_theta) and 0 < tol_theta < math.pi / 2):
        raise ValueError(f"tol_theta = {tol_theta!r} is not allowed; allowed: 0 < tol_theta < pi/2")


def arrived(
    poses: jax.Array,
    refs: jax.Array,
    *,
    tol_r: float = DEFAULT_TOL_R,
    tol_theta: float = DEFAULT_TOL_THETA,
) -> jax.Array:
    """Return whether each pose is arrived: ``r_e ≤ tol_r`` and ``|θ̄_e| ≤ tol_theta``.

    Args:
        poses: ``(..., 3)`` poses.
        refs: ``(..., 3)`` references, broadcastable against ``poses``.
        tol_r: distance tolerance, cm.
        tol_theta: folded-heading tolerance, rad, ``< π/2``.
    """
    err = law.polar_error(poses, refs)
    cos_theta_bar, _ = law.fold(err.cos_theta, err.sin_theta)
    # |θ̄_e| ≤ tol ⇔ cos θ̄_e ≥ cos tol, since |θ̄_e| ≤ π/2.
    return (err.r <= tol_r) & (cos_theta_bar >= jnp.cos(tol_theta))


def arrival_time(
    traj: Any,
    refs: Any,
    *,
    dt: float,
    tol_r: float = DEFAULT_TOL_R,
    tol_theta: float = DEFAULT_TOL_THETA,
) -> jax.Array:
    """Return the arrival time of each run in s, ``inf`` where it never settles (SPEC §6).

    The arrival time is ``(k + 1) dt`` for the smallest ``k`` such that the
    robot is arrived at every sample from ``k`` to the end of the horizon; the
    samples are the poses after each control period (``traj.poses[..., 1:, :]``).

    Args:
        traj: a ``Trajectory`` (poses ``(..., steps + 1, 3)``).
        refs: ``(..., 3)`` the references of the runs.
        dt: control period, s.
        tol_r: distance tolerance, cm.
        tol_theta: folded-heading tolerance, rad.

    Returns:
        ``(...)`` arrival times, s.
    """
    _check_tolerances(tol_r, tol_theta)
    samples = traj.poses[..., 1:, :]
    ok = arrived(samples, jnp.asarray(refs)[..., None, :], tol_r=tol_r, tol_theta=tol_theta)
    # Length of the run of arrived samples that ends the horizon.
    settled = jnp.sum(jnp.cumprod(ok[..., ::-1], axis=-1), axis=-1)
    steps = ok.shape[-1]
    first = steps - settled
    return jnp.where(settled > 0, (first + 1) * dt, jnp.inf)


def success_rate(times: Any) -> float:
    """Return the fraction of finite arrival times."""
    return float(jnp.mean(jnp.isfinite(jnp.asarray(times))))


def path_length(traj: Any) -> jax.Array:
    """Return the distance the centre travelled over the run, cm (SPEC §6).

    The sum of ``|v| dt`` for the ideal loop; the integrated centre speed over
    the inner sub-steps for the non-ideal one (``Trajectory.distance``).
    """
    return jnp.sum(traj.distance, axis=-1)


def _sign_changes(x: jax.Array, dead_band: float) -> jax.Array:
    """Count sign changes along the last axis, ignoring samples with ``|x| ≤ dead_band``."""
    signs = jnp.where(x > dead_band, 1, jnp.where(x < -dead_band, -1, 0))
    signs = jnp.moveaxis(signs, -1, 0)

    def body(carry, s):
        last, count = carry
        flipped = (s != 0) & (last != 0) & (s != last)
        return (jnp.where(s != 0, s, last), count + flipped), None

    init = (jnp.zeros(signs.shape[1:], signs.dtype), jnp.zeros(signs.shape[1:], jnp.int32))
    (_, count), _ = jax.lax.scan(body, init, signs)
    return count


def zigzag_count(traj: Any, *, v_dead_band: float = 1.0, omega_dead_band: float = 0.1) -> jax.Array:
    """Return the number of sign changes of ``v`` plus those of ``ω`` (SPEC §6).

    Args:
        traj: a ``Trajectory``.
        v_dead_band: speeds with ``|v| ≤`` this (cm/s) carry no sign.
        omega_dead_band: turn rates with ``|ω| ≤`` this (rad/s) carry no sign.
    """
    return _sign_changes(traj.v, v_dead_band) + _sign_changes(traj.omega, omega_dead_band)


def region_time(traj: Any, *, dt: float) -> jax.Array:
    """Return the time spent in each region 0–3, s, shape ``(..., 4)``."""
    one_hot = traj.region[..., None] == jnp.arange(4)
    return jnp.sum(one_hot, axis=-2) * dt
