"""Fit the model of ``identify.model`` to a log: multiple shooting, Levenberg–Marquardt.

The log is cut into short segments; each is replayed from rest a few
periods before its window (the wheel loop and the commands in flight settle
in that warm-up), all of them at once under one ``vmap``. A segment's start
pose is not taken from the tracker: each segment's replay is placed by the
rigid transform that best matches its measured poses, eliminated in closed
form (variable projection), so the tracker's noise enters the fit only as
noise, never as a biased starting point.

The residuals are smooth in the four continuous parameters
``θ = (δ_L, δ_R, L, log k_p)`` and there are thousands of them: a least-squares
problem that Gauss–Newton solves in a handful of steps where a first-order
method (Adam, L-BFGS on the summed loss) needs hundreds. The Jacobian is
exact (``jax.jacfwd``, four tangents through the scan), the step is
Levenberg–Marquardt's (damped where a step would not lower the cost), and
``JᵀJ`` at the optimum is the curvature the 95 % intervals come from. The
latency ``m`` is an integer: every ``m`` in ``0 … MAX_LATENCY`` is fitted for
a few steps on the first segments and the lowest cost wins (a profile over
``m``). The residuals and their normal equations are one compiled program
over a fixed-size chunk of segments and a batch of robots (``vmap``), so a
log of any length, or a hundred robots' logs, compile it once.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.identify import model
from wmr_jax._src.model.controllers import shim_sung as law
from wmr_jax._src.model.params import Robot

Z95 = 1.959963984540054
SEGMENT = 60  # samples in a segment's window
WARMUP = model.MAX_LATENCY + 10  # periods replayed before it
CHUNK = 16  # segments evaluated together
PROFILE_CHUNKS = 2  # chunks the latency profile uses
PROFILE_ITERATIONS = 3


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
    rho = jnp.abs(cross)
    d0 = law.wrap_angle(measured[0, 2] - predicted[0, 2])
    d = d0 + law.wrap_angle(measured[:, 2] - predicted[:, 2] - d0)
    # The positions' angle on the headings' branch: near ±π the two would
    # otherwise fall on either side of the cut, 2π apart.
    alpha = jnp.angle(cross)
    alpha = alpha + 2 * jnp.pi * jnp.round((jnp.mean(d) - alpha) / (2 * jnp.pi))
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
    robot = model.fitted_robot(base, theta[2], jnp.exp(theta[3]))
    scale = jnp.stack([1 + theta[0], 1 + theta[1]])
    init = jnp.zeros((3,), commands.dtype)
    poses = model.replay(commands, init, robot, scale, base_half_track, delay, dt)
    rx, ry, rt = _placed(poses[WARMUP:], measured, 1 / sigma[0] ** 2, 1 / sigma[1] ** 2)
    return jnp.stack([rx / sigma[0], ry / sigma[0], rt / sigma[1]], axis=-1)


def _residuals(theta, delay, segs, base_half_track, base, dt, sigma):
    return jax.vmap(
        lambda c, m: _segment_residuals(theta, delay, c, m, base_half_track, base, dt, sigma)
    )(segs.commands, segs.measured)


def _normal_one(theta, delay, commands, measured, mask, base_half_track, base, dt, sigma):
    """``(cost, JᵀJ, Jᵀr, r)`` of one chunk of segments; ``mask`` drops padding segments."""

    def flat(t):
        r = _residuals(t, delay, Segments(commands, measured), base_half_track, base, dt, sigma)
        r = (r * mask[:, None, None]).reshape(-1)
        return r, r

    jac, r = jax.jacfwd(flat, has_aux=True)(theta)
    return r @ r, jac.T @ jac, jac.T @ r, r


def _normal_fd_one(theta, delay, commands, measured, mask, base_half_track, base, dt, sigma):
    """``_normal_one`` with the Jacobian by central differences (the baseline)."""

    def flat(t):
        r = _residuals(t, delay, Segments(commands, measured), base_half_track, base, dt, sigma)
        return (r * mask[:, None, None]).reshape(-1)

    h = jnp.maximum(jnp.abs(theta), 1.0) * FD_STEP
    probes = jnp.concatenate([theta + jnp.diag(h), theta - jnp.diag(h)])
    values = jax.vmap(flat)(probes)
    jac = ((values[:4] - values[4:]) / (2 * h[:, None])).T
    r = flat(theta)
    return r @ r, jac.T @ jac, jac.T @ r, r


# Batched over robots (leading axis of every argument but the base robot):
# one log is a batch of one, a coverage study a batch of many, one program each.
_AXES = (0, 0, 0, 0, 0, 0, None, 0, 0)
_normal = jax.jit(jax.vmap(_normal_one, in_axes=_AXES))
_normal_fd = jax.jit(jax.vmap(_normal_fd_one, in_axes=_AXES))
FD_STEP = 1e-6
# The wheel loop's gain is fitted as its logarithm (always positive, and a
# relative step in every direction), kept where the replay's RK4 sub-steps
# stay stable (k_p dt / substeps <= 2.5, docs/model.md §4.3).
_LOG_GAIN_LOW = math.log(0.5)
_STABLE = 2.5 * model.SUBSTEPS


class Chunks(NamedTuple):
    """Segments in chunks of ``CHUNK`` (the last padded with copies, masked out).

    Every field has a leading batch axis (robots), then the chunk axis.
    """

    commands: np.ndarray  # (B, K, CHUNK, T, 2)
    measured: np.ndarray  # (B, K, CHUNK, S, 3)
    mask: np.ndarray  # (B, K, CHUNK)


def chunked(segs: list[Segments]) -> Chunks:
    """Chunk the segments of each robot of a batch (all with the same number of segments)."""
    count = len(segs[0].commands)
    k = -(-count // CHUNK)
    index = np.arange(k * CHUNK) % count
    mask = (np.arange(k * CHUNK) < count).astype(float).reshape(k, CHUNK)
    return Chunks(
        np.stack(
            [np.asarray(s.commands)[index].reshape(k, CHUNK, *s.commands.shape[1:]) for s in segs]
        ),
        np.stack(
            [np.asarray(s.measured)[index].reshape(k, CHUNK, *s.measured.shape[1:]) for s in segs]
        ),
        np.broadcast_to(mask, (len(segs), k, CHUNK)),
    )


def _summed(function, theta, delay, chunks, chunk_ids, fixed, sigma):
    """``function`` summed over the chunks ``chunk_ids`` (residuals concatenated)."""
    total = None
    for j in chunk_ids:
        out = function(
            theta,
            delay,
            chunks.commands[:, j],
            chunks.measured[:, j],
            chunks.mask[:, j],
            fixed[0],
            fixed[1],
            fixed[2],
            sigma,
        )
        out = jax.device_get(out)
        if total is None:
            total = list(out) if isinstance(out, tuple) else out
        elif isinstance(out, tuple):
            total = [a + b for a, b in zip(total[:3], out[:3], strict=True)] + [
                np.concatenate([total[3], out[3]], axis=-1)
            ]
        else:
            total = total + out
    return total


def levenberg_marquardt(
    theta, delay, chunks, fixed, sigma, iterations, chunk_ids=None, normal=None
):
    """Levenberg–Marquardt on a batch: ``θ (B, 4)`` → ``(θ, cost, JᵀJ, r)``, host-side loop.

    ``fixed``: ``(base half-track (B,), base robot, dt (B,))``. A trial point
    is evaluated with its Jacobian: an accepted step (the usual case) needs
    nothing more for the next one, and the fit compiles one program, not a
    second for the cost alone.
    """
    ids = range(chunks.commands.shape[1]) if chunk_ids is None else chunk_ids
    normal = _normal if normal is None else normal
    theta = np.asarray(theta, float)
    lam = np.full(theta.shape[0], 1e-3)
    current = _summed(normal, theta, delay, chunks, ids, fixed, sigma)
    for _ in range(iterations):
        cost, jtj, g, _ = current
        damped = jtj + lam[:, None, None] * (
            np.eye(4) * np.diagonal(jtj, axis1=1, axis2=2)[:, None]
        )
        trial = theta - np.linalg.solve(damped, g[..., None])[..., 0]
        trial[:, 3] = np.clip(trial[:, 3], _LOG_GAIN_LOW, np.log(_STABLE / fixed[2]))
        found = _summed(normal, trial, delay, chunks, ids, fixed, sigma)
        better = found[0] < cost
        theta = np.where(better[:, None], trial, theta)
        current = [
            np.where(better.reshape(-1, *[1] * (new.ndim - 1)), new, old)
            for new, old in zip(found, current, strict=True)
        ]
        lam = np.where(better, lam * 0.3, lam * 10.0)
    cost, jtj, _, r = current
    return theta, cost, jtj, r


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
        covariance: ``(4, 4)`` of ``θ = (δ_L, δ_R, L, log k_p)``.
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


def _segments(logs, segment):
    parts = [segments_of(c, p, segment) for c, p in logs]
    parts = [s for s in parts if len(s.commands)]
    if not parts:
        raise ValueError(
            f"the logs are too short: each needs at least {WARMUP + segment + 1} samples"
        )
    return Segments(*(np.concatenate(x) for x in zip(*parts, strict=True)))


def fit_batch(
    segs: list[Segments], base: Robot, dt: float, iterations: int = 8, *, jacobian: str = "exact"
) -> list[Fit]:
    """Fit a batch of robots' logs (same length each) at once; one ``Fit`` per robot.

    ``jacobian="fd"``: central finite differences instead of ``jacfwd`` (the
    baseline).
    """
    with jax.enable_x64(True):
        return _fit_batch(segs, base, dt, iterations, _normal_fd if jacobian == "fd" else None)


def _fit_batch(segs, base, dt, iterations, normal=None):
    batch = len(segs)
    chunks = chunked(segs)
    base = jax.tree.map(lambda x: np.float64(x), base)
    base_l = float(base.half_track)
    fixed = (np.full(batch, base_l), base, np.full(batch, float(dt)))
    theta0 = np.tile([0.0, 0.0, base_l, math.log(float(base.speed_gain))], (batch, 1))
    sigma0 = np.tile([1.0, 0.02], (batch, 1))
    # The profile over m on the first chunks only: the latency shows in
    # every segment, and the refinement then uses them all.
    profile_ids = range(min(PROFILE_CHUNKS, chunks.commands.shape[1]))
    thetas, costs = [], []
    for m in range(model.MAX_LATENCY + 1):
        delay = np.full(batch, float(m))
        theta, cost, _, _ = levenberg_marquardt(
            theta0, delay, chunks, fixed, sigma0, PROFILE_ITERATIONS, profile_ids, normal
        )
        thetas.append(theta)
        costs.append(cost)
    costs = np.stack(costs, axis=1)  # (B, M)
    latency = np.argmin(costs, axis=1)
    theta = np.stack([thetas[m][i] for i, m in enumerate(latency)])
    delay = latency.astype(float)
    theta, _, _, r = levenberg_marquardt(theta, delay, chunks, fixed, sigma0, 2, None, normal)
    sigma = _noise(r, sigma0, chunks)
    theta, _, _, r = levenberg_marquardt(
        theta, delay, chunks, fixed, sigma, iterations, None, normal
    )
    sigma = _noise(r, sigma, chunks)
    # Weights from the final noise: the curvature in units of the noise itself.
    theta, _, jtj, r = levenberg_marquardt(theta, delay, chunks, fixed, sigma, 1, None, normal)
    return [
        _result(theta[i], int(latency[i]), sigma[i], jtj[i], r[i], costs[i], chunks)
        for i in range(batch)
    ]


def _fit(logs, base, dt, iterations, segment):
    return _fit_batch([_segments(logs, segment)], base, dt, iterations)[0]


def _result(theta, latency, sigma, jtj, r, costs, chunks):
    covariance = np.linalg.inv(jtj)
    half = Z95 * np.sqrt(np.diag(covariance))
    names = ("wheel_scale_left", "wheel_scale_right", "half_track")
    centre = np.array([1 + theta[0], 1 + theta[1], theta[2]])
    ci = {n: (float(c - h), float(c + h)) for n, c, h in zip(names, centre, half, strict=False)}
    # The gain's interval is that of its logarithm, mapped back.
    ci["speed_gain"] = (math.exp(theta[3] - half[3]), math.exp(theta[3] + half[3]))
    dof_xy, dof_t = _dof(chunks)
    for name, s, dof in (("sigma_xy", sigma[0], dof_xy), ("sigma_theta", sigma[1], dof_t)):
        spread = Z95 / math.sqrt(2 * dof)
        ci[name] = (float(s * (1 - spread)), float(s * (1 + spread)))
    res = _kept(r, chunks)
    rms = {
        "xy": float(np.sqrt(np.mean(res[:, :2] ** 2)) * sigma[0]),
        "theta": float(np.sqrt(np.mean(res[:, 2] ** 2)) * sigma[1]),
    }
    return Fit(
        centre[:2],
        float(theta[2]),
        math.exp(theta[3]),
        latency,
        float(sigma[0]),
        float(sigma[1]),
        ci,
        rms,
        np.asarray(costs),
        covariance,
        res * np.array([sigma[0], sigma[0], sigma[1]]),
    )


def _kept(r, chunks):
    """The residuals ``(n, 3)`` of one robot's real (unpadded) segments."""
    window = chunks.measured.shape[3]
    res = np.asarray(r).reshape(-1, window, 3)
    keep = chunks.mask[0].reshape(-1) > 0
    return res[keep].reshape(-1, 3)


def _dof(chunks):
    n = int(np.sum(chunks.mask[0]))
    s = chunks.measured.shape[3]
    # Each segment's transform takes two degrees of freedom from the
    # positions and one from the headings.
    return n * (2 * s - 2), n * (s - 1)


def _noise(r, sigma, chunks):
    """σ_xy and σ_θ ``(B, 2)`` from weighted residuals ``r`` ``(B, …)`` at weights ``sigma``."""
    dof_xy, dof_t = _dof(chunks)
    out = []
    for i in range(len(sigma)):
        res = np.asarray(r[i]).reshape(-1, 3)
        s_xy = math.sqrt(float(np.sum(res[:, :2] ** 2)) / dof_xy) * float(sigma[i][0])
        s_t = math.sqrt(float(np.sum(res[:, 2] ** 2)) / dof_t) * float(sigma[i][1])
        out.append([s_xy, s_t])
    return np.asarray(out)
