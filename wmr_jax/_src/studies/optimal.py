"""The time-optimal yardstick for arrival times (docs/model.md §8), vectorised over references."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from wmr_jax._src.checks import as_poses, check_dt, check_number, real_array, require_concrete
from wmr_jax._src.model.params import Robot, validate_robot
from wmr_jax._src.sim.metrics import DEFAULT_TOL_R
from wmr_jax._src.sim.rollout import DEFAULT_DT

_ROUNDING = 1e-9  # a whole number of periods up to rounding is not one more


class TimeBounds(NamedTuple):
    """Per-reference yardsticks of docs/model.md §8, each ``(N,)`` in s.

    Attributes:
        turn_drive_turn: turn in place, drive straight at ``V_max``, turn in
            place (best of forward and backward), rounded up to whole samples.
        lower_bound: ``⌈(r − tol_r) / (V_max dt)⌉ dt``.
    """

    turn_drive_turn: np.ndarray
    lower_bound: np.ndarray


def _folded_magnitude(angle: np.ndarray) -> np.ndarray:
    """``|fold(wrap(a))|``: the turn to a heading or its opposite, in ``[0, π/2]``, rad."""
    wrapped = np.abs(np.mod(angle + math.pi, 2 * math.pi) - math.pi)
    return np.minimum(wrapped, math.pi - wrapped)


def _ceil_samples(seconds: np.ndarray, dt: float) -> np.ndarray:
    # A positive time takes one sample at least (the slack would round a time
    # below 1e-9 periods down to 0); zero takes none.
    samples = np.ceil(seconds / dt - _ROUNDING)
    return np.where(seconds > 0, np.maximum(samples, 1.0), 0.0) * dt


def _per_reference(robot: Robot, name: str, refs: np.ndarray) -> np.ndarray:
    """A robot field as one value, or one per reference (``(N,)`` against ``(N, 3)``)."""
    value = np.asarray(getattr(robot, name), dtype=float)
    n = refs.shape[0] if refs.ndim == 2 else 1
    if value.ndim and value.shape[0] not in (1, n):
        raise ValueError(
            f"robot.{name} has {value.shape[0]} values; allowed: one, or one per reference ({n})"
        )
    return value.reshape(()) if value.size == 1 else value


def time_bounds(
    refs: Any,
    *,
    robot: Robot | None = None,
    dt: float = DEFAULT_DT,
    tol_r: float = DEFAULT_TOL_R,
) -> TimeBounds:
    """The turn–drive–turn time and the lower bound of each reference (docs/model.md §8).

    Args:
        refs: ``(N, 3)`` or ``(3,)`` reference poses ``[x cm, y cm, θ rad]``,
            the robot starting at ``(0, 0, 0)``.
        robot: gives ``V_max`` (cm/s) and ``L`` (cm); default ``Robot()``.
        dt: control period, s.
        tol_r: the arrival distance tolerance of docs/model.md §6, cm.

    Returns:
        ``TimeBounds`` of arrays with the leading shape of ``refs``, s.
    """
    require_concrete("time_bounds", refs, robot, dt, tol_r)
    robot = validate_robot(Robot() if robot is None else robot)
    as_poses("refs", refs, batch=None)  # shape, finiteness and the heading's range
    # The references as given, in float64: in float32 a heading of π is above π.
    refs = np.asarray(refs, dtype=np.float64)
    dt = float(check_dt(dt))
    tol_r = check_number("tol_r", tol_r, unit="cm")
    v_max, half_track = (_per_reference(robot, name, refs) for name in ("v_max", "half_track"))
    omega_max = v_max / half_track  # rad/s, spinning with the wheels at ±V_max
    x, y, theta = refs[..., 0], refs[..., 1], refs[..., 2]
    r = np.hypot(x, y)
    bearing = np.where(r > 0, np.arctan2(y, x), 0.0)
    turns = _folded_magnitude(bearing) + _folded_magnitude(theta - bearing)
    tdt = turns / omega_max + r / v_max
    lower = np.maximum(r - tol_r, 0.0) / v_max
    return TimeBounds(_ceil_samples(tdt, dt), _ceil_samples(lower, dt))


def bound_ratios(mean_arrival: float, bounds: TimeBounds) -> dict[str, float]:
    """A mean arrival time as ratios to the mean of each yardstick.

    Args:
        mean_arrival: a controller's mean arrival time on the references, s.
        bounds: ``time_bounds`` of the same references.

    Returns:
        ``{"turn_drive_turn_s", "lower_bound_s", "vs_turn_drive_turn", "vs_lower_bound"}``.
    """
    if not isinstance(bounds, TimeBounds):
        raise ValueError(
            f"bounds is a {type(bounds).__name__}; allowed: a TimeBounds (from time_bounds)"
        )
    allowed = "a time > 0 s, or inf"  # inf (none arrived) gives inf ratios
    value = real_array("mean_arrival", mean_arrival, allowed)
    if value.shape != () or not value > 0:
        raise ValueError(f"mean_arrival = {mean_arrival!r} is not allowed; allowed: {allowed}")
    mean_arrival = float(value)
    tdt = float(np.mean(bounds.turn_drive_turn))
    lower = float(np.mean(bounds.lower_bound))
    if not (tdt > 0 and lower > 0):
        raise ValueError(
            f"bounds of {tdt:.4g} / {lower:.4g} s are not allowed as yardsticks; allowed: "
            "references beyond tol_r (bounds > 0)"
        )
    return {
        "turn_drive_turn_s": tdt,
        "lower_bound_s": lower,
        "vs_turn_drive_turn": mean_arrival / tdt,
        "vs_lower_bound": mean_arrival / lower,
    }
