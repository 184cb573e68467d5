"""The NumPy batch baseline of ``wmr-jax bench``: the ideal loop as a user would vectorise it.

The law with angles and ``atan2`` as docs/model.md §3 states it, the exact
arc of docs/model.md §4, arrays over the batch and one Python iteration per
control period; no JAX. ``bench`` times it beside ``final_poses``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np


def numpy_final_poses(
    refs: Any,
    gains: Any = None,
    *,
    init: Sequence[float] = (0.0, 0.0, 0.0),
    dt: float = 0.033,
    steps: int = 150,
) -> np.ndarray:
    """Return the final poses of the ideal closed loop, vectorised with NumPy.

    The arithmetic is in the dtype of ``refs`` (float32 or float64).

    Args:
        refs: ``(N, 3)`` reference poses ``[x cm, y cm, θ rad]``.
        gains: ``wmr_jax.Gains`` with scalar fields; default ``Gains()``.
        init: ``(3,)`` initial pose shared by every run, ``[x cm, y cm, θ rad]``.
        dt: control period, s.
        steps: number of control periods.

    Returns:
        ``(N, 3)`` final poses ``[x cm, y cm, θ rad]``, dtype of ``refs``.
    """
    import jax

    from wmr_jax._src.checks import MAX_STEPS, as_poses, check_dt, check_int, require_unbatched
    from wmr_jax._src.model.params import Gains, validate_gains

    # final_poses' checks in the refs' own precision; the caller's values are used.
    wide = np.dtype(getattr(refs, "dtype", np.float64)) != np.float32  # lists are float64
    with jax.enable_x64(bool(wide)):
        as_poses("refs", refs, batch=True)
        as_poses("init", init, batch=False)
    init = np.asarray(init, dtype=np.float64)
    dt = check_dt(dt)
    steps = check_int("steps", steps, 1, MAX_STEPS)
    if gains is not None:
        if not isinstance(gains, Gains):
            raise ValueError(f"gains = {gains!r} is not allowed; allowed: a wmr_jax.Gains")
        validate_gains(gains)
        require_unbatched(gains, "gains", "a number per field (one gain set for the batch)")
    refs = np.asarray(refs)
    if refs.dtype not in (np.float32, np.float64):
        refs = refs.astype(np.float64)
    dtype = refs.dtype.type
    g = Gains() if gains is None else gains
    law = _NumpyLaw(dtype, g)
    one, h = dtype(1), dtype(dt)
    n = refs.shape[0]
    x = np.full(n, init[0], dtype)
    y = np.full(n, init[1], dtype)
    th = np.full(n, init[2], dtype)
    for _ in range(steps):
        v, omega = law(refs, x, y, th)
        # Exact arc over dt (docs/model.md §4), sinc by its series near 0.
        half = dtype(0.5) * omega * h
        small = np.abs(half) < 1e-3
        sinc = np.where(
            small,
            one - half * half / dtype(6),
            np.sin(half) / np.where(small, one, half),
        )
        chord = v * h * sinc
        heading = th + half
        x = x + chord * np.cos(heading)
        y = y + chord * np.sin(heading)
        th = th + omega * h
    return np.stack([x, y, th], axis=-1)


class _NumpyLaw:
    """The Shim–Sung law (paper Eqs. 3–8) on NumPy arrays of one dtype."""

    def __init__(self, dtype: Any, g: Any) -> None:
        self.dtype = dtype
        self.kr, self.k_theta, self.phi_m = dtype(g.kr), dtype(g.k_theta), dtype(g.phi_m)
        self.r_m, self.r_a, self.r_e = dtype(g.r_m), dtype(g.r_a), dtype(g.r_e)
        self.alpha = dtype(g.alpha)
        self.pi, self.half_pi = dtype(math.pi), dtype(math.pi / 2)

    def fold(self, a: np.ndarray) -> np.ndarray:
        pi, half_pi = self.pi, self.half_pi
        return np.where(a > half_pi, a - pi, np.where(a < -half_pi, a + pi, a))

    def __call__(self, refs: np.ndarray, x, y, th) -> tuple[np.ndarray, np.ndarray]:
        """Return the commands ``(v cm/s, ω rad/s)`` at poses ``(x, y, th)``."""
        dtype, pi, half_pi = self.dtype, self.pi, self.half_pi
        one, zero = dtype(1), dtype(0)
        # Error coordinates (Eq. 3, 4).
        cos_c, sin_c = np.cos(th), np.sin(th)
        dx, dy = refs[:, 0] - x, refs[:, 1] - y
        e_x = cos_c * dx + sin_c * dy
        e_y = cos_c * dy - sin_c * dx
        r = np.hypot(e_x, e_y)
        phi = np.arctan2(e_y, e_x)  # atan2(0, 0) = 0: the model's choice at r_e = 0
        theta_e = np.mod(refs[:, 2] - th + pi, 2 * pi) - pi
        # The law (Eq. 6–8), regions tested in the order of docs/model.md §3.
        r_bar = np.minimum(r * (half_pi / self.r_m), half_pi)
        abs_phi = np.abs(phi)
        d = np.where(abs_phi <= self.phi_m, one, np.where(abs_phi > pi - self.phi_m, -one, zero))
        phi_bar = self.fold(phi)
        sin_phi_bar, cos_phi_bar = np.sin(phi_bar), np.cos(phi_bar)
        sin_theta_bar = np.sin(self.fold(theta_e))
        sgn_t = np.where(sin_theta_bar > 0, one, -one)
        sgn_sum = np.where(sin_theta_bar + sin_phi_bar > 0, one, -one)
        eps_1 = dtype(0.5) - self.alpha * sgn_t * sgn_sum
        eps = np.where(
            r <= self.r_e, zero, np.where(d == 0, one, np.where(r < self.r_a, eps_1, one))
        )
        v = self.kr * d * np.sin(r_bar) * cos_phi_bar
        omega = self.k_theta * (eps * sin_phi_bar + (one - eps) * sin_theta_bar)
        return v, omega
