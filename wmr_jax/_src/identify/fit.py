"""Fit the model of ``identify.model`` to a log: multiple shooting, Levenberg–Marquardt.

The log is cut into short segments; each is replayed from rest a few
periods before its window (the wheel loop and the commands in flight settle
in that warm-up), all of them at once under one ``vmap``. A segment's start
pose is not taken from the tracker: each segment's replay is placed by the
rigid transform that best matches its measured poses, eliminated in closed
form (variable projection), so the tracker's noise enters the fit only as
noise, never as a biased starting point.

The residuals are smooth in the four continuous parameters
``θ = (δ_L, δ_R, L, k_p)`` and there are thousands of them: a least-squares
problem that Gauss–Newton solves in a handful of steps where a first-order
method (Adam, L-BFGS on the summed loss) needs hundreds. The Jacobian is
exact (``jax.jacfwd``, four tangents through the scan), the step is
Levenberg–Marquardt's (damped where a step would not lower the cost), and
``JᵀJ`` at the optimum is the curvature the 95 % intervals come from. The
latency ``m`` is an integer: every ``m`` in ``0 … MAX_LATENCY`` is fitted in
one ``vmap`` and the lowest cost wins (a profile over ``m``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.controllers import shim_sung as law
from wmr_jax._src.identify import model
from wmr_jax._src.params import Robot

__all__ = ["Fit", "Segments", "fit_log", "segments_of", "Z95"]

Z95 = 1.959963984540054
SEGMENT = 60  # samples in a segment's window
WARMUP = model.MAX_LATENCY + 10  # periods replayed before it
PROFILE_SEGMENTS = 24  # segments the latency profile uses


class Segments(NamedTuple):
    """A log cut into windows (leading axis: segment).

    Attributes:
        commands: ``(n, WARMUP + S, 2)`` the commands from the warm-up on.
        measured: ``(n, S, 3)`` the poses measured over the window.
    """

    commands: jax.Array
    measured: jax.Array


def segments_of(commands: np.ndarray, poses: np.ndarray, segment: int = SEGMENT) -> Segments:
    """Cut one log (``commands (N, 2)``, ``poses (N, 3)``, θ unwrapped) into segments.

    Segment ``s`` replays the commands of samples ``b … b + W + S − 1`` from
    rest at sample ``b``; its window is the poses of samples
    ``b + W + 1 … b + W + S``.
    """
    total = len(commands)
    cmd, meas = [], []
    b = 0
    while b + WARMUP + segment + 1 <= total:
        cmd.append(commands[b : b + WARMUP + segment])
        meas.append(poses[b + WARMUP + 1 : b + WARMUP + segment + 1])
        b += segment
    return Segments(np.asarray(cmd), np.asarray(meas))


def _placed(predicted: jax.Array, measured: jax.Array, w_xy: jax.Array, w_theta: jax.Array):
    """Residuals of ``predicted`` ``(S, 3)`` after the rigid transform that best fits ``measured``.

    The transform minimises ``w_xy |Δxy|² + w_θ Δθ²`` summed over the window:
    the translation is that of the centroids, the rotation the Procrustes
    angle moved by four Newton steps toward the headings.
    """
    p = jax.lax.complex(predicted[:, 0], predicted[:, 1])
    z = jax.lax.complex(measured[:, 0], measured[:, 1])
    pc, zc = p - jnp.mean(p), z - jnp.mean(z)
    cross = jnp.sum(jnp.conj(pc) * zc)
    alpha = jnp.angle(cross)
    rho = jnp.abs(cross)
    d0 = law.wrap_angle(measured[0, 2] - predicted[0, 2])
    d = d0 + law.wrap_angle(measured[:, 2] - predicted[:, 2] - d0)
    count = d.shape[0]
    phi = (w_xy * rho * alpha + w_theta * count * jnp.mean(d)) / (w_xy * rho + w_theta * count)
    for _ in range(4):
        grad = 2 * w_xy * rho * jnp.sin(phi - alpha) - 2 * w_theta * jnp.sum(d - phi)
        curv = 2 * w_xy * rho * jnp.cos(phi - alpha) + 2 * w_theta * count
        phi = phi - grad / curv
    turn = jax.lax.complex(jnp.cos(phi), jnp.sin(phi))
    r = zc - turn * pc
    return r.real, r.imag, d - phi


def _segment_residuals(theta, delay, commands, measured, base_half_track, base, dt, sigma):
    """Weighted residuals ``(S, 3)`` of one segment at parameters ``θ``."""
    robot = model.fitted_robot(base, theta[2], theta[3])
    scale = jnp.stack([1 + theta[0], 1 + theta[1]])
    init = jnp.zeros((3,), commands.dtype)
    poses = model.replay(commands, init, robot, scale, base_half_track, delay, dt)
    rx, ry, rt = _placed(poses[WARMUP:], measured, 1 / sigma[0] ** 2, 1 / sigma[1] ** 2)
    return jnp.stack([rx / sigma[0], ry / sigma[0], rt / sigma[1]], axis=-1)


def _residuals(theta, delay, segs, base_half_track, base, dt, sigma):
    per = jax.vmap(
        lambda c, m: _segment_residuals(theta, delay, c, m, base_half_track, base, dt, sigma)
    )(segs.commands, segs.measured)
    return per


def _lm(theta0, delay, segs, base_half_track, base, dt, sigma, iterations):
    """Levenberg–Marquardt from ``theta0``; returns ``(θ, cost, JᵀJ, residuals)``."""

    def flat(theta):
        return _residuals(theta, delay, segs, base_half_track, base, dt, sigma).reshape(-1)

    def body(state, _):
        theta, lam = state
        r = flat(theta)
        jac = jax.jacfwd(flat)(theta)
        jtj, g = jac.T @ jac, jac.T @ r
        diag = jnp.diag(jnp.diag(jtj))
        step = -jnp.linalg.solve(jtj + lam * diag, g)
        cost, trial = r @ r, flat(theta + step)
        better = trial @ trial < cost
        theta = jnp.where(better, theta + step, theta)
        lam = jnp.where(better, lam * 0.3, lam * 10.0)
        return (theta, lam), None

    (theta, _), _ = jax.lax.scan(body, (theta0, jnp.asarray(1e-3, theta0.dtype)), None, iterations)
    r = flat(theta)
    jac = jax.jacfwd(flat)(theta)
    return theta, r @ r, jac.T @ jac, r


class Fit(NamedTuple):
    """What ``fit_log`` finds (all in float64 NumPy).

    Attributes:
        wheel_scale: ``[1 + δ_L, 1 + δ_R]``.
        half_track: the true half-track, cm.
        speed_gain: the wheel loop's gain, 1/s.
        latency: ``m``, samples.
        sigma_xy: cm; sigma_theta: rad.
        ci95: ``{name: (low, high)}``.
        residual_rms: ``{"xy": cm, "theta": rad}``.
        profile: cost per latency ``0 … MAX_LATENCY``.
        covariance: ``(4, 4)`` of ``θ``.
        segment_residuals: ``(n, 3)`` the windows' residuals, cm, cm, rad.
    """

    wheel_scale: np.ndarray
    half_track: float
    speed_gain: float
    latency: int
    sigma_xy: float
    sigma_theta: float
    ci95: dict
    residual_rms: dict
    profile: np.ndarray
    covariance: np.ndarray
    segment_residuals: np.ndarray


def fit_log(
    logs: list[tuple[np.ndarray, np.ndarray]],
    base: Robot,
    dt: float,
    *,
    iterations: int = 8,
    segment: int = SEGMENT,
) -> Fit:
    """Fit the model to ``logs``, each ``(commands (N, 2) cm/s rad/s, poses (N, 3) cm rad)``."""
    with jax.enable_x64(True):
        return _fit(logs, base, dt, iterations, segment)


def _stacked(logs, segment):
    parts = [segments_of(c, p, segment) for c, p in logs]
    parts = [s for s in parts if len(s.commands)]
    if not parts:
        raise ValueError(
            f"the logs are too short: each needs at least {WARMUP + segment + 1} samples"
        )
    return Segments(*(jnp.asarray(np.concatenate(x)) for x in zip(*parts, strict=True)))


@jax.jit
def _profile(theta0, segs, base_half_track, base, dt, sigma):
    delays = jnp.arange(model.MAX_LATENCY + 1, dtype=theta0.dtype)
    run = jax.vmap(lambda m: _lm(theta0, m, segs, base_half_track, base, dt, sigma, 4)[:2])
    return run(delays)


_refine = jax.jit(_lm, static_argnames="iterations")


def _fit(logs, base, dt, iterations, segment):
    segs = _stacked(logs, segment)
    base = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), base)
    base_l = base.half_track
    theta0 = jnp.asarray([0.0, 0.0, float(base_l), float(base.speed_gain)])
    dt = jnp.asarray(dt, jnp.float64)
    sigma0 = jnp.asarray([1.0, 0.02])
    # The profile over m on an even subset of the segments: the latency
    # shows in every one of them, and the refinement then uses them all.
    every = max(1, len(segs.commands) // PROFILE_SEGMENTS)
    subset = Segments(segs.commands[::every], segs.measured[::every])
    thetas, costs = _profile(theta0, subset, base_l, base, dt, sigma0)
    latency = int(jnp.argmin(costs))
    theta, _, _, r = _refine(
        thetas[latency], float(latency), segs, base_l, base, dt, sigma0, iterations=2
    )
    sigma = _noise(r, sigma0, segs)
    theta, cost, jtj, r = _refine(
        theta, float(latency), segs, base_l, base, dt, sigma, iterations=iterations
    )
    sigma = _noise(r, sigma, segs)
    # Weights from the final noise: the curvature in units of the noise itself.
    theta, cost, jtj, r = _refine(
        theta, float(latency), segs, base_l, base, dt, sigma, iterations=2
    )
    theta = np.asarray(theta)
    covariance = np.linalg.inv(np.asarray(jtj))
    half = Z95 * np.sqrt(np.diag(covariance))
    names = ("wheel_scale_left", "wheel_scale_right", "half_track", "speed_gain")
    centre = np.array([1 + theta[0], 1 + theta[1], theta[2], theta[3]])
    ci = {n: (float(c - h), float(c + h)) for n, c, h in zip(names, centre, half, strict=True)}
    sigma = np.asarray(sigma)
    dof_xy, dof_t = _dof(segs)
    for name, s, dof in (("sigma_xy", sigma[0], dof_xy), ("sigma_theta", sigma[1], dof_t)):
        spread = Z95 / math.sqrt(2 * dof)
        ci[name] = (float(s * (1 - spread)), float(s * (1 + spread)))
    res = np.asarray(r).reshape(-1, 3)
    rms = {
        "xy": float(np.sqrt(np.mean(res[:, :2] ** 2)) * sigma[0]),
        "theta": float(np.sqrt(np.mean(res[:, 2] ** 2)) * sigma[1]),
    }
    return Fit(
        centre[:2],
        float(theta[2]),
        float(theta[3]),
        latency,
        float(sigma[0]),
        float(sigma[1]),
        ci,
        rms,
        np.asarray(costs),
        covariance,
        res * np.array([sigma[0], sigma[0], sigma[1]]),
    )


def _dof(segs):
    n, s = segs.measured.shape[:2]
    # Each segment's transform takes two degrees of freedom from the
    # positions and one from the headings.
    return n * (2 * s - 2), n * (s - 1)


def _noise(r, sigma, segs):
    """σ_xy and σ_θ from weighted residuals ``r`` at weights ``sigma``."""
    res = np.asarray(r).reshape(-1, 3)
    dof_xy, dof_t = _dof(segs)
    s_xy = math.sqrt(float(np.sum(res[:, :2] ** 2)) / dof_xy) * float(sigma[0])
    s_t = math.sqrt(float(np.sum(res[:, 2] ** 2)) / dof_t) * float(sigma[1])
    return jnp.asarray([s_xy, s_t])
