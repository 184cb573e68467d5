"""UMBmark (Borenstein & Feng 1996): the square-path correction, the baseline of ``identify``.

The robot drives a square of side ``L`` clockwise and counter-clockwise
several times; the tracker measures where each run ends against where it
started. Two systematic errors explain the end points: unequal wheel
diameters (``E_d = D_R / D_L``, which curves every straight side) and a
wheelbase other than believed (``E_b = b_actual / b_nominal``, which makes
every quarter turn too short or too long). From the centres of gravity of
the end errors of the two directions, ``x_cw`` and ``x_ccw``:

``α = (x_cw + x_ccw) / (−4 L)``, ``β = (x_cw − x_ccw) / (−4 L)`` (rad),
``R = (L / 2) / sin(β / 2)``, ``E_d = (R + b/2) / (R − b/2)``,
``E_b = (π/2) / (π/2 − α)``.

UMBmark corrects the ratio of the wheels and the wheelbase; the mean wheel
scale is outside it (taken as 1: it is calibrated separately by driving a
measured straight line).
"""

from __future__ import annotations

import numpy as np


def square_ends(poses: np.ndarray, starts: list[int], ends: list[int]) -> np.ndarray:
    """End errors ``(runs, 2)`` of square runs, in the frame of each run's start pose."""
    out = []
    for a, b in zip(starts, ends, strict=True):
        x0, y0, t0 = poses[a]
        d = (poses[b, 0] - x0) + 1j * (poses[b, 1] - y0)
        d = d * np.exp(-1j * t0)
        out.append([d.real, d.imag])
    return np.asarray(out)


def umbmark(
    cw_ends: np.ndarray, ccw_ends: np.ndarray, side: float, half_track: float
) -> tuple[float, float, float]:
    """The corrected ``(scale left, scale right, half-track)`` from the runs' end errors.

    ``cw_ends``, ``ccw_ends``: ``(runs, 2)`` end errors ``(x, y)`` in each run's
    start frame, x along the first side (cm).
    """
    x_cw, x_ccw = float(np.mean(cw_ends[:, 0])), float(np.mean(ccw_ends[:, 0]))
    alpha = (x_cw + x_ccw) / (-4 * side)
    beta = (x_cw - x_ccw) / (-4 * side)
    b = 2 * half_track
    if abs(beta) < 1e-12:
        e_d = 1.0
    else:
        radius = (side / 2) / np.sin(beta / 2)
        e_d = (radius + b / 2) / (radius - b / 2)
    e_b = (np.pi / 2) / (np.pi / 2 - alpha)
    left, right = 2 / (1 + e_d), 2 * e_d / (1 + e_d)
    return left, right, e_b * half_track
