"""The C of the estimators: the observer's and the extended Kalman filter's update.

Each mirrors ``sensing.estimators`` operation for operation, with the
estimator's constants baked in (``codegen`` assembles the pieces).
"""

from __future__ import annotations

from wmr_jax._src.export import c_law
from wmr_jax._src.model.params import Robot
from wmr_jax._src.sim.sensing.estimators import (
    EKFParams,
    ObserverParams,
    observer_radii,
)


def observer(c: c_law.Emitter, params: ObserverParams) -> str:
    """The observer's correction (``estimators._observer_update``)."""
    parts, gains = [], {}
    for name in ("position", "heading"):
        table = params.position if name == "position" else params.heading
        if isinstance(table, tuple):
            values = tuple(c_law.scalar(v, f"estimator.{name}") for v in table)
            parts.append(
                c_law.table_code(c, f"wmr_gain_{name}", values, observer_radii(len(values)), "r")
            )
            gains[name] = f"wmr_gain_{name}(distance)"
        else:
            gains[name] = c(c_law.scalar(table, f"estimator.{name}"))
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


def ekf(c: c_law.Emitter, params: EKFParams, robot: Robot) -> str:
    """The extended Kalman filter's prediction and correction (``estimators._ekf_update``)."""
    dtype = c.dtype.type
    sxy = dtype(c_law.scalar(params.sigma_xy, "estimator.sigma_xy"))
    sth = dtype(c_law.scalar(params.sigma_theta, "estimator.sigma_theta"))
    we = dtype(c_law.scalar(params.wheel_error, "estimator.wheel_error"))
    half_track = dtype(c_law.scalar(robot.half_track, "robot.half_track"))
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
