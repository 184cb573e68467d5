"""The C of the control law and the robot's motion: literals, kernels, the laws, the limits.

Each function returns the C text of one piece of ``wmr_controller.c``, with
the tuned constants baked in and the arithmetic in the order the JAX code
evaluates it (``codegen`` assembles the pieces).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from wmr_jax._src.model import dynamics
from wmr_jax._src.model.controllers.schedule import ScheduleParams, knot_radii
from wmr_jax._src.model.params import Robot


class Emitter:
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


def horner(c: Emitter, var: str, coefficients: tuple[float, ...]) -> str:
    """``Σ c_k var^k`` by Horner's rule, as ``dynamics._polynomial`` evaluates it."""
    expr = c(coefficients[-1])
    for k in coefficients[-2::-1]:
        expr = f"({expr} * {var} + {c(k)})"
    return expr


def table_code(c: Emitter, name: str, values: tuple, radii: np.ndarray, var: str) -> str:
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


def scalar(value: Any, name: str) -> float:
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


def law(c: Emitter, params: Any) -> str:
    """The law: ``wmr_law(c, x, y, cos θ, sin θ, command)`` (docs/model.md §2–3)."""
    schedule = isinstance(params, ScheduleParams)
    names = ("phi_m", "r_m", "r_a", "r_e", "alpha")
    g = {name: scalar(getattr(params, name), f"params.{name}") for name in names}
    dtype = c.dtype.type
    cos_m = dtype(np.cos(dtype(g["phi_m"])))
    r_scale = dtype(np.pi / 2) / dtype(g["r_m"])
    parts = []
    if schedule:
        knots = len(params.kr)
        radii = knot_radii(knots)
        for table in ("kr", "k_theta", "k_turn"):
            values = tuple(scalar(v, f"params.{table}") for v in getattr(params, table))
            parts.append(table_code(c, f"wmr_table_{table}", values, radii, "r"))
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
        v_max = scalar(params.v_max, "params.v_max")
        half_track = scalar(params.half_track, "params.half_track")
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
        kr, k_theta = scalar(params.kr, "params.kr"), scalar(params.k_theta, "params.k_theta")
        body += f"""    out[0] = {c(kr)} * d * sin_r_bar * cos_phi_bar;
    out[1] = {c(k_theta)} * (eps * sin_phi_bar + ({c(1)} - eps) * sin_theta_bar);
}}
"""
    return "\n".join(parts) + body


def polar_law(c: Emitter, name: str, params: Any) -> str:
    """A baseline polar law as ``wmr_law`` (``controllers/aicardi.py``, ``astolfi.py``).

    ``ρ``, ``α`` and ``θ_A`` from the same error coordinates as the Shim–Sung
    law, with ``atan2``; within ``goal_floor`` the robot only turns.
    """
    from wmr_jax._src.model.controllers import polar

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
        gamma, k, h = (scalar(getattr(params, f), f"params.{f}") for f in ("gamma", "k", "h"))
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
            scalar(getattr(params, f), f"params.{f}") for f in ("k_rho", "k_alpha", "k_beta")
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


def kernels(c: Emitter, polar: bool) -> str:
    """``sin_cos`` and the helpers the law uses (``sin_small`` and ``Sgn`` for Shim–Sung)."""
    p1, p2, p3 = dynamics._PIO2[c.dtype]
    sin_poly = horner(c, "z", dynamics._SIN[c.dtype])
    cos_poly = horner(c, "z", dynamics._COS[c.dtype])
    taylor = horner(c, "z", dynamics._SIN_TAYLOR[c.dtype])
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


def arc(c: Emitter) -> str:
    """The exact arc of the ideal robot (docs/model.md §4): ``motion.ArcMove``, ``ideal_move``."""
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
    /* One Newton step towards |heading| = 1 (motion.ideal_move). */
    wmr_real newton = {c(1.5)} - {c(0.5)} * (h_c * h_c + h_s * h_s);
    out.x = p.x + a.chord * mid_c;
    out.y = p.y + a.chord * mid_s;
    out.cos_h = h_c * newton;
    out.sin_h = h_s * newton;
    out.theta = p.theta + a.rotation;
    return out;
}}
"""


def wrap(c: Emitter) -> str:
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


def limits(c: Emitter, robot: Robot) -> str:
    """The speed limiter (docs/model.md §4.2.2) and the wheel-speed limit, as ``wmr_limit``."""
    accel = scalar(robot.accel_max, "robot.accel_max")
    angular = scalar(robot.angular_accel_max, "robot.angular_accel_max")
    v_max = scalar(robot.v_max, "robot.v_max")
    half_track = scalar(robot.half_track, "robot.half_track")
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
