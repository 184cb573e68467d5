"""The C source of a tuned closed loop: law, estimator, latency compensation, limits.

``c_sources`` turns a ``ClosedLoop`` (what ``load_tuned`` returns) into a
header and a C99 file with every tuned constant baked in. The C mirrors the
project's arithmetic operation for operation, in the same order (the sine and
cosine are ``dynamics.sin_cos``'s Cody–Waite reduction and polynomials, the
complex products are written out as XLA evaluates them), so that a step in
double equals the JAX step to rounding; the float build runs the same code
in single precision.

One call of ``wmr_step`` is one sample of ``sensing.loop.disturbed_run``
(docs/model.md §7, §9): the first starts the estimate from the measurement;
each later one predicts over the period just ended with the command that
acted in it, corrects toward the measurement, rolls the estimate over the
commands still in flight (compensation), and runs the law. The command then
passes the robot's speed limiter (where the robot gives one) and the
wheel-speed limit (each rim within ``±V_max``, which gains within the wheel
budget never reach), and is what the estimator predicts with.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from wmr_jax._src import dynamics
from wmr_jax._src.controllers.aicardi import AICARDI, AicardiGains
from wmr_jax._src.controllers.astolfi import ASTOLFI, AstolfiGains
from wmr_jax._src.controllers.schedule import SCHEDULE, ScheduleParams, knot_radii
from wmr_jax._src.controllers.shim_sung import SHIM_SUNG
from wmr_jax._src.params import Gains, Robot
from wmr_jax._src.rollout import DEFAULT_DT
from wmr_jax._src.sensing.estimators import (
    EKFParams,
    ObserverParams,
    observer_radii,
    resolve_estimator,
)
from wmr_jax._src.sensing.loop import ClosedLoop

__all__ = ["MAX_LATENCY", "REALS", "CSources", "c_sources"]

REALS = ("double", "float")
# Commands in flight the controller can hold (its ring of sent commands is
# one longer): a compile-time bound, so that the state has a fixed size.
MAX_LATENCY = 10
HEADER = "wmr_controller.h"
SOURCE = "wmr_controller.c"


@dataclasses.dataclass(frozen=True)
class CSources:
    """The generated files and what they were generated from.

    Attributes:
        header: text of ``wmr_controller.h``.
        source: text of ``wmr_controller.c``.
        real: ``"double"`` or ``"float"``, the arithmetic of the step.
        period: the control period baked in, s.
        max_latency: the largest latency the controller holds, periods.
    """

    header: str
    source: str
    real: str
    period: float
    max_latency: int


class _Emitter:
    """Literals of one precision: a constant as the C of the chosen real type."""

    def __init__(self, real: str, period: float):
        self.real = real
        self.dtype = np.dtype(np.float64 if real == "double" else np.float32)
        self.period = period
        self.dt = self(period)

    def __call__(self, value: Any) -> str:
        """``value`` rounded to the real type, written so that C reads it back exactly."""
        x = float(self.dtype.type(value))
        if not math.isfinite(x):
            raise ValueError(f"constant {value!r} is not finite in {self.real}")
        text = repr(x)
        if "e" not in text and "." not in text:
            text += ".0"
        return f"{text}f" if self.real == "float" else text

    def fn(self, name: str) -> str:
        """A ``<math.h>`` function of the real type (``sqrt`` or ``sqrtf``)."""
        return name + ("f" if self.real == "float" else "")


def _horner(c: _Emitter, var: str, coefficients: tuple[float, ...]) -> str:
    """``Σ c_k var^k`` by Horner's rule, as ``dynamics._polynomial`` evaluates it."""
    expr = c(coefficients[-1])
    for k in coefficients[-2::-1]:
        expr = f"({expr} * {var} + {c(k)})"
    return expr


def _table_code(c: _Emitter, name: str, values: tuple, radii: np.ndarray, var: str) -> str:
    """A C function of a piecewise-linear table, as ``schedule._table`` evaluates it."""
    lines = [f"static wmr_real {name}(wmr_real {var})", "{", f"    wmr_real out = {c(values[0])};"]
    lines.append("    wmr_real ramp;")
    dtype = c.dtype.type
    for k in range(1, len(values)):
        inv = 1.0 / (radii[k] - radii[k - 1])
        step = dtype(values[k]) - dtype(values[k - 1])
        lines.append(
            f"    ramp = wmr_clip(({var} - {c(radii[k - 1])}) * {c(inv)}, {c(0)}, {c(1)});"
        )
        lines.append(f"    out = out + {c(step)} * ramp;")
    lines += ["    return out;", "}", ""]
    return "\n".join(lines)


def _scalar(value: Any, name: str) -> float:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 0:
        raise ValueError(f"{name} has shape {arr.shape}; allowed: one value (an unbatched loop)")
    return float(arr)


# The error coordinates of Eq. 3 (shim_sung.polar_error), shared by every law.
_ERROR = """    /* The error in the robot frame (Eq. 3), docs/model.md §2. */
    wmr_real dx = c->ref[0] - x, dy = c->ref[1] - y;
    wmr_real e_x = cos_c * dx - (-sin_c) * dy;
    wmr_real e_y = cos_c * dy + (-sin_c) * dx;
    wmr_real r_sq = e_x * e_x + e_y * e_y;
    int positive = r_sq > {zero};
    wmr_real safe_r = {sqrt}(positive ? r_sq : {one});
    wmr_real inv_r = {one} / safe_r;
    wmr_real r = positive ? safe_r : {zero};
    wmr_real cos_phi = positive ? e_x * inv_r : {one};
    wmr_real sin_phi = e_y * inv_r;
    wmr_real cos_theta = c->ref_cos * cos_c + c->ref_sin * sin_c;
    wmr_real sin_theta = c->ref_sin * cos_c - c->ref_cos * sin_c;"""


def _law(c: _Emitter, params: Any) -> str:
    """The law: ``wmr_law(c, x, y, cos θ, sin θ, command)`` (docs/model.md §2–3)."""
    schedule = isinstance(params, ScheduleParams)
    names = ("phi_m", "r_m", "r_a", "r_e", "alpha")
    g = {name: _scalar(getattr(params, name), f"params.{name}") for name in names}
    dtype = c.dtype.type
    cos_m = dtype(np.cos(dtype(g["phi_m"])))
    r_scale = dtype(np.pi / 2) / dtype(g["r_m"])
    parts = []
    if schedule:
        knots = len(params.kr)
        radii = knot_radii(knots)
        for table in ("kr", "k_theta", "k_turn"):
            values = tuple(_scalar(v, f"params.{table}") for v in getattr(params, table))
            parts.append(_table_code(c, f"wmr_table_{table}", values, radii, "r"))
    body = f"""static void wmr_law(const wmr_controller *c, wmr_real x, wmr_real y, wmr_real cos_c,
                    wmr_real sin_c, wmr_real out[2])
{{
{_ERROR.format(zero=c(0), one=c(1), sqrt=c.fn("sqrt"))}
    /* Direction d, blend and commands (Eq. 6-8), docs/model.md §3. */
    wmr_real ahead = (cos_phi - {c(cos_m)} >= {c(0)}) ? {c(1)} : {c(0)};
    wmr_real behind = (-{c(cos_m)} - cos_phi > {c(0)}) ? {c(1)} : {c(0)};
    wmr_real d = ahead - behind;
    wmr_real flip_phi = cos_phi < {c(0)} ? {c(-1)} : {c(1)};
    wmr_real flip_theta = cos_theta < {c(0)} ? {c(-1)} : {c(1)};
    wmr_real cos_phi_bar = flip_phi * cos_phi, sin_phi_bar = flip_phi * sin_phi;
    wmr_real sin_theta_bar = flip_theta * sin_theta;
    wmr_real in_region_0 = ({c(g["r_e"])} - r >= {c(0)}) ? {c(1)} : {c(0)};
    wmr_real inside_r_a = ({c(g["r_a"])} - r > {c(0)}) ? {c(1)} : {c(0)};
    wmr_real eps_1 = {c(0.5)} - {c(g["alpha"])} * wmr_sgn(sin_theta_bar)
                     * wmr_sgn(sin_theta_bar + sin_phi_bar);
    wmr_real eps = ({c(1)} - in_region_0) * ({c(1)} - d * d * inside_r_a * ({c(1)} - eps_1));
    wmr_real r_bar = wmr_min(r * {c(r_scale)}, {c(np.pi / 2)});
    wmr_real sin_r_bar = wmr_sin_small(r_bar);
"""
    if schedule:
        v_max = _scalar(params.v_max, "params.v_max")
        half_track = _scalar(params.half_track, "params.half_track")
        omega_max = dtype(v_max) / dtype(half_track)
        body += f"""    wmr_real k_theta = wmr_table_k_theta(r);
    wmr_real kr = wmr_table_kr(r);
    wmr_real v, omega, budget;
    k_theta = k_theta + ({c(1)} - d * d) * (wmr_table_k_turn(r) - k_theta);
    v = kr * d * sin_r_bar * cos_phi_bar;
    omega = k_theta * (eps * sin_phi_bar + ({c(1)} - eps) * sin_theta_bar);
    /* |v| + L|w| <= V_max by construction (schedule.py). */
    omega = wmr_clip(omega, -{c(omega_max)}, {c(omega_max)});
    budget = {c(v_max)} - {c(half_track)} * {c.fn("fabs")}(omega);
    out[0] = wmr_clip(v, -budget, budget);
    out[1] = omega;
}}
"""
    else:
        kr, k_theta = _scalar(params.kr, "params.kr"), _scalar(params.k_theta, "params.k_theta")
        body += f"""    out[0] = {c(kr)} * d * sin_r_bar * cos_phi_bar;
    out[1] = {c(k_theta)} * (eps * sin_phi_bar + ({c(1)} - eps) * sin_theta_bar);
}}
"""
    return "\n".join(parts) + body


def _polar_law(c: _Emitter, name: str, params: Any) -> str:
    """A baseline polar law as ``wmr_law`` (``controllers/aicardi.py``, ``astolfi.py``).

    ``ρ``, ``α`` and ``θ_A`` from the same error coordinates as the Shim–Sung
    law, with ``atan2``; within ``goal_floor`` the robot only turns.
    """
    from wmr_jax._src.controllers import polar

    backward = bool(params.backward)
    eps = float(np.finfo(c.dtype).eps)
    if backward:
        alpha = f"""    int behind = cos_phi < {c(0)};
    wmr_real alpha = behind ? wmr_wrap(phi + {c(np.pi)}) : phi;
    wmr_real direction = behind ? {c(-1)} : {c(1)};"""
    else:
        alpha = f"""    wmr_real alpha = phi;
    wmr_real direction = {c(1)};"""
    if name == "aicardi":
        gamma, k, h = (_scalar(getattr(params, f), f"params.{f}") for f in ("gamma", "k", "h"))
        law = f"""    wmr_real cos_alpha, sin_alpha, sinc;
    wmr_real theta_a = wmr_wrap(alpha - theta_e);
    wmr_sin_cos(alpha, &cos_alpha, &sin_alpha);
    /* sin(a)/a, by its series where it would cancel (dynamics.sinc). */
    sinc = {c.fn("fabs")}(alpha) < {c(dynamics._SINC_SERIES_BELOW)}
        ? {c(1)} - alpha * alpha / {c(6)} * ({c(1)} - alpha * alpha / {c(20)})
        : sin_alpha / alpha;
    v = direction * {c(gamma)} * r * cos_alpha;
    omega = {c(k)} * alpha + {c(gamma)} * cos_alpha * sinc * (alpha + {c(h)} * theta_a);
    rate = {c(k)};"""
    else:
        k_rho, k_alpha, k_beta = (
            _scalar(getattr(params, f), f"params.{f}") for f in ("k_rho", "k_alpha", "k_beta")
        )
        law = f"""    wmr_real theta_a = wmr_wrap(alpha - theta_e);
    alpha = wmr_clip(alpha, {c(-np.pi / 2)}, {c(np.pi / 2)});
    v = direction * {c(k_rho)} * r;
    omega = {c(k_alpha)} * alpha - {c(k_beta)} * theta_a;
    rate = {c(k_alpha)};"""
    return f"""static void wmr_law(const wmr_controller *c, wmr_real x, wmr_real y, wmr_real cos_c,
                    wmr_real sin_c, wmr_real out[2])
{{
{_ERROR.format(zero=c(0), one=c(1), sqrt=c.fn("sqrt"))}
    wmr_real phi = {c.fn("atan2")}(sin_phi, cos_phi);
    wmr_real theta_e = wmr_wrap({c.fn("atan2")}(sin_theta, cos_theta));
    wmr_real v, omega, rate, magnitude, floor;
{alpha}
{law}
    /* At the goal: hold the position, turn to the goal's heading (polar.hold_at_goal). */
    magnitude = wmr_max(wmr_max({c.fn("fabs")}(x), {c.fn("fabs")}(y)),
                        wmr_max({c.fn("fabs")}(c->ref[0]), {c.fn("fabs")}(c->ref[1])));
    floor = wmr_max({c(polar.AT_GOAL)}, {c(polar.GOAL_EPS)} * {c(eps)} * magnitude);
    if (r < floor) {{
        v = {c(0)};
        omega = rate * wmr_wrap(alpha - theta_a);
    }}
    out[0] = v;
    out[1] = omega;
}}
"""


def _kernels(c: _Emitter, polar: bool) -> str:
    """``sin_cos`` and the helpers the law uses (``sin_small`` and ``Sgn`` for Shim–Sung)."""
    p1, p2, p3 = dynamics._PIO2[c.dtype]
    sin_poly = _horner(c, "z", dynamics._SIN[c.dtype])
    cos_poly = _horner(c, "z", dynamics._COS[c.dtype])
    taylor = _horner(c, "z", dynamics._SIN_TAYLOR[c.dtype])
    helpers = (
        "static wmr_real wmr_max(wmr_real a, wmr_real b) { return a > b ? a : b; }\n"
        if polar
        else f"""static wmr_real wmr_min(wmr_real a, wmr_real b) {{ return a < b ? a : b; }}

/* Sgn of Eq. 8: 1 if x > 0, else -1. */
static wmr_real wmr_sgn(wmr_real x) {{ return x > {c(0)} ? {c(1)} : {c(-1)}; }}

/* sin of an angle in [0, pi/2] by its Taylor series (dynamics.sin_small). */
static wmr_real wmr_sin_small(wmr_real angle)
{{
    wmr_real z = angle * angle;
    return angle * {taylor};
}}
"""
    )
    return (
        helpers
        + f"""
static wmr_real wmr_clip(wmr_real x, wmr_real low, wmr_real high)
{{
    x = x > low ? x : low;
    return x < high ? x : high;
}}

/* cos and sin of an angle: Cody-Waite reduction by pi/2, minimax kernels
   (dynamics.sin_cos; within an ulp or two up to |angle| ~ 1e6 rad). */
static void wmr_sin_cos(wmr_real angle, wmr_real *cos_out, wmr_real *sin_out)
{{
    wmr_real k = {c.fn("nearbyint")}(angle * {c(2 / np.pi)});
    wmr_real r = ((angle - k * {c(p1)}) - k * {c(p2)}) - k * {c(p3)};
    wmr_real z = r * r;
    wmr_real sin_r = r + (r * z) * {sin_poly};
    wmr_real cos_r = ({c(1)} - {c(0.5)} * z) + (z * z) * {cos_poly};
    unsigned int quadrant = (unsigned int)(long)k;
    int odd = (quadrant & 1u) == 1u;
    wmr_real cos_k = odd ? sin_r : cos_r;
    wmr_real sin_k = odd ? cos_r : sin_r;
    *cos_out = ((quadrant + 1u) & 2u) == 2u ? -cos_k : cos_k;
    *sin_out = (quadrant & 2u) == 2u ? -sin_k : sin_k;
}}
"""
    )


def _arc(c: _Emitter) -> str:
    """The exact arc of the ideal robot (docs/model.md §4): ``loops.ArcMove``, ``ideal_move``."""
    return f"""/* One period at the held command (v, w): half turn, chord and rotation. */
typedef struct {{
    wmr_real turn_cos, turn_sin, chord, rotation;
}} wmr_arc;

static wmr_arc wmr_arc_of(wmr_real v, wmr_real omega)
{{
    wmr_arc a;
    wmr_real half = {c(0.5)} * omega * {c.dt};
    wmr_real sinc, u2 = half * half;
    wmr_sin_cos(half, &a.turn_cos, &a.turn_sin);
    if ({c.fn("fabs")}(half) < {c(dynamics._SINC_SERIES_BELOW)})
        sinc = {c(1)} - u2 / {c(6)} * ({c(1)} - u2 / {c(20)});
    else
        sinc = a.turn_sin / half;
    a.chord = v * {c.dt} * sinc;
    a.rotation = omega * {c.dt};
    return a;
}}

static wmr_pose wmr_move(wmr_pose p, wmr_arc a)
{{
    wmr_pose out;
    wmr_real mid_c = p.cos_h * a.turn_cos - p.sin_h * a.turn_sin;
    wmr_real mid_s = p.cos_h * a.turn_sin + p.sin_h * a.turn_cos;
    wmr_real h_c = mid_c * a.turn_cos - mid_s * a.turn_sin;
    wmr_real h_s = mid_c * a.turn_sin + mid_s * a.turn_cos;
    /* One Newton step towards |heading| = 1 (loops.ideal_move). */
    wmr_real newton = {c(1.5)} - {c(0.5)} * (h_c * h_c + h_s * h_s);
    out.x = p.x + a.chord * mid_c;
    out.y = p.y + a.chord * mid_s;
    out.cos_h = h_c * newton;
    out.sin_h = h_s * newton;
    out.theta = p.theta + a.rotation;
    return out;
}}
"""


def _wrap(c: _Emitter) -> str:
    return f"""/* An angle wrapped to [-pi, pi) (shim_sung.wrap_angle, jnp.mod's convention). */
static wmr_real wmr_wrap(wmr_real angle)
{{
    wmr_real a = angle + {c(np.pi)};
    wmr_real m = {c.fn("fmod")}(a, {c(2 * np.pi)});
    if (m != {c(0)} && m < {c(0)})
        m = m + {c(2 * np.pi)};
    return m - {c(np.pi)};
}}
"""


def _observer(c: _Emitter, params: ObserverParams) -> str:
    """The observer's correction (``estimators._observer_update``)."""
    parts, gains = [], {}
    for name in ("position", "heading"):
        table = params.position if name == "position" else params.heading
        if isinstance(table, tuple):
            values = tuple(_scalar(v, f"estimator.{name}") for v in table)
            parts.append(
                _table_code(c, f"wmr_gain_{name}", values, observer_radii(len(values)), "r")
            )
            gains[name] = f"wmr_gain_{name}(distance)"
        else:
            gains[name] = c(_scalar(table, f"estimator.{name}"))
    correct = f"""static void wmr_correct(wmr_controller *c, wmr_pose predicted,
                        const wmr_real cmd[2], wmr_real mx, wmr_real my, wmr_real mth)
{{
    wmr_real dre = c->ref[0] - predicted.x, dim = c->ref[1] - predicted.y;
    wmr_real distance = {c.fn("sqrt")}(dre * dre + dim * dim);
    wmr_real g_position = {gains["position"]};
    wmr_real g_heading = {gains["heading"]};
    wmr_real back = ({c(1)} - g_heading) * wmr_wrap(mth - predicted.theta);
    (void)cmd;
    (void)distance;
    c->est.x = mx + ({c(1)} - g_position) * (predicted.x - mx);
    c->est.y = my + ({c(1)} - g_position) * (predicted.y - my);
    wmr_sin_cos(mth - back, &c->est.cos_h, &c->est.sin_h);
    c->est.theta = mth - back;
}}

static void wmr_start(wmr_controller *c) {{ (void)c; }}
"""
    return "\n".join(parts) + correct


def _ekf(c: _Emitter, params: EKFParams, robot: Robot) -> str:
    """The extended Kalman filter's prediction and correction (``estimators._ekf_update``)."""
    dtype = c.dtype.type
    sxy = dtype(_scalar(params.sigma_xy, "estimator.sigma_xy"))
    sth = dtype(_scalar(params.sigma_theta, "estimator.sigma_theta"))
    we = dtype(_scalar(params.wheel_error, "estimator.wheel_error"))
    half_track = dtype(_scalar(robot.half_track, "robot.half_track"))
    rxy, rth = sxy**2, sth**2
    return f"""static void wmr_start(wmr_controller *c)
{{
    c->cov[0] = {c(rxy)}; c->cov[1] = {c(0)}; c->cov[2] = {c(0)};
    c->cov[3] = {c(rxy)}; c->cov[4] = {c(0)}; c->cov[5] = {c(rth)};
}}

static void wmr_correct(wmr_controller *c, wmr_pose predicted,
                        const wmr_real cmd[2], wmr_real mx, wmr_real my, wmr_real mth)
{{
    wmr_real v = cmd[0], omega = cmd[1];
    wmr_real a = -(predicted.y - c->est.y), b = predicted.x - c->est.x;
    wmr_real p00 = c->cov[0], p01 = c->cov[1], p02 = c->cov[2];
    wmr_real p11 = c->cov[3], p12 = c->cov[4], p22 = c->cov[5];
    wmr_real travel_left = {c.fn("fabs")}(v - {c(half_track)} * omega) * {c.dt};
    wmr_real travel_right = {c.fn("fabs")}(v + {c(half_track)} * omega) * {c.dt};
    wmr_real q = {c(we)} * {c(we)} * (travel_left * travel_left + travel_right * travel_right)
                 / {c(4)};
    wmr_real m02 = p02 + a * p22, m12 = p12 + b * p22;
    wmr_real m22 = p22 + q / {c(half_track**2)};
    wmr_real m00 = p00 + {c(2)} * a * p02 + a * a * p22 + q;
    wmr_real m01 = p01 + a * p12 + b * p02 + a * b * p22;
    wmr_real m11 = p11 + {c(2)} * b * p12 + b * b * p22 + q;
    wmr_real s00 = m00 + {c(rxy)}, s11 = m11 + {c(rxy)}, s22 = m22 + {c(rth)};
    wmr_real c00 = s11 * s22 - m12 * m12, c01 = m02 * m12 - m01 * s22;
    wmr_real c02 = m01 * m12 - m02 * s11, c11 = s00 * s22 - m02 * m02;
    wmr_real c12 = m01 * m02 - s00 * m12, c22 = s00 * s11 - m01 * m01;
    wmr_real det = s00 * c00 + m01 * c01 + m02 * c02;
    wmr_real y0, y1, y2, dx, dy, dth, turn_c, turn_s;
    p00 = {c(rxy)} * (c00 * m00 + c01 * m01 + c02 * m02) / det;
    p01 = {c(rxy)} * (c00 * m01 + c01 * m11 + c02 * m12) / det;
    p02 = {c(rxy)} * (c00 * m02 + c01 * m12 + c02 * m22) / det;
    p11 = {c(rxy)} * (c01 * m01 + c11 * m11 + c12 * m12) / det;
    p12 = {c(rxy)} * (c01 * m02 + c11 * m12 + c12 * m22) / det;
    p22 = {c(rth)} * (c02 * m02 + c12 * m12 + c22 * m22) / det;
    c->cov[0] = p00; c->cov[1] = p01; c->cov[2] = p02;
    c->cov[3] = p11; c->cov[4] = p12; c->cov[5] = p22;
    /* The correction K y = P R^-1 y. */
    y0 = (mx - predicted.x) / {c(rxy)};
    y1 = (my - predicted.y) / {c(rxy)};
    y2 = wmr_wrap(mth - predicted.theta) / {c(rth)};
    dx = p00 * y0 + p01 * y1 + p02 * y2;
    dy = p01 * y0 + p11 * y1 + p12 * y2;
    dth = p02 * y0 + p12 * y1 + p22 * y2;
    wmr_sin_cos(dth, &turn_c, &turn_s);
    c->est.x = predicted.x + dx;
    c->est.y = predicted.y + dy;
    c->est.cos_h = predicted.cos_h * turn_c - predicted.sin_h * turn_s;
    c->est.sin_h = predicted.cos_h * turn_s + predicted.sin_h * turn_c;
    c->est.theta = predicted.theta + dth;
}}
"""


def _limits(c: _Emitter, robot: Robot) -> str:
    """The speed limiter (docs/model.md §4.2.2) and the wheel-speed limit, as ``wmr_limit``."""
    accel = _scalar(robot.accel_max, "robot.accel_max")
    angular = _scalar(robot.angular_accel_max, "robot.angular_accel_max")
    v_max = _scalar(robot.v_max, "robot.v_max")
    half_track = _scalar(robot.half_track, "robot.half_track")
    limiter = accel > 0 or angular > 0
    lines = ["static void wmr_limit(wmr_controller *c, wmr_real cmd[2])", "{"]
    if limiter:
        dtype = c.dtype.type
        for i, rate in enumerate((accel, angular)):
            if rate > 0:  # an axis without a limit passes unchanged (dynamics.rate_limit)
                step = c(dtype(rate) * dtype(c.period))
                lines.append(
                    f"    cmd[{i}] = wmr_clip(cmd[{i}], c->held[{i}] - {step}, "
                    f"c->held[{i}] + {step});"
                )
        lines += ["    c->held[0] = cmd[0];", "    c->held[1] = cmd[1];"]
    else:
        lines.append("    (void)c;")
    # Each rim within +-V_max; the round trip through the rims only where one
    # exceeds it, so that commands within the limit pass bit for bit.
    lines += [
        "    {",
        f"        wmr_real left = cmd[0] - {c(half_track)} * cmd[1];",
        f"        wmr_real right = cmd[0] + {c(half_track)} * cmd[1];",
        f"        if ({c.fn('fabs')}(left) > {c(v_max)} || {c.fn('fabs')}(right) > {c(v_max)}) {{",
        f"            left = wmr_clip(left, -{c(v_max)}, {c(v_max)});",
        f"            right = wmr_clip(right, -{c(v_max)}, {c(v_max)});",
        f"            cmd[0] = {c(0.5)} * (left + right);",
        f"            cmd[1] = (right - left) / {c(2 * half_track)};",
        "        }",
        "    }",
        "}",
        "",
    ]
    return "\n".join(lines)


def _describe(loop: ClosedLoop, estimator: Any, robot: Robot, real: str, period: float) -> str:
    """The header's account of what was baked in."""
    if isinstance(loop.params, ScheduleParams):
        law = f"Shim-Sung (2003), gain schedule of {len(loop.params.kr)} knots"
    elif isinstance(loop.params, Gains):
        law = "Shim-Sung (2003), fixed gains"
    else:
        law = {AICARDI.name: "Aicardi et al. (1995)", ASTOLFI.name: "Astolfi (Corke's form)"}[
            getattr(loop.controller, "name", loop.controller)
        ]
    feedback = "raw measurements" if estimator is None else estimator.name
    return (
        f" * Law: {law}. Feedback: {feedback}.\n"
        f" * Robot: V_max = {float(robot.v_max):g} cm/s, L = {float(robot.half_track):g} cm, "
        f"speed limiter: {_limiter_text(robot)}.\n"
        f" * Period: {period:g} s. Arithmetic: {real}."
    )


def _limiter_text(robot: Robot) -> str:
    accel, angular = float(robot.accel_max), float(robot.angular_accel_max)
    if accel <= 0 and angular <= 0:
        return "none"
    return f"{accel:g} cm/s^2, {angular:g} rad/s^2 (0: that axis unlimited)"


def _header(description: str, real: str, max_latency: int) -> str:
    return f"""/* wmr_controller.h: a tuned Shim-Sung pose controller, differential-drive robot.
 *
 * Generated by `wmr-jax export` from a tuned_gains.json; see docs/deploy.md.
{description}
 * Units: cm, s, rad. No heap, no global state: all state is in wmr_controller.
 */
#ifndef WMR_CONTROLLER_H
#define WMR_CONTROLLER_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {{
#endif

/* The largest latency wmr_init accepts, in control periods. */
#define WMR_MAX_LATENCY {max_latency}

typedef {real} wmr_real;

typedef struct wmr_controller wmr_controller;

/* A pose as the estimator carries it: position cm, heading (cos, sin), unwrapped theta rad. */
typedef struct wmr_pose {{
    wmr_real x, y, cos_h, sin_h, theta;
}} wmr_pose;

/* The controller's whole state; fixed size (wmr_size()). Its fields are the
   generated code's business: set them with wmr_init only. */
struct wmr_controller {{
    wmr_real ref[3];              /* goal [x cm, y cm, theta rad] */
    wmr_real ref_cos, ref_sin;    /* cos and sin of the goal's heading */
    wmr_pose est;                 /* the pose estimate at the last sample */
    wmr_real cov[6];              /* EKF covariance P00 P01 P02 P11 P12 P22 */
    wmr_real sent[WMR_MAX_LATENCY + 1][2];  /* ring of the commands sent, v cm/s, w rad/s */
    wmr_real held[2];             /* the speed limiter's last output */
    int latency;                  /* periods between sending a command and its effect */
    int oldest;                   /* ring index of the oldest command */
    int started;                  /* 0 until the first wmr_step */
}};

/* sizeof(wmr_controller), for hosts that allocate it through an FFI. */
size_t wmr_size(void);

/* The control period the controller was tuned for, s: call wmr_step once per period. */
double wmr_period(void);

/* Start a run toward the goal ref = [x cm, y cm, theta rad]. latency: the periods
   between sending a command and its taking effect (0, 1, 2, ...); a latency below
   0 is taken as 0, one above WMR_MAX_LATENCY as WMR_MAX_LATENCY. */
void wmr_init(wmr_controller *c, const double ref[3], int latency);

/* One sample: measured = the pose [x cm, y cm, theta rad] measured now; writes the
   command to send now, command = [v cm/s, w rad/s]. */
void wmr_step(wmr_controller *c, const double measured[3], double command[2]);

#ifdef __cplusplus
}}
#endif

#endif /* WMR_CONTROLLER_H */
"""


def _step(c: _Emitter, estimator: Any, compensate: bool) -> str:
    """``wmr_init`` and ``wmr_step``: the order of ``sensing.loop.disturbed_run``."""
    if estimator is None:
        feedback = """    wmr_sin_cos(mth, &cos_m, &sin_m);
    wmr_law(c, mx, my, cos_m, sin_m, cmd);"""
    else:
        roll = ""
        if compensate:
            roll = """
    /* Compensation: roll the estimate over the commands still in flight. */
    for (j = 1; j <= c->latency; ++j) {
        const wmr_real *flight = c->sent[(c->oldest + j) % ring];
        law_input = wmr_move(law_input, wmr_arc_of(flight[0], flight[1]));
    }"""
        feedback = f"""    if (!c->started) {{
        /* The estimate starts from the first measurement (docs/model.md §9). */
        wmr_sin_cos(mth, &c->est.cos_h, &c->est.sin_h);
        c->est.x = mx;
        c->est.y = my;
        c->est.theta = mth;
        wmr_start(c);
    }} else {{
        /* Predict over the period just ended with the command that acted in it. */
        const wmr_real *acted = c->sent[c->oldest];
        wmr_pose predicted = wmr_move(c->est, wmr_arc_of(acted[0], acted[1]));
        wmr_correct(c, predicted, acted, mx, my, mth);
    }}
    law_input = c->est;{roll}
    wmr_law(c, law_input.x, law_input.y, law_input.cos_h, law_input.sin_h, cmd);"""
    decl = "    wmr_real cos_m, sin_m;" if estimator is None else "    wmr_pose law_input;"
    if estimator is not None and compensate:
        decl += "\n    int j;"
    return f"""size_t wmr_size(void) {{ return sizeof(wmr_controller); }}

double wmr_period(void) {{ return {float(c.period)!r}; }}

void wmr_init(wmr_controller *c, const double ref[3], int latency)
{{
    int i;
    c->ref[0] = (wmr_real)ref[0];
    c->ref[1] = (wmr_real)ref[1];
    c->ref[2] = (wmr_real)ref[2];
    wmr_sin_cos(c->ref[2], &c->ref_cos, &c->ref_sin);
    c->est.x = c->est.y = c->est.theta = c->est.sin_h = {c(0)};
    c->est.cos_h = {c(1)};
    for (i = 0; i < 6; ++i)
        c->cov[i] = {c(0)};
    for (i = 0; i <= WMR_MAX_LATENCY; ++i)
        c->sent[i][0] = c->sent[i][1] = {c(0)};
    c->held[0] = c->held[1] = {c(0)};
    c->latency = latency < 0 ? 0 : (latency > WMR_MAX_LATENCY ? WMR_MAX_LATENCY : latency);
    c->oldest = 0;
    c->started = 0;
}}

void wmr_step(wmr_controller *c, const double measured[3], double command[2])
{{
    wmr_real mx = (wmr_real)measured[0], my = (wmr_real)measured[1];
    wmr_real mth = (wmr_real)measured[2];
    wmr_real cmd[2];
    int ring = c->latency + 1;
{decl}
{feedback}
    wmr_limit(c, cmd);
    /* The new command replaces the oldest: it acts latency periods from now. */
    c->sent[c->oldest][0] = cmd[0];
    c->sent[c->oldest][1] = cmd[1];
    c->oldest = (c->oldest + 1) % ring;
    c->started = 1;
    command[0] = (double)cmd[0];
    command[1] = (double)cmd[1];
}}
"""


def c_sources(
    loop: ClosedLoop,
    *,
    real: str = "double",
    period: float = DEFAULT_DT,
    max_latency: int = MAX_LATENCY,
) -> CSources:
    """Return the C header and source of ``loop`` with its constants baked in.

    Args:
        loop: a ``ClosedLoop`` of the Shim–Sung law (``Gains``) or its gain
            schedule (``ScheduleParams``), raw feedback or an estimator
            (``load_tuned`` returns one). Its ``robot`` (``Robot()`` where
            ``None``) gives the wheel-speed limit, the speed limiter and the
            estimator's model.
        real: ``"double"`` or ``"float"``, the arithmetic of the step.
        period: the control period, s.
        max_latency: the largest latency the controller holds, periods.

    Raises:
        ValueError: for anything but one unbatched Shim–Sung loop, naming it.
    """
    if not isinstance(loop, ClosedLoop):
        raise ValueError(f"loop is a {type(loop).__name__}; allowed: a wmr_jax.ClosedLoop")
    if real not in REALS:
        raise ValueError(f"real = {real!r} is not allowed; allowed: {' or '.join(REALS)}")
    if not (isinstance(period, (int, float)) and math.isfinite(period) and period > 0):
        raise ValueError(f"period = {period!r} is not allowed; allowed: a finite number > 0 s")
    if not (isinstance(max_latency, int) and 0 <= max_latency <= 1000):
        raise ValueError(f"max_latency = {max_latency!r} is not allowed; allowed: 0 to 1000")
    params = loop.params
    controller = getattr(loop.controller, "name", loop.controller)
    laws = {
        SHIM_SUNG.name: (SHIM_SUNG, Gains),
        SCHEDULE.name: (SCHEDULE, ScheduleParams),
        AICARDI.name: (AICARDI, AicardiGains),
        ASTOLFI.name: (ASTOLFI, AstolfiGains),
    }
    if controller not in laws or not isinstance(params, laws[controller][1]):
        allowed = ", ".join(f"{name!r} with {cls.__name__}" for name, (_, cls) in laws.items())
        raise ValueError(
            f"loop.controller = {controller!r} with {type(params).__name__} is not allowed; "
            f"allowed: {allowed}"
        )
    laws[controller][0].validate(params)
    polar = controller in (AICARDI.name, ASTOLFI.name)
    estimator, estimate = resolve_estimator(loop.estimator)
    robot = Robot() if loop.robot is None else loop.robot
    c = _Emitter(real, float(period))
    law = _polar_law(c, controller, params) if polar else _law(c, params)
    pieces = [_kernels(c, polar), _arc(c) if estimator is not None else ""]
    if polar or estimator is not None:
        pieces.append(_wrap(c))
    pieces.append(law)
    pieces.append(_limits(c, robot))
    compensate = False
    if estimator is not None:
        if isinstance(estimate, EKFParams):
            pieces.append(_ekf(c, estimate, robot))
        else:
            pieces.append(_observer(c, estimate))
        compensate = bool(estimate.compensate)
    pieces.append(_step(c, estimator, compensate))
    description = _describe(loop, estimator, robot, real, float(period))
    source = (
        f"/* wmr_controller.c: generated by `wmr-jax export`; see wmr_controller.h. */\n"
        f'#include <math.h>\n#include <stddef.h>\n\n#include "{HEADER}"\n\n'
        + "\n".join(p for p in pieces if p)
    )
    return CSources(
        header=_header(description, real, max_latency),
        source=source,
        real=real,
        period=float(period),
        max_latency=max_latency,
    )


def write_sources(folder: Any, sources: CSources, loop: ClosedLoop) -> list[Any]:
    """Write ``wmr_controller.h``, ``.c`` and ``wmr_controller.json`` (the loop) to ``folder``.

    The JSON holds the ``tuned_gains.json`` content the C was generated
    from, its period, arithmetic and latency bound: what ``wmr-jax evaluate
    --c`` needs to run the same loop around it.
    """
    from pathlib import Path

    from wmr_jax._src.io import atomic_write_json
    from wmr_jax._src.tuning.saved import tuned_json

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in ((HEADER, sources.header), (SOURCE, sources.source)):
        (folder / name).write_text(text, encoding="utf-8")
        written.append(folder / name)
    if isinstance(loop.params, (Gains, ScheduleParams)):
        gains, baseline = tuned_json(loop), None
    else:  # a baseline law, which a tuned_gains.json cannot hold
        gains, baseline = None, _baseline_json(loop)
    meta = {
        "gains": gains,
        "baseline": baseline,
        "period_s": sources.period,
        "real": sources.real,
        "max_latency": sources.max_latency,
    }
    written.append(atomic_write_json(folder / "wmr_controller.json", meta))
    return written


def _baseline_json(loop: ClosedLoop) -> dict[str, Any]:
    """A baseline loop as ``wmr_controller.json`` holds it: law, gains, estimator, robot."""
    from wmr_jax._src.robots import robot_json
    from wmr_jax._src.tuning.estimation import estimator_json

    params = loop.params
    return {
        "controller": getattr(loop.controller, "name", loop.controller),
        "params": {
            f.name: _field_json(getattr(params, f.name)) for f in dataclasses.fields(params)
        },
        "estimator": estimator_json(loop.estimator),
        "robot": None if loop.robot is None else robot_json(loop.robot),
    }


def _field_json(value: Any) -> Any:
    return value if isinstance(value, bool) else float(np.asarray(value))
