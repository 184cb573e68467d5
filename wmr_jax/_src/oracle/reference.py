"""A plain NumPy/``math`` reference of docs/model.md §2–4, §7 and §9, one pose at a time, no JAX.

Written straight from ``docs/model.md`` with angles and ``atan2``,
independently of ``wmr_jax.controllers``; the tests hold the JAX rollouts
equal to it in float64, and the benchmark times it as a scalar simulator.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from wmr_jax._src.checks import (
    MAX_HEADING,
    MAX_STEPS,
    check_dt,
    check_int,
    position_limit,
    real_array,
    require_unbatched,
)
from wmr_jax._src.model.params import Gains, Robot, check_sampling, validate_gains, validate_robot
from wmr_jax._src.model.velocity_loop import check_stability
from wmr_jax._src.sim.sensing.estimators import OBSERVER_R, EKFParams, resolve_estimator

# π as a sum of two floats: shifting an angle by PI_HI and then PI_LO gives the
# correctly rounded a ∓ π, so that e.g. fold(−float(π)) is the tiny positive
# number it is in exact arithmetic rather than 0. Sgn(sin θ̄_e) depends on it.
_PI_HI = math.pi
_PI_LO = 1.2246467991473532e-16


def _wrap(a: float) -> float:
    """Wrap an angle to [−π, π), with π exact to two floats."""
    turns = round(a / (2 * math.pi))
    a = (a - turns * 2 * _PI_HI) - turns * 2 * _PI_LO
    if a > _PI_HI:  # a ≥ π: no float lies between π and the next float above it
        a = (a - 2 * _PI_HI) - 2 * _PI_LO
    elif a < -_PI_HI:  # a < −π
        a = (a + 2 * _PI_HI) + 2 * _PI_LO
    return a


def _fold(a: float) -> float:
    """Fold an angle of [−π, π] into [−π/2, π/2] (docs/model.md §3): front and back alike."""
    if a > math.pi / 2:
        return (a - _PI_HI) - _PI_LO
    if a < -math.pi / 2:
        return (a + _PI_HI) + _PI_LO
    return a


def _sgn(x: float) -> float:
    return 1.0 if x > 0 else -1.0


def _in_float64(fn: Callable) -> Callable:
    """Check the arguments of ``fn`` against float64's range, which it computes in."""

    @functools.wraps(fn)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        with jax.enable_x64(True):
            return fn(*args, **kwargs)

    return wrapped


@_in_float64
def reference_diagnostics(pose: Any, ref: Any, gains: Gains) -> dict[str, float]:
    """Return the command and every intermediate of the law for one pose (docs/model.md §2–3)."""
    gains = _one_set(gains, validate_gains, "gains")
    return _diagnostics(_one_pose("pose", pose), _one_pose("ref", ref), gains)


def _diagnostics(pose: tuple, ref: tuple, gains: Gains) -> dict[str, float]:
    """``reference_diagnostics`` on checked arguments (the rollout's inner call)."""
    x_c, y_c, th_c = pose
    x_r, y_r, th_r = ref
    fields = ("kr", "k_theta", "phi_m", "r_m", "r_a", "r_e", "alpha")
    kr, k_th, phi_m, r_m, r_a, r_e_lim, alpha = (float(getattr(gains, f)) for f in fields)
    e_x = math.cos(th_c) * (x_r - x_c) + math.sin(th_c) * (y_r - y_c)
    e_y = -math.sin(th_c) * (x_r - x_c) + math.cos(th_c) * (y_r - y_c)
    r_e = math.hypot(e_x, e_y)
    phi_e = math.atan2(e_y, e_x) if r_e > 0 else 0.0
    theta_e = _wrap(th_r - th_c)

    r_bar = math.pi / 2 if r_e >= r_m else math.pi * r_e / (2 * r_m)
    if abs(phi_e) <= phi_m:
        d = 1.0
    elif phi_e < -math.pi + phi_m or phi_e > math.pi - phi_m:
        d = -1.0
    else:
        d = 0.0
    phi_bar, theta_bar = _fold(phi_e), _fold(theta_e)
    if r_e <= r_e_lim:
        eps, region = 0.0, 0
    elif d == 0.0:
        eps, region = 1.0, 3
    elif r_e < r_a:
        s_th = math.sin(theta_bar)
        eps, region = 0.5 - alpha * _sgn(s_th) * _sgn(s_th + math.sin(phi_bar)), 1
    else:
        eps, region = 1.0, 2
    v = kr * d * math.sin(r_bar) * math.cos(phi_bar)
    omega = k_th * (eps * math.sin(phi_bar) + (1 - eps) * math.sin(theta_bar))
    lyap = 0.5 * r_e**2 + (1 - math.cos(phi_bar)) + (1 - math.cos(theta_bar))
    return {
        "v": v,
        "omega": omega,
        "region": region,
        "d": d,
        "eps": eps,
        "lyapunov": lyap,
        "r_e": r_e,
        "phi_e": phi_e,
        "theta_e": theta_e,
    }


def _one_pose(name: str, value: Any) -> tuple[float, float, float]:
    """A checked pose ``[x, y, θ]`` as three floats (float64: this is the reference)."""
    arr = real_array(name, value, "[x cm, y cm, theta rad]")
    if arr.shape != (3,):
        raise ValueError(f"{name} has shape {arr.shape}; allowed: (3,) [x cm, y cm, theta rad]")
    # Squared distances must stay finite in float64, as in the JAX loop's check.
    limit = position_limit(np.float64)
    if not np.all(np.isfinite(arr)) or abs(arr[2]) > MAX_HEADING or np.max(np.abs(arr[:2])) > limit:
        raise ValueError(
            f"{name} = {arr.tolist()} is not allowed; allowed: finite numbers, "
            f"|x|, |y| <= {limit:.0e} cm, |theta| <= {MAX_HEADING:.0e} rad"
        )
    return float(arr[0]), float(arr[1]), float(arr[2])


def _one_set(params: Any, validate: Any, name: str) -> Any:
    """Validated scalar parameters: the reference runs one pose with one gain set and robot."""
    params = validate(params)
    require_unbatched(
        params, name, "a number (the reference runs one pose; batch with wmr_jax.batch_rollout)"
    )
    return params


def reference_control(pose: Any, ref: Any, gains: Gains) -> tuple[float, float]:
    """Return the command ``(v cm/s, ω rad/s)`` for one pose (Eq. 6, 7)."""
    out = reference_diagnostics(pose, ref, gains)
    return out["v"], out["omega"]


def _limited(command: float, last: float, accel: float, dt: float) -> float:
    """One axis of the speed limiter (docs/model.md §4.2.2); ``accel`` 0: none.

    The change since ``last``, clamped to ``±accel dt``, is added to it as
    ros2_controllers' ``SpeedLimiter`` computes it.
    """
    if accel <= 0:
        return command
    change = min(max(command - last, -accel * dt), accel * dt)
    return last + change


def _arc(x: float, y: float, th: float, v: float, w: float, h: float):
    """Exact unicycle motion at constant (v, ω) over h (docs/model.md §4)."""
    turn = w * h
    if abs(turn) < 1e-3:
        # Chord of the arc, sin(u)/u by its series (error < u⁶/5040) where the
        # closed form below would cancel.
        half = 0.5 * turn
        chord = v * h * (1 - half * half / 6 + half**4 / 120)
        return x + chord * math.cos(th + half), y + chord * math.sin(th + half), th + turn
    # Closed-form integral of Eq. 2 along a circle of radius v/ω.
    th_new = th + turn
    radius = v / w
    return (
        x + radius * (math.sin(th_new) - math.sin(th)),
        y - radius * (math.cos(th_new) - math.cos(th)),
        th_new,
    )


class _Loop:
    """The non-ideal loop of docs/model.md §4 for one robot, in plain floats."""

    def __init__(self, robot: Robot):
        f = {k: float(v) for k, v in vars(robot).items()}
        self.L, self.v_max, self.r = f["half_track"], f["v_max"], f["wheel_radius"]
        self.kp, self.ki, self.tau_max = f["speed_gain"], f["integral_gain"], f["torque_max"]
        M, m, r, a = f["body_mass"], f["wheel_mass"], f["wheel_radius"], f["com_offset"]
        # Kinetic energy of body (disc of diameter D, centre of mass a ahead of
        # the axle) and two disc wheels rolling without slip, in (v, ω).
        self.m11 = M + 2 * m + m  # 2 wheels' translation + 2 × (m r²/2)/r² of spin
        self.m22 = (
            M * f["body_diameter"] ** 2 / 8
            + M * a * a
            + 2 * m * self.L**2
            + 2 * (m * r * r / 4)
            + 2 * (m * r * r / 2) * self.L**2 / (r * r)
        )
        self.ma = M * a

    def rims_limited(self, v, w, mode):
        left, right = v - self.L * w, v + self.L * w
        if mode == "clip":
            left = min(max(left, -self.v_max), self.v_max)
            right = min(max(right, -self.v_max), self.v_max)
        else:
            excess = max(abs(left) / self.v_max, abs(right) / self.v_max, 1.0)
            left, right = left / excess, right / excess
        return 0.5 * (left + right), 0.5 * (right - left) / self.L

    def rates(self, y, target):
        v, w, zv, zw = y
        # Computed torque: wanted accelerations through the model, then per-wheel limits.
        acc_v = self.kp * (target[0] - v) + self.ki * zv
        acc_w = self.kp * (target[1] - w) + self.ki * zw
        force = self.m11 * acc_v - self.ma * w * w
        moment = self.m22 * acc_w + self.ma * v * w
        tau_r = 0.5 * self.r * (force + moment / self.L)
        tau_l = 0.5 * self.r * (force - moment / self.L)
        tau_r = min(max(tau_r, -self.tau_max), self.tau_max)
        tau_l = min(max(tau_l, -self.tau_max), self.tau_max)
        # Eq. 5: H q̇ = B τ − G(q).
        v_dot = ((tau_l + tau_r) / self.r + self.ma * w * w) / self.m11
        w_dot = (self.L * (tau_r - tau_l) / self.r - self.ma * v * w) / self.m22
        return [v_dot, w_dot, target[0] - v, target[1] - w]

    def period(self, pose, y, command, dt, substeps, mode):
        target = self.rims_limited(command[0], command[1], mode)
        h = dt / substeps
        x, yy, th = pose
        travelled = 0.0
        for _ in range(substeps):
            k1 = self.rates(y, target)
            k2 = self.rates([a + 0.5 * h * b for a, b in zip(y, k1, strict=True)], target)
            k3 = self.rates([a + 0.5 * h * b for a, b in zip(y, k2, strict=True)], target)
            k4 = self.rates([a + h * b for a, b in zip(y, k3, strict=True)], target)
            new = [
                a + h / 6 * (b1 + 2 * b2 + 2 * b3 + b4)
                for a, b1, b2, b3, b4 in zip(y, k1, k2, k3, k4, strict=True)
            ]
            new[0], new[1] = self.rims_limited(new[0], new[1], "clip")
            v_mean, w_mean = 0.5 * (y[0] + new[0]), 0.5 * (y[1] + new[1])
            x, yy, th = _arc(x, yy, th, v_mean, w_mean, h)
            travelled += abs(v_mean) * h
            y = new
        return (x, yy, th), y, travelled


@_in_float64
def reference_rollout(
    ref: Any,
    gains: Gains | None = None,
    *,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = 0.033,
    steps: int = 150,
    robot: Robot | None = None,
    velocity: str = "ideal",
    substeps: int = 10,
    wheel_limit: str = "clip",
) -> dict[str, np.ndarray]:
    """Simulate one closed-loop run with a Python loop (docs/model.md §4).

    The arguments are those of ``wmr_jax.rollout`` (Shim–Sung only).

    Returns:
        The fields of ``wmr_jax.Trajectory`` as float64 NumPy arrays in a dict.
    """
    gains = _one_set(Gains() if gains is None else gains, validate_gains, "gains")
    robot = _one_set(Robot() if robot is None else robot, validate_robot, "robot")
    if velocity not in ("ideal", "nonideal"):
        raise ValueError(f"velocity = {velocity!r} is not allowed; allowed: ('ideal', 'nonideal')")
    if wheel_limit not in ("clip", "scale"):
        raise ValueError(
            f"wheel_limit = {wheel_limit!r} is not allowed; allowed: ('clip', 'scale')"
        )
    dt, steps = float(check_dt(dt)), check_int("steps", steps, 1, MAX_STEPS)
    substeps = check_int("substeps", substeps, 1, MAX_STEPS)
    check_sampling(gains, dt, stacklevel=4)  # the JAX rollout's warning, at the caller
    if velocity == "nonideal":
        check_stability(robot, dt, substeps)  # the same bound as the JAX loop's
    ref = _one_pose("ref", ref)
    loop = _Loop(robot)
    accel, angular_accel = float(robot.accel_max), float(robot.angular_accel_max)
    x, y, th = _one_pose("init", init)
    state = [0.0, 0.0, 0.0, 0.0]  # v, ω and the wheel loop's integrals
    poses = np.empty((steps + 1, 3))
    v_out, w_out, region = np.empty(steps), np.empty(steps), np.empty(steps, dtype=np.int32)
    rims, dist = np.empty((steps, 2)), np.empty(steps)
    poses[0] = x, y, th
    for k in range(steps):
        out = _diagnostics((x, y, th), ref, gains)
        v, w = out["v"], out["omega"]
        if velocity == "ideal":
            # The robot starts at rest: the first limited change is from (0, 0).
            v_held = _limited(v, state[0], accel, dt)
            w_held = _limited(w, state[1], angular_accel, dt)
            x, y, th = _arc(x, y, th, v_held, w_held, dt)
            state, dist[k] = [v_held, w_held, 0.0, 0.0], abs(v_held) * dt
        else:
            (x, y, th), state, dist[k] = loop.period(
                (x, y, th), state, (v, w), dt, substeps, wheel_limit
            )
        poses[k + 1] = x, y, th
        v_out[k], w_out[k], region[k] = v, w, out["region"]
        rims[k] = state[0] - loop.L * state[1], state[0] + loop.L * state[1]
    with np.errstate(invalid="ignore"):
        resolved = np.isfinite(poses).all() and np.abs(poses[:, 2]).max() <= MAX_HEADING
    if not resolved:  # as the JAX rollout refuses an inf or NaN pose
        raise ValueError(
            f"the run left the range float64 resolves (a pose became inf or NaN, or its "
            f"heading beyond {MAX_HEADING:.0e} rad); allowed: gains and dt that keep the "
            "sampled law stable (docs/model.md §4)"
        )
    return {
        "poses": poses,
        "v": v_out,
        "omega": w_out,
        "region": region,
        "wheel_speeds": rims,
        "distance": dist,
    }


# ---------------------------------------------------------------- the disturbed loop (§7, §9)


def _residual(a: float) -> float:
    """An angle difference wrapped to (−π, π] (a heading residual)."""
    return -_wrap(-a)


def _gain_at(table: Any, r: float) -> float:
    """A gain table at distance ``r``: linear between knots at R (k / (K − 1))², constant beyond."""
    if not isinstance(table, tuple):
        return float(table)
    values = [float(g) for g in table]
    radii = [OBSERVER_R * (k / (len(values) - 1)) ** 2 for k in range(len(values))]
    for k in range(1, len(values)):
        if r <= radii[k]:
            share = (r - radii[k - 1]) / (radii[k] - radii[k - 1])
            return values[k - 1] + share * (values[k] - values[k - 1])
    return values[-1]


class _Observer:
    """The observer in plain floats: predict on the exact arc, blend toward the measurement."""

    def __init__(self, params: Any, measured: tuple, half_track: float):
        del half_track  # the filter's signature
        self.position, self.heading = params.position, params.heading
        self.pose = measured

    def update(self, v: float, w: float, z: tuple, ref: tuple, dt: float) -> None:
        px, py, pth = _arc(*self.pose, v, w, dt)
        r = math.hypot(ref[0] - px, ref[1] - py)
        g_pos, g_head = _gain_at(self.position, r), _gain_at(self.heading, r)
        back = (1.0 - g_head) * _residual(z[2] - pth)
        self.pose = (
            z[0] + (1.0 - g_pos) * (px - z[0]),
            z[1] + (1.0 - g_pos) * (py - z[1]),
            z[2] - back,
        )


class _Filter:
    """The extended Kalman filter of the ideal robot over ``[x, y, θ]``, in NumPy."""

    def __init__(self, params: EKFParams, measured: tuple, half_track: float):
        self.wheel_error, self.L = float(params.wheel_error), half_track
        sxy, sth = float(params.sigma_xy), float(params.sigma_theta)
        self.meas_cov = np.diag([sxy**2, sxy**2, sth**2])
        self.pose, self.cov = measured, self.meas_cov.copy()

    def update(self, v: float, w: float, z: tuple, ref: tuple, dt: float) -> None:
        x, y, th = self.pose
        px, py, pth = _arc(x, y, th, v, w, dt)
        # d(new position)/dθ is the displacement turned by a right angle.
        jac = np.array([[1.0, 0.0, -(py - y)], [0.0, 1.0, px - x], [0.0, 0.0, 1.0]])
        # Independent relative errors on each wheel's travel: the centre moves
        # by their mean (taken as isotropic in x and y), the heading turns by
        # their difference over 2L.
        left, right = abs(v - self.L * w) * dt, abs(v + self.L * w) * dt
        var = self.wheel_error**2 * (left**2 + right**2) / 4.0
        cov = jac @ self.cov @ jac.T + np.diag([var, var, var / self.L**2])
        gain = cov @ np.linalg.inv(cov + self.meas_cov)
        step = gain @ np.array([z[0] - px, z[1] - py, _residual(z[2] - pth)])
        self.pose = (px + step[0], py + step[1], pth + step[2])
        cov = (np.eye(3) - gain) @ cov
        self.cov = 0.5 * (cov + cov.T)


def _checked_disturbance(noise: Any, mismatch: Any, delay: Any) -> tuple[np.ndarray, tuple, int]:
    """One run's checked noise ``(steps, 3)``, ``(left, right)`` rim factors and latency."""
    arr = real_array("noise", noise, "(steps, 3) real numbers [cm, cm, rad]")
    if arr.ndim != 2 or arr.shape[1] != 3 or not 1 <= arr.shape[0] <= MAX_STEPS:
        raise ValueError(f"noise has shape {arr.shape}; allowed: (steps, 3), steps >= 1")
    limit = position_limit(np.float64)
    ok = np.isfinite(arr) & (np.abs(arr) <= np.array([limit, limit, MAX_HEADING]))
    if not np.all(ok):
        raise ValueError(
            f"noise holds {float(arr[~ok][0])!r}; allowed: finite numbers, |x|, |y| noise <= "
            f"{limit:.0e} cm and heading noise <= {MAX_HEADING:.0e} rad"
        )
    allowed = "(left, right) rim factors > 0, or (left, right, mass) (mass unused: ideal loop)"
    factors = real_array("mismatch", mismatch, allowed)
    if factors.shape not in ((2,), (3,)) or not np.all(np.isfinite(factors) & (factors > 0)):
        raise ValueError(f"mismatch = {factors.tolist()} is not allowed; allowed: {allowed}")
    allowed = "an integer number of samples m >= 0"
    late = real_array("delay", delay, allowed)
    if late.shape != () or not (np.isfinite(late) and late >= 0 and np.floor(late) == late):
        raise ValueError(f"delay = {delay!r} is not allowed; allowed: {allowed}")
    return arr, (float(factors[0]), float(factors[1])), int(late)


@_in_float64
def reference_disturbed_rollout(
    ref: Any,
    gains: Gains | None = None,
    *,
    noise: Any,
    mismatch: Any = (1.0, 1.0),
    delay: Any = 0,
    estimator: Any = None,
    init: Any = (0.0, 0.0, 0.0),
    dt: float = 0.033,
    robot: Robot | None = None,
) -> dict[str, np.ndarray]:
    """Simulate one disturbed run of the ideal loop with a Python loop (docs/model.md §7, §9).

    One row of ``wmr_jax.studies.disturbed_rollout`` (Shim–Sung law, ideal
    loop) in angles and plain floats, and its return values.

    Args:
        noise: ``(steps, 3)`` measurement error at each sample ``k`` (which
            ends period ``k − 1``); sets the number of periods.
        mismatch: ``(left, right)`` rim factors (a ``(left, right, mass)`` row
            too: the ideal loop has no mass).
        delay: the latency, samples.
        estimator: ``None``, ``"observer"``, ``"ekf"`` or one
            ``ObserverParams``/``EKFParams``.
        ref, gains, init, dt, robot: as for ``reference_rollout``.
    """
    gains = _one_set(Gains() if gains is None else gains, validate_gains, "gains")
    robot = _one_set(Robot() if robot is None else robot, validate_robot, "robot")
    kind, params = resolve_estimator(estimator)
    if kind is not None and not kind.own:
        raise ValueError(f"estimator = {kind!r} is not allowed; allowed: None, 'observer', 'ekf'")
    require_unbatched(params, "estimator", "a number (the reference runs one pose)")
    ref, (x, y, th) = _one_pose("ref", ref), _one_pose("init", init)
    noise, (f_left, f_right), late = _checked_disturbance(noise, mismatch, delay)
    dt = float(check_dt(dt))
    half_track, steps = float(robot.half_track), noise.shape[0]

    def law(pose: tuple) -> tuple[float, float]:
        out = _diagnostics(pose, ref, gains)
        return out["v"], out["omega"]

    def measure(k: int) -> tuple:
        n = noise[k] if k < steps else (0.0, 0.0, 0.0)  # the last one is never used
        return x + float(n[0]), y + float(n[1]), th + float(n[2])

    estimate = None
    if kind is not None:
        make = _Observer if kind.params_type is not EKFParams else _Filter
        estimate = make(params, measure(0), half_track)
    roll = estimate is not None and late > 0 and bool(params.compensate)

    def seen(z: tuple, in_flight: list) -> tuple:
        """The pose the law is handed: the measurement, or the estimate (rolled forward)."""
        if estimate is None:
            return z
        if not roll:
            return estimate.pose
        pose = estimate.pose
        for command in in_flight:
            pose = _arc(*pose, *command, dt)
        return pose

    # The commands in flight, the next one to be applied first.
    in_flight = [(0.0, 0.0)] * late
    fresh = law(seen(measure(0), in_flight))
    poses, estimates = np.empty((steps + 1, 3)), np.empty((steps, 3))
    v_out, w_out = np.empty(steps), np.empty(steps)
    poses[0] = x, y, th
    for k in range(steps):
        v, w = in_flight[0] if late else fresh
        left, right = f_left * (v - half_track * w), f_right * (v + half_track * w)
        x, y, th = _arc(x, y, th, 0.5 * (left + right), 0.5 * (right - left) / half_track, dt)
        poses[k + 1], v_out[k], w_out[k] = (x, y, th), v, w
        z = measure(k + 1)
        if estimate is not None:
            estimate.update(v, w, z, ref, dt)
        estimates[k] = z if estimate is None else estimate.pose
        # Under latency the command just computed joins those in flight.
        in_flight = in_flight[1:] + [fresh] if late else in_flight
        fresh = law(seen(z, in_flight))
    return {"poses": poses, "v": v_out, "omega": w_out, "estimates": estimates}
